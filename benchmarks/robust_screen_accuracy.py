"""Diagnosis: how well the linearised leave-one-out screen of the admission check
(`slam.admission.AdmissionPass._screened`, `slam.innovation.removal_costs`) predicts the
cost the exact check computes, on one corrupted pose graph.

Run from the repository root::

    python benchmarks/robust_screen_accuracy.py input_M3500_g2o.g2o [--data DIR]
        [--scale 1] [--policy random] [--ratio 50] [--seed 0] [--cache DIR] [--cap 600]

Runs `slam.optimize.optimize` (``gnc``, incremental, from the odometry chain) with the
default, exact check; every leave-one-out minimum it solves (`AdmissionPass._minimum`)
is paired with the linearised cost ``rho`` of the same loop at the same joint solution
(one more factorisation each: a diagnosis, not the screen's cost).  Prints, in gtsam
error units with ``c`` the TLS threshold: the pairs, how many loops cost above ``c``,
how many of them the screen would have cleared (``rho <= SCREEN_FRACTION c``: the
screen's misses), and the largest ratio ``cost / rho`` among loops costing above
``SCREEN_FRACTION c``.  ``--cap``: stop after that many CPU seconds (ITIMER_PROF).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.robust_cell import capped_gnc, cell_parser, read_cell
from slam.admission import SCREEN_FRACTION, AdmissionPass
from slam.admission_undo import with_loops


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--cap", type=float, default=0.0)
    args = parser.parse_args()
    _graph, _reference, corrupted, is_false = read_cell(args)
    name = f"{args.graph} x{args.scale:g} {args.policy} {args.ratio:g}% seed {args.seed}"
    pairs: list[tuple[float, float, bool]] = []  # (rho, cost, false loop)
    minimum = AdmissionPass._minimum

    def paired(self, without, current, start, removed):  # type: ignore[no-untyped-def]
        low = minimum(self, without, current, start, removed)
        q = int(removed[-1])
        kept = with_loops(without, self.unit, np.array([q]))
        rho = self._screened(kept, current, np.array([q]))
        if rho is not None:
            pairs.append((float(rho[0]), float(kept.error(current) - low), bool(is_false[q])))
        return low

    AdmissionPass._minimum = paired
    began = time.process_time()
    finished = capped_gnc(corrupted, args.cap) is not None
    status = f"{'finished in' if finished else 'capped at'} {time.process_time() - began:.1f} s CPU"
    AdmissionPass._minimum = minimum
    c = AdmissionPass(corrupted, corrupted.gtsam_values(corrupted.initial))._c
    rho, cost, false = (np.array(v) for v in zip(*pairs, strict=True)) if pairs else (
        np.zeros(0), np.zeros(0), np.zeros(0, dtype=bool))
    above = cost > c
    missed = above & (rho <= SCREEN_FRACTION * c)
    watched = cost > SCREEN_FRACTION * c
    ratio = float(np.max(cost[watched] / rho[watched])) if watched.any() else float("nan")
    cleared = rho <= SCREEN_FRACTION * c
    print(f"{name}: {status}; c {c:.3f}; {len(rho)} exact minima paired; cost > c: "
          f"{int(above.sum())} ({int((above & false).sum())} false loops); the screen "
          f"would clear {int(cleared.sum())}, of them cost > c: {int(missed.sum())}; "
          f"largest cost/rho where cost > {SCREEN_FRACTION:g} c: {ratio:.3g}")
    order = np.argsort(-cost)
    for n in order[:15]:
        print(f"  rho {rho[n]:10.3f}  cost {cost[n]:10.3f}  {'false' if false[n] else 'true'}")


if __name__ == "__main__":
    main()
