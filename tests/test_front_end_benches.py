"""The front-end benchmarks' diagnostics: the lever arm of short relations, the along-track
scale, and the noise floor of a simulated scan on an exact map."""

from __future__ import annotations

import numpy as np

from data import se2
from data.sim import MotionConfig, simulate_run
from slam.odometry.icp2d import Icp2dConfig
from tests.helpers import load_benchmark


def test_lever_arm_of_relations_of_an_offset_point() -> None:
    """Relations of a point 0.3 m ahead of the laser: the fit finds (0.3, 0) and no residual."""
    bench = load_benchmark("short_relations")
    rng = np.random.default_rng(0)
    laser = np.column_stack([rng.uniform(-0.5, 0.5, (20, 2)), rng.uniform(-0.5, 0.5, 20)])
    mount = np.array([0.3, 0.0, 0.0])
    # The same motion seen from the point at `mount`: mount^-1 (+) delta (+) mount.
    other = np.array([se2.compose(se2.compose(se2.inverse(mount), d), mount) for d in laser])
    arm, rest = bench.lever_arm(laser, other)
    # Hand check: t_laser - t_other = (R(theta) - I) l, l = -mount's translation here,
    # since the laser's relation is mount (+) other (+) mount^-1.
    np.testing.assert_allclose(arm, [-0.3, 0.0], atol=1e-12)
    np.testing.assert_allclose(rest, 0.0, atol=1e-12)
    # One relation by hand: a quarter turn, t_other = 0: t_laser = (R - I) l = (0.3, -0.3).
    quarter = np.array([0.0, 0.0, np.pi / 2])
    t_laser = se2.compose(se2.compose(mount, quarter), se2.inverse(mount))
    np.testing.assert_allclose(t_laser[:2], [0.3, -0.3], atol=1e-12)


def test_along_track_scale() -> None:
    """A relation 2 % longer along the motion reads +2 %; a sideways error reads 0; a
    relation shorter than the minimum is left out (NaN)."""
    bench = load_benchmark("short_relations")
    ref = np.array([0.3, 0.4, 0.1])
    assert abs(bench._along(np.array([0.306, 0.408, 0.1]), ref) - 0.02) < 1e-12
    assert abs(bench._along(np.array([0.3 - 0.04, 0.4 + 0.03, 0.1]), ref)) < 1e-12
    assert np.isnan(bench._along(ref, np.array([0.01, 0.0, 0.0])))


def test_noise_floor_is_millimetres_and_exact_without_noise() -> None:
    """Noise-free scans on their exact maps register to their true poses; with 1 cm noise
    the consecutive-scan error stays in millimetres."""
    bench = load_benchmark("front_end_precision")
    motion = MotionConfig(speed=0.5, rate_hz=5.0, laps=0.05)
    errors = []
    for sigma in (0.0, 0.01):
        run = simulate_run("box", seed=1, fov_deg=180.0, beams=181, max_range=30.0,
                           noise_sigma=sigma, dropout=0.0, motion=motion)
        scans = run.scans[:8]
        poses = bench.noise_floor(run, scans, Icp2dConfig())
        errors.append(bench.consecutive_error(poses, run.ground_truth.xytheta()[:8]))
    assert errors[0][0] < 2e-4 and errors[0][1] < 0.01
    assert 2e-4 < errors[1][0] < 5e-3


def test_pipeline_consecutive_errors_by_hand() -> None:
    """Four poses along x, the estimate's third step 1 cm too long and turned 0.3 deg:
    mean errors over the three steps are 1 cm / 3 and 0.3 deg / 3 (the turn comes
    after the step, so it moves no later position of that relation)."""
    bench = load_benchmark("pipeline")
    truth = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.0], [0.3, 0.0, 0.0]])
    est = truth.copy()
    est[3] = [0.31, 0.0, np.radians(0.3)]
    row = bench.consecutive(est, truth, "c_")
    assert abs(row["c_trans_m"] - 0.01 / 3) < 1e-12
    assert abs(row["c_rot_deg"] - 0.1) < 1e-9


def test_turn_scale_of_front_end_bends() -> None:
    """Turns on the spot of 30 degrees read 1 % too large: turn_scale +1 %; the straight
    steps (no turn) are left out of it, and the heading RMS is 0.3 deg over the four
    turns of eight increments: sqrt(4 * 0.3^2 / 8)."""
    bench = load_benchmark("front_end_bends")
    turn, walk = np.array([0.01, 0.0, np.radians(30)]), np.array([1.0, 0.0, 0.0])
    ref, front = [np.zeros(3)], [np.zeros(3)]
    for k in range(8):
        step = turn if k % 2 else walk
        ref.append(se2.compose(ref[-1], step))
        front.append(se2.compose(front[-1], step * np.array([1.0, 1.0, 1.01])))
    rpe, scale = bench.turn_scale(np.array(front), np.array(ref))
    assert abs(scale - 1.0) < 1e-9
    assert abs(rpe - np.sqrt(4 * 0.3 ** 2 / 8)) < 1e-9


def test_turn_onto_finds_a_scan_turned_by_two_degrees() -> None:
    """An L-shaped room's points turned by 2 degrees about the origin: ICP turns them back."""
    bench = load_benchmark("front_end_bends")
    s = np.linspace(0.0, 3.0, 150)
    room = np.vstack([np.column_stack([s, np.full_like(s, 2.0)]),
                      np.column_stack([np.full_like(s, 3.0), s - 1.0]),
                      np.column_stack([-s, np.full_like(s, -1.5)])])
    turned = se2.transform_points(np.array([0.0, 0.0, np.radians(2.0)]), room)
    assert abs(bench.turn_onto(turned, room) - 2.0) < 0.05


def test_heading_sigma_separates_reference_jitter_from_the_walk() -> None:
    """Reference = truth + white heading noise 0.4 deg, estimate = truth + a random walk
    of 0.2 deg per step: the lag fit recovers both within 10 %."""
    bench = load_benchmark("front_end_heading_sigma")
    rng = np.random.default_rng(0)
    n = 20000
    truth = np.c_[np.arange(n) * 0.5, np.zeros(n), np.zeros(n)]
    ref = truth.copy()
    ref[:, 2] += rng.normal(0.0, np.radians(0.4), n)
    est = truth.copy()
    est[:, 2] += np.cumsum(rng.normal(0.0, np.radians(0.2), n))
    jitter, walk = bench.jitter_and_walk(est, ref)
    assert abs(np.degrees(jitter) - 0.4) < 0.04
    assert abs(np.degrees(walk) - 0.2) < 0.02
