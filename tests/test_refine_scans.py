"""Final per-scan refinement onto a map centred on each scan (`slam.refine_scans`)."""

from __future__ import annotations

import numpy as np
import pytest

from data.errors import UserError
from data.sim import LaserModel, cast
from slam.refine_scans import RefineConfig, refine_scan_poses

#: A 10 m x 6 m room with a pillar and a notch: every pose is well constrained.
WALLS = np.array([
    [[-5.0, -3.0], [5.0, -3.0]], [[5.0, -3.0], [5.0, 3.0]], [[5.0, 3.0], [-2.0, 3.0]],
    [[-2.0, 3.0], [-2.0, 2.0]], [[-2.0, 2.0], [-5.0, 2.0]], [[-5.0, 2.0], [-5.0, -3.0]],
    [[1.0, 0.5], [1.6, 0.5]], [[1.6, 0.5], [1.6, 1.1]], [[1.6, 1.1], [1.0, 1.1]],
    [[1.0, 1.1], [1.0, 0.5]],
])


def _scans(noise: float = 0.0):
    k = np.arange(40)
    truth = np.column_stack([-3.5 + 0.15 * k, -1.0 + 0.3 * np.sin(k / 8.0), 0.1 * np.cos(k / 6.0)])
    laser = LaserModel(fov_deg=360.0, beams=360, max_range=20.0, noise_sigma=noise, dropout=0.0)
    ranges = cast(WALLS, truth, laser, np.random.default_rng(0))
    angles = laser.angles()
    points = []
    for r in ranges:
        ok = r < laser.max_range
        points.append(np.column_stack([r[ok] * np.cos(angles[ok]), r[ok] * np.sin(angles[ok])]))
    return truth, points


def test_a_displaced_scan_is_pulled_back_and_exact_poses_stay() -> None:
    truth, points = _scans()
    given = truth.copy()
    given[17] += [0.05, -0.03, 0.01]  # one scan (not a map scan) is off by 6 cm / 0.6 deg
    map_scans = np.arange(0, 40, 2)
    res = refine_scan_poses(points, given, map_scans)
    assert res.refined[17]
    np.testing.assert_allclose(res.poses[17], truth[17], atol=3e-3)
    others = np.delete(np.arange(40), 17)
    assert np.abs(res.poses[others] - truth[others]).max() < 3e-3


def test_a_displaced_map_scan_is_not_matched_onto_itself() -> None:
    truth, points = _scans()
    given = truth.copy()
    given[10] += [0.04, 0.03, -0.01]  # a map scan: its own points must not hold it there
    res = refine_scan_poses(points, given, np.arange(0, 40, 2))
    np.testing.assert_allclose(res.poses[10], truth[10], atol=3e-3)


def test_noisy_scans_get_closer_to_the_truth() -> None:
    truth, points = _scans(noise=0.01)
    rng = np.random.default_rng(1)
    given = truth + rng.normal(0.0, [0.01, 0.01, 0.004], truth.shape)
    res = refine_scan_poses(points, given, np.arange(0, 40, 3))
    before = np.hypot(*(given - truth)[:, :2].T).mean()
    after = np.hypot(*(res.poses - truth)[:, :2].T).mean()
    assert res.refined.mean() > 0.9 and after < 0.5 * before


def test_float32_points_give_the_poses_of_their_float64_copies() -> None:
    """The pipeline keeps scans as float32 and passes them as they are: each is
    converted when used, so the result equals that of converting them all first."""
    truth, points = _scans(noise=0.01)
    rng = np.random.default_rng(2)
    given = truth + rng.normal(0.0, [0.01, 0.01, 0.004], truth.shape)
    single = [p.astype(np.float32) for p in points]
    a = refine_scan_poses(single, given, np.arange(0, 40, 3))
    b = refine_scan_poses([p.astype(float) for p in single], given, np.arange(0, 40, 3))
    assert a.refined.sum() > 30
    np.testing.assert_array_equal(a.poses, b.poses)
    np.testing.assert_array_equal(a.refined, b.refined)


def test_bounds_and_bad_input() -> None:
    truth, points = _scans()
    given = truth.copy()
    given[5] += [0.05, -0.03, 0.01]  # a correction beyond max_correction: kept
    res = refine_scan_poses(points, given, np.arange(0, 40, 2),
                            RefineConfig(max_correction=(0.02, 0.1)))
    assert not res.refined[5]
    np.testing.assert_array_equal(res.poses[5], given[5])
    one = refine_scan_poses(points, given, [3])  # fewer than two map scans: nothing to do
    np.testing.assert_array_equal(one.poses, given)
    with pytest.raises(UserError, match="point sets"):
        refine_scan_poses(points[:-1], given, [0, 2])
    with pytest.raises(UserError, match="increasing"):
        refine_scan_poses(points, given, [4, 2])
    with pytest.raises(UserError, match="half_window"):
        RefineConfig(half_window=0)
    with pytest.raises(UserError, match="line_anchor"):
        RefineConfig(line_anchor="median")


def test_mean_anchor_refines_noisy_scans_too() -> None:
    """With lines through the mean of their neighbours, noisy scans also get closer
    to the truth, and the result differs from the point anchor's (the option is used)."""
    truth, points = _scans(noise=0.01)
    rng = np.random.default_rng(1)
    given = truth + rng.normal(0.0, [0.01, 0.01, 0.004], truth.shape)
    mean = refine_scan_poses(points, given, np.arange(0, 40, 3),
                             RefineConfig(line_anchor="mean", line_anchor_band=0.03))
    point = refine_scan_poses(points, given, np.arange(0, 40, 3))
    before = np.hypot(*(given - truth)[:, :2].T).mean()
    after = np.hypot(*(mean.poses - truth)[:, :2].T).mean()
    assert mean.refined.mean() > 0.9 and after < 0.5 * before
    assert not np.array_equal(mean.poses, point.poses)
