"""Odometry variance factors per segment and the segment re-check, on hand-made graphs."""

from __future__ import annotations

import numpy as np
import pytest

from data import se2
from evaluation.robustness import aligned_position_error
from slam.optimize import optimize
from slam.pose_graph import PoseGraph
from slam.segment_variance import odometry_segments, segment_factors
from slam.variance_components import _redundancies

STEPS = [np.array([1.0, 0.0, 0.0])] * 3 + [np.array([1.0, 0.0, np.pi / 2])]


def _laps(
    n: int = 300, quiet: float = 0.003, noisy: float = 0.03, stated: float = 0.03,
    every: int = 2, seed: int = 0,
) -> tuple[PoseGraph, np.ndarray]:
    """`n` poses driving laps of a 4 m square (1 m steps); odometry noise `quiet` (m; a
    fifth of it in rad) except on poses 100-199 (`noisy`), stated as `stated`; a loop
    (noise 0.01 m) from every `every`-th pose to the pose one lap (16 poses) back."""
    rng = np.random.default_rng(seed)
    truth = [np.zeros(3)]
    while len(truth) < n:
        for s in STEPS:
            truth.append(se2.compose(truth[-1], s))
    truth = np.array(truth[:n])
    graph = PoseGraph(dim=2)
    info = np.diag([stated**-2] * 2 + [(0.2 * stated) ** -2])
    odo = [np.zeros(3)]
    for k in range(n):
        if k:
            sigma = noisy if 100 <= k < 200 else quiet
            meas = se2.between(truth[k - 1], truth[k]) + rng.normal(0, sigma, 3) * [1, 1, 0.2]
            odo.append(se2.compose(odo[-1], meas))
            graph.add_odometry(k - 1, k, meas, info)
        graph.add_pose(k, odo[-1])
    loop_info = np.diag([0.01**-2] * 2 + [0.002**-2])
    for k in range(16, n, every):
        meas = se2.between(truth[k - 16], truth[k]) + rng.normal(0, 0.01, 3) * [1, 1, 0.2]
        graph.add_loop(k - 16, k, meas, loop_info)
    return graph, truth


def _solved(graph: PoseGraph):
    return graph.gtsam_values(optimize(graph, "none", init="odometry").poses)


def test_segments_are_runs_of_consecutive_poses() -> None:
    graph, _ = _laps(n=250)
    segment = odometry_segments(graph)
    # Odometry k -> k+1 belongs to the segment of pose k+1.
    np.testing.assert_array_equal(segment, np.arange(1, 250) // 100)


def test_the_noisy_segment_gets_the_larger_factor() -> None:
    # Stated sigma 0.03 everywhere; actual 0.003 (factor 0.01) outside poses 100-199 and
    # 0.03 (factor 1) inside, so the middle segment's factor is near 1, the others small.
    graph, _ = _laps()
    values = _solved(graph)
    f = segment_factors(graph, values, np.ones(len(graph.loops)))
    assert f.factors[1] > 0.5
    assert f.factors[0] < 0.1 and f.factors[2] < 0.1
    assert f.factors[0] < f.pooled < f.factors[1]
    # At the stated weights (one Helmert step) the Hutchinson redundancies add up to the
    # odometry's exact redundancy (within the estimate's noise): m - n less the loops'.
    f = segment_factors(graph, values, np.ones(len(graph.loops)), iterations=1)
    groups = np.array([0] + [1] * len(graph.odometry) + [2] * len(graph.loops))
    factors, _ = graph.factor_graph()
    exact = _redundancies(factors, values, groups, 3)[1]
    assert f.redundancy.sum() == pytest.approx(exact, rel=0.05)


def test_factors_are_capped_at_one() -> None:
    # Odometry stated ten times tighter than it is: every raw factor is near 100, and
    # the calibrated odometry is never made looser than stated.
    graph, _ = _laps(quiet=0.03, noisy=0.03, stated=0.003)
    f = segment_factors(graph, _solved(graph), np.ones(len(graph.loops)))
    assert np.all(f.raw > 10.0)
    np.testing.assert_array_equal(f.factors, 1.0)


def _with_local_false_loop() -> tuple[PoseGraph, PoseGraph]:
    """The laps with loose stated odometry (sigma 0.1 m; actual 0.003 outside poses
    100-199, 0.1 inside), a loop every fourth pose, and the same graph with a false loop
    210 -> 221 (15 cm, 10 cm and 0.02 rad off)."""
    clean, truth = _laps(noisy=0.1, stated=0.1, every=4)
    corrupted, _ = _laps(noisy=0.1, stated=0.1, every=4)
    wrong = se2.compose(se2.between(truth[210], truth[221]), np.array([0.15, 0.1, 0.02]))
    corrupted.add_loop(210, 221, wrong, clean.loops[0].information)
    return clean, corrupted


def test_segment_recheck_removes_a_local_false_loop_the_admission_keeps() -> None:
    clean, corrupted = _with_local_false_loop()
    kwargs = {"init": "odometry", "gnc_start": "incremental"}
    # Chosen by the stated TLS cost, the admission keeps it.
    without = optimize(corrupted, "none", "gnc", segments=False, calibrated=False, **kwargs)
    assert without.loop_weights[-1] == 1.0
    assert without.loop_weights[:-1].all()
    checked = optimize(corrupted, "none", "gnc", calibrated=False, **kwargs)
    assert checked.loop_weights[-1] == 0.0
    assert checked.loop_weights[:-1].all()
    assert checked.solver.endswith("-segments")
    plain = optimize(clean, "none", init="odometry").poses
    assert aligned_position_error(checked.poses, plain, 2) < 1e-4
    # The default back end (calibrated choice, then the segment re-check) rejects it too.
    default = optimize(corrupted, "none", "gnc", **kwargs)
    assert default.loop_weights[-1] == 0.0
    assert default.loop_weights[:-1].all()
    assert aligned_position_error(default.poses, plain, 2) < 1e-4


def test_outlier_free_graph_is_left_unchanged() -> None:
    clean, _ = _with_local_false_loop()
    kwargs = {"init": "odometry", "gnc_start": "incremental"}
    checked = optimize(clean, "none", "gnc", **kwargs)
    assert checked.loop_weights.all()
    assert not checked.solver.endswith("-segments")
    plain = optimize(clean, "none", init="odometry").poses
    assert aligned_position_error(checked.poses, plain, 2) < 1e-3
