"""Diagnosis: the false loops the default robust back end obeys on one cell, and what
evidence the rest of the graph holds for or against each.

Run from the repository root::

    python benchmarks/robust_lone_false.py input_M3500a_g2o.g2o [--data DIR] [--scale 1]
        [--policy random] [--ratio 50] [--seed 0] [--cache DIR] [--save FILE]
        [--load FILE] [--near 20]

Runs `slam.optimize.optimize` as `eval robustness` does (``gnc``, incremental, from
the odometry chain) and stores its poses in `--save` (or reads them from `--load`
instead of running).  For each false loop the result obeys (whitened residual at most
the default outlier residual), printed: its pose ids and span [poses]; its whitened
residual at the clean optimum; its innovation ``delta`` against the outlier-free graph
linearised at the clean optimum (gtsam error units; ``c`` is the TLS threshold); the
loops whose two ends both lie within `--near` poses of its two ends (its neighbours:
true / false, and how many of them the result obeys); and the objective check of
`benchmarks/robust_objective_limited.py`: the stated TLS objective of the clean graph
solved with this loop added, its ATE [m] against the clean optimum, and the objective
of the clean optimum, each less the result's.
"""

from __future__ import annotations

import pickle
import sys
import time
from pathlib import Path

import gtsam
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.robust_cell import cell_outcome, cell_parser, read_cell
from evaluation.robustness import aligned_position_error
from slam.consistency import tls_cost, tls_threshold
from slam.innovation import InnovationTest, admission_costs
from slam.least_squares import StickySolver
from slam.optimize import default_outlier_residual, optimize
from slam.pose_graph import RobustKernel, pose_dof, poses_from_values, whitened_residual


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--save", type=Path, default=None)
    parser.add_argument("--load", type=Path, default=None)
    parser.add_argument("--near", type=int, default=20)
    args = parser.parse_args()
    graph, reference, corrupted, false = read_cell(args)
    if args.load is not None:
        poses = pickle.loads(args.load.read_bytes())
    else:
        cpu = time.process_time()
        result = optimize(corrupted, "none", "gnc", init="odometry", gnc_start="incremental")
        print(f"default: {time.process_time() - cpu:.1f} s CPU, {result.solver}", flush=True)
        poses = result.poses
        if args.save is not None:
            args.save.write_bytes(pickle.dumps(poses))
    out = cell_outcome(graph, reference, corrupted, false, poses)
    print(f"ATE {out.ate:.3g} m, {len(out.false_obeyed)} F ({out.consistent}), "
          f"{out.true_rejected} T, gap {out.gap:+.2f}")
    c = tls_threshold(graph.dim)
    threshold = default_outlier_residual(graph.dim)
    base, loop_index = corrupted.factor_graph(RobustKernel("none"))
    n_fixed = base.size() - len(loop_index)
    clean_values = corrupted.gtsam_values(reference)
    result_values = corrupted.gtsam_values(poses)
    ends = np.array([(lp.i, lp.j) for lp in corrupted.loops])
    at_clean = np.array([whitened_residual(lp, reference, graph.dim) for lp in corrupted.loops])
    # The outlier-free graph at its optimum, as `consistent_with_clean` builds it.
    clean_factors = gtsam.NonlinearFactorGraph()
    for n in range(n_fixed):
        clean_factors.add(base.at(n))
    for k in np.flatnonzero(~false & (at_clean <= threshold)):
        clean_factors.add(base.at(loop_index[k]))
    test = InnovationTest(clean_factors, clean_values, graph.keys, pose_dof(graph.dim))
    solve = StickySolver()
    result_cost = tls_cost(corrupted, result_values)
    for k in out.false_obeyed:
        i, j = ends[k]
        delta = admission_costs(test.gains([base.at(loop_index[k])]))[0]
        near = ((np.abs(ends[:, 0] - i) <= args.near) & (np.abs(ends[:, 1] - j) <= args.near)
                | (np.abs(ends[:, 0] - j) <= args.near) & (np.abs(ends[:, 1] - i) <= args.near))
        near[k] = False
        nt, nf = int((near & ~false).sum()), int((near & false).sum())
        obeyed_t = int((near & ~false & out.obeyed).sum())
        with_loop = gtsam.NonlinearFactorGraph(clean_factors)
        with_loop.add(base.at(loop_index[k]))
        admitted = solve(with_loop, clean_values)
        ate = aligned_position_error(poses_from_values(admitted, graph.dim), reference, graph.dim)
        clean_gap = tls_cost(corrupted, clean_values) - result_cost
        loop_gap = tls_cost(corrupted, admitted) - result_cost
        print(f"false loop {k}: {i}-{j} span {abs(j - i)}, residual at clean "
              f"{at_clean[k]:.2f} (limit {threshold:.2f}), delta vs clean graph {delta:.2f} "
              f"(c {c:.2f}); neighbours within {args.near}: {nt} true ({obeyed_t} obeyed), "
              f"{nf} false; clean+loop: objective {loop_gap:+.2f}"
              f" vs result, ATE {ate:.3g} m; clean optimum {clean_gap:+.2f} vs result", flush=True)


if __name__ == "__main__":
    main()
