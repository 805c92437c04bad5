"""Diagnosis: how much work the nonlinear check of admissions (``confirm``,
`slam.admission.AdmissionPass._unconfirmed`) does on one corrupted pose graph.

Run from the repository root::

    python benchmarks/robust_confirm_count.py input_M3500_g2o.g2o [--data DIR] [--scale 1]
        [--policy random] [--ratio 50] [--seed 0] [--cache DIR] [--cap 600] [--rounds]
        [--confirm exact|screen] [--skip on|off]

Runs `slam.optimize.optimize` (``gnc``, incremental, from the odometry chain) with the
check counted: the rounds it judged (the innovation gate admitted loops), how many loops
each admitted, how many leave-one-out minima it computed (`AdmissionPass._solved_without`,
from a copy of the iSAM2 prefix or by a batch solve of the whole accepted prefix), how many
loops it turned back, and its CPU seconds.  ``--cap``: stop after that many CPU seconds
of the process (ITIMER_PROF) and print the counts so far; ``--rounds``: one line per
round that admitted several loops; ``--confirm screen``: the check with the linearised
leave-one-out screen (``optimize(confirm="screen")``), whose screenings are counted too;
``--skip off``: that screen without its ordered skip (`slam.admission.SCREEN_SKIP`).
When the run finishes the cell's outcome follows
(ATE against the outlier-free optimum [m], false loops obeyed (of them, consistent with
the outlier-free graph), true loops rejected, TLS gap to the clean optimum).
"""

from __future__ import annotations

import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.robust_cell import CpuCapped, cell_outcome, cell_parser, cpu_cap, read_cell
from slam import admission
from slam.admission import AdmissionPass
from slam.optimize import optimize


@dataclass
class ConfirmCount:
    """Counts of the check's work (module docstring); `sizes`: rounds by the number of
    loops the gate admitted; `cpu`: CPU seconds inside the check."""

    rounds: int = 0
    turned_back: int = 0
    minima: int = 0
    screens: int = 0
    from_isam: int = 0
    cpu: float = 0.0
    sizes: Counter = field(default_factory=Counter)
    verbose: bool = False


def counted(count: ConfirmCount):  # type: ignore[no-untyped-def]
    """Replacements of `AdmissionPass._unconfirmed`, `_solved_without` and `_screened`
    that add to `count` and call the originals (`restore` puts them back)."""
    unconfirmed, minimum = AdmissionPass._unconfirmed, AdmissionPass._solved_without
    screened = AdmissionPass._screened

    def _unconfirmed(self, fixed, pending, accepted, admitted, current, before, start):  # type: ignore[no-untyped-def]
        began, minima = time.process_time(), count.minima
        out = unconfirmed(self, fixed, pending, accepted, admitted, current, before, start)
        spent = time.process_time() - began
        count.cpu += spent
        count.rounds += 1
        count.sizes[len(admitted)] += 1
        count.turned_back += len(out)
        if count.verbose and len(admitted) > 1:
            print(f"block {self.blocks}: admitted {len(admitted)}, turned back {len(out)}, "
                  f"{count.minima - minima} minima, {spent:.2f} s CPU", flush=True)
        return out

    def _minimum(self, without, current, start, removed):  # type: ignore[no-untyped-def]
        count.minima += 1
        count.from_isam += self._isam is not None
        return minimum(self, without, current, start, removed)

    def _screened(self, kept, current, loops):  # type: ignore[no-untyped-def]
        count.screens += 1
        return screened(self, kept, current, loops)

    return _unconfirmed, _minimum, _screened


def install(count: ConfirmCount) -> tuple:
    """Count the check's work into `count`; returns the originals for `restore`."""
    originals = (AdmissionPass._unconfirmed, AdmissionPass._solved_without,
                 AdmissionPass._screened)
    (AdmissionPass._unconfirmed, AdmissionPass._solved_without,
     AdmissionPass._screened) = counted(count)
    return originals


def restore(originals: tuple) -> None:
    """Undo `install`."""
    (AdmissionPass._unconfirmed, AdmissionPass._solved_without,
     AdmissionPass._screened) = originals


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--cap", type=float, default=0.0)
    parser.add_argument("--rounds", action="store_true")
    parser.add_argument("--confirm", default="exact", choices=("exact", "screen"))
    parser.add_argument("--skip", default="on", choices=("on", "off"))
    args = parser.parse_args()
    admission.SCREEN_SKIP = args.skip == "on"
    graph, reference, corrupted, is_false = read_cell(args)
    name = (f"{args.graph} x{args.scale:g} {args.policy} {args.ratio:g}% seed {args.seed} "
            f"confirm {args.confirm}" + (f" skip {args.skip}" if args.confirm == "screen" else ""))
    count = ConfirmCount(verbose=args.rounds)
    install(count)
    began = time.process_time()
    try:
        with cpu_cap(args.cap):
            result = optimize(corrupted, "none", "gnc", init="odometry",
                              gnc_start="incremental",
                              confirm=True if args.confirm == "exact" else args.confirm)
        out = cell_outcome(graph, reference, corrupted, is_false, result.poses)
        status = (f"finished in {time.process_time() - began:.1f} s CPU: ATE {out.ate:.3g} m, "
                  f"{len(out.false_obeyed)} F ({out.consistent}), {out.true_rejected} T, "
                  f"gap {out.gap:+.1f}")
    except CpuCapped:
        status = f"capped at {time.process_time() - began:.1f} s CPU"
    print(f"{name}: {status}; the check: {count.rounds} rounds, {count.minima} minima "
          f"({count.from_isam} from iSAM2 copies), {count.screens} screens, "
          f"{count.turned_back} turned back, "
          f"{count.cpu:.1f} s CPU; rounds by loops admitted {sorted(count.sizes.items())}")


if __name__ == "__main__":
    main()
