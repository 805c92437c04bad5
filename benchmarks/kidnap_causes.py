"""Which test makes the ``icp2d`` front end call an odometry jump a kidnap, and why.

Run from the repository root::

    python benchmarks/kidnap_causes.py [--data DIR] [--logs belgioioso,intel-corrected]
        [--variant NAME:key=value,...]
    python benchmarks/kidnap_causes.py --resolve OUT [OUT ...]

Each log is read as ``loopclosure bench slam LOG --odometry-noise 0
--reference-from-log`` reads it (`evaluation.slam_input.load_input`, seed 0) and the
front end (`slam.odometry.icp2d.Icp2dOdometry`, default `slam.config.PipelineConfig`
with ``--set``-style overrides) and the keyframe selection run alone.  For every
scan the jump rule flagged (``extra["odometry_step"]``) one line:

* scan and keyframe index, ``dt`` the time since the previous scan [s] (and the
  log's median);
* ``test``: which branch ended it: ``confirmed`` (a good match as fit as the recent
  ones), ``fitness`` (a good match, below `jump_fitness_ratio` times the median recent
  fitness), ``nomatch`` (no good match) or ``nomap`` (too few points / no map);
* the odometry step (length [m], turn [deg]) against the usual motion the rule scaled
  by (`_usual_motion`) and against the reference's increment (the logged poses);
* the registration there: fitness, the recent median fitness, inlier ratio, rms,
  whether the search won, and its increment's difference from the reference's
  (``icp-ref``: [m], [deg]) and from the odometry's (``icp-odo``, also in sigmas of
  the odometry model, the `jump_agreement` gate's measure);
* the odometry's own difference from the reference (``odo-ref``).

``--resolve OUT``: a ``bench slam --out`` folder's saved graph (``session.npz``: the
odometry factors and the loops the final GNC kept) re-solved (LM, Gaussian factors,
first pose fixed) as saved and with the loops the GNC rejected (``loops.csv``, their
measured ``dx, dy, dtheta``) added at the loop check's covariance floor (0.02 m,
0.5 deg): keyframe ATE [m] against the logged poses (rigid alignment) and each
rejected loop's chi-square at the solution with all loops.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from data import se2  # noqa: E402
from evaluation.slam_input import load_input  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402
from slam.config_io import apply_overrides  # noqa: E402
from slam.keyframes import KeyframeSelector  # noqa: E402
from slam.odometry.icp2d import Icp2dOdometry  # noqa: E402


def _describe_with_pose(res, extra) -> None:
    """`Icp2dOdometry._describe` that also keeps the match's pose (this script only)."""
    extra.update(inlier_ratio=res.inlier_ratio, rms=res.rms, iterations=res.iterations,
                 degeneracy=res.degeneracy, converged=res.converged,
                 icp_pose=np.asarray(res.pose, float).copy(), icp_fitness=res.fitness)


def diff(a, b) -> tuple[float, float]:
    """(|translation| [m], |rotation| [deg]) of ``between(a, b)`` of two increments."""
    d = se2.between(np.asarray(a, float), np.asarray(b, float))
    return float(np.hypot(d[0], d[1])), abs(float(np.degrees(d[2])))


def sigmas(u, d, cov) -> float:
    """Mahalanobis distance [sigma] of ``between(u, d)`` under `cov` (the
    `Icp2dConfig.jump_agreement` gate's measure)."""
    e = se2.between(np.asarray(u, float), np.asarray(d, float))
    return float(np.sqrt(e @ np.linalg.solve(cov, e)))


def resolve(out: Path) -> None:
    """Print the ``--resolve`` figures of one ``bench slam --out`` folder (docstring)."""
    import csv

    import gtsam

    sess = dict(np.load(out / "pipeline" / "session.npz"))
    d = np.loadtxt(out / "reference_logged.tum")
    ref = np.c_[d[:, 1], d[:, 2], 2.0 * np.arctan2(d[:, 6], d[:, 7])][sess["kf_scan_index"]]
    rows = [r for r in csv.DictReader(open(out / "pipeline" / "loops.csv"))
            if r["rejected_by_gnc"] == "1"]
    floor = np.linalg.inv(np.diag([0.02**2, 0.02**2, np.radians(0.5) ** 2]))
    extra = [((int(r["keyframe_a"]), int(r["keyframe_b"])),
              np.array([float(r["dx"]), float(r["dy"]), float(r["dtheta"])])) for r in rows]

    def solve(loops):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for k, p in enumerate(sess["kf_pose"]):
            values.insert(k, gtsam.Pose2(*p))
        graph.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(*sess["kf_pose"][0]),
                                         gtsam.noiseModel.Diagonal.Sigmas(np.full(3, 1e-4))))
        factors = [*zip(sess["odom_ij"], sess["odom_z"], sess["odom_info"], strict=True),
                   *zip(sess["loop_ij"], sess["loop_z"], sess["loop_info"], strict=True),
                   *[(ij, z, floor) for ij, z in loops]]
        for (i, j), z, info in factors:
            graph.add(gtsam.BetweenFactorPose2(int(i), int(j), gtsam.Pose2(*z),
                                               gtsam.noiseModel.Gaussian.Information(info)))
        res = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
        return np.array([[res.atPose2(k).x(), res.atPose2(k).y(), res.atPose2(k).theta()]
                         for k in range(len(sess["kf_pose"]))])

    def ate(est):
        a, b = est[:, :2], ref[:, :2]
        ma, mb = a.mean(0), b.mean(0)
        u, _, vt = np.linalg.svd((a - ma).T @ (b - mb))
        rot = vt.T @ np.diag([1.0, np.sign(np.linalg.det(vt.T @ u.T))]) @ u.T
        return float(np.sqrt(np.mean(np.sum(((a - ma) @ rot.T + mb - b) ** 2, axis=1))))

    kept, every = solve([]), solve(extra)
    free = sum(np.linalg.inv(m)[0, 0] > 1.0 for m in sess["odom_info"])
    print(f"== {out}: {len(sess['loop_ij'])} loops kept, {len(extra)} rejected by GNC, "
          f"{free} free odometry joints; keyframe ATE as saved {ate(kept):.4f} m, "
          f"with the rejected loops {ate(every):.4f} m")
    for (i, j), z in extra:
        e = np.array(se2.between(se2.between(every[i], every[j]), z))
        print(f"    rejected kf {i}-{j}: chi2 at the all-loops solution "
              f"{e @ floor @ e:.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default="../shared/data")
    ap.add_argument("--logs", default="belgioioso,intel-corrected")
    ap.add_argument("--variant", action="append", default=[],
                    help="NAME:key=value,key=value (repeatable)")
    ap.add_argument("--resolve", nargs="+", type=Path, help="bench slam --out folders")
    args = ap.parse_args()
    if args.resolve:
        for out in args.resolve:
            resolve(out)
        return
    Icp2dOdometry._describe = staticmethod(_describe_with_pose)
    for log in args.logs.split(","):
        name = log if log.endswith("-corrected") else f"{log}-corrected"
        data = load_input(Path(args.data) / "carmen-corrected" / f"{name}.log.gz",
                          odometry_noise=0)
        ref = np.asarray(data.logged_poses, float)
        stamps = np.array([float(s.stamp) for s in data.scans])
        print(f"== {name}: {len(data.scans)} scans, median dt "
              f"{np.median(np.diff(stamps)):.3f} s")
        for v in args.variant or ["default:"]:
            vname, _, sets = v.partition(":")
            cfg = apply_overrides(PipelineConfig(), [s for s in sets.split(",") if s])
            fe, sel = Icp2dOdometry(cfg.icp2d), KeyframeSelector(cfg.keyframes)
            noise = cfg.icp2d.odometry_noise
            rows, counts = [], {}
            for i, scan in enumerate(data.scans):
                prev = None if fe._pose is None else fe._pose.copy()
                usual = fe._usual_motion()
                fit_med = (statistics.median(fe._recent_fitness)
                           if fe._recent_fitness else float("nan"))
                e = fe.process(scan)
                sel.push(scan, e)
                x = e.extra
                if "odometry_step" not in x:
                    continue
                u = x["odometry_step"]
                rinc = se2.between(ref[i - 1], ref[i])
                if not x.get("kidnap"):
                    test = "confirmed"
                elif "rejected_fitness" in x:
                    test = "fitness"
                elif "icp_pose" in x:
                    test = "nomatch"
                else:
                    test = "nomap"
                counts[test] = counts.get(test, 0) + 1
                step, turn = float(np.hypot(u[0], u[1])), abs(float(u[2]))
                line = (f"  scan {i:4d} kf {len(sel.keyframes) - 1:4d}"
                        f" dt {stamps[i] - stamps[i - 1]:5.2f}"
                        f" {test:9s} odo {step:.3f} m {np.degrees(turn):6.1f} deg"
                        f" usual {usual[0]:.3f} m {np.degrees(usual[1]):5.1f} deg"
                        f" ref {np.hypot(rinc[0], rinc[1]):.3f} m"
                        f" {np.degrees(abs(rinc[2])):6.1f} deg"
                        f" odo-ref {diff(rinc, u)[0]:.3f} m {diff(rinc, u)[1]:.2f} deg")
                if "icp_pose" in x and prev is not None:
                    inc = se2.between(prev, x["icp_pose"])
                    line += (f" | fit {x['icp_fitness']:.2f} med {fit_med:.2f}"
                             f" inl {x['inlier_ratio']:.2f} rms {x['rms']:.3f}"
                             f" won {int(bool(x.get('search_won', False)))}"
                             f" icp-ref {diff(rinc, inc)[0]:.3f} m {diff(rinc, inc)[1]:.2f} deg"
                             f" icp-odo {diff(u, inc)[0]:.3f} m {diff(u, inc)[1]:.2f} deg"
                             f" = {sigmas(u, inc, noise.diagonal(step, turn)):.2f}"
                             " sigma")
                rows.append(line)
            print(f"-- {vname}: jumps {sum(counts.values())} {counts}")
            print("\n".join(rows))


if __name__ == "__main__":
    main()
