"""The cascade matcher (loopclosure.cascade): prefilter -> verifiers -> fused score."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data.errors import UserError
from data.sim import place_dataset
from evaluation.retrieval import best_fscore, bullseye, roc_auc
from loopclosure import matcher_registry
from loopclosure.cascade import (
    CASCADE_LOGISTIC,
    CascadeConfig,
    CascadeMatcher,
    CascadeStack,
    calibrate_logistic,
    candidate_pairs,
)
from loopclosure.fusion import LogisticFusion
from loopclosure.matchers import MATCHER_NAMES, get_matcher
from loopclosure.place_config import DEFAULT_LOGISTIC, PlaceDatabaseConfig
from loopclosure.polygon import Polygon, polygon_from_scan
from tests.helpers import shared_file

# verify_all_up_to=0: the top K only, even in these tiny databases.
QUICK = dict(prefilter=("fft", "ring"), verifiers=("integral",), top_k=20, verify_all_up_to=0)


@pytest.fixture(scope="module")
def box() -> tuple[list[Polygon], np.ndarray]:
    """A small simulated Box subset: 6 places x 8 scans (2n = 16 nearest per query)."""
    ds = place_dataset("box", places=6, scans_per_place=8, seed=5)
    return [polygon_from_scan(s) for _, s in ds], np.array([label for label, _ in ds])


def all_pairs(matcher: CascadeMatcher, polygons: list[Polygon]) -> np.ndarray:
    return matcher.pairwise([matcher.describe(p) for p in polygons])


def test_default_configs_are_consistent() -> None:
    cfg = CascadeConfig()
    assert sorted(cfg.stages) == sorted(CASCADE_LOGISTIC.names)
    assert sorted(PlaceDatabaseConfig().stages) == sorted(DEFAULT_LOGISTIC.names)
    assert cfg.top_k > 2 * 21  # re-ranking must reach beyond the Bull's eye window


def test_cascade_is_never_worse_than_its_prefilter() -> None:
    ds = place_dataset("box", places=3, scans_per_place=6, seed=5)
    polys = [polygon_from_scan(s) for _, s in ds]
    labels = np.array([label for label, _ in ds])
    # Default stages and fusion; K = 14 > 2n = 12 so re-ranking reaches the Bull's eye.
    cascade = CascadeMatcher(top_k=14, scale_pairs=16)
    d = all_pairs(cascade, polys)
    prefilter = all_pairs(CascadeMatcher(fusion="prefilter", verifiers=()), polys)
    assert np.isfinite(d).all() and (d >= 0).all()
    assert bullseye(d, labels) >= bullseye(prefilter, labels)
    assert roc_auc(d, labels) >= roc_auc(prefilter, labels) - 1e-9
    assert best_fscore(d, labels) >= best_fscore(prefilter, labels) - 1e-9


def test_verified_entries_come_first_by_score_then_prefilter_order(box) -> None:
    polys, _ = box
    m = CascadeMatcher(fusion="rank", **QUICK)
    descs = [m.describe(p) for p in polys]
    stacked = m.stack(descs)
    q = descs[3]
    d = m.distances(q, stacked)
    c = stacked.database.candidates(q)
    verified = np.zeros(len(d), bool)
    verified[c.indices] = True
    assert verified.sum() == 20
    assert d[verified].max() <= 1.0 < d[~verified].min()
    # Verified: decreasing fused score, ties by prefilter rank.
    by_d = np.argsort(d[c.indices], kind="stable")
    np.testing.assert_array_equal(by_d, c.order())
    # Others keep the prefilter order.
    p, _ = stacked.database.prefilter_distances(q)
    rest = np.flatnonzero(~verified)
    assert np.all(np.diff(p[rest][np.argsort(d[rest], kind="stable")]) >= -1e-6)
    assert m.distance(q, descs[5]) == m.distances(q, m.stack([descs[5]]))[0]


@lru_cache(maxsize=1)
def _small_stack() -> tuple[CascadeMatcher, list[Polygon], CascadeStack]:
    ds = place_dataset("box", places=3, scans_per_place=4, seed=2)
    polys = [polygon_from_scan(s) for _, s in ds]
    m = CascadeMatcher(fusion="rank", **QUICK)
    return m, polys, m.stack([m.describe(p) for p in polys])


@settings(max_examples=10, deadline=None)
@given(st.floats(-np.pi, np.pi))
def test_cascade_distances_are_rotation_invariant(angle: float) -> None:
    m, polys, stacked = _small_stack()
    d0 = m.distances(m.describe(polys[0]), stacked)
    d1 = m.distances(m.describe(polys[0].rotated(angle)), stacked)
    # FFT, ring and integral invariant are exactly rotation invariant up to rounding.
    np.testing.assert_allclose(d1, d0, atol=1e-6)


def test_calibration_gives_probabilities_and_helps(box) -> None:
    polys, labels = box
    cfg = CascadeConfig(**QUICK, fusion="rank")
    model = calibrate_logistic(polys, labels, cfg, top_k=10)
    assert isinstance(model, LogisticFusion)
    assert sorted(model.names) == ["fft", "integral", "ring"]
    assert all(w < 0 for w in model.coefficients)
    dist, same, stages, scales = candidate_pairs(polys, labels, cfg, top_k=10)
    assert dist.shape == (len(polys) * 10, 3) and stages == ("fft", "ring", "integral")
    p = model.score(dist, scales)
    assert np.all((p >= 0) & (p <= 1))
    assert p[same].mean() > 0.5 > p[~same].mean()
    m = CascadeMatcher(CascadeConfig(**QUICK, logistic=model))
    d = all_pairs(m, polys)
    assert np.isfinite(d).all() and (d >= 0).all()
    prefilter = all_pairs(CascadeMatcher(fusion="prefilter", **QUICK), polys)
    assert bullseye(d, labels) >= bullseye(prefilter, labels)


def test_degenerate_polygons_give_finite_distances() -> None:
    shapes = [
        Polygon(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])),
        Polygon(np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 0.01], [0.0, 0.01]])),
        Polygon(np.array([[-3.0, -3.0], [3.0, -3.0], [3.0, 3.0], [-3.0, 3.0]])),
    ]
    m = CascadeMatcher(fusion="rank", **QUICK)
    d = all_pairs(m, shapes)
    assert np.isfinite(d).all() and (d >= 0).all()


def test_cascade_on_mpeg7_beats_its_prefilter() -> None:
    from data.mpeg7 import load_silhouettes

    folder = shared_file("mpeg7-subset")
    sil = load_silhouettes(folder)
    keep = sorted({s.label for s in sil})[:3]
    chosen = [s for s in sil if s.label in keep][::4]  # 3 classes x 5 shapes
    polys = [Polygon(s.contour) for s in chosen]
    labels = np.array([s.label for s in chosen])
    m = CascadeMatcher(scale_invariant=True, top_k=12, scale_pairs=16)
    assert m.config.resolved_fusion == "rank"
    d = all_pairs(m, polys)
    prefilter = all_pairs(CascadeMatcher(scale_invariant=True, fusion="prefilter", verifiers=()),
                          polys)
    assert np.isfinite(d).all()
    assert bullseye(d, labels) >= bullseye(prefilter, labels)


def test_k_is_the_whole_database_when_small_and_config_is_checked() -> None:
    cfg = CascadeConfig(top_k=10, verify_all_up_to=50)
    assert [cfg.k_for(m) for m in (0, 7, 50, 51, 1000)] == [0, 7, 50, 10, 10]
    assert CascadeConfig(top_k=10, verify_all_up_to=0).k_for(5) == 5  # K <= M
    assert CascadeConfig().anchored and not CascadeConfig(scale_invariant=True).anchored
    assert not CascadeConfig(fusion="logistic").anchored
    assert not CascadeConfig(anchor=None).anchored
    assert not CascadeConfig(verifiers=("mrm",), fusion="rank").anchored  # anchor not verified
    assert not CascadeConfig(verifiers=("mrm",), anchor="mrm", fusion="rank").anchored
    with pytest.raises(UserError, match="verify_all_up_to"):
        CascadeConfig(verify_all_up_to=-1)


def test_anchored_cascade_orders_by_the_anchor_with_calibrated_values(box) -> None:
    polys, labels = box
    m = CascadeMatcher(verifiers=("integral", "flirt"), fusion="auto", anchor="flirt",
                       logistic=LogisticFusion(("fft", "ring", "integral", "flirt"),
                                               (-1.0, -1.0, -1.0, -1.0), 0.0))
    descs = [m.describe(p) for p in polys]
    stacked = m.stack(descs)
    flirt = get_matcher("flirt")
    fd = [flirt.describe(p) for p in polys]
    raw = flirt.distances(fd[3], flirt.stack(fd))
    d = m.distances(descs[3], stacked)
    # M = 48 <= verify_all_up_to: every entry is verified, D = 1 - exp(-d_flirt / scale).
    scale = stacked.database.scales["flirt"]
    np.testing.assert_allclose(d, 1.0 - np.exp(-raw / scale), atol=1e-11)
    assert (d < 1.0).all() and (d >= 0).all()
    # The anchor's Bull's eye is reached exactly (the fusion cannot fall below it).
    full = np.array([m.distances(q, stacked) for q in descs])
    flirt_all = flirt.pairwise(fd)
    assert bullseye(full, labels) == bullseye(flirt_all, labels)
    assert roc_auc(full, labels) == pytest.approx(roc_auc(flirt_all, labels), abs=1e-3)


def test_anchored_top_k_keeps_unverified_entries_after_verified_ones(box) -> None:
    polys, _ = box
    m = CascadeMatcher(verifiers=("integral", "flirt"), top_k=10, verify_all_up_to=0,
                       logistic=LogisticFusion(("fft", "ring", "integral", "flirt"),
                                               (-1.0, -1.0, -1.0, -1.0), 0.0))
    descs = [m.describe(p) for p in polys]
    stacked = m.stack(descs)
    d = m.distances(descs[0], stacked)
    verified = d < 1.0
    assert verified.sum() == 10
    assert d[verified].max() < 1.0 < d[~verified].min()


@pytest.mark.slow
def test_cascade_reaches_flirt_on_real_robot_places() -> None:
    """Real scans (Intel lab, 5 places): the default cascade is not below FLIRT."""
    from evaluation.place_datasets import load_dataset

    log = shared_file("carmen-corrected/intel-corrected.log.gz")
    polys, labels, _ = load_dataset(f"robot:{log}", seed=0)
    keep = np.isin(labels, np.unique(labels)[:5])
    idx = np.flatnonzero(keep)[::2]  # about 30 scans: a few seconds of MRM / shape context
    polys, labels = [polys[i] for i in idx], labels[idx]
    cascade = all_pairs(CascadeMatcher(scale_pairs=16), polys)
    flirt = get_matcher("flirt")
    f = flirt.pairwise([flirt.describe(p) for p in polys])
    assert bullseye(cascade, labels) >= bullseye(f, labels)


def test_the_registry_above_the_matchers_builds_the_cascade() -> None:
    assert "cascade" not in MATCHER_NAMES  # the paper's eight only: no cycle back up
    assert matcher_registry.MATCHER_NAMES == (*MATCHER_NAMES, "cascade")
    cascade = matcher_registry.get_matcher("cascade", top_k=5)
    assert isinstance(cascade, CascadeMatcher) and cascade.config.top_k == 5
    assert matcher_registry.matcher_class("mrm") is type(get_matcher("mrm"))
    for lookup in (matcher_registry.matcher_class, get_matcher):
        with pytest.raises(UserError, match="unknown matcher 'nope'"):
            lookup("nope")
    with pytest.raises(UserError, match="CascadeConfig fields"):
        CascadeMatcher(nonsense=1)
