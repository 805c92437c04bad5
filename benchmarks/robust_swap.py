"""Benchmark: the swap search (`slam.swap`) on and off, cell by cell, in one process.

Run from the repository root::

    python benchmarks/robust_swap.py --graphs input_M3500a_g2o.g2o [--data DIR]
        [--scales 1,0.1] [--policies random] [--ratios 50] [--seeds 0,1] [--group-size 10]
        [--json OUT]

Every cell (graph x odometry scaling x policy x ratio x seed) is solved by the ``gnc``
kernel of `evaluation.robustness` (`optimize` ``gnc``, incremental, from odometry) with
the swap search; only when the search kept a swap (the solver label says ``swapped`` or
``replayed``) is the cell solved again without it, since otherwise both are the same
computation.  Printed per cell and setting: ATE against the outlier-free optimum [m],
false loops obeyed, true loops rejected, stated TLS objective minus the clean optimum's
(``tls_gap``; below 0 the false loops are the cheaper reading), CPU seconds, the solver
label, and the false loops admitted (pose ids ``i-j``) when any.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from data.g2o import read_g2o
from evaluation.robustness import aligned_position_error, clean_optimum, inject_false_loops
from slam.consistency import tls_cost
from slam.optimize import default_outlier_residual, optimize
from slam.pose_graph import PoseGraph, whitened_residual
from slam.variance_components import with_information_scaled


def solve_cell(graph: PoseGraph, corrupted: PoseGraph, false_idx: list[int],
               reference: dict, swap: bool) -> dict:
    """One solve of `corrupted` (swap on or off) judged against `reference`."""
    cpu, wall = time.process_time(), time.perf_counter()
    solution = optimize(corrupted, "none", "gnc", init="odometry", gnc_start="incremental",
                        swap=swap)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    threshold = default_outlier_residual(graph.dim)
    residuals = np.array([whitened_residual(c, solution.poses, graph.dim)
                          for c in corrupted.loops])
    obeyed = residuals <= threshold
    is_false = np.zeros(len(corrupted.loops), dtype=bool)
    is_false[list(false_idx)] = True
    admitted_false = [f"{corrupted.loops[k].i}-{corrupted.loops[k].j}"
                      for k in np.flatnonzero(obeyed & is_false)]
    gap = (tls_cost(corrupted, corrupted.gtsam_values(solution.poses))
           - tls_cost(corrupted, corrupted.gtsam_values(reference)))
    return {
        "swap": swap,
        "ate_vs_clean_m": aligned_position_error(solution.poses, reference, graph.dim),
        "false_obeyed": int((obeyed & is_false).sum()),
        "true_rejected": int((~obeyed & ~is_false).sum()),
        "tls_gap": float(gap),
        "cpu_s": cpu,
        "wall_s": wall,
        "solver": solution.solver,
        "false_admitted": admitted_false,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", default="../shared/data/g2o")
    parser.add_argument("--graphs", required=True)
    parser.add_argument("--scales", default="1")
    parser.add_argument("--policies", default="random")
    parser.add_argument("--ratios", default="50")
    parser.add_argument("--seeds", default="0,1")
    parser.add_argument("--group-size", type=int, default=10)
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    rows = []
    for name in args.graphs.split(","):
        given = PoseGraph.from_g2o(read_g2o(Path(args.data) / name))
        for scale in (float(s) for s in args.scales.split(",")):
            graph = given if scale == 1.0 else with_information_scaled(given, scale)
            reference = clean_optimum(graph)
            for policy in args.policies.split(","):
                for ratio in (float(r) / 100 for r in args.ratios.split(",")):
                    for seed in (int(s) for s in args.seeds.split(",")):
                        corrupted, false_idx = inject_false_loops(
                            graph, ratio, np.random.default_rng(seed), policy,
                            group_size=args.group_size, reference=reference)
                        on = solve_cell(graph, corrupted, false_idx, reference, True)
                        kept = "swapped" in on["solver"] or "replayed" in on["solver"]
                        off = (solve_cell(graph, corrupted, false_idx, reference, False)
                               if kept else dict(on, swap=False, same=True))
                        for r in (off, on):
                            row = {"graph": name, "scale": scale, "policy": policy,
                                   "ratio": ratio, "seed": seed, **r}
                            rows.append(row)
                            print(f"{name} x{scale:g} {policy} {100 * ratio:.0f}% s{seed} "
                                  f"swap={'on ' if r['swap'] else 'off'} "
                                  f"ATE {r['ate_vs_clean_m']:.3g} m false {r['false_obeyed']} "
                                  f"true-rej {r['true_rejected']} gap {r['tls_gap']:.4g} "
                                  f"cpu {r['cpu_s']:.1f} s {r['solver']}"
                                  f"{' (same run)' if r.get('same') else ''} "
                                  f"{' '.join(r['false_admitted'][:12])}", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
