"""How close can any registration come to a log's short reference relations?

Run from the repository root, after mapping the log::

    loopclosure run ../shared/data/carmen/intel.clf.bz2 --out intel
    python benchmarks/short_relations.py ../shared/data/carmen/intel.clf.bz2 \
        ../shared/data/carmen/intel.relations intel/trajectory.tum [--max-dt 5] [--every 3]

The relations metric (Kümmerle et al. 2009, `evaluation.relations_metric`) on the
relations whose two scans are less than ``--max-dt`` seconds apart measures the
registration of nearby scans, not drift.  For each such relation (every
``--every``-th) this script prints the mean error of three estimates of the
relative pose of the two scans (laser poses, scan ``t2`` in the frame of scan
``t1``):

- the trajectory's (the mapper's per-scan poses);
- a careful point-to-line ICP of the two raw scans (`loopclosure.registration.register`,
  60 iterations, residual floor 2 mm), started from the trajectory's relative pose;
- the same ICP started from the reference relation itself.

The distance the ICP started from the trajectory moves away from it is printed too:
how far the two scans alone (no map, no reference) disagree with the trajectory.
When the ICP started at the reference moves away from it by about as much as the
trajectory disagrees with it, the scans themselves do not support the reference
more precisely than that: the error floor of these relations for a scan matcher
(the reference's own noise, or a laser model it used that the log does not state).
Errors as the metric computes them: translation [m] and rotation [deg] of
``delta_est * delta_ref^-1``, mean and median.  The last column, ``along``, is the
median over relations longer than `MIN_ALONG_M` of ``(t_est - t_ref) . u / |t_ref|``
(``t`` the relation's translation, ``u = t_ref / |t_ref|``): a relative length
error of the estimate along the motion.  A scale that every estimate shares,
pairwise ICP from the reference included, is a property of the reference (a range
scale or a lever arm of the method that made it), not of the mapper.

Last line: the lever arm ``l`` [m] that best explains the trajectory's
translation errors if the reference's relations were of another point of the
robot than the laser, ``t_est - t_ref = (R(theta_ref) - I) l`` (least squares over
the relations; a laser mounted off the robot centre shifts every relation that
turns), and the trajectory's mean translation error once it is removed.  A lever
arm of centimetres that removes much of the error says the reference is not in
the laser's frame.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from data import se2  # noqa: E402
from data.carmen import CarmenLog  # noqa: E402
from data.relations import read_relations  # noqa: E402
from data.trajectory_io import read_tum  # noqa: E402
from loopclosure.registration import IcpConfig, RegistrationTarget, register  # noqa: E402

#: Relations shorter than this [m] do not enter the along-track scale.
MIN_ALONG_M = 0.05


def _along(estimate: np.ndarray, reference: np.ndarray) -> float:
    """``(t_est - t_ref) . t_ref / |t_ref|^2`` (relative length error along the motion)."""
    t = reference[:2]
    length2 = float(t @ t)
    if length2 < MIN_ALONG_M**2:
        return float("nan")
    return float((estimate[:2] - t) @ t / length2)


def lever_arm(estimates: np.ndarray, references: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares ``l`` of ``t_est - t_ref = (R(theta_ref) - I) l`` and the residuals.

    `estimates`, `references`: ``(K, 3)`` relative poses ``(x, y, theta)``.  Returns
    ``l`` ``(2,)`` [m] and the translation residuals ``(K, 2)`` once it is removed.
    """
    c, s = np.cos(references[:, 2]), np.sin(references[:, 2])
    a = np.zeros((2 * len(references), 2))
    a[0::2, 0], a[0::2, 1] = c - 1.0, -s
    a[1::2, 0], a[1::2, 1] = s, c - 1.0
    b = (estimates[:, :2] - references[:, :2]).reshape(-1)
    arm = np.linalg.lstsq(a, b, rcond=None)[0]
    return arm, (b - a @ arm).reshape(-1, 2)


def _xytheta(m: np.ndarray) -> np.ndarray:
    return np.array([m[0, 3], m[1, 3], np.arctan2(m[1, 0], m[0, 0])])


def _error(estimate: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    d = se2.compose(estimate, se2.inverse(reference))
    return float(np.hypot(d[0], d[1])), float(abs(np.degrees(se2.wrap_angle(d[2]))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log", type=Path)
    parser.add_argument("relations", type=Path)
    parser.add_argument("trajectory", type=Path, help="TUM file of the mapper's scan poses")
    parser.add_argument("--max-dt", type=float, default=5.0, help="relations shorter than [s]")
    parser.add_argument("--every", type=int, default=3, help="every n-th short relation")
    args = parser.parse_args()
    scans = list(CarmenLog(args.log))
    scan_stamps = np.array([s.stamp for s in scans])
    traj = read_tum(args.trajectory)
    cfg = IcpConfig(min_residual_scale=0.002, max_iterations=60)
    short = [r for r in read_relations(args.relations) if abs(r.t2 - r.t1) < args.max_dt]
    rows, pairs, moved = [], [], []
    for rel in short[:: max(args.every, 1)]:
        ti = np.abs(traj.stamps - rel.t1).argmin(), np.abs(traj.stamps - rel.t2).argmin()
        si = np.abs(scan_stamps - rel.t1).argmin(), np.abs(scan_stamps - rel.t2).argmin()
        if (abs(traj.stamps[ti[0]] - rel.t1) > 1e-3 or abs(traj.stamps[ti[1]] - rel.t2) > 1e-3
                or abs(scan_stamps[si[0]] - rel.t1) > 1e-3):
            continue
        reference = _xytheta(rel.delta)
        ours = se2.between(_xytheta(traj.poses[ti[0]]), _xytheta(traj.poses[ti[1]]))
        target = RegistrationTarget(scans[si[0]].points(), cfg)
        source = scans[si[1]].points()
        from_ours = register(source, target, ours, config=cfg).pose
        from_reference = register(source, target, reference, config=cfg).pose
        pairs.append((ours, reference))
        moved.append(_error(from_ours, ours))
        rows.append([*_error(ours, reference), *_error(from_ours, reference),
                     *_error(from_reference, reference), _along(ours, reference),
                     _along(from_ours, reference), _along(from_reference, reference)])
    if not rows:
        sys.exit("no short relation matched both the trajectory and the log (stamps within 1 ms)")
    e = np.array(rows)
    print(f"{len(e)} relations under {args.max_dt:g} s (every {args.every}) of {len(short)}")
    print(f"{'estimate':34s} {'trans mean':>10s} {'median':>8s} {'rot mean':>9s} {'median':>8s} "
          f"{'along':>8s}")
    for k, name in enumerate(("trajectory", "pairwise ICP from the trajectory",
                              "pairwise ICP from the reference")):
        t, r = e[:, 2 * k], e[:, 2 * k + 1]
        print(f"{name:34s} {t.mean():10.4f} {np.median(t):8.4f} {r.mean():9.3f} "
              f"{np.median(r):8.3f} {np.nanmedian(e[:, 6 + k]):+8.2%}")
    m = np.array(moved)
    print(f"pairwise ICP from the trajectory moves from it by {m[:, 0].mean():.4f} m "
          f"(median {np.median(m[:, 0]):.4f}), {m[:, 1].mean():.3f} deg: the trajectory's "
          "disagreement with the two scans alone, no reference involved")
    arm, rest = lever_arm(np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs]))
    print(f"lever arm of the trajectory's errors: ({arm[0]:+.4f}, {arm[1]:+.4f}) m; "
          f"translation error without it {np.hypot(rest[:, 0], rest[:, 1]).mean():.4f} m "
          "(difference of translations, not the metric's composition)")


if __name__ == "__main__":
    main()
