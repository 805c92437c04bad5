"""Benchmark: the icp2d front end's local precision when the laser's beams are not
taken at one instant (a rotating mirror's sweep, a SICK's interlaced 0.5-degree mode).

Run from the repository root::

    python benchmarks/sweep_distortion.py [--sim-scans N] [--speed M_S] [--period S]
        [--variant NAME:key=value,key=value ...]

The simulated runs of `benchmarks/front_end_precision.py` (the ``box`` and
``surface`` worlds, half a figure-eight at ``--speed`` m/s and 5 Hz, 180-degree
lasers of 181 beams at 1 degree and 361 at 0.5 degree, 1 cm Gaussian range noise,
1 % dropout) are cast again with each beam from the robot's true pose at the
instant the mirror points it out (`beam_times`), the scan's stamp being the
instant of beam 0.  Timing modes (``--period`` the mirror's turn, 1/75 s for a
SICK LMS):

- ``instant``: every beam at the stamp (the simulator's own scans);
- ``sweep``: beam ``j`` of ``N`` at ``j / (N - 1) * fov / 360 * period``;
- ``interlaced`` (361 beams only): a SICK LMS at 0.5 degree takes the even beams in
  one turn and the odd ones in the next (a 1-degree sweep each), so beam ``j`` is
  at ``(j mod 2) * period + (j // 2) / ((N - 1) / 2) * fov / 360 * period``.

Poses between two scan stamps are interpolated linearly (position and unwrapped
heading) between the true poses at the stamps.  Beams are cast in `TIME_BINS`
groups of equal time (each group from one pose).  The error is the mean over
consecutive scans of the translation [m] and rotation [deg] of the relative-pose
error against the true poses at the stamps (a constant-twist motion gives the
same relative pose at any fixed phase of the sweep).  Every variant (``--set``
syntax of ``loopclosure run``, keys under ``icp2d.``) runs on the same scans.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from front_end_precision import SIM_LASERS, SIM_WORLDS, consecutive_error, front_end  # noqa: E402

from data.raycast import LaserModel, cast  # noqa: E402
from data.sim import MotionConfig, simulate_run  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402
from slam.config_io import apply_overrides  # noqa: E402

TIME_BINS = 24
SICK_PERIOD_S = 1.0 / 75.0


def beam_times(beams: int, fov_deg: float, period: float, mode: str) -> np.ndarray:
    """Time [s] after the scan's stamp at which each of `beams` beams is taken (module doc)."""
    j = np.arange(beams, dtype=float)
    sweep = fov_deg / 360.0 * period
    if mode == "instant":
        return np.zeros(beams)
    if mode == "sweep":
        return j / (beams - 1) * sweep
    if mode == "interlaced":
        half = (beams - 1) / 2.0
        return (j % 2) * period + (j // 2) / half * sweep
    raise ValueError(f"unknown timing mode {mode!r}")


def interpolate(truth: np.ndarray, stamps: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``(K, 3)`` poses at times `t` [s], linear between the ``(M, 3)`` `truth` poses
    at `stamps` (heading unwrapped first)."""
    heading = np.unwrap(truth[:, 2])
    return np.column_stack([np.interp(t, stamps, truth[:, 0]),
                            np.interp(t, stamps, truth[:, 1]),
                            np.interp(t, stamps, heading)])


def distorted_ranges(run, n_scans: int, period: float, mode: str,
                     rng: np.random.Generator) -> np.ndarray:
    """``(n_scans, N)`` noisy ranges of `run`'s laser with beams at `beam_times`."""
    laser = run.laser
    n_scans = min(n_scans, len(run.scans))
    stamps = run.ground_truth.stamps
    truth = run.ground_truth.xytheta()
    times = beam_times(laser.beams, laser.fov_deg, period, mode)
    exact = LaserModel(fov_deg=laser.fov_deg, beams=laser.beams, max_range=laser.max_range,
                       noise_sigma=0.0, dropout=0.0)
    edges = np.linspace(times.min(), times.max() + 1e-12, TIME_BINS + 1)
    group = np.clip(np.searchsorted(edges, times, side="right") - 1, 0, TIME_BINS - 1)
    out = np.empty((n_scans, laser.beams))
    for g in np.unique(group):
        cols = group == g
        t = stamps[:n_scans] + times[cols].mean()
        out[:, cols] = cast(run.world, interpolate(truth, stamps, t), exact)[:, cols]
    hit = out < laser.max_range
    noisy = out + rng.normal(0.0, laser.noise_sigma, size=out.shape)
    out = np.where(hit, np.clip(noisy, 1e-3, laser.max_range - 1e-3), out)
    out[rng.random(out.shape) < laser.dropout] = 0.0
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sim-scans", type=int, default=200, help="scans per simulated run")
    parser.add_argument("--speed", type=float, default=0.5, help="robot speed [m/s]")
    parser.add_argument("--period", type=float, default=SICK_PERIOD_S,
                        help="mirror's turn [s]")
    parser.add_argument("--variant", action="append", default=None,
                        help="NAME:key=value,key=value (repeatable; the first is the reference)")
    args = parser.parse_args()
    variants = []
    for spec in args.variant or ("defaults:",):
        name, _, sets = spec.partition(":")
        overrides = [s for s in sets.split(",") if s]
        variants.append((name, apply_overrides(PipelineConfig(), overrides).icp2d))
    motion = MotionConfig(speed=args.speed, rate_hz=5.0, laps=0.5)
    print(f"{'case':<24} {'timing':<11} {'variant':<14} {'trans m':>9} {'rot deg':>8}")
    for world in SIM_WORLDS:
        for lname, fov, beams, sigma in SIM_LASERS:
            run = simulate_run(world, seed=3, fov_deg=fov, beams=beams, max_range=30.0,
                               noise_sigma=sigma, dropout=0.01, motion=motion)
            n = min(args.sim_scans, len(run.scans))
            truth = run.ground_truth.xytheta()[:n]
            turn = np.degrees(np.abs(np.diff(np.unwrap(truth[:, 2])))).mean() * 5.0
            modes = ["instant", "sweep"] + (["interlaced"] if beams % 2 == 1 and beams > 181
                                            else [])
            for mode in modes:
                ranges = distorted_ranges(run, n, args.period, mode, np.random.default_rng(7))
                scans = [dataclasses.replace(s, ranges=r)
                         for s, r in zip(run.scans[:n], ranges, strict=True)]
                for name, cfg in variants:
                    poses, _, _, _ = front_end(scans, cfg)
                    te, re = consecutive_error(poses, truth)
                    print(f"{f'sim {world} {lname}':<24} {mode:<11} {name:<14} {te:9.5f} "
                          f"{re:8.4f}", flush=True)
            print(f"  (mean turn rate {turn:.1f} deg/s)")


if __name__ == "__main__":
    main()
