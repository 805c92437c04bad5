"""Diagnosis: could one loop's own statistics tell a false loop the TLS objective keeps
from the true ones?  Leave-one-out cost and Occam penalty of every obeyed loop.

Run from the repository root::

    python benchmarks/robust_loop_evidence.py input_M3500a_g2o.g2o [--data DIR]
        [--scale 1] [--policy random] [--ratio 50] [--seed 0] [--cache DIR]
        [--load FILE] [--near 20] [--show 8] [--drop i-j,...]

The poses are the clean optimum, or those `benchmarks/robust_lone_false.py --save`
stored (`--load`).  The loops they obey (whitened residual at most the default outlier
residual) and the odometry are linearised there (`slam.innovation.InnovationTest`, whose
information ``H`` includes every obeyed loop); for each obeyed loop ``k`` with whitened
residual ``b`` and ``M = B H^-1 B^T``:

    rho_k = 0.5 b^T (I - M)^-1 b          (leave-one-out innovation, gtsam error units)
    pen_k = -0.5 log det (I - M)          (Occam penalty: 0.5 log det S_k, S_k = (I - M)^-1)

``S_k`` is the covariance of the loop's whitened innovation against the graph without
it, so ``rho_k + pen_k`` is the loop's negative log evidence as an inlier (up to a
constant); the TLS objective keeps it when ``rho_k < c``.  A loop is *lone* when no
other obeyed loop has both ends within `--near` poses of its two ends.  Printed: the
threshold ``c``; the `--show` obeyed loops of largest ``pen`` (true / false, pose ids,
span, neighbours, rho, pen, and its own cost ``0.5 |(I - M)^-1 b|^2`` at the optimum
without it, linearised); how many true loops have ``rho + pen >= c``, and the largest
``rho + pen`` of a lone true loop and of any false loop.  `--drop i-j,...`: the obeyed
loops less those between these pose ids, solved from the clean optimum, and that
solution's ATE [m] against the clean optimum.
"""

from __future__ import annotations

import pickle
import sys
from pathlib import Path

import gtsam
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.robust_cell import cell_parser, read_cell
from evaluation.robustness import aligned_position_error
from slam.innovation import InnovationTest, tls_threshold
from slam.least_squares import StickySolver
from slam.optimize import default_outlier_residual
from slam.pose_graph import RobustKernel, pose_dof, poses_from_values, whitened_residual


def neighbours(ends: np.ndarray, near: int) -> np.ndarray:
    """Per loop (rows of `ends`, pose ids ``(low, high)``), the other loops whose two ends
    both lie within `near` poses of its own (ends compared low to low, high to high)."""
    close = ((np.abs(ends[:, None, 0] - ends[None, :, 0]) <= near)
             & (np.abs(ends[:, None, 1] - ends[None, :, 1]) <= near))
    return close.sum(axis=1) - 1


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--load", type=Path, default=None)
    parser.add_argument("--near", type=int, default=20)
    parser.add_argument("--show", type=int, default=8)
    parser.add_argument("--drop", default="")
    args = parser.parse_args()
    graph, reference, corrupted, false = read_cell(args)
    poses = pickle.loads(args.load.read_bytes()) if args.load is not None else reference
    c = tls_threshold(graph.dim)
    residual = np.array([whitened_residual(lp, poses, graph.dim) for lp in corrupted.loops])
    obeyed = np.flatnonzero(residual <= default_outlier_residual(graph.dim))
    base, loop_index = corrupted.factor_graph(RobustKernel("none"))
    factors = gtsam.NonlinearFactorGraph()
    for n in range(base.size() - len(loop_index)):
        factors.add(base.at(n))
    for k in obeyed:
        factors.add(base.at(loop_index[k]))
    test = InnovationTest(factors, corrupted.gtsam_values(poses), graph.keys, pose_dof(graph.dim))
    b, m = test.blocks([base.at(loop_index[k]) for k in obeyed])
    rest = np.eye(b.shape[1]) - m
    rho = 0.5 * np.einsum("ma,ma->m", b, np.linalg.solve(rest, b[..., None])[..., 0])
    pen = -0.5 * np.linalg.slogdet(rest)[1]
    # The loop's own cost at the graph's optimum without it (linearised): 0.5 |b_loo|^2,
    # b_loo = (I - M)^-1 b its whitened residual there.
    loo = np.linalg.solve(rest, b[..., None])[..., 0]
    raw = 0.5 * np.einsum("ma,ma->m", loo, loo)
    ends = np.sort(np.array([(corrupted.loops[k].i, corrupted.loops[k].j) for k in obeyed]), axis=1)
    near = neighbours(ends, args.near)
    bad = false[obeyed]
    print(f"{args.graph} x{args.scale:g} {args.policy} {args.ratio:g}% seed {args.seed}: "
          f"{len(obeyed)} obeyed ({int(bad.sum())} false), c {c:.2f}")
    for n in np.argsort(-pen)[:args.show]:
        print(f"  {'F' if bad[n] else 'T'} {ends[n][0]}-{ends[n][1]} span {ends[n][1] - ends[n][0]}"
              f" neighbours {near[n]} rho {rho[n]:.2f} pen {pen[n]:.2f}"
              f" own cost without {raw[n]:.3g}")
    evidence = rho + pen
    lone_true = (near == 0) & ~bad
    print(f"true with rho + pen >= c: {int((evidence[~bad] >= c).sum())} "
          f"(lone {int((evidence[lone_true] >= c).sum())} of {int(lone_true.sum())} lone); "
          f"largest rho + pen: lone true {evidence[lone_true].max(initial=0):.2f}, "
          f"false {evidence[bad].max(initial=0):.2f}")
    print(f"own cost without it: largest of a true loop {raw[~bad].max(initial=0):.3g}, "
          f"of a lone true loop {raw[lone_true].max(initial=0):.3g}, smallest of a false loop "
          f"{raw[bad].min(initial=np.inf):.3g}")
    if args.drop:
        drop = {tuple(sorted(map(int, pair.split("-")))) for pair in args.drop.split(",")}
        kept = gtsam.NonlinearFactorGraph()
        for n in range(base.size() - len(loop_index)):
            kept.add(base.at(n))
        for n, k in enumerate(obeyed):
            if tuple(ends[n]) not in drop:
                kept.add(base.at(loop_index[k]))
        solved = StickySolver()(kept, corrupted.gtsam_values(reference))
        ate = aligned_position_error(poses_from_values(solved, graph.dim), reference, graph.dim)
        print(f"obeyed less {args.drop}: ATE {ate:.3g} m")


if __name__ == "__main__":
    main()
