"""Diagnosis: the time-ordered admission under each of its optional modes, on one
corrupted pose graph: deferring loops whose innovation test has no power
(`slam.deferral`, ``--defer``) and undoing earlier admissions that a later block's loops
contradict (`slam.admission_undo`, ``--undo``).

Run from the repository root::

    python benchmarks/robust_modes.py input_M3500a_g2o.g2o [--data DIR] [--scale 1]
        [--policy random] [--ratio 50] [--seed 0] [--defer off,all,candidate]
        [--undo off,on,myopic] [--confirm off,on] [--cache DIR]

For each pair of a `--defer` mode and an `--undo` setting of `slam.optimize.optimize`
(``gnc``, incremental, from the odometry chain) prints one line: ATE against the
outlier-free optimum [m], false loops obeyed (of them, consistent with the outlier-free
graph), true loops rejected, seconds (wall, and CPU of this process) and the TLS
objective's gap to the clean optimum, as `benchmarks/robustness.py` judges a cell.
`--undo myopic`: the undo hypotheses without their look-ahead (every kept hypothesis is
final; `slam.admission_undo.LOOKAHEAD` 0).  `--confirm on`: the admission passes
turn back innovation-gate admissions whose actual cost is above ``c``.  `--cache`: a
folder where the clean optimum of each graph and scaling is kept between runs (minutes on M3500a).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import slam.admission_undo as admission_undo
from benchmarks.robust_cell import cell_parser, read_cell
from evaluation.robustness import aligned_position_error, consistent_with_clean
from slam.consistency import tls_cost
from slam.optimize import default_outlier_residual, optimize
from slam.pose_graph import whitened_residual


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--defer", default="off")
    parser.add_argument("--undo", default="off")
    parser.add_argument("--confirm", default="off", help="off,on: the nonlinear check")
    args = parser.parse_args()
    graph, reference, corrupted, is_false = read_cell(args)
    clean_cost = tls_cost(corrupted, corrupted.gtsam_values(reference))
    threshold = default_outlier_residual(graph.dim)
    modes = [(defer, undo, confirm) for defer in args.defer.split(",")
             for undo in args.undo.split(",") for confirm in args.confirm.split(",")]
    lookahead = admission_undo.LOOKAHEAD
    for defer, undo, confirm in modes:
        admission_undo.LOOKAHEAD = 0 if undo == "myopic" else lookahead
        start, cpu = time.perf_counter(), time.process_time()
        result = optimize(corrupted, "none", "gnc", init="odometry", gnc_start="incremental",
                          defer=defer, undo=undo != "off", confirm=confirm == "on")
        seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
        residuals = np.array([whitened_residual(c, result.poses, graph.dim)
                              for c in corrupted.loops])
        obeyed = residuals <= threshold
        false_obeyed = np.flatnonzero(obeyed & is_false)
        consistent = consistent_with_clean(graph, reference,
                                           [corrupted.loops[k] for k in false_obeyed])
        gap = tls_cost(corrupted, corrupted.gtsam_values(result.poses)) - clean_cost
        print(f"{args.graph} x{args.scale:g} {args.policy} {args.ratio:g}% seed {args.seed} "
              f"defer={defer} undo={undo} confirm={confirm}: "
              f"ATE {aligned_position_error(result.poses, reference, graph.dim):.3g}"
              f" m, {len(false_obeyed)} false obeyed ({consistent} consistent), "
              f"{int((~obeyed & ~is_false).sum())} true rejected, {seconds:.1f} s "
              f"({cpu:.1f} s CPU), gap {gap:+.1f}", flush=True)

if __name__ == "__main__":
    main()
