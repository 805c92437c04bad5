"""Shortcuts that must give the same numbers to the bit as the code they replace: the
front end's fused beam points, the pose graph's kept factors, the submaps' transform
and the loops.csv writer."""

from __future__ import annotations

import gtsam
import numpy as np

from data import se2
from data.types import Scan
from loopclosure.fast_icp import beam_points_fast, voxel_downsample_fast
from slam.odometry.icp2d import Icp2dConfig, Icp2dOdometry
from slam.outputs import LoopRecord, write_loops_csv
from slam.pose_graph import PoseGraph, RobustKernel
from slam.submap_cache import _transform
from tests.helpers import load_benchmark


def _reference_points(ranges, angles, bounds, voxel):
    above, below, low, high = bounds
    with np.errstate(invalid="ignore"):
        keep = (np.isfinite(ranges) & (ranges > above) & (ranges < below)
                & (ranges >= low) & (ranges <= high))
    pts = np.column_stack([ranges[keep] * np.cos(angles[keep]),
                           ranges[keep] * np.sin(angles[keep])])
    return voxel_downsample_fast(pts, voxel)


def test_beam_points_hand_checked() -> None:
    """NaN, too short (0.01 < 0.05), too long (50 > 40) beams dropped; no voxel."""
    ranges = np.array([1.0, np.nan, 2.0, 0.01, 50.0, np.inf])
    angles = np.array([0.0, 0.5, np.pi / 2, 0.0, 0.0, 1.0])
    out = beam_points_fast(ranges, np.cos(angles), np.sin(angles), (0.0, 40.0, 0.05, 30.0),
                           0.0)
    np.testing.assert_allclose(out, [[1.0, 0.0], [0.0, 2.0]], atol=1e-15)
    # voxel 10 m: both points in cell (0, 0), their centroid
    out = beam_points_fast(ranges, np.cos(angles), np.sin(angles), (0.0, 40.0, 0.05, 30.0),
                           10.0)
    np.testing.assert_allclose(out, [[0.5, 1.0]], atol=1e-15)
    empty = beam_points_fast(ranges[:2] * 0, np.ones(2), np.zeros(2), (0.0, 40.0, 0.05, 30.0),
                             0.05)
    assert empty.shape == (0, 2)


def test_beam_points_equal_masking_and_voxels_to_the_bit() -> None:
    rng = np.random.default_rng(7)
    angles = np.linspace(-np.pi / 2, np.pi / 2, 181)
    ranges = rng.uniform(0.0, 45.0, 181)
    ranges[rng.integers(0, 181, 20)] = np.nan
    for bounds in ((0.0, 40.0, 0.05, 40.0), (0.1, 81.9, 0.5, 30.0)):
        for voxel in (0.0, 0.05, 1.0):
            np.testing.assert_array_equal(
                beam_points_fast(ranges, np.cos(angles), np.sin(angles), bounds, voxel),
                _reference_points(ranges, angles, bounds, voxel))


def test_front_end_scan_points_equal_the_numpy_path() -> None:
    """The compiled scan points (bearings' trig kept between scans, recomputed when the
    bearings change) equal the numpy path's for the same scans."""
    rng = np.random.default_rng(8)
    fast = Icp2dOdometry(Icp2dConfig())
    slow = Icp2dOdometry(Icp2dConfig(compiled=False))
    angles = np.linspace(-np.pi / 2, np.pi / 2, 181)
    for n in range(4):
        bearings = angles.copy() if n < 3 else angles + 0.01  # equal copies, then a change
        ranges = rng.uniform(0.0, 30.0, 181)
        ranges[::17] = 81.9
        scan = Scan(float(n), ranges, bearings, 81.9, 0.0)
        np.testing.assert_array_equal(fast.scan_points(scan), slow.scan_points(scan))
    assert np.array_equal(fast._trig[0], angles + 0.01)


def _two_pose_graph() -> PoseGraph:
    graph = PoseGraph()
    graph.add_pose(0, np.zeros(3))
    graph.add_pose(1, np.array([1.5, 0.0, 0.0]))
    graph.add_odometry(0, 1, np.array([1.0, 0.0, 0.0]), 4.0 * np.eye(3))
    graph.add_loop(0, 1, np.array([1.0, 0.0, 0.0]), 4.0 * np.eye(3))
    return graph


def test_factor_graph_keeps_factors_until_a_constraint_changes() -> None:
    """Error of each factor 0.5 e^T I e with e = 0.5 m: 0.5 * 0.25 * 4 = 0.5; the kept
    factors give the same, and a replaced information (x2) gives a new factor (1.0)."""
    graph = _two_pose_graph()
    values = graph.gtsam_values()
    none = RobustKernel("none")
    first, loops = graph.factor_graph(none)
    again, _ = graph.factor_graph(none)
    assert loops == [2]
    assert [first.at(k).error(values) for k in (1, 2)] == [0.5, 0.5]
    assert [again.at(k).error(values) for k in (1, 2)] == [0.5, 0.5]
    assert len(graph._factors) == 2
    graph.loops[0].information = 8.0 * np.eye(3)
    changed, _ = graph.factor_graph(none)
    assert changed.at(1).error(values) == 0.5
    assert np.isclose(changed.at(2).error(values), 1.0)
    # another kernel, a factor of its own: Cauchy of scale 1, log(1 + e^T I e) / 2, e^T I e = 2
    cauchy, _ = graph.factor_graph(RobustKernel("cauchy"))
    assert np.isclose(cauchy.at(2).error(values), 0.5 * np.log1p(2.0))
    assert isinstance(cauchy, gtsam.NonlinearFactorGraph)


def test_factor_cache_is_pruned_of_removed_constraints() -> None:
    graph = _two_pose_graph()
    for _ in range(40):  # loops added and dropped again
        graph.add_loop(0, 1, np.array([1.0, 0.0, 0.0]), np.eye(3))
        graph.factor_graph()
        graph.loops.pop()
    assert len(graph._factors) <= 4 * 3 + 64
    graph.factor_graph()
    owned = {id(c) for c in graph.odometry + graph.loops}
    assert {k[0] for k in graph._factors} >= owned


def test_submap_transform_is_se2_transform_points_to_the_bit() -> None:
    rng = np.random.default_rng(9)
    pts = rng.uniform(-20, 20, (300, 2))
    for pose in (np.array([1.0, -2.0, 0.3]), np.array([0.0, 0.0, -3.1]),
                 se2.between(np.array([3.0, 1.0, 2.0]), np.array([-1.0, 4.0, -2.5]))):
        np.testing.assert_array_equal(_transform(pose, pts), se2.transform_points(pose, pts))
    np.testing.assert_allclose(_transform(np.array([1.0, 0.0, np.pi / 2]),
                                          np.array([[1.0, 0.0]])), [[1.0, 1.0]], atol=1e-15)


def test_loops_csv_row(tmp_path) -> None:
    rec = LoopRecord(3, 10, 1.5, 7.25, "place", True, "ok", prefilter_rank=2, score=0.5,
                     relative=np.array([1.0, -0.5, 0.25]), prior=True)
    text = write_loops_csv(tmp_path / "loops.csv", [rec]).read_text()
    header, row = text.splitlines()
    assert header.split(",")[:3] == ["keyframe_a", "keyframe_b", "stamp_a"]
    assert row == ("3,10,1.500000,7.250000,place,1,1,0,ok,nan,2,nan,0.500000,nan,nan,nan,"
                   "nan,1.000000,-0.500000,0.250000")


def test_stage_benchmark_compares_bytes_and_keeps_the_best_pass() -> None:
    bench = load_benchmark("exact_stage_speed")
    a = [np.array([1.0, 2.0]), np.zeros((0, 2))]
    assert bench.same_arrays(a, [np.array([1.0, 2.0]), np.zeros((0, 2))])
    assert not bench.same_arrays(a, [np.array([1.0, 2.0 + 1e-15]), np.zeros((0, 2))])
    assert not bench.same_arrays(a, a[:1])
    assert not bench.same_arrays([np.zeros(2)], [np.zeros((1, 2))])  # shape, same bytes
    calls: list[str] = []
    best = bench.best_of(2, {"old": lambda: calls.append("old"),
                             "new": lambda: calls.append("new")})
    assert calls == ["old", "new", "new", "old"]  # alternate order
    assert set(best) == {"old", "new"} and all(0.0 <= t < 1.0 for t in best.values())
