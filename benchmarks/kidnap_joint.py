"""Why a correct loop can make a pose graph worse: each factor's error against the
reference in units of its stated covariance, and the same graph re-solved with the
front end's kidnapped increments weighted as the odometry's own noise model.

Input: the ``--out`` folders of ``loopclosure bench slam LOG --odometry-noise N
--reference-from-log --methods pipeline --out DIR`` (``DIR/pipeline/session.npz``,
``DIR/pipeline/trajectory.tum``, ``DIR/reference_logged.tum``), one per run to
compare (e.g. without and with a loop).  Per run it prints

- odometry and loop factors: the chi-square ``e^T Lambda e`` of each factor's
  measurement ``z`` against the reference's relative pose (``e = z - between(ref_i,
  ref_j)``, angle wrapped; ``Lambda`` the stated information; expected 3 for a
  calibrated 3-dof factor), the largest ones, and the factors whose stated sigma is
  above 1 m or 1 rad (kidnapped increments, ``icp2d.kidnap_sigma``);
- the pipeline's scan ATE (Umeyama SE(2) alignment, as ``bench slam``) per block of
  scans;
- the keyframe ATE of the saved graph re-solved by Levenberg-Marquardt with plain
  Gaussian factors: as stated, and with each kidnapped increment given
  ``MotionNoise.diagonal(|t|, |theta|) * k`` (the front end's `odometry_noise`,
  ``k`` = 1, 10, 100), and with every other odometry factor's information divided
  by ``s`` (their overconfidence);
- a judge that needs no reference: per block of scans, how well each keyframe's scan
  end points lie on the other keyframes' points (keyframes more than `--gap` apart in
  the sequence) with the pipeline's poses: the mean nearest-neighbour distance [m] of
  the points within `--near` of another keyframe's point (a crisper map: lower), and
  their fraction.

    python benchmarks/kidnap_joint.py OUT_DEFAULT OUT_WITH_LOOP [--block 50]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gtsam
import numpy as np
from scipy.spatial import cKDTree

from data import se2
from slam.odometry import MotionNoise

Array = np.ndarray


def read_tum_xytheta(path: Path) -> Array:
    """(N, 3) planar poses (x [m], y [m], theta [rad]) of a TUM file (yaw from qz, qw)."""
    d = np.loadtxt(path)
    return np.c_[d[:, 1], d[:, 2], 2.0 * np.arctan2(d[:, 6], d[:, 7])]


def aligned_errors(est: Array, ref: Array) -> Array:
    """Per-pose position error [m] after the least-squares rigid (SE(2)) alignment of
    `est` onto `ref` (Umeyama 1991, no scale)."""
    a, b = est[:, :2], ref[:, :2]
    ma, mb = a.mean(0), b.mean(0)
    u, _, vt = np.linalg.svd((a - ma).T @ (b - mb))
    d = np.diag([1.0, np.sign(np.linalg.det(vt.T @ u.T))])
    rot = vt.T @ d @ u.T
    return np.linalg.norm((a - ma) @ rot.T + mb - b, axis=1)


def factor_errors(ij: Array, z: Array, info: Array, ref_kf: Array) -> tuple[Array, Array, Array]:
    """Errors ``z - between(ref_i, ref_j)`` (N, 3), their chi-square under `info`, and
    the stated sigmas (N, 3)."""
    rz = np.array([se2.between(ref_kf[i], ref_kf[j]) for i, j in ij]).reshape(-1, 3)
    e = z - rz
    e[:, 2] = se2.wrap_angle(e[:, 2])
    chi2 = np.einsum("ni,nij,nj->n", e, info, e)
    sig = np.sqrt(np.array([np.diag(np.linalg.inv(m)) for m in info])).reshape(-1, 3)
    return e, chi2, sig


def resolve(s: dict, kidnap_cov=None, odom_scale: float = 1.0) -> Array:
    """Keyframe poses of the saved graph re-solved (LM, Gaussian factors, first pose
    fixed); kidnapped increments (stated x sigma > 1 m) get ``kidnap_cov(z)`` when
    given, every other odometry information is divided by `odom_scale`."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    poses = s["kf_pose"]
    for k, p in enumerate(poses):
        values.insert(k, gtsam.Pose2(*p))
    graph.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(*poses[0]),
                                     gtsam.noiseModel.Diagonal.Sigmas(np.full(3, 1e-4))))
    for (i, j), z, info in zip(s["odom_ij"], s["odom_z"], s["odom_info"], strict=True):
        kidnapped = np.linalg.inv(info)[0, 0] > 1.0
        if kidnapped and kidnap_cov is not None:
            info = np.linalg.inv(kidnap_cov(z))
        elif not kidnapped:
            info = info / odom_scale
        graph.add(gtsam.BetweenFactorPose2(int(i), int(j), gtsam.Pose2(*z),
                                           gtsam.noiseModel.Gaussian.Information(info)))
    for (i, j), z, info in zip(s["loop_ij"], s["loop_z"], s["loop_info"], strict=True):
        graph.add(gtsam.BetweenFactorPose2(int(i), int(j), gtsam.Pose2(*z),
                                           gtsam.noiseModel.Gaussian.Information(info)))
    out = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    return np.array([[out.atPose2(k).x(), out.atPose2(k).y(), out.atPose2(k).theta()]
                     for k in range(len(poses))])


def keyframe_points(s: dict, poses: Array) -> tuple[Array, Array]:
    """World end points (M, 2) of every keyframe's scan (finite ranges below its max
    range) placed by `poses` (one per keyframe), and each point's keyframe."""
    off = s["scan_offsets"]
    pts, owner = [], []
    for k, pose in enumerate(poses):
        r, a = s["scan_ranges"][off[k]:off[k + 1]], s["scan_angles"][off[k]:off[k + 1]]
        ok = np.isfinite(r) & (r < s["scan_max_range"][k]) & (r > s["scan_min_range"][k])
        local = np.c_[r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok])]
        pts.append(se2.transform_points(pose, local))
        owner.append(np.full(len(local), k))
    return np.vstack(pts), np.concatenate(owner)


def crispness(s: dict, poses: Array, gap: int, near: float) -> tuple[Array, Array]:
    """Per keyframe: mean distance [m] from its scan's points to the nearest point of a
    keyframe more than `gap` keyframes away, over the points that have one within
    `near`; and the fraction of its points that do (NaN, 0 without any)."""
    pts, owner = keyframe_points(s, poses)
    n = len(poses)
    mean, frac = np.full(n, np.nan), np.zeros(n)
    for k in range(n):
        mine = owner == k
        other = np.abs(owner - k) > gap
        if not mine.any() or not other.any():
            continue
        d, _ = cKDTree(pts[other]).query(pts[mine], distance_upper_bound=near)
        hit = np.isfinite(d)
        frac[k] = hit.mean()
        if hit.any():
            mean[k] = d[hit].mean()
    return mean, frac


def rms(x: Array) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path, help="bench slam --out folders")
    ap.add_argument("--block", type=int, default=50, help="scans per ATE block")
    ap.add_argument("--top", type=int, default=5, help="largest factors printed")
    ap.add_argument("--gap", type=int, default=10, help="crispness: keyframes apart")
    ap.add_argument("--near", type=float, default=0.3, help="crispness: radius [m]")
    args = ap.parse_args()
    noise = MotionNoise()

    def odometry_model(k: float):
        return lambda z: noise.diagonal(float(np.hypot(z[0], z[1])), abs(float(z[2]))) * k

    for out in args.runs:
        s = dict(np.load(out / "pipeline" / "session.npz"))
        ref = read_tum_xytheta(out / "reference_logged.tum")
        kscan = s["kf_scan_index"]
        ref_kf = ref[kscan]
        print(f"== {out}: {len(s['odom_ij'])} odometry, {len(s['loop_ij'])} loop factors")
        for name in ("odom", "loop"):
            ij = s[f"{name}_ij"]
            e, chi2, sig = factor_errors(ij, s[f"{name}_z"], s[f"{name}_info"], ref_kf)
            free = sig[:, 0] > 1.0
            print(f"  {name}: chi2 mean {chi2[~free].mean():.2f} median "
                  f"{np.median(chi2[~free]):.2f} (calibrated: 3); |e_xy| median "
                  f"{np.median(np.hypot(e[~free, 0], e[~free, 1])):.4f} m, sigma_x median "
                  f"{np.median(sig[~free, 0]):.4f} m; |e_theta| median "
                  f"{np.degrees(np.median(np.abs(e[~free, 2]))):.3f} deg, sigma median "
                  f"{np.degrees(np.median(sig[~free, 2])):.3f} deg")
            for k in np.argsort(-chi2)[:args.top]:
                print(f"    {name} kf {ij[k].tolist()} scans {kscan[ij[k]].tolist()} chi2 "
                      f"{chi2[k]:.1f} e {np.round(e[k], 4)} sigma {np.round(sig[k], 4)}")
            for k in np.flatnonzero(free):
                print(f"    FREE {name} kf {ij[k].tolist()} scans {kscan[ij[k]].tolist()} sigma "
                      f"{np.round(sig[k], 3)} e {np.round(e[k], 4)}")
        err = aligned_errors(read_tum_xytheta(out / "pipeline" / "trajectory.tum"), ref)
        blocks = range(0, len(err), args.block)
        print(f"  pipeline scan ATE {rms(err):.4f}; per {args.block} scans: "
              + " ".join(f"{rms(err[a:a + args.block]):.3f}" for a in blocks))
        traj = read_tum_xytheta(out / "pipeline" / "trajectory.tum")
        mean, frac = crispness(s, traj[kscan], args.gap, args.near)
        cr = []
        for a in blocks:
            sel = (kscan >= a) & (kscan < a + args.block) & np.isfinite(mean)
            cr.append(f"{np.mean(mean[sel]):.4f}/{np.mean(frac[sel]):.2f}" if sel.any() else "-")
        print(f"  crispness (no reference; mean NN m / fraction within {args.near} m), "
              f"all {np.nanmean(mean):.4f}/{frac.mean():.2f}; blocks " + " ".join(cr))
        variants = [("as stated", None, 1.0)]
        variants += [(f"kidnapped = odometry model x{k:g}", odometry_model(k), 1.0)
                     for k in (1.0, 10.0, 100.0)]
        variants += [(f"kidnapped x10, other odometry info / {c:g}", odometry_model(10.0), c)
                     for c in (4.0, 9.0)]
        for label, cov, scale in variants:
            e = aligned_errors(resolve(s, cov, scale), ref_kf)
            per = " ".join(f"{rms(e[(kscan >= a) & (kscan < a + args.block)]):.3f}"
                           for a in blocks)
            print(f"  re-solved, {label:42s} keyframe ATE {rms(e):.4f}; blocks {per}")


if __name__ == "__main__":
    main()
