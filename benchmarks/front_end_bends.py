"""Where and why the ``icp2d`` front end holds a GMapping-corrected log's scans badly.

Run from the repository root::

    python benchmarks/front_end_bends.py [--data DIR] [--logs intel-corrected,...]
        [--spans FIRST:LAST,...] [--true-odometry] [--all] [--variant NAME:key=value,...]

Each log is read as ``loopclosure bench slam LOG --odometry-noise 0
--reference-from-log`` reads it (`evaluation.slam_input.load_input`: the simulator's
drifting wheel odometry of the logged poses, seed 0; ``--true-odometry``: the logged
poses themselves as odometry, a perfect seed), and every variant (default
`slam.config.PipelineConfig` with ``key=value`` overrides of ``loopclosure run
--set``) runs the front end alone (`slam.odometry.icp2d.Icp2dOdometry`) and the
keyframe selection (`slam.keyframes.KeyframeSelector`) on it.  Per variant:

* ``status``: the count of each estimate status, and of kidnaps (an odometry jump
  the map did not confirm: the map restarts and the pose follows the odometry);
* ``rpe_rot``: RMS [deg] of the heading difference between the front end's and
  the reference's consecutive increments;
* ``turn_scale``: over the turns on the spot (step under 0.2 m, turn over 10 deg),
  the least-squares factor ``k`` of ``error = k * turn`` [%]: a systematic under- or
  over-estimated rotation of ICP would show here;
* per span ``FIRST:LAST`` of keyframes: every keyframe's scan registered (point to
  line, `benchmarks.tolerance_cases.FINE`) onto the other keyframes' scans of the
  span as the front end places them, started at its place: the median and the
  largest turn [deg] ICP makes (a scan the front end holds badly turns), and
  ``end-vs-ref``: the heading [deg] of the span's last keyframe relative to its
  first, the front end's minus the reference's (how far the span is bent against
  the reference);
* with ``--all``: the same turn for every keyframe onto its five neighbours on each
  side (`benchmarks.tolerance_cases.keyframe_consistency`), its median, 90th
  percentile and the shares above 1 and 2 degrees.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from tolerance_cases import FINE  # noqa: E402

from data import se2  # noqa: E402
from evaluation.slam_input import load_input  # noqa: E402
from loopclosure.registration import RegistrationTarget, register  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402
from slam.config_io import apply_overrides  # noqa: E402
from slam.keyframes import KeyframeSelector  # noqa: E402
from slam.odometry.icp2d import Icp2dOdometry  # noqa: E402


def turn_onto(points: np.ndarray, others: np.ndarray) -> float:
    """|heading| [deg] ICP turns `points` onto `others` (same frame), from identity;
    NaN when ICP fails."""
    r = register(np.asarray(points, float), RegistrationTarget(others, FINE), np.zeros(3),
                 config=FINE)
    return abs(float(np.degrees(r.pose[2]))) if r.ok else float("nan")


def span_turns(keyframes, poses: np.ndarray, ids: list[int], i: int) -> float:
    """Turn of keyframe i's scan onto the scans of `ids` (i left out) placed by `poses`."""
    others = np.vstack([se2.transform_points(se2.between(poses[i], poses[j]),
                                             keyframes[j].points) for j in ids if j != i])
    return turn_onto(keyframes[i].points, others)


def turn_scale(front: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    """(RMS heading error of consecutive increments [deg], turn-on-the-spot factor [%])."""
    ri = np.array([se2.between(ref[k], ref[k + 1]) for k in range(len(ref) - 1)])
    fi = np.array([se2.between(front[k], front[k + 1]) for k in range(len(ref) - 1)])
    err = np.degrees([se2.between(a, b)[2] for a, b in zip(ri, fi, strict=True)])
    turn, step = np.degrees(ri[:, 2]), np.hypot(ri[:, 0], ri[:, 1])
    spot = (step < 0.2) & (np.abs(turn) > 10)
    k = np.sum(err[spot] * turn[spot]) / max(np.sum(turn[spot] ** 2), 1e-12)
    return float(np.sqrt(np.mean(err ** 2))), 100 * float(k)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default="../shared/data")
    ap.add_argument("--logs", default="intel-corrected")
    ap.add_argument("--spans", default="10:30,541:562", help="FIRST:LAST keyframes")
    ap.add_argument("--true-odometry", action="store_true")
    ap.add_argument("--all", action="store_true", help="every keyframe onto its neighbours")
    ap.add_argument("--variant", action="append", default=[],
                    help="NAME:key=value,key=value (repeatable)")
    args = ap.parse_args()
    variants = args.variant or ["default:"]
    for log in args.logs.split(","):
        name = log if log.endswith("-corrected") else f"{log}-corrected"
        data = load_input(Path(args.data) / "carmen-corrected" / f"{name}.log.gz",
                          odometry_noise=None if args.true_odometry else 0)
        ref = np.asarray(data.logged_poses, float)
        print(f"== {name}: {len(data.scans)} scans, odometry "
              f"{'= the logged poses' if args.true_odometry else 'synthetic, seed 0'}")
        for v in variants:
            vname, _, sets = v.partition(":")
            cfg = apply_overrides(PipelineConfig(), [s for s in sets.split(",") if s])
            start = time.perf_counter()
            front_end, sel = Icp2dOdometry(cfg.icp2d), KeyframeSelector(cfg.keyframes)
            est = []
            for scan in data.scans:
                e = front_end.process(scan)
                sel.push(scan, e)
                est.append(e)
            seconds = time.perf_counter() - start
            kfs = sel.keyframes
            kp = np.array([k.odom_pose for k in kfs])
            status: dict[str, int] = {}
            for e in est:
                status[e.status] = status.get(e.status, 0) + 1
            kidnaps = sum(bool(e.extra.get("kidnap")) for e in est)
            rpe, scale = turn_scale(np.array([e.pose for e in est]), ref)
            line = (f"{vname}: {seconds:.1f} s, {len(kfs)} keyframes, status {status}, "
                    f"kidnaps {kidnaps}, rpe_rot {rpe:.3f} deg, turn_scale {scale:+.2f} %")
            for span in args.spans.split(","):
                lo, hi = map(int, span.split(":"))
                if hi >= len(kfs):
                    continue
                ids = list(range(lo, hi + 1))
                turns = {i: span_turns(kfs, kp, ids, i) for i in ids}
                worst = max(ids, key=lambda i: np.nan_to_num(turns[i]))
                e = se2.between(se2.between(kp[lo], kp[hi]),
                                se2.between(ref[kfs[lo].scan_index], ref[kfs[hi].scan_index]))
                line += (f"\n    span {lo}-{hi}: turns median "
                         f"{np.nanmedian(list(turns.values())):.2f} max {turns[worst]:.2f} deg "
                         f"(keyframe {worst}), end-vs-ref {np.degrees(e[2]):+.2f} deg")
            if args.all:
                t = np.array([span_turns(kfs, kp, list(range(max(0, i - 5),
                                                             min(len(kfs), i + 6))), i)
                              for i in range(len(kfs))])
                t = t[np.isfinite(t)]
                line += (f"\n    every keyframe onto its neighbours: median {np.median(t):.3f} "
                         f"p90 {np.percentile(t, 90):.3f} deg, > 1 deg {np.mean(t > 1):.3f}, "
                         f"> 2 deg {np.mean(t > 2):.3f}")
            print(line, flush=True)


if __name__ == "__main__":
    main()
