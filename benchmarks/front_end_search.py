"""The icp2d front end's multi-hypothesis search: numpy ICP against the compiled grid ICP.

Run from the repository root::

    python benchmarks/front_end_search.py LOG [LOG ...] [--limit N]

Each log (a CARMEN log; a GMapping-corrected one gets the simulator's drifting
wheel odometry of seed 0, as ``loopclosure bench slam --odometry-noise 0`` feeds
it) is registered scan by scan by `slam.odometry.icp2d.Icp2dOdometry` (defaults)
twice in this one process, the scans read before timing:

* ``numpy``: the search (and the check of an odometry jump) by
  `loopclosure.multi_start.register_multi` with numpy ICP on the map's
  `RegistrationTarget` (KD-tree prescreen), every other ICP compiled;
* ``compiled``: the default, compiled ICP on the map's grid.

It prints CPU seconds of the front end (``time.process_time``) and their ratio,
how many scans ran the search, the largest difference of a scan's pose between the
two (translation [m], rotation [deg]), and for a corrected log each one's ATE RMSE
[m] against the logged poses (`evaluation.trajectory_error`, SE(2) alignment, scans
matched by index).  The two ICPs agree to about 1e-15 in fitness; when two
hypotheses converge to nearly one pose, that rounding can decide which one ranks
first (`Icp2dOdometry._rank`), and a front end without loop closure then follows
a slightly different path: the ATE says whether that matters.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _numpy_multi(self, points, guesses, keep=None):
    from loopclosure.multi_start import register_multi

    return register_multi(points, self._grid.target, guesses, config=self.config.icp,
                          keep=keep)


def main() -> None:
    from data import se2
    from data.types import Trajectory
    from evaluation.slam_input import load_input
    from evaluation.trajectory_error import trajectory_errors
    from loopclosure.warm_up import warm_up
    from slam.odometry.icp2d import Icp2dOdometry

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("logs", nargs="+", type=Path)
    parser.add_argument("--limit", type=int, default=None, help="first N scans")
    args = parser.parse_args()
    warm_up()
    compiled = Icp2dOdometry._multi
    print(f"{'log':28s} {'scans':>6s} {'search':>6s} {'numpy s':>8s} {'compiled s':>10s} "
          f"{'ratio':>6s} {'max dt m':>9s} {'max dr deg':>10s} {'ATE numpy':>9s} "
          f"{'ATE compiled':>12s}")
    for log in args.logs:
        corrected = "corrected" in log.name
        data = load_input(log, odometry_noise=0 if corrected else None)
        scans = data.scans[: args.limit] if args.limit else data.scans
        poses, cpu, searched = {}, {}, 0
        for name, multi in (("numpy", _numpy_multi), ("compiled", compiled)):
            Icp2dOdometry._multi = multi
            try:
                front = Icp2dOdometry()
                start = time.process_time()
                out = [front.process(s) for s in scans]
                cpu[name] = time.process_time() - start
            finally:
                Icp2dOdometry._multi = compiled
            poses[name] = np.array([e.pose for e in out])
            searched = sum("search" in e.extra for e in out)
        d = np.array([se2.between(a, b) for a, b in zip(poses["numpy"], poses["compiled"],
                                                        strict=True)])
        dt = float(np.hypot(d[:, 0], d[:, 1]).max(initial=0.0))
        dr = float(np.degrees(np.abs(d[:, 2])).max(initial=0.0))
        ate = {name: float("nan") for name in poses}
        if corrected and data.logged_poses is not None:
            index = np.arange(len(scans), dtype=float)
            reference = Trajectory.from_xytheta(index, data.logged_poses[: len(scans)])
            ate = {name: trajectory_errors(Trajectory.from_xytheta(index, p), reference).ate_rmse
                   for name, p in poses.items()}
        print(f"{log.name:28s} {len(scans):6d} {searched:6d} {cpu['numpy']:8.2f} "
              f"{cpu['compiled']:10.2f} {cpu['compiled'] / cpu['numpy']:6.2f} {dt:9.2e} "
              f"{dr:10.2e} {ate['numpy']:9.4f} {ate['compiled']:12.4f}", flush=True)


if __name__ == "__main__":
    main()
