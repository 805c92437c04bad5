"""The cascade matcher (loopclosure.cascade): prefilter -> verifiers -> fused score."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data.sim import place_dataset
from evaluation.retrieval import best_fscore, bullseye, roc_auc
from loopclosure.cascade import (
    CASCADE_LOGISTIC,
    CascadeConfig,
    CascadeMatcher,
    CascadeStack,
    calibrate_logistic,
    candidate_pairs,
)
from loopclosure.fusion import LogisticFusion
from loopclosure.place_database import DEFAULT_LOGISTIC, PlaceDatabaseConfig
from loopclosure.polygon import Polygon, polygon_from_scan
from tests.conftest import shared_file

QUICK = dict(prefilter=("fft", "ring"), verifiers=("integral",), top_k=20)


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
