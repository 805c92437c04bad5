"""The laser-model diagnostics of the front end: beam timing of a sweeping laser
(`benchmarks/sweep_distortion.py`) and the beam layout, range scale and along/across
errors of short relations (`benchmarks/laser_layout.py`)."""

from __future__ import annotations

import numpy as np

from data import se2
from data.raycast import cast
from data.sim import MotionConfig, simulate_run
from data.types import Scan
from tests.helpers import load_benchmark


def test_beam_times_of_a_sweep_and_an_interlaced_sick() -> None:
    """181 beams over 180 degrees of a 1/75 s turn: the last beam 1/150 s after the first.
    361 interlaced beams: the odd ones a turn later, beam 2 one half-sweep step on."""
    bench = load_benchmark("sweep_distortion")
    period = 1.0 / 75.0
    assert not bench.beam_times(181, 180.0, period, "instant").any()
    sweep = bench.beam_times(181, 180.0, period, "sweep")
    assert sweep[0] == 0.0 and abs(sweep[-1] - period / 2) < 1e-15
    assert abs(sweep[90] - period / 4) < 1e-15
    inter = bench.beam_times(361, 180.0, period, "interlaced")
    assert inter[0] == 0.0 and abs(inter[1] - period) < 1e-15
    assert abs(inter[2] - period / 2 / 180) < 1e-15
    assert abs(inter[360] - period / 2) < 1e-15  # even: the end of the first sweep
    assert abs(inter[359] - (period + period / 2 * 179 / 180)) < 1e-15


def test_interpolate_halfway_and_across_pi() -> None:
    """Halfway between two poses in time: the mean position, and the heading turned the
    short way across +-pi (3.1 to -3.1 rad is a turn of 0.083 rad, not 6.2)."""
    bench = load_benchmark("sweep_distortion")
    truth = np.array([[0.0, 0.0, 3.1], [1.0, 2.0, -3.1]])
    got = bench.interpolate(truth, np.array([10.0, 10.2]), np.array([10.1]))
    half = 3.1 + (2 * np.pi - 6.2) / 2
    np.testing.assert_allclose(got, [[0.5, 1.0, half]], atol=1e-12)


def test_instant_timing_reproduces_the_simulator() -> None:
    """Without noise or dropout, ``instant`` beams are the simulator's own cast at the
    stamps; a sweep differs (the robot moves during it) by millimetres only."""
    bench = load_benchmark("sweep_distortion")
    run = simulate_run("box", seed=1, fov_deg=180.0, beams=181, max_range=30.0,
                       noise_sigma=0.0, dropout=0.0,
                       motion=MotionConfig(speed=0.5, rate_hz=5.0, laps=0.05))
    rng = np.random.default_rng(0)
    instant = bench.distorted_ranges(run, 5, 1 / 75, "instant", rng)
    exact = cast(run.world, run.ground_truth.xytheta()[:5], run.laser)
    np.testing.assert_array_equal(instant, exact)
    swept = bench.distorted_ranges(run, 5, 1 / 75, "sweep", rng)
    hit = exact < run.laser.max_range
    diff = np.abs(swept - exact)[hit]
    assert 0.0 < np.median(diff) < 0.01


def test_along_and_across_errors_of_a_relation() -> None:
    """Reference (0.3, 0.4): an estimate 2 % longer is +0.02 along (+0.01 m, 0 across);
    an error (-0.04, 0.03) is 0.05 m to the left; a 1 cm relation is left out."""
    bench = load_benchmark("laser_layout")
    ref = se2.to_se3(np.array([[0.3, 0.4, 0.1], [0.3, 0.4, 0.1], [0.01, 0.0, 0.0]]))
    est = se2.to_se3(np.array([[0.306, 0.408, 0.1], [0.26, 0.43, 0.1], [0.02, 0.0, 0.0]]))
    scale = bench.along_error(est, ref)
    np.testing.assert_allclose(scale[:2], [0.02, 0.0], atol=1e-12)
    assert np.isnan(scale[2])
    along, across = bench.along_across(est, ref)
    np.testing.assert_allclose(along[:2], [0.01, 0.0], atol=1e-12)
    np.testing.assert_allclose(across[:2], [0.0, 0.05], atol=1e-12)
    assert np.isnan(along[2]) and np.isnan(across[2])


def test_relayout_rebears_beams_and_scales_only_returns() -> None:
    """Beams re-borne at -89.5 + i degrees; a 2 % range scale leaves no-return and
    zero readings as they were."""
    bench = load_benchmark("laser_layout")
    ranges = np.array([1.0, 0.0, 50.0, 2.0])
    scan = Scan(stamp=1.0, ranges=ranges, angles=np.radians([-90.0, -89.0, -88.0, -87.0]),
                max_range=50.0)
    moved = bench.relayout(scan, -89.5, 1.0, 1.02)
    np.testing.assert_allclose(np.degrees(moved.angles), [-89.5, -88.5, -87.5, -86.5])
    np.testing.assert_allclose(moved.ranges, [1.02, 0.0, 50.0, 2.04])
    assert scan.ranges[0] == 1.0  # the input is not changed
    same = bench.relayout(scan, None, None, 1.0)
    np.testing.assert_array_equal(same.angles, scan.angles)
