"""Diagnosis: the false loops one time-ordered admission pass admits, and what each cost.

Run from the repository root::

    python benchmarks/robust_false_admissions.py input_M3500a_g2o.g2o [--data DIR]
        [--scale 1] [--policy random] [--ratio 50] [--seed 0] [--rung 10]
        [--defer off|bounded|all] [--undo] [--show 8] [--cache DIR]

One `slam.admission.AdmissionPass` (stated gate, batch prefix solves) on the corrupted
graph with its odometry information multiplied by `--rung` (one rung of
`slam.consistency.incremental_tls`'s odometry ladder), block by block.  Printed for each
of the first `--show` false loops it admits: the block's last pose id, the loop's pose
ids and span [poses], its whitened residual at the clean optimum, its innovation
``delta`` when the greedy admitted it (the linearised cost of admitting it, gtsam error
units; nan when the residual rule admitted it), the actual least-squares cost of keeping
it (the accepted prefix's error with it less the error re-solved without it, gtsam error
units; the TLS rule keeps a loop whose cost is below ``c``), its own factor error at the
prefix solution, and the largest move [m] of every 25th pose between the two solutions
(how far it bent the map).  Then the pass's totals: false loops admitted, true loops
rejected.  `--confirm`: the pass re-checks every innovation-gate admission by its
actual cost (`AdmissionPass.confirm`).  `--undo`: the pass tests its undo hypotheses
(`slam.admission_undo`); `--cache`: a folder keeping the clean optimum
between runs, as in `benchmarks/robust_modes.py`.
"""

from __future__ import annotations

import sys
from pathlib import Path

import gtsam
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import slam.admission as admission
from benchmarks.robust_cell import cell_parser, read_cell
from slam.consistency import BOUNDED_WAIT, _odometry_scaled, polish, tls_threshold
from slam.optimize import initial_guess
from slam.pose_graph import whitened_residual


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--rung", type=float, default=10.0)
    parser.add_argument("--defer", choices=("off", "bounded", "all"), default="off")
    parser.add_argument("--show", type=int, default=8)
    parser.add_argument("--undo", action="store_true")
    parser.add_argument("--confirm", action="store_true")
    args = parser.parse_args()
    graph, reference, corrupted, false = read_cell(args)
    values = corrupted.gtsam_values(initial_guess(corrupted, "odometry"))
    decide = corrupted if args.rung == 1.0 else _odometry_scaled(corrupted, args.rung)
    run = admission.AdmissionPass(decide, values, prefix_solver="batch",
                                  defer=args.defer != "off",
                                  wait=BOUNDED_WAIT if args.defer == "bounded" else None,
                                  undo=args.undo, confirm=args.confirm)
    position = {id(f): k for k, f in enumerate(run.unit)}
    candidates: list[int] = []
    rows: list[np.ndarray] = []  # the candidates' whitened residuals, to find subsets' rows
    delta_at: dict[int, float] = {}
    gains, greedy = admission.InnovationTest.gains, admission.greedy_admission

    def recorded_gains(self, factors):  # the loops behind the next greedies' candidates
        candidates[:] = [position[id(f)] for f in factors]
        out = gains(self, factors)
        rows[:] = [out.b.copy()]
        return out

    def recorded_greedy(g, gate, costs=None):  # `g` may be a subset of those candidates
        costs = [] if costs is None else costs
        b = g.b.copy()
        chosen, final = greedy(g, gate, costs)
        for q, d in zip(chosen, costs, strict=True):
            row = int(np.flatnonzero((rows[0] == b[q]).all(axis=1))[0])
            delta_at[candidates[row]] = d
        return chosen, final

    admission.InnovationTest.gains = recorded_gains
    admission.greedy_admission = recorded_greedy
    c = tls_threshold(graph.dim)
    shown = 0
    while not run.done:
        before = run.weights.copy()
        end = run._ends[run._step]
        run.advance(blocks=1)
        for k in np.flatnonzero((run.weights > 0.5) & (before < 0.5) & false):
            if shown >= args.show:
                continue
            shown += 1
            target = run.unit[k]
            fixed = run._fixed
            without = gtsam.NonlinearFactorGraph()
            for n in range(fixed.size()):
                if fixed.at(n).keys() != target.keys():
                    without.add(fixed.at(n))
            solved = polish((without, []), np.zeros(0), run.current)
            moved = max(np.hypot(solved.atPose2(x).x() - run.current.atPose2(x).x(),
                                 solved.atPose2(x).y() - run.current.atPose2(x).y())
                        for x in run.keys[: run.last + 1 : 25]) if graph.dim == 2 else np.nan
            loop = corrupted.loops[k]
            print(f"block to {end}: false {loop.i}-{loop.j} span {abs(loop.j - loop.i)} "
                  f"r_clean {whitened_residual(loop, reference, graph.dim):.1f} "
                  f"delta {delta_at.get(int(k), float('nan')):.2f} "
                  f"cost {fixed.error(run.current) - without.error(solved):.2f} "
                  f"(c {c:.2f}) own error {target.error(run.current):.2f} "
                  f"moved {moved:.2f} m")
    w = run.weights
    print(f"pass at odometry x{args.rung:g}, defer {args.defer}: "
          f"{int((w[false] > 0.5).sum())} false admitted, "
          f"{int((w[~false] < 0.5).sum())} true rejected, "
          f"{run.undone} of {run.tried} undo hypotheses kept, {run.reverted} of "
          f"{run.examined} look-aheads reverted, {run.refused} admissions refused by "
          f"their nonlinear cost")


if __name__ == "__main__":
    main()
