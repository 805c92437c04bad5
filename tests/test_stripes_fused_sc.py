"""The ``fused-sc`` row: stripe profile verified by shape context (median-normalised sum)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from data.stripe_scanner import ScannerConfig
from evaluation.stripes_benchmark import (
    StripesBenchmarkConfig,
    baseline_distances,
    run_stripes_benchmark,
)
from evaluation.stripes_objects import daily_objects, silhouette_polygon
from loopclosure.stripes import SC_VERIFIERS, fuse
from loopclosure.stripes.fusion import verifier, verifier_options


def test_fused_sc_rule_on_a_hand_checked_row():
    # One query (object 0) against four objects.  Profile: median of [0, 1, 3, 2] is 1.5;
    # shape context: median of [0, 4, 2, 2] is 2.  Normalised and averaged:
    #   object 1: (1/1.5 + 4/2) / 2 = 4/3;  object 2: (3/1.5 + 2/2) / 2 = 3/2;
    #   object 3: (2/1.5 + 2/2) / 2 = 7/6.
    # The profile alone picks object 1, shape context alone objects 2 and 3 (a tie);
    # the fused distance picks object 3, second in both.
    profile = np.array([[0.0, 1.0, 3.0, 2.0]])
    sc = np.array([[0.0, 4.0, 2.0, 2.0]])
    d = fuse([profile, sc])
    np.testing.assert_allclose(d, [[0.0, 4 / 3, 3 / 2, 7 / 6]])
    assert int(np.argmin(d[0, 1:])) + 1 == 3


def test_fused_sc_row_is_the_fusion_of_profile_and_shape_context():
    objs = daily_objects(1, 2, ("apple", "pen"))
    scanner = replace(ScannerConfig(), step=0.004)
    cfg = StripesBenchmarkConfig(seed=1, baselines=("fft",), fused=(), scanner=scanner)
    res = run_stripes_benchmark(objs, cfg)
    assert SC_VERIFIERS == ("shape-context-50",)
    assert res.fused is None and "fused-sc" in res.methods()
    assert set(res.baselines) == {"fft"}  # the verifier is not reported as a baseline
    polys = [silhouette_polygon(s, cfg.scanner, cfg.silhouette_smooth)
             for s in res.scanned.scans]
    sc, _, options = baseline_distances("shape-context-50", polys)
    assert options == {"scale_invariant": True, "n_points": 50, "kernel": "numba"}
    np.testing.assert_allclose(res.fused_sc.distances, fuse([res.profile.distances, sc]))
    assert res.fused_sc.options["verifiers"] == ["shape-context-50"]
    # The preset's matrix is shape context's on 50 points, row by row, to rounding.
    m = verifier("shape-context-50")
    assert m.config.n_points == 50 and m.config.scale_invariant
    descs = [m.describe(p) for p in polys]
    rows = np.stack([m.distances(q, m.stack(descs)) for q in descs])
    np.testing.assert_allclose(sc, rows, rtol=0, atol=1e-12)
    assert res.to_json()["fused_sc"]["top10_counts"][0] == 4
    none = run_stripes_benchmark(objs, StripesBenchmarkConfig(
        seed=1, baselines=(), fused=(), fused_sc=(), scanner=scanner))
    assert none.fused_sc is None and "fused-sc" not in none.methods()


def test_elongation_of_a_rectangle_is_the_log_of_its_side_ratio():
    # Second moments of area of an a x b rectangle: a^3 b / 12 and a b^3 / 12, so
    # 0.5 log(l_max / l_min) = log(a / b), whatever the yaw and the vertex order.
    from benchmarks.stripes_variants import elongation

    a, b = 4.0, 1.0
    rect = np.array([[0, 0], [a, 0], [a, b], [0, b]], float)
    c, s = np.cos(0.7), np.sin(0.7)
    turned = rect @ np.array([[c, -s], [s, c]]).T
    for v in (rect, turned, rect[::-1]):
        assert abs(elongation(v) - np.log(a / b)) < 1e-9


def test_verifier_presets_name_a_matcher_with_options():
    assert verifier_options("shape-context-50") == (
        "shape-context", {"n_points": 50, "kernel": "numba"})
    assert verifier_options("fft") == ("fft", {})
    assert verifier("shape-context").config.n_points == 100
