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

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import slam.admission_undo as admission_undo
from benchmarks.robust_cell import cell_outcome, cell_parser, read_cell
from slam.optimize import optimize


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--defer", default="off")
    parser.add_argument("--undo", default="off")
    parser.add_argument("--confirm", default="off", help="off,on: the nonlinear check")
    args = parser.parse_args()
    graph, reference, corrupted, is_false = read_cell(args)
    modes = [(defer, undo, confirm) for defer in args.defer.split(",")
             for undo in args.undo.split(",") for confirm in args.confirm.split(",")]
    lookahead = admission_undo.LOOKAHEAD
    for defer, undo, confirm in modes:
        admission_undo.LOOKAHEAD = 0 if undo == "myopic" else lookahead
        start, cpu = time.perf_counter(), time.process_time()
        result = optimize(corrupted, "none", "gnc", init="odometry", gnc_start="incremental",
                          defer=defer, undo=undo != "off", confirm=confirm == "on")
        seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
        out = cell_outcome(graph, reference, corrupted, is_false, result.poses)
        print(f"{args.graph} x{args.scale:g} {args.policy} {args.ratio:g}% seed {args.seed} "
              f"defer={defer} undo={undo} confirm={confirm}: "
              f"ATE {out.ate:.3g} m, {len(out.false_obeyed)} false obeyed "
              f"({out.consistent} consistent), {out.true_rejected} true rejected, "
              f"{seconds:.1f} s ({cpu:.1f} s CPU), gap {out.gap:+.1f}", flush=True)

if __name__ == "__main__":
    main()
