"""The compiled scan-to-map ICP (`slam.odometry.fast_icp`) against hand-checked cases and
against the numpy reference `loopclosure.registration.register`."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.spatial import cKDTree

from data import se2
from data.errors import UserError
from loopclosure.registration import IcpConfig, RegistrationTarget, register
from slam.odometry.fast_icp import KIND_CLUTTER, KIND_LINE, GridTarget, register_fast

EXACT = IcpConfig(translation_tolerance=1e-10, rotation_tolerance=1e-10)


def segment(a, b, step=0.05):
    a_, b_ = np.asarray(a, float), np.asarray(b, float)
    n = max(round(float(np.linalg.norm(b_ - a_)) / step), 1)
    return a_ + (np.arange(n) / n)[:, None] * (b_ - a_)


def room() -> np.ndarray:
    """6 x 4 m with a notch and a pillar (no rotational symmetry) [m]."""
    corners = [(-3, -2), (3, -2), (3, 0.5), (2, 0.5), (2, 2), (-3, 2)]
    outline = np.vstack([segment(a, b) for a, b in itertools.pairwise(corners + corners[:1])])
    pillar = [(-1.0, -0.5), (-0.6, -0.5), (-0.6, -0.1), (-1.0, -0.1)]
    return np.vstack([outline] + [segment(a, b, 0.02)
                                  for a, b in itertools.pairwise(pillar + pillar[:1])])


def test_grid_nearest_neighbour_is_exact() -> None:
    """Every query's match equals the KD-tree's nearest neighbour within the gate."""
    rng = np.random.default_rng(1)
    pts = rng.uniform(-5, 5, (400, 2))
    grid = GridTarget(RegistrationTarget(pts), cell=0.3)
    from slam.odometry.fast_icp import _nearest

    tree = cKDTree(grid.points)
    for gate in (0.05, 0.3, 1.0, 2.5):
        for q in rng.uniform(-6, 6, (200, 2)):
            d_ref, j_ref = tree.query(q, distance_upper_bound=gate)
            j, d = _nearest(q[0], q[1], gate, grid.origin[0], grid.origin[1], grid.cell,
                            grid.shape[0], grid.shape[1], grid.start, grid.points)
            if np.isfinite(d_ref):
                assert j == j_ref and d == pytest.approx(d_ref, abs=1e-12)
            else:
                assert j == -1


def test_grid_kinds_follow_the_target() -> None:
    pts = np.vstack([segment((0, 0), (3, 0)), np.random.default_rng(0).uniform(5, 6, (60, 2))])
    target = RegistrationTarget(pts, IcpConfig(point_to_point_clutter=True))
    grid = GridTarget(target)
    assert (grid.kind == KIND_LINE).sum() == target.usable.sum()
    assert (grid.kind == KIND_CLUTTER).sum() == target.clutter.sum()
    no_clutter = GridTarget(RegistrationTarget(pts))
    assert (no_clutter.kind == KIND_CLUTTER).sum() == 0
    with pytest.raises(UserError, match="cell"):
        GridTarget(target, cell=0.0)


def test_recovers_a_known_pose_exactly() -> None:
    """Noise-free room seen from pose (0.2, -0.1, 0.05): ICP from zero finds that pose."""
    target_pts = room()
    pose = np.array([0.2, -0.1, 0.05])
    source = se2.transform_points(se2.inverse(pose), target_pts[::2])
    res = register_fast(source, GridTarget(RegistrationTarget(target_pts)), config=EXACT)
    assert res.ok and res.converged
    np.testing.assert_allclose(res.pose, pose, atol=1e-8)
    assert res.rms < 1e-8 and res.inlier_ratio > 0.95


@pytest.mark.parametrize("clutter", [False, True])
def test_matches_the_numpy_reference(clutter: bool) -> None:
    """Same pose, covariance and figures as `register` on noisy scans, with and
    without a prior and with point-to-point clutter."""
    rng = np.random.default_rng(4)
    bush = rng.normal([1.5, 1.0], 0.15, (80, 2))
    target_pts = np.vstack([room(), bush])
    cfg = IcpConfig(point_to_point_clutter=clutter, clutter_weight=0.3)
    target = RegistrationTarget(target_pts, cfg)
    grid = GridTarget(target)
    for k in range(6):
        pose = np.array([0.15 * np.cos(k), 0.1 * np.sin(k), 0.04 * (k - 3)])
        src = se2.transform_points(se2.inverse(pose), target_pts[k % 3::3])
        src = src + rng.normal(0, 0.01, src.shape)
        kw = {}
        if k % 2:
            kw = {"prior": pose + 0.02, "prior_covariance": np.diag([0.05, 0.05, 0.02]) ** 2}
        ref = register(src, target, np.zeros(3), config=cfg, **kw)
        got = register_fast(src, grid, np.zeros(3), config=cfg, **kw)
        assert got.ok == ref.ok and got.converged == ref.converged
        assert got.iterations == ref.iterations and got.correspondences == ref.correspondences
        np.testing.assert_allclose(got.pose, ref.pose, atol=1e-12)
        np.testing.assert_allclose(got.covariance, ref.covariance, rtol=1e-9, atol=1e-18)
        np.testing.assert_allclose(got.hessian, ref.hessian, rtol=1e-9)
        for name in ("fitness", "rms", "inlier_ratio", "degeneracy", "sigma"):
            assert getattr(got, name) == pytest.approx(getattr(ref, name), rel=1e-9, abs=1e-15)


def test_failure_keeps_the_initial_guess() -> None:
    grid = GridTarget(RegistrationTarget(room()))
    far = np.array([[50.0, 50.0]] * 30) + np.arange(30)[:, None] * 0.05
    res = register_fast(far, grid, (1.0, 2.0, 0.3))
    assert not res.ok
    np.testing.assert_array_equal(res.pose, [1.0, 2.0, 0.3])
    assert not register_fast(room()[:5], grid).ok  # fewer points than min_correspondences
