"""Diagnosis: does the TLS objective itself prefer a false loop that a result keeps?

Run from the repository root::

    python benchmarks/robust_objective_limited.py input_M3500a_g2o.g2o --loop 3457-444
        [--data DIR] [--scale 1] [--policy random] [--ratio 50] [--seed 0] [--cache DIR]

The clean graph (the corrupted graph's true loops, odometry and anchors as stated) is
solved from the clean optimum, then solved again with the false loop(s) between the two
poses of `--loop` added.  Printed: the TLS threshold ``c`` (gtsam error units), the
`tls_cost` of the clean solution (every false loop truncated at ``c``) and the loop's
factor error there, the `tls_cost` with the loop admitted and the ATE [m] of that
solution against the clean optimum.  A lower cost with the loop admitted means the loop
is the objective's choice: no method that minimises the TLS objective rejects it.
"""

from __future__ import annotations

import sys
from pathlib import Path

import gtsam
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.robust_cell import cell_parser, read_cell
from evaluation.robustness import aligned_position_error
from slam.consistency import tls_cost, tls_threshold
from slam.least_squares import StickySolver
from slam.pose_graph import RobustKernel, poses_from_values


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--loop", required=True, help="pose ids i-j of the false loop")
    args = parser.parse_args()
    graph, reference, corrupted, false = read_cell(args)
    i, j = map(int, args.loop.split("-"))
    chosen = [k for k, lp in enumerate(corrupted.loops) if {lp.i, lp.j} == {i, j} and false[k]]
    if not chosen:
        raise SystemExit(f"no false loop between poses {i} and {j}")
    base, loop_index = corrupted.factor_graph(RobustKernel("none"))
    n_fixed = base.size() - len(loop_index)
    solve = StickySolver()

    def solved(weights: np.ndarray, start: gtsam.Values) -> gtsam.Values:
        factors = gtsam.NonlinearFactorGraph()
        for n in range(n_fixed):
            factors.add(base.at(n))
        for k in np.flatnonzero(weights > 0.5):
            factors.add(base.at(loop_index[k]))
        return solve(factors, start)

    weights = (~false).astype(float)
    clean = solved(weights, corrupted.gtsam_values(reference))
    weights[chosen] = 1.0
    admitted = solved(weights, clean)
    ate = aligned_position_error(poses_from_values(admitted, graph.dim), reference, graph.dim)
    print(f"c {tls_threshold(graph.dim):.2f}; clean: objective {tls_cost(corrupted, clean):.2f}, "
          f"the loop's error {base.at(loop_index[chosen[0]]).error(clean):.1f}; "
          f"with {args.loop} admitted: objective {tls_cost(corrupted, admitted):.2f}, "
          f"ATE {ate:.3g} m")


if __name__ == "__main__":
    main()
