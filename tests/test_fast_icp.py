"""The compiled ICP (`loopclosure.fast_icp`) against hand-checked cases and
against the numpy reference `loopclosure.registration.register`."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.spatial import cKDTree

from data import se2
from data.errors import UserError
from loopclosure.fast_icp import (
    JOIN_ROTATION,
    JOIN_TRANSLATION,
    KIND_CLUTTER,
    KIND_LINE,
    GridTarget,
    estimate_normals_fast,
    overlap_bound,
    overlap_screen,
    register_fast,
    register_target,
    voxel_downsample_fast,
)
from loopclosure.geometric_check import GeometricCheckConfig, verify
from loopclosure.multi_start import initial_guesses, overlap_scores, register_multi
from loopclosure.registration import (
    IcpConfig,
    RegistrationTarget,
    estimate_normals,
    register,
    voxel_downsample,
)

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
    grid = GridTarget(pts, cell=0.3)
    from loopclosure.grid_nearest import _nearest

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
    for grid in (GridTarget.from_target(target), GridTarget(pts, target.config)):
        assert (grid.kind == KIND_LINE).sum() == target.usable.sum()
        assert (grid.kind == KIND_CLUTTER).sum() == target.clutter.sum()
    no_clutter = GridTarget(pts)
    assert (no_clutter.kind == KIND_CLUTTER).sum() == 0
    with pytest.raises(UserError, match="cell"):
        GridTarget(pts, cell=0.0)


def test_compiled_normals_equal_the_numpy_ones() -> None:
    """Walls, a noisy wall, a bush and isolated points: same normals and kinds."""
    rng = np.random.default_rng(2)
    pts = np.vstack([room(), segment((4, -2), (4, 2)) + rng.normal(0, 0.01, (80, 2)),
                     rng.normal([1.5, 1.0], 0.15, (60, 2)), [[9.0, 9.0], [-9.0, 4.0]]])
    for cfg in (IcpConfig(point_to_point_clutter=True), IcpConfig(normal_neighbors=5)):
        target = RegistrationTarget(pts, cfg)
        grid = GridTarget(pts, cfg)
        ref = GridTarget.from_target(target)
        np.testing.assert_array_equal(grid.points, ref.points)
        np.testing.assert_array_equal(grid.kind, ref.kind)
        line = grid.kind == KIND_LINE
        # a normal and its opposite are the same line
        dots = np.abs(np.einsum("ij,ij->i", grid.normals[line], ref.normals[line]))
        np.testing.assert_allclose(dots, 1.0, atol=1e-9)


def test_compiled_voxel_downsample_equals_the_numpy_one() -> None:
    rng = np.random.default_rng(3)
    pts = rng.uniform(-3, 3, (500, 2))
    for voxel in (0.0, 0.05, 0.4):
        np.testing.assert_array_equal(voxel_downsample_fast(pts, voxel),
                                      voxel_downsample(pts, voxel))
    # hand-checked: two cells, centroids in the order of their first point
    out = voxel_downsample_fast([[0.9, 0.1], [0.1, 0.1], [1.2, 0.0], [0.5, 0.3]], 1.0)
    np.testing.assert_allclose(out, [[0.5, 0.5 / 3], [1.2, 0.0]])


def test_compiled_voxel_downsample_is_bit_identical_on_dense_far_clouds() -> None:
    """Many points per cell, cells far from the origin on both signs and a single
    point: the hashed cells give the reference's centroids to the bit (same cells,
    same summation order, same output order)."""
    rng = np.random.default_rng(4)
    walls = np.repeat(rng.uniform(-1e4, 1e4, (300, 2)), 20, axis=0)
    pts = walls + rng.normal(0.0, 0.03, walls.shape)
    for cloud in (pts, pts[rng.permutation(len(pts))], pts[:1]):
        for voxel in (0.05, 0.4, 7.0):
            np.testing.assert_array_equal(voxel_downsample_fast(cloud, voxel),
                                          voxel_downsample(cloud, voxel))


def test_recovers_a_known_pose_exactly() -> None:
    """Noise-free room seen from pose (0.2, -0.1, 0.05): ICP from zero finds that pose."""
    target_pts = room()
    pose = np.array([0.2, -0.1, 0.05])
    source = se2.transform_points(se2.inverse(pose), target_pts[::2])
    res = register_fast(source, GridTarget(target_pts), config=EXACT)
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
    grid = GridTarget.from_target(target)
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


def test_register_target_is_register_from_every_start() -> None:
    """`register_target` (the geometric check's ICP) equals `register` onto the same
    prepared target from each start (0.3 m / 0.1 rad off and another), and keeps no
    grid in the target."""
    target = RegistrationTarget(room(), IcpConfig(max_correspondence_distance=1.0))
    pose = np.array([0.8, -0.4, 0.6])
    src = se2.transform_points(se2.inverse(pose), room()[::2])
    start = pose + np.array([0.3, -0.2, 0.1])
    starts = np.array([start, pose + np.array([-0.2, 0.3, -0.05])])
    for ref, got in zip([register(src, target, s) for s in starts],
                        register_target(src, target, starts, join=False), strict=True):
        np.testing.assert_allclose(got.pose, ref.pose, atol=1e-12)
        np.testing.assert_allclose(got.pose, pose, atol=1e-6)
        assert got.fitness == pytest.approx(ref.fitness, rel=1e-9)
        assert got.iterations == ref.iterations
    assert not target.derived  # the grid is not kept


def test_a_run_that_meets_an_earlier_one_stops_with_its_result() -> None:
    """With `join` (the default) the second start, which converges to the same pose,
    stops once within `JOIN_TRANSLATION` / `JOIN_ROTATION` of where the first ended and
    returns the first's result with its own start and fewer iterations; a start that
    ends elsewhere runs to its own end."""
    target = RegistrationTarget(room(), IcpConfig(max_correspondence_distance=1.0))
    pose = np.array([0.8, -0.4, 0.6])
    src = se2.transform_points(se2.inverse(pose), room()[::2])
    starts = pose + np.array([[0.3, -0.2, 0.1], [-0.2, 0.3, -0.05]])
    alone = register_target(src, target, starts, join=False)
    first, second = register_target(src, target, starts)
    np.testing.assert_array_equal(first.pose, alone[0].pose)
    np.testing.assert_array_equal(second.pose, first.pose)
    np.testing.assert_array_equal(second.initial, starts[1])
    assert second.fitness == first.fitness
    assert 0 < second.iterations < alone[1].iterations
    moved = se2.between(alone[1].pose, first.pose)
    assert np.hypot(*moved[:2]) < JOIN_TRANSLATION and abs(moved[2]) < JOIN_ROTATION
    # A failed first run (no overlap) is no place to stop at.
    far = np.array([[50.0, 50.0, 0.0], starts[1]])
    failed, own = register_target(src, target, far)
    assert not failed.ok
    np.testing.assert_allclose(own.pose, alone[1].pose, atol=1e-12)
    assert own.iterations == alone[1].iterations


def test_the_check_decides_alike_with_either_icp() -> None:
    """The geometric check with the compiled ICP gives the numpy ICP's verdict and pose,
    with a prior (multi-start ICP) and without (correlative search, then ICP)."""
    target_pts = room()
    pose = np.array([0.5, 0.3, 0.4])
    query = se2.transform_points(se2.inverse(pose), target_pts[1::2])
    for kwargs in ({"prior": pose + np.array([0.1, -0.1, 0.05])}, {"headings": [0.35]}):
        out = []
        for compiled in (False, True):
            cfg = GeometricCheckConfig(compiled_icp=compiled)
            target = RegistrationTarget(target_pts, cfg.icp)
            out.append(verify(query, target, max_distance=2.0, config=cfg, **kwargs))
        numpy_icp, compiled_icp = out
        assert numpy_icp.accepted and compiled_icp.accepted
        np.testing.assert_allclose(compiled_icp.relative, numpy_icp.relative, atol=1e-9)
        np.testing.assert_allclose(compiled_icp.relative, pose, atol=0.02)


def test_failure_keeps_the_initial_guess() -> None:
    grid = GridTarget(room())
    far = np.array([[50.0, 50.0]] * 30) + np.arange(30)[:, None] * 0.05
    res = register_fast(far, grid, (1.0, 2.0, 0.3))
    assert not res.ok
    np.testing.assert_array_equal(res.pose, [1.0, 2.0, 0.3])
    assert not register_fast(room()[:5], grid).ok  # fewer points than min_correspondences


def test_mean_anchor_puts_the_line_through_the_neighbourhood_mean() -> None:
    """A noisy straight wall y = 1: with the mean anchor every line passes within the
    averaged noise of y = 1, and ICP still recovers a known pose."""
    rng = np.random.default_rng(5)
    wall = segment((-3, 1), (3, 1))
    wall[:, 1] += rng.normal(0, 0.01, len(wall))
    grid_pt = GridTarget(wall, IcpConfig(), anchor="point")
    grid_mean = GridTarget(wall, IcpConfig(), anchor="mean")
    line = grid_mean.kind == KIND_LINE
    off_pt = np.abs(grid_pt.anchors[line, 1] - 1.0).mean()
    off_mean = np.abs(grid_mean.anchors[line, 1] - 1.0).mean()
    assert off_mean < 0.6 * off_pt
    np.testing.assert_array_equal(grid_mean.anchors[~line], grid_mean.points[~line])
    pose = np.array([0.1, -0.05, 0.03])
    target_pts = room()
    src = se2.transform_points(se2.inverse(pose), target_pts[1::2])
    res = register_fast(src, GridTarget(target_pts, anchor="mean"), config=EXACT)
    np.testing.assert_allclose(res.pose, pose, atol=1e-3)
    with pytest.raises(UserError, match="anchor"):
        GridTarget(wall, anchor="centroid")
    with pytest.raises(UserError, match="anchor radius"):
        GridTarget(wall, anchor="mean", anchor_radius=0.0)
    # a radius below the point spacing leaves each point its own anchor
    lone = GridTarget(wall, IcpConfig(), anchor="mean", anchor_radius=0.01)
    np.testing.assert_array_equal(lone.anchors, lone.points)


def test_solve3_matches_numpy_and_survives_a_singular_matrix() -> None:
    from loopclosure.icp_kernel import _solve3

    rng = np.random.default_rng(6)
    a = rng.normal(size=(3, 3))
    h = a @ a.T + 0.1 * np.eye(3)
    g = rng.normal(size=3)
    np.testing.assert_allclose(_solve3(h, g), np.linalg.solve(h, g), rtol=1e-10)
    corridor = np.diag([0.0, 4.0, 2.0]) + 1e-12 * np.eye(3)  # nothing along x
    assert np.all(np.isfinite(_solve3(corridor, np.array([0.0, 1.0, 1.0]))))


def test_anchor_band_ignores_the_other_face_of_a_thin_wall() -> None:
    """Two faces 8 cm apart (a thin wall seen from both sides): with a band below the
    thickness the line of a face stays on that face; without, it moves towards the middle."""
    face_a = segment((-2, 0.0), (2, 0.0))
    face_b = segment((-1.975, 0.08), (2.025, 0.08))
    pts = np.vstack([face_a, face_b])
    cfg = IcpConfig(normal_neighbors=8, max_normal_ratio=0.5)
    wide = GridTarget(pts, cfg, anchor="mean", anchor_radius=0.2)
    band = GridTarget(pts, cfg, anchor="mean", anchor_radius=0.2, anchor_band=0.03)
    on_a = ((np.abs(band.points[:, 1]) < 1e-9) & (band.kind == KIND_LINE)
            & (np.abs(band.points[:, 0]) < 1.5))  # away from the ends
    assert on_a.any()
    np.testing.assert_allclose(band.anchors[on_a, 1], 0.0, atol=1e-9)
    assert np.abs(wide.anchors[on_a, 1]).max() > 0.01
    with pytest.raises(UserError, match="band"):
        GridTarget(pts, anchor="mean", anchor_band=0.0)


def test_overlap_bound_counts_points_within_reach_of_the_map_at_each_guess() -> None:
    # A wall along y = 0 (x in [0, 10], every 0.1 m); four query points.
    grid = GridTarget(np.column_stack([np.linspace(0, 10, 101), np.zeros(101)]), cell=0.5)
    src = np.array([[1.0, 0.3], [2.0, 0.3], [3.0, 1.5], [4.0, 5.0]])
    guesses = np.array([[0.0, 0.0, 0.0],     # (1, .3), (2, .3) within 0.5: 2 of 4
                        [0.0, -1.8, 0.0],    # (3, -.3) only: 1 of 4
                        [0.0, 0.0, np.pi],   # (-1, -.3), ...: 1.04 m from (0, 0) and farther
                        [20.0, 0.0, 0.0]])   # off the map
    np.testing.assert_allclose(overlap_bound(src, grid, guesses, 0.5), [0.5, 0.25, 0.0, 0.0])
    # A reach of 2 m also counts (3, 1.5) at the first guess, (-1, -.3) at the third.
    np.testing.assert_allclose(overlap_bound(src, grid, guesses[:3], 2.0)[[0, 2]],
                               [0.75, 0.25])
    assert overlap_bound(np.zeros((0, 2)), grid, guesses, 0.5).tolist() == [0.0] * 4



def _cloud() -> np.ndarray:
    """Walls, a noisy wall, a bush and isolated points [m]."""
    rng = np.random.default_rng(2)
    return np.vstack([room(), segment((4, -2), (4, 2)) + rng.normal(0, 0.01, (80, 2)),
                      rng.normal([1.5, 1.0], 0.15, (60, 2)), [[9.0, 9.0], [-9.0, 4.0]]])


def test_estimate_normals_fast_equals_the_numpy_estimate_in_the_points_order() -> None:
    pts = _cloud()
    for cfg in (IcpConfig(), IcpConfig(normal_neighbors=5, normal_radius=0.3)):
        normals, line, ratio = estimate_normals_fast(pts, cfg)
        ref_n, ref_line, ref_ratio = estimate_normals(pts, cKDTree(pts), cfg)
        np.testing.assert_array_equal(line, ref_line)
        np.testing.assert_array_equal(np.isinf(ratio), np.isinf(ref_ratio))
        finite = np.isfinite(ref_ratio)
        assert finite.sum() > 300 and (~finite).sum() >= 2  # both kinds are tested
        np.testing.assert_allclose(ratio[finite], ref_ratio[finite], rtol=0, atol=1e-9)
        # Line-like normals (the ones ICP uses); a corner's may differ where equidistant
        # neighbours tie for the last of the k places (the ratio is then the same).
        np.testing.assert_allclose(normals[line], ref_n[line], rtol=0, atol=1e-9)
    # hand-checked: four points on the line y = x: normal (-1, 1) / sqrt 2, ratio 0
    n, ok, r = estimate_normals_fast(np.array([[0.0, 0.0], [0.1, 0.1], [0.2, 0.2],
                                               [0.3, 0.3]]), IcpConfig())
    assert ok.all()
    np.testing.assert_allclose(np.abs(n), np.sqrt(0.5), atol=1e-12)
    np.testing.assert_allclose(n[:, 0] * n[:, 1], -0.5, atol=1e-12)
    np.testing.assert_allclose(r, 0.0, atol=1e-12)
    few = estimate_normals_fast(np.zeros((2, 2)), IcpConfig())
    assert not few[1].any() and np.isinf(few[2]).all()


def test_a_target_with_injected_normals_makes_its_tree_on_first_use() -> None:
    pts = _cloud()
    cfg = IcpConfig(point_to_point_clutter=True)
    ref = RegistrationTarget(pts, cfg)
    lazy = RegistrationTarget(pts, cfg, normals=estimate_normals_fast)
    assert lazy._tree is not None and not isinstance(lazy._tree, cKDTree)
    np.testing.assert_array_equal(lazy.usable, ref.usable)
    np.testing.assert_array_equal(lazy.clutter, ref.clutter)
    assert isinstance(lazy.tree, cKDTree) and lazy.tree is lazy.tree
    np.testing.assert_array_equal(lazy.tree.data, pts)
    # nothing matchable (too few points): no tree, either way
    for normals in (None, estimate_normals_fast):
        assert RegistrationTarget(pts[:3], cfg, normals=normals).tree is None
        assert RegistrationTarget(np.zeros((0, 2)), cfg, normals=normals).tree is None


def test_overlap_screen_is_overlap_scores_and_overlap_bound_in_one_pass() -> None:
    pts = _cloud()
    cfg = IcpConfig()
    target = RegistrationTarget(pts, cfg)
    grid = GridTarget.from_target(target, 0.5)
    rng = np.random.default_rng(4)
    src = room()[::3] + rng.normal(0, 0.02, (len(room()[::3]), 2))
    guesses = np.column_stack([rng.uniform(-1.5, 1.5, (40, 2)), rng.uniform(-np.pi, np.pi, 40)])
    guesses[0] = 0.0  # one guess right on the map
    for gate, reach in ((1.0, 0.55), (0.2, 0.0), (0.3, 1.2)):
        scores, bounds = overlap_screen(src, grid, guesses, gate, reach)
        np.testing.assert_allclose(scores, overlap_scores(src, target, guesses, gate),
                                   rtol=0, atol=1e-12)
        np.testing.assert_allclose(bounds, overlap_bound(src, grid, guesses, reach),
                                   rtol=0, atol=0)
        assert scores[0] > 0.5 and scores.min() < scores[0]
    empty = overlap_screen(np.zeros((0, 2)), grid, guesses, 1.0, 0.5)
    assert not empty[0].any() and not empty[1].any()


def test_register_multi_on_the_grid_alone_is_the_compiled_run_on_the_target() -> None:
    target_pts = room()
    true = np.array([0.3, -0.2, 0.4])
    source = se2.transform_points(se2.inverse(true), target_pts[::2])
    target = RegistrationTarget(target_pts, EXACT, normals=estimate_normals_fast)
    grid = GridTarget(target_pts, EXACT, cell=0.25)
    guesses = initial_guesses((0.0, 0.0, 0.0), [0.4, 2.0, -1.0], [[0.5, 0], [0, 0.5]])
    a = register_multi(source, target, guesses, config=EXACT, keep=4, compiled=True,
                       grid=grid)
    b = register_multi(source, None, guesses, config=EXACT, keep=4, compiled=True, grid=grid)
    np.testing.assert_array_equal(a.guesses, b.guesses)
    np.testing.assert_allclose(b.best.pose, true, atol=1e-6)
    np.testing.assert_allclose(a.best.pose, b.best.pose, atol=0)
    with pytest.raises(UserError, match="target"):
        register_multi(source, None, guesses)


def test_initial_guesses_keep_the_first_of_equal_guesses_in_order() -> None:
    g = initial_guesses((1.0, 2.0, 0.5), [0.5, 0.5 + 2 * np.pi, -0.25], [[0.1, 0.0]])
    np.testing.assert_allclose(g, [[1.0, 2.0, 0.5], [1.1, 2.0, 0.5],
                                   [1.0, 2.0, -0.25], [1.1, 2.0, -0.25]])


def test_a_gated_check_screens_and_registers_without_the_candidates_kd_tree() -> None:
    """Screens and ICP of a check from a prior run on the candidate's grid: its KD-tree
    (made on first use when the normals are injected) is never made; verdicts as with
    the numpy normals and KD-tree."""
    target_pts = room()
    pose = np.array([0.5, 0.3, 0.4])
    query = se2.transform_points(se2.inverse(pose), target_pts[1::2])
    cfg = GeometricCheckConfig()
    cov = np.diag([0.1, 0.1, 0.01])
    near, far = pose + np.array([0.1, -0.1, 0.05]), pose + np.array([30.0, 0.0, 0.0])
    for prior, accepted, reason in ((near, True, "accepted"),
                                    (far, False, "no overlap at the prior")):
        lazy = RegistrationTarget(target_pts, cfg.icp, normals=estimate_normals_fast)
        res = verify(query, lazy, prior=prior, prior_covariance=cov, config=cfg)
        assert not isinstance(lazy._tree, cKDTree)
        ref = verify(query, RegistrationTarget(target_pts, cfg.icp), prior=prior,
                     prior_covariance=cov, config=cfg)
        assert res.accepted == ref.accepted == accepted and res.reason.startswith(reason)
        assert ref.reason == res.reason
        np.testing.assert_allclose(res.relative, ref.relative, atol=1e-9)


def test_upper_median_by_selection_is_the_sorted_one() -> None:
    """`_upper_median_abs` is ``sorted(|v[:n]|)[n // 2]`` for every n (ties, signs, a
    tail beyond n that must not count)."""
    from loopclosure.icp_kernel import _upper_median_abs

    rng = np.random.default_rng(5)
    for n in range(1, 60):
        v = np.concatenate([rng.normal(size=n), [1e9, -1e9]])
        v[: n // 3] = np.round(v[: n // 3], 1)  # ties
        assert _upper_median_abs(v, n) == np.sort(np.abs(v[:n]))[n // 2]
    assert _upper_median_abs(np.array([-3.0, 1.0, 2.0]), 3) == 2.0  # |.| = 3, 1, 2



def test_inv3_is_numpys_inverse_to_the_bit() -> None:
    """`_inv3` (LAPACK gesv on the identity, as `np.linalg.inv`) on symmetric positive
    definite 3x3 matrices of widely different scales, and on a non-symmetric one."""
    from loopclosure.icp_kernel import _inv3

    rng = np.random.default_rng(3)
    for _ in range(200):
        a = rng.normal(size=(3, 3)) * 10.0 ** rng.uniform(-3, 6, size=(3, 1))
        a = a @ a.T + 1e-3 * np.eye(3)
        assert np.array_equal(_inv3(a), np.linalg.inv(a))
    b = np.array([[2.0, 1.0, 0.5], [0.25, 3.0, 1.0], [0.1, 0.2, 4.0]])
    assert np.array_equal(_inv3(b), np.linalg.inv(b))


def test_figures_are_the_numpy_expressions() -> None:
    """The kernel's covariance and degenerate axis are the reference's numpy
    expressions on the result's Hessian and sigma (the axis to the bit: the Hessian
    is returned as computed; the covariance to rounding: sigma is returned as the
    square root of the variance the kernel used), with and without a prior."""
    pts = room()
    grid = GridTarget(pts)
    source = se2.transform_points(se2.inverse(np.array([0.1, -0.05, 0.03])), pts[::3])
    prior = np.array([0.08, -0.04, 0.02])
    prior_cov = np.array([[0.02, 0.003, 0.0], [0.003, 0.03, 0.001], [0.0, 0.001, 0.01]])
    for kw in ({}, {"prior": prior, "prior_covariance": prior_cov}):
        res = register_fast(source, grid, (0.0, 0.0, 0.0), **kw)
        assert res.ok and res.converged
        lam = np.linalg.inv(prior_cov) if kw else np.zeros((3, 3))
        h = res.hessian
        info = h / res.sigma**2 + lam
        cov = np.linalg.inv(info + 1e-12 * max(np.trace(info), 1e-12) * np.eye(3))
        np.testing.assert_allclose(res.covariance, 0.5 * (cov + cov.T), rtol=1e-9)
        h_tt = h[:2, :2] - np.outer(h[:2, 2], h[2, :2]) / h[2, 2]
        assert np.array_equal(res.degenerate_axis, np.linalg.eigh(h_tt)[1][:, 0])
        assert -np.pi <= res.pose[2] < np.pi
