"""Tests of the 2D laser simulator (data.sim): ray caster, worlds, motion, runs, places."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data import se2
from data.errors import UserError
from data.sim import (
    LaserModel,
    MotionConfig,
    OdometryNoise,
    World,
    cast,
    drive,
    make_world,
    place_dataset,
    simulate_run,
    trace,
    turning_angles,
    wheel_odometry,
    write_run,
)
from data.sim.run import STREAM_WORLD, streams
from data.sim.worlds import point_segment_distance, segments_from_loops

# --------------------------------------------------------------------------- helpers


def square_room(half: float) -> np.ndarray:
    """Segments of a square room ``[-half, half]^2`` centred on the origin."""
    corners = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
    return segments_from_loops([corners])


def brute_force(segments: np.ndarray, poses: np.ndarray, laser: LaserModel) -> np.ndarray:
    """Reference ray caster: every beam against every segment, nearest hit, no shortcuts."""
    out = np.full((len(poses), laser.beams), np.inf)
    for k, pose in enumerate(poses):
        b = pose[2] + laser.angles()
        d = np.stack([np.cos(b), np.sin(b)], axis=-1)[:, None]  # (N, 1, 2)
        a = segments[None, :, 0]
        e = segments[None, :, 1] - a
        w = a - pose[:2]
        den = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w[..., 0] * e[..., 1] - w[..., 1] * e[..., 0]) / den
            u = (w[..., 0] * d[..., 1] - w[..., 1] * d[..., 0]) / den
        ok = (t > 0) & (u >= 0) & (u <= 1) & (t < laser.max_range)
        out[k] = np.where(ok, t, np.inf).min(axis=1)
    return out


EXACT = dict(noise_sigma=0.0, dropout=0.0)


@pytest.fixture(scope="module")
def box_run():
    return simulate_run("box", seed=0)


@pytest.fixture(scope="module")
def surface_run():
    return simulate_run("surface", seed=0)


# --------------------------------------------------------------------------- laser model


def test_beam_layout_360_and_centred():
    full = LaserModel(beams=360)
    a = full.angles()
    assert a[0] == pytest.approx(-np.pi)
    assert a[-1] == pytest.approx(np.pi - 2 * np.pi / 360)
    assert np.all(np.diff(a) > 0)
    half = LaserModel(fov_deg=180.0, beams=181)
    b = half.angles()
    assert b[0] == pytest.approx(-np.pi / 2) and b[-1] == pytest.approx(np.pi / 2)
    assert b[90] == pytest.approx(0.0, abs=1e-12)
    assert half.angle_increment == pytest.approx(np.radians(1.0))


@pytest.mark.parametrize(
    "kwargs",
    [dict(fov_deg=0.0), dict(fov_deg=400.0), dict(beams=1), dict(max_range=-1.0),
     dict(noise_sigma=-0.1), dict(dropout=1.0)],
)
def test_bad_laser_parameters_are_user_errors(kwargs):
    with pytest.raises(UserError):
        LaserModel(**kwargs)


# --------------------------------------------------------------------------- ray caster


@pytest.mark.parametrize("theta", [0.0, 0.3, -2.0])
def test_square_room_from_centre_is_d_over_cos(theta):
    d = 2.5
    laser = LaserModel(beams=720, max_range=10.0, **EXACT)
    r = cast(square_room(d), np.array([[0.0, 0.0, theta]]), laser)[0]
    bearing = theta + laser.angles()
    offset = (bearing + np.pi / 4) % (np.pi / 2) - np.pi / 4  # angle to the nearest wall normal
    np.testing.assert_allclose(r, d / np.cos(offset), rtol=0, atol=1e-9)


def test_square_room_off_centre_matches_hand_geometry():
    d = 3.0
    pose = np.array([1.0, -0.5, 0.7])
    laser = LaserModel(fov_deg=270.0, beams=271, max_range=20.0, **EXACT)
    r = cast(square_room(d), pose[None], laser)[0]
    b = pose[2] + laser.angles()
    c, s = np.cos(b), np.sin(b)
    with np.errstate(divide="ignore"):
        cand = np.stack([
            np.where(c > 0, (d - pose[0]) / c, np.inf),
            np.where(c < 0, (-d - pose[0]) / c, np.inf),
            np.where(s > 0, (d - pose[1]) / s, np.inf),
            np.where(s < 0, (-d - pose[1]) / s, np.inf),
        ])
    np.testing.assert_allclose(r, cand.min(axis=0), atol=1e-9)


def test_single_segment_hit_at_known_distance_and_misses():
    seg = np.array([[[3.0, -1.0], [3.0, 1.0]]])
    laser = LaserModel(beams=360, max_range=10.0, **EXACT)
    angles = laser.angles()
    r = cast(seg, np.array([[0.0, 0.0, 0.0]]), laser)[0]
    ahead = int(np.argmin(np.abs(angles)))
    assert r[ahead] == pytest.approx(3.0, abs=1e-12)
    hit = np.abs(np.tan(angles)) * 3.0 <= 1.0 - 1e-9
    hit &= np.cos(angles) > 0
    np.testing.assert_allclose(r[hit], 3.0 / np.cos(angles[hit]), atol=1e-12)
    assert np.all(r[~hit] == 10.0)  # misses read exactly max range
    # Moving the sensor 1 m back adds exactly 1 m along the x axis.
    r2 = cast(seg, np.array([[-1.0, 0.0, 0.0]]), laser)[0]
    assert r2[ahead] == pytest.approx(4.0, abs=1e-12)


def test_segment_seen_from_behind_rotated_sensor():
    seg = np.array([[[-1.0, 2.0], [1.0, 2.0]]])  # wall 2 m to the left (+y)
    laser = LaserModel(fov_deg=180.0, beams=181, max_range=10.0, **EXACT)
    # Sensor facing +y: the beam at bearing 0 hits at 2 m.
    r = cast(seg, np.array([[0.0, 0.0, np.pi / 2]]), laser)[0]
    assert r[90] == pytest.approx(2.0, abs=1e-12)
    # Facing -y the wall is behind the 180-degree field of view.
    r = cast(seg, np.array([[0.0, 0.0, -np.pi / 2]]), laser)[0]
    assert np.all(r == 10.0)


def test_beam_parallel_to_segment_does_not_hit_it():
    seg = np.array([[[1.0, 0.5], [4.0, 0.5]]])  # parallel to the beam at bearing 0
    laser = LaserModel(fov_deg=2.0, beams=3, max_range=10.0, **EXACT)  # bearings -1, 0, 1 deg
    r = cast(seg, np.array([[0.0, 0.0, 0.0]]), laser)[0]
    assert r[1] == 10.0
    assert r[0] == 10.0  # pointing away from the segment
    # +1 degree reaches y = 0.5 at x = 28.6 m, beyond the segment's end: a miss.
    assert r[2] == 10.0
    # Tilt the sensor so the +1-degree beam meets the line at x = 0.5 / tan(11 deg).
    tilt = np.radians(10.0)
    r = cast(seg, np.array([[0.0, 0.0, tilt]]), laser)[0]
    assert r[2] == pytest.approx(0.5 / np.sin(np.radians(11.0)), abs=1e-12)


def test_segments_beyond_max_range_are_misses():
    seg = np.array([[[30.0, -5.0], [30.0, 5.0]], [[-2.0, -5.0], [-2.0, 5.0]]])
    laser = LaserModel(beams=8, max_range=25.0, **EXACT)  # bearings -180, -135, ... 135
    r = cast(seg, np.array([[0.0, 0.0, 0.0]]), laser)[0]
    assert r[4] == 25.0  # 30 m ahead, out of range
    assert r[0] == pytest.approx(2.0)  # the near wall behind
    assert r[1] == pytest.approx(2.0 * np.sqrt(2.0))


def test_nearest_of_several_segments_wins():
    seg = np.array([[[x, -1.0], [x, 1.0]] for x in (5.0, 2.0, 8.0)])
    laser = LaserModel(fov_deg=10.0, beams=11, max_range=20.0, **EXACT)
    r = cast(seg, np.array([[0.0, 0.0, 0.0]]), laser)[0]
    np.testing.assert_allclose(r, 2.0 / np.cos(laser.angles()), atol=1e-12)


def test_noise_and_dropout_statistics():
    d, sigma, p = 3.0, 0.05, 0.1
    laser = LaserModel(beams=360, max_range=10.0, noise_sigma=sigma, dropout=p)
    poses = np.zeros((200, 3))
    exact = cast(square_room(d), poses, LaserModel(beams=360, max_range=10.0, **EXACT))
    r = cast(square_room(d), poses, laser, np.random.default_rng(1))
    dropped = r == 0.0
    n = r.size
    assert abs(dropped.mean() - p) < 5 * np.sqrt(p * (1 - p) / n)
    resid = (r - exact)[~dropped]
    assert abs(resid.mean()) < 5 * sigma / np.sqrt(resid.size)
    assert resid.std() == pytest.approx(sigma, rel=0.03)


def test_misses_stay_exactly_max_range_under_noise():
    seg = np.array([[[3.0, -1.0], [3.0, 1.0]]])
    laser = LaserModel(beams=360, max_range=10.0, noise_sigma=0.5, dropout=0.0)
    r = cast(seg, np.zeros((50, 3)), laser, np.random.default_rng(0))
    miss = cast(seg, np.zeros((50, 3)), LaserModel(beams=360, max_range=10.0, **EXACT)) == 10.0
    assert np.all(r[miss] == 10.0)
    assert np.all((r[~miss] > 0.0) & (r[~miss] < 10.0))  # noisy returns stay returns


def test_trace_matches_brute_force_on_generated_worlds():
    for name in ("box", "surface"):
        world = make_world(name, np.random.default_rng(4))
        rng = np.random.default_rng(5)
        idx = rng.integers(0, len(world.route), 15)
        poses = np.column_stack([world.route[idx], rng.uniform(-np.pi, np.pi, 15)])
        for laser in (LaserModel(**EXACT), LaserModel(fov_deg=200.0, beams=301, max_range=6.0)):
            got = trace(world.segments, poses, laser.angle_min, laser.angle_increment,
                        laser.beams, laser.max_range)
            ref = brute_force(world.segments, poses, laser)
            assert np.array_equal(np.isfinite(got), np.isfinite(ref))
            fin = np.isfinite(ref)
            np.testing.assert_allclose(got[fin], ref[fin], atol=1e-9)


def random_segments(rng: np.random.Generator, n: int) -> np.ndarray:
    centre = rng.uniform(-3, 3, size=(n, 2))
    direction = rng.uniform(-np.pi, np.pi, n)
    half = rng.uniform(0.2, 2.0, n)
    offset = half[:, None] * np.column_stack([np.cos(direction), np.sin(direction)])
    return np.stack([centre - offset, centre + offset], axis=1)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    fov=st.one_of(st.just(360.0), st.floats(5.0, 359.0)),
    beams=st.integers(2, 400),
    max_range=st.floats(0.5, 20.0),
)
def test_trace_matches_brute_force_on_random_segments(seed, fov, beams, max_range):
    rng = np.random.default_rng(seed)
    seg = random_segments(rng, 15)
    poses = np.column_stack([rng.uniform(-4, 4, size=(4, 2)), rng.uniform(-np.pi, np.pi, 4)])
    laser = LaserModel(fov_deg=fov, beams=beams, max_range=max_range, **EXACT)
    got = trace(seg, poses, laser.angle_min, laser.angle_increment, laser.beams, laser.max_range)
    ref = brute_force(seg, poses, laser)
    np.testing.assert_array_equal(np.isfinite(got), np.isfinite(ref))
    fin = np.isfinite(ref)
    np.testing.assert_allclose(got[fin], ref[fin], rtol=1e-9, atol=1e-9)


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    dx=st.floats(-50, 50),
    dy=st.floats(-50, 50),
    rot=st.floats(-np.pi, np.pi),
)
def test_ranges_invariant_under_rigid_motion_of_world_and_sensor(seed, dx, dy, rot):
    rng = np.random.default_rng(seed)
    seg = random_segments(rng, 12)
    poses = np.column_stack([rng.uniform(-4, 4, size=(5, 2)), rng.uniform(-np.pi, np.pi, 5)])
    laser = LaserModel(beams=90, max_range=15.0, **EXACT)
    motion = np.array([dx, dy, rot])
    seg2 = se2.transform_points(motion, seg.reshape(-1, 2)).reshape(-1, 2, 2)
    poses2 = se2.compose(motion, poses)
    r1 = trace(seg, poses, laser.angle_min, laser.angle_increment, laser.beams, laser.max_range)
    r2 = trace(seg2, poses2, laser.angle_min, laser.angle_increment, laser.beams,
               laser.max_range)
    # A grazing hit at a segment's very end may flip under rounding: allow one beam.
    assert np.count_nonzero(np.isfinite(r1) != np.isfinite(r2)) <= 1
    both = np.isfinite(r1) & np.isfinite(r2)
    np.testing.assert_allclose(r1[both], r2[both], rtol=1e-7, atol=1e-7)


def test_empty_world_reads_max_range():
    laser = LaserModel(beams=16, max_range=7.0, **EXACT)
    r = cast(np.zeros((0, 2, 2)), np.zeros((3, 3)), laser)
    assert r.shape == (3, 16) and np.all(r == 7.0)


# --------------------------------------------------------------------------- worlds


def test_free_space_test_on_hand_made_world():
    outer = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
    box = np.array([[4.0, 4.0], [6.0, 4.0], [6.0, 6.0], [4.0, 6.0]])
    world = World("box", [outer, box], (0, 0, 10, 10), np.array([[1.0, 1.0], [2.0, 2.0]]), 0.5)
    pts = np.array([[1.0, 1.0], [5.0, 5.0], [11.0, 5.0], [3.5, 5.0], [3.9, 5.0]])
    np.testing.assert_array_equal(world.is_free(pts), [True, False, False, True, True])
    np.testing.assert_array_equal(world.is_free(pts, margin=0.3), [True, False, False, True, False])
    np.testing.assert_allclose(point_segment_distance(pts[:1], world.segments), [1.0])


@pytest.mark.parametrize("name", ["box", "surface"])
def test_route_is_clear_and_revisits_its_crossing(name):
    world = make_world(name, np.random.default_rng(2))
    assert world.is_free(world.route).all()
    assert world.distance_to_walls(world.route).min() >= world.clearance - 1e-6
    # A figure-eight: the crossing is passed twice per lap, half a lap apart.
    n = len(world.route)
    outer = np.concatenate([world.route[: n // 4], world.route[3 * n // 4 :]])
    middle = world.route[n // 4 : 3 * n // 4]
    assert np.linalg.norm(outer[:, None] - middle[None], axis=-1).min() < 0.1


def test_box_has_corners_and_surface_has_none():
    for seed in range(3):
        box = make_world("box", np.random.default_rng(seed))
        surface = make_world("surface", np.random.default_rng(seed))
        box_turns = np.concatenate([turning_angles(lp) for lp in box.loops])
        surf_turns = np.concatenate([turning_angles(lp) for lp in surface.loops])
        assert np.degrees(box_turns.max()) == pytest.approx(90.0, abs=1e-6)
        assert np.sum(np.degrees(box_turns) > 80.0) >= 4 * 20  # many boxes, 4 corners each
        assert np.degrees(surf_turns.max()) < 35.0
        assert len(surface.loops) >= 15  # cluttered: many obstacles
        assert len(surface.segments) > 5 * len(box.segments)  # finely discretised curves


def test_unknown_world_is_a_user_error():
    with pytest.raises(UserError, match="unknown world"):
        simulate_run("forest")
    with pytest.raises(UserError, match="seed"):
        simulate_run("box", seed=-1)


# --------------------------------------------------------------------------- motion


def test_drive_constant_speed_and_rate():
    world = make_world("box", np.random.default_rng(0))
    cfg = MotionConfig(speed=0.5, rate_hz=4.0, laps=1.0, lateral_offset=0.0)
    stamps, poses = drive(world.route, cfg, np.random.default_rng(0))
    np.testing.assert_allclose(np.diff(stamps), 0.25)
    step = np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1)
    np.testing.assert_allclose(step, 0.125, rtol=0.01)
    # Heading along the direction of travel.
    travel = np.arctan2(*np.diff(poses[:, :2], axis=0)[:, ::-1].T)
    assert np.abs(se2.wrap_angle(travel - poses[:-1, 2])).max() < np.radians(3.0)
    # Without lateral offset the robot is on the route.
    assert point_segment_distance(poses[:, :2], segments_from_loops([world.route])).max() < 1e-3


def test_odometry_without_noise_is_exact_and_biases_are_hand_checked():
    poses = np.column_stack([np.linspace(0, 10, 101), np.zeros(101), np.zeros(101)])
    zero = OdometryNoise(0, 0, 0, 0, 0, 0, 0)
    np.testing.assert_allclose(wheel_odometry(poses, zero, np.random.default_rng(0)), poses,
                               atol=1e-12)
    scaled = wheel_odometry(poses, OdometryNoise(0, 0, 0, 0, 0.02, 0, 0), np.random.default_rng(0))
    np.testing.assert_allclose(scaled[-1], [10.2, 0.0, 0.0], atol=1e-12)
    bias = 0.01  # rad/m over 100 steps of 0.1 m: heading k * 0.001 after k steps
    turned = wheel_odometry(poses, OdometryNoise(0, 0, 0, 0, 0, 0, bias), np.random.default_rng(0))
    assert turned[-1, 2] == pytest.approx(bias * 10.0)
    k = np.arange(100)
    x = np.sum(0.1 * np.cos(k * 0.001))
    y = np.sum(0.1 * np.sin(k * 0.001))
    np.testing.assert_allclose(turned[-1, :2], [x, y], atol=1e-12)


def test_odometry_drifts_and_ground_truth_is_exact(box_run):
    gt = box_run.ground_truth.xytheta()
    od = np.array([s.odom for s in box_run.scans])
    np.testing.assert_allclose(box_run.odometry.xytheta(), od, atol=1e-9)
    assert np.allclose(od[0], gt[0])
    err = se2.between(gt, od)
    pos_err = np.hypot(err[:, 0], err[:, 1])
    n = len(pos_err)
    assert pos_err[-1] > 0.1
    assert pos_err[-n // 10 :].mean() > 3 * pos_err[: n // 10].mean()
    # Ground truth is exact: the noise-free scan from it matches the recorded one.
    laser = box_run.laser
    clean = cast(box_run.world, gt[:50], LaserModel(laser.fov_deg, laser.beams, laser.max_range,
                                                    **EXACT))
    rec = np.array([s.ranges for s in box_run.scans[:50]])
    valid = (rec > 0) & (rec < laser.max_range)
    assert np.abs(rec - clean)[valid].max() < 6 * laser.noise_sigma
    # Stamps: one per scan, strictly increasing, same in scans and ground truth.
    np.testing.assert_array_equal([s.stamp for s in box_run.scans], box_run.ground_truth.stamps)


@pytest.mark.parametrize("fixture", ["box_run", "surface_run"])
def test_every_scan_pose_is_in_free_space(fixture, request):
    run = request.getfixturevalue(fixture)
    xy = run.ground_truth.xytheta()[:, :2]
    assert run.world.is_free(xy, margin=0.5).all()
    ranges = np.array([s.ranges for s in run.scans])
    assert np.all((ranges == 0.0) | (ranges > 0.5))  # nothing closer than the clearance


@pytest.mark.parametrize("fixture", ["box_run", "surface_run"])
def test_trajectory_revisits_places_after_long_excursions(fixture, request):
    run = request.getfixturevalue(fixture)
    assert 500 <= len(run.scans) <= 1500
    pairs = run.revisits(radius=1.0, min_gap_s=60.0)
    assert len(pairs) > 100
    # Most of the first lap is revisited on the second one.
    lap_scans = len(run.scans) // 2
    revisited = np.unique(pairs[:, 0][pairs[:, 0] < lap_scans])
    assert len(revisited) > 0.8 * lap_scans
    # ...after an excursion far from the place.
    gt = run.ground_truth.xytheta()[:, :2]
    i, j = pairs[len(pairs) // 2]
    assert np.linalg.norm(gt[i : j + 1] - gt[i], axis=1).max() > 5.0


def test_run_is_deterministic_for_a_seed():
    cfg = MotionConfig(laps=0.2)
    a = simulate_run("surface", seed=7, motion=cfg)
    b = simulate_run("surface", seed=7, motion=cfg)
    c = simulate_run("surface", seed=8, motion=cfg)
    np.testing.assert_array_equal(a.world.segments, b.world.segments)
    np.testing.assert_array_equal(a.ground_truth.poses, b.ground_truth.poses)
    for sa, sb in zip(a.scans, b.scans, strict=True):
        np.testing.assert_array_equal(sa.ranges, sb.ranges)
        np.testing.assert_array_equal(sa.odom, sb.odom)
    assert not np.array_equal(a.scans[0].ranges, c.scans[0].ranges)
    assert not np.array_equal(a.ground_truth.poses, c.ground_truth.poses)


def test_fov_option_shapes_scans(box_run):
    run = simulate_run("box", seed=0, fov_deg=180.0, beams=181, motion=MotionConfig(laps=0.1))
    s = run.scans[0]
    assert len(s.ranges) == 181 and s.fov == pytest.approx(np.pi)  # first to last beam
    assert s.angles[0] == pytest.approx(-np.pi / 2) and s.angles[-1] == pytest.approx(np.pi / 2)
    full = box_run.scans[0]
    assert len(full.ranges) == 360 and full.fov == pytest.approx(2 * np.pi)
    assert np.all(np.isfinite(full.ranges))


# --------------------------------------------------------------------------- places


@pytest.mark.parametrize("name", ["box", "surface"])
def test_place_dataset_shapes_labels_and_geometry(name):
    data = place_dataset(name, seed=0)
    assert len(data) == 11 * 21
    labels = [label for label, _ in data]
    assert sorted(set(labels)) == [f"place{i:02d}" for i in range(11)]
    assert all(labels.count(f"place{i:02d}") == 21 for i in range(11))
    assert labels == sorted(labels)  # grouped by place
    poses = np.array([s.odom for _, s in data]).reshape(11, 21, 3)
    centres = poses[:, :, :2].mean(axis=1)
    spread = np.linalg.norm(poses[:, :, :2] - centres[:, None], axis=-1)
    assert spread.max() < 2 * 0.3 + 1e-9  # every scan within the displacement disc
    assert spread.mean() > 0.05  # displacement varies
    assert np.ptp(poses[:, :, 2]) > np.pi  # orientation varies
    gaps = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    assert gaps[~np.eye(11, dtype=bool)].min() > 2.0  # places are distinct
    world = make_world(name, streams(0)[STREAM_WORLD])
    assert world.is_free(poses.reshape(-1, 3)[:, :2], margin=0.5).all()
    scan = data[0][1]
    assert len(scan.ranges) == 360 and scan.fov == pytest.approx(2 * np.pi)
    assert np.mean(scan.valid) > 0.8


def test_place_dataset_custom_sizes_and_errors():
    data = place_dataset("box", places=3, scans_per_place=4, seed=1, displacement=0.0)
    assert [label for label, _ in data] == ["place00"] * 4 + ["place01"] * 4 + ["place02"] * 4
    poses = np.array([s.odom for _, s in data])
    np.testing.assert_allclose(poses[:4, :2], np.repeat(poses[:1, :2], 4, axis=0))
    with pytest.raises(UserError):
        place_dataset("box", places=200, seed=0)


# --------------------------------------------------------------------------- files


def test_write_run_round_trips_through_the_readers(tmp_path):
    carmen = pytest.importorskip("data.carmen", reason="data.carmen not available yet")
    trajectory_io = pytest.importorskip("data.trajectory_io",
                                        reason="data.trajectory_io not available yet")
    run = simulate_run("box", seed=2, motion=MotionConfig(laps=0.25))
    paths = write_run(run, tmp_path / "out")
    assert set(paths) == {"log", "groundtruth", "world"}
    assert all(p.is_file() for p in paths.values())
    scans = list(carmen.CarmenLog(paths["log"]))
    assert len(scans) == len(run.scans)
    for a, b in zip(run.scans, scans, strict=True):
        assert b.stamp == pytest.approx(a.stamp, abs=1e-6)
        np.testing.assert_allclose(b.ranges, a.ranges, atol=1e-4)
        np.testing.assert_allclose(b.angles, a.angles, atol=1e-9)
        np.testing.assert_array_equal(b.valid, a.valid)
        np.testing.assert_allclose(b.odom, a.odom, atol=1e-5)
        assert b.max_range == a.max_range
    gt = trajectory_io.read_tum(paths["groundtruth"])
    np.testing.assert_allclose(gt.xytheta(), run.ground_truth.xytheta(), atol=1e-6)
    np.testing.assert_allclose(gt.stamps, run.ground_truth.stamps)
    meta = json.loads(paths["world"].read_text())
    assert meta["seed"] == 2
    assert len(meta["world"]["segments"]) == len(run.world.segments)
    assert meta["params"]["laser"]["beams"] == 360
