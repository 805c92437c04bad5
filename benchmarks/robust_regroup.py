"""The regroup search (`slam.regroup`) on one cell: its hypotheses and the outcome.

Run from the repository root::

    python benchmarks/robust_regroup.py input_M3500a_g2o.g2o --scale 0.1 [--seed 0]
        [--policy random] [--ratio 50] [--cache DIR] [--runs off,on] [--cap SECONDS]
        [--lazy-off]
    python benchmarks/robust_regroup.py G ... --save-stage FILE   # the admission, off
    python benchmarks/robust_regroup.py G ... --stage FILE        # regroup on it alone

Default mode: `slam.optimize.optimize` as `eval robustness` runs it (``gnc``,
incremental, from the odometry chain) once per entry of `--runs`, with
`slam.consistency.REGROUP` off or on, in one process; per run the CPU seconds (and those
spent inside `slam.regroup.regroup`), the solver label, the largest pose difference from
the process' first run, the regroup hypotheses tested (group, contradicted loops, drop
of the TLS objective, kept) and the cell's outcome
(`benchmarks.robust_cell.cell_outcome`: ATE against the clean optimum [m], false loops
obeyed (consistent with the clean graph), true loops rejected, stated TLS objective less
the clean optimum's). An "on" run in which no hypothesis is solved is the "off" run bit
for bit (the admission is passed on unchanged and the solver untouched; pose difference
0): `--lazy-off` skips an "off" run listed after such an "on" run; the cost of regroup
is then its CPU seconds inside.

`--save-stage`: `slam.consistency.incremental_tls` as `optimize` calls it (regroup
off), its poses and weights stored; `--stage`: `slam.regroup.regroup` on a stored
admission, printed as above, with the outcome before and after.
"""

from __future__ import annotations

import pickle
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.robust_cell import capped_gnc, cell_outcome, cell_parser, read_cell
from slam import consistency, regroup
from slam.admission import Admission
from slam.consistency import incremental_tls, tls_cost
from slam.offer_back import choose_and_offer_back
from slam.optimize import initial_guess
from slam.pose_graph import poses_from_values


def spread(first, poses) -> float:  # type: ignore[no-untyped-def]
    """Largest absolute difference between two solutions' pose entries (`OptimizeResult.poses`,
    id to pose vector; m and rad); 0 for the first."""
    if first is None:
        return 0.0
    return max(float(np.abs(np.asarray(poses[k]) - np.asarray(first[k])).max()) for k in first)


def show(name: str, cell, poses) -> None:  # type: ignore[no-untyped-def]
    """One line: the outcome of `poses` on `cell` (`read_cell`'s tuple)."""
    out = cell_outcome(*cell, poses)
    print(f"{name}: ATE {out.ate:.3g} m, {len(out.false_obeyed)} F ({out.consistent}), "
          f"{out.true_rejected} T, gap {out.gap:+.2f}", flush=True)


def show_trials(trials, screened=()) -> None:  # type: ignore[no-untyped-def]
    """The hypotheses `slam.regroup.regroup` tested, then those its screen skipped."""
    for group, against, drop in screened:
        print(f"  screened out: return of {len(group)} loops ({group[0]}..), {len(against)} "
              f"suspects, predicted drop {drop:+.2f}", flush=True)
    for group, against, drop, kept in trials:
        print(f"  return of {len(group)} loops ({group[0]}..), {len(against)} suspects out "
              f"({against[:8]}..), "
              f"drop {drop:+.2f}, {'kept' if kept else 'not kept'}", flush=True)


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--runs", default="off,on")
    parser.add_argument("--cap", type=float, default=0.0, help="CPU seconds per run (0: none)")
    parser.add_argument("--save-stage", type=Path, default=None)
    parser.add_argument("--stage", type=Path, default=None)
    parser.add_argument("--no-screen", action="store_true",
                        help="with --stage: solve every hypothesis (regroup(screen=False))")
    parser.add_argument("--lazy-off", action="store_true",
                        help="skip an off run after an on run that solved no hypothesis")
    args = parser.parse_args()
    cell = read_cell(args)
    corrupted = cell[2]
    chain = corrupted.gtsam_values(initial_guess(corrupted, "odometry"))
    if args.save_stage is not None:
        cpu = time.process_time()
        adm = incremental_tls(corrupted, chain, choose=partial(choose_and_offer_back, factor=[]),
                              undo=True, confirm=True, regroup=False)
        print(f"admission: {time.process_time() - cpu:.1f} s CPU, {adm.gate}", flush=True)
        poses = poses_from_values(adm.values, corrupted.dim)
        args.save_stage.write_bytes(pickle.dumps((poses, adm.weights, adm.gate)))
        show("admission", cell, poses)
        return
    if args.stage is not None:
        data = pickle.loads(args.stage.read_bytes())
        poses, weights, gate = data[0], data[1], data[-1]
        values = corrupted.gtsam_values(poses)
        adm = Admission(values, np.asarray(weights, float), tls_cost(corrupted, values), 0, gate)
        show("before", cell, poses)
        cpu = time.process_time()
        out = regroup.regroup(corrupted, adm, chain, screen=not args.no_screen)
        print(f"regroup: {time.process_time() - cpu:.1f} s CPU", flush=True)
        show_trials(out.trials, out.screened)
        show("after", cell, poses_from_values(out.admission.values, corrupted.dim))
        return
    original = regroup.regroup
    trials: list = []
    screened: list = []
    inside = [0.0]  # CPU seconds spent in regroup during the current run

    def recorded(*a, **k):  # type: ignore[no-untyped-def]
        cpu = time.process_time()
        result = original(*a, **k)
        inside[0] += time.process_time() - cpu
        trials.extend(result.trials)
        screened.extend(result.screened)
        return result

    predict = regroup.predicted_cost
    predicted: list = []  # the screen's predicted drop of every hypothesis, in order

    def predicting(graph, values, weights, factors, probability=0.99):  # type: ignore[no-untyped-def]
        cost = predict(graph, values, weights, factors, probability)
        predicted.append(tls_cost(graph, values, probability, factors) - cost)
        return cost

    regroup.predicted_cost = predicting
    regroup.regroup = recorded
    consistency.redecide = recorded  # the name incremental_tls calls
    first = None  # the poses of this process' first run
    idle_on = False  # an "on" run of this process solved no hypothesis
    for run in args.runs.split(","):
        if run == "off" and args.lazy_off and idle_on:
            print("off: not run (the on run solved no hypothesis: its result is off's)",
                  flush=True)
            continue
        consistency.REGROUP = run == "on"
        trials.clear()
        screened.clear()
        inside[0] = 0.0
        predicted.clear()
        cpu = time.process_time()
        result = capped_gnc(corrupted, args.cap)
        if result is None:
            print(f"{run}: over {args.cap:.0f} s CPU", flush=True)
            continue
        print(f"{run}: {time.process_time() - cpu:.1f} s CPU ({inside[0]:.2f} s in regroup), "
              f"{result.solver}, {len(trials)} hypotheses, {len(screened)} screened out, "
              f"poses differ from the first run's by {spread(first, result.poses):.2g}", flush=True)
        first = result.poses if first is None else first
        idle_on = idle_on or (run == "on" and not trials)
        show_trials(trials, screened)
        print(f"  predicted drops, in the order screened: "
              f"{', '.join(f'{d:+.2f}' for d in predicted)}", flush=True)
        show(run, cell, result.poses)


if __name__ == "__main__":
    main()
