"""Diagnosis: which false loops the time-ordered TLS admission keeps, and what the swap
search (`slam.swap`) does about them, on one corrupted pose graph.

Run from the repository root::

    python benchmarks/robust_admission_trace.py input_M3500a_g2o.g2o [--data DIR]
        [--scale 1] [--policy random] [--ratio 50] [--seed 1]

Printed: per candidate of `slam.consistency.incremental_tls` (odometry ladder rung x
gate, after `refine_tls`) its stated TLS objective, the false loops it keeps (pose ids
``i-j``, span in poses, whitened residual at the clean optimum) and the true loops it
rejects; the clean optimum's objective; then the swap search on the winner: per group
tried, its size, pose ids, the loops it pushed out (false or true) and the objective's
drop.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.robust_cell import cell_parser, read_cell
from slam.consistency import incremental_tls, tls_cost
from slam.offer_back import choose_and_offer_back
from slam.optimize import initial_guess
from slam.pose_graph import whitened_residual
from slam.swap import swap_search


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0], seed=1, cache=False)
    args = parser.parse_args()
    graph, reference, corrupted, false = read_cell(args)
    print(f"{len(graph.keys)} poses, {(~false).sum()} true loops, {false.sum()} false; "
          f"clean objective {tls_cost(corrupted, corrupted.gtsam_values(reference)):.1f}")

    def describe(weights: np.ndarray) -> str:
        kept = np.flatnonzero((weights > 0.5) & false)
        parts = []
        for k in kept:
            c = corrupted.loops[k]
            r = whitened_residual(c, reference, graph.dim)
            parts.append(f"{c.i}-{c.j} (span {abs(c.j - c.i)}, r {r:.3g})")
        rejected = int(((weights < 0.5) & ~false).sum())
        return f"{len(kept)} false kept [{', '.join(parts)}], {rejected} true rejected"

    values = corrupted.gtsam_values(initial_guess(corrupted, "odometry"))
    candidates: list = []

    def record(g, cands, **kw):  # the chooser `optimize` uses, candidates recorded
        candidates.extend(cands)
        return choose_and_offer_back(g, cands, factor=[], **kw)

    t = time.process_time()
    best = incremental_tls(corrupted, values, choose=record)
    print(f"admission: {time.process_time() - t:.1f} s cpu")
    for n, (_, w, cost) in enumerate(candidates):
        print(f"  candidate {n}: objective {cost:.1f}, {describe(w)}")
    print(f"  winner ({best.gate}): objective {best.tls_cost:.1f}, {describe(best.weights)}")
    t = time.process_time()
    out = swap_search(corrupted, best, values)
    print(f"swap search: {time.process_time() - t:.1f} s cpu, {len(out.tried)} groups tried")
    for group, (pushed, gain) in zip(out.tried, out.trials, strict=True):
        ends = f"{corrupted.loops[group[0]].i}-{corrupted.loops[group[0]].j}"
        kinds = ["F" if false[k] else "T" for k in pushed]
        print(f"  group of {len(group)} at {ends}: pushed out {len(pushed)} "
              f"({''.join(kinds)}), drop {gain:.1f}")
    print(f"  result ({out.admission.gate}, replayed {out.replayed}): objective "
          f"{out.admission.tls_cost:.1f}, {describe(out.admission.weights)}")


if __name__ == "__main__":
    main()
