"""The icp2d front end's motion de-skew: beam delays of a sweeping or interlaced laser,
the points moved into the stamp's frame, and the front end on interlaced scans."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from data.errors import UserError
from data.sim import MotionConfig, simulate_run
from slam.odometry.icp2d import Icp2dConfig, Icp2dOdometry, beam_delays, deskew_points
from tests.helpers import load_benchmark


def test_beam_delays_by_hand() -> None:
    """361 beams over 180 degrees, a 1/75 s mirror: the last beam half a turn after the
    first; interlaced, the odd beams one turn later; "none" all zero."""
    period = 1.0 / 75.0
    angles = np.radians(np.linspace(-90.0, 90.0, 361))
    sweep = beam_delays(angles, period, "sweep")
    assert sweep[0] == 0.0 and abs(sweep[-1] - period / 2) < 1e-15
    inter = beam_delays(angles, period, "interlaced")
    assert abs(inter[1] - (period + period / 720)) < 1e-15
    assert abs(inter[2] - period / 360) < 1e-15
    assert not beam_delays(angles, period, "none").any()


def test_deskew_points_by_hand() -> None:
    """Half-way through a 0.2 m forward step, a point 1 m ahead moves to 1.1 m; at the
    end of a quarter turn, a point 1 m ahead is 1 m to the left; no delay, no move."""
    pts = np.array([[1.0, 0.0], [1.0, 0.0], [0.5, -0.5]])
    out = deskew_points(pts, np.array([0.05, 0.1, 0.0]), np.array([0.2, 0.0, 0.0]), 0.1)
    np.testing.assert_allclose(out, [[1.1, 0.0], [1.2, 0.0], [0.5, -0.5]], atol=1e-15)
    out = deskew_points(pts[:1], np.array([0.1]), np.array([0.0, 0.0, np.pi / 2]), 0.1)
    np.testing.assert_allclose(out, [[0.0, 1.0]], atol=1e-15)


def test_deskew_config_is_checked() -> None:
    with pytest.raises(UserError, match="deskew"):
        Icp2dConfig(deskew="rolling")
    with pytest.raises(UserError, match="mirror_period"):
        Icp2dConfig(mirror_period=0.0)
    with pytest.raises(UserError, match="deskew_baseline"):
        Icp2dConfig(deskew_baseline=-1.0)


def test_deskew_reduces_the_error_of_interlaced_scans() -> None:
    """Noise-free interlaced 0.5-degree scans of a robot at 1.5 m/s: de-skewed as
    interlaced, the consecutive-scan error is below the front end's without de-skew."""
    bench = load_benchmark("sweep_distortion")
    run = simulate_run("box", seed=3, fov_deg=180.0, beams=361, max_range=30.0,
                       noise_sigma=0.0, dropout=0.0,
                       motion=MotionConfig(speed=1.5, rate_hz=5.0, laps=0.3))
    n = min(60, len(run.scans))
    assert n >= 50
    ranges = bench.distorted_ranges(run, n, 1.0 / 75.0, "interlaced",
                                    np.random.default_rng(0))
    scans = [dataclasses.replace(s, ranges=r) for s, r in zip(run.scans[:n], ranges, strict=True)]
    truth = run.ground_truth.xytheta()[:n]
    errors = {}
    for mode in ("none", "interlaced"):
        odo = Icp2dOdometry(Icp2dConfig(deskew=mode))
        poses = np.array([odo.process(s).pose for s in scans])
        errors[mode] = bench.consecutive_error(poses, truth)
    assert errors["interlaced"][1] < errors["none"][1]
    assert errors["interlaced"][0] < errors["none"][0]


def test_deskew_velocity_spans_the_baseline() -> None:
    """Tracked scans at 0, 0.09, 0.1 and 0.105 s (stamps a few milliseconds apart, as
    in logs that send two scans at once): with a 0.1 s baseline the velocity joins
    the newest scan to the one at 0 s (0.105 s), not to the one 5 ms before it;
    none while no scan is old enough."""
    odo = Icp2dOdometry(Icp2dConfig(deskew="sweep", deskew_baseline=0.1))
    for t, x in ((0.0, 0.0), (0.09, 0.05), (0.1, 0.06), (0.105, 0.1)):
        odo._track.append((t, np.array([x, 0.0, 0.0])))
    velocity, dt = odo._track_velocity()
    np.testing.assert_allclose(velocity, [0.1, 0.0, 0.0], atol=1e-15)
    assert abs(dt - 0.105) < 1e-15
    odo._track.popleft()
    assert odo._track_velocity() == (None, 0.0)
