"""Diagnosis: which stage of the robust back end leaves a corrupted cell's false loops in.

Run from the repository root::

    python benchmarks/robust_stage_trace.py input_MITb_g2o.g2o [--data DIR] [--scale 0.1]
        [--policy random] [--ratio 70] [--seed 0] [--undo on|off] [--confirm] [--cache DIR]

Runs `slam.optimize.optimize` (``gnc``, incremental, from the odometry chain, as
`benchmarks/robust_modes.py`) with its stages wrapped, and prints after each one the
false loops kept (their indices), the true loops rejected and the stated TLS objective
(`slam.consistency.tls_cost`, gtsam error units) with its gap to the clean optimum's:
every rung's admission pass refined (`refine_tls`), the calibrated choice and the loops
offered back (`slam.offer_back.choose_and_offer_back`), `bar_search`, the polish, and
the segment re-check.  Finally the false loops the result obeys.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import slam.consistency as consistency
import slam.optimize as optimize_module
from benchmarks.robust_cell import cell_parser, read_cell
from slam.consistency import tls_cost
from slam.optimize import default_outlier_residual, optimize
from slam.pose_graph import whitened_residual


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--undo", default="on")
    parser.add_argument("--confirm", action="store_true")
    args = parser.parse_args()
    graph, reference, corrupted, false = read_cell(args)
    clean = tls_cost(corrupted, corrupted.gtsam_values(reference))

    def show(stage, values, weights):
        w = np.asarray(weights) > 0.5
        cost = tls_cost(corrupted, values)
        print(f"{stage}: false kept {np.flatnonzero(w & false).tolist()}, "
              f"{int((~w & ~false).sum())} true rejected, tls {cost:.2f} "
              f"(gap {cost - clean:+.2f})", flush=True)

    refine, bar, polish, choose = (consistency.refine_tls, consistency.bar_search,
                                   consistency.polish, optimize_module.choose_and_offer_back)
    recheck = optimize_module._segment_rechecked

    def refine_traced(g, values, weights, **kw):
        show("  pass decisions (before refine)", values, weights)
        out = refine(g, values, weights, **kw)
        show("  refine_tls", *out)
        return out

    def choose_traced(g, candidates, **kw):
        out = choose(g, candidates, **kw)
        print(f"calibrated choice: candidate {out[0]} of {len(candidates)} "
              f"(stated costs {[round(c[2], 2) for c in candidates]})", flush=True)
        if out[1] is not None:
            print(f"  offered back: false kept {np.flatnonzero((out[1] > 0.5) & false).tolist()}")
        return out

    def bar_traced(*a, **kw):
        out = bar(*a, **kw)
        show(f"bar_search ({out.gate})", out.values, out.weights)
        return out

    def recheck_traced(g, factors, loop_index, values, weights, *a):
        show("before segment re-check", values, weights)
        out = recheck(g, factors, loop_index, values, weights, *a)
        show(f"segment re-check ({out[2]})", out[0], out[1])
        return out

    consistency.refine_tls, consistency.bar_search = refine_traced, bar_traced
    optimize_module.choose_and_offer_back = choose_traced
    optimize_module._segment_rechecked = recheck_traced
    del polish
    result = optimize(corrupted, "none", "gnc", init="odometry", gnc_start="incremental",
                      undo=args.undo != "off", confirm=args.confirm)
    residuals = np.array([whitened_residual(c, result.poses, graph.dim)
                          for c in corrupted.loops])
    obeyed = residuals <= default_outlier_residual(graph.dim)
    print(f"result ({result.solver}): false obeyed {np.flatnonzero(obeyed & false).tolist()}")
    for k in np.flatnonzero(obeyed & false):
        lp = corrupted.loops[k]
        r_clean = whitened_residual(lp, reference, graph.dim)
        print(f"  false {k}: {lp.i}-{lp.j} r_clean {r_clean:.1f}")


if __name__ == "__main__":
    main()
