"""Diagnosis: the nonlinear check of innovation-gate admissions (``confirm``) off, as
first written (every admission re-solved one loop left out, batch solves for the rest
of a pass after a refusal) and as it is now (`slam.admission.AdmissionPass._unconfirmed`:
the joint cost bounds each loop's; `_turned_back`: the refused loops are taken out of the
iSAM2 prefix), on one corrupted pose graph, in one process.

Run from the repository root::

    python benchmarks/robust_confirm_ab.py input_MITb_g2o.g2o [--data DIR] [--scale 1]
        [--policy random] [--ratio 50] [--seed 0] [--modes off,old,new] [--cache DIR]

One line per mode: ATE against the outlier-free optimum [m], false loops obeyed (of
them, consistent with the outlier-free graph), true loops rejected, the TLS objective's
gap to the clean optimum, CPU seconds of this process and the ratio to the first mode's;
then, for each later mode, whether it kept the same loops as the mode before it and the
largest distance between their poses [m].  `slam.optimize.optimize` as `benchmarks/robust_modes.py`
calls it (``gnc``, incremental, from the odometry chain, undo on), after an untimed
warm-up on the graph's first 200 poses.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.robust_cell import cell_outcome, cell_parser, read_cell
from slam.admission import AdmissionPass
from slam.admission_undo import with_loops
from slam.optimize import optimize
from slam.pose_graph import PoseGraph

NEW = (AdmissionPass._unconfirmed, AdmissionPass._turned_back)


def _old_unconfirmed(self, fixed, pending, accepted, admitted, current, before, start):
    """The check as first written: every admitted loop's cost by a batch solve without it."""
    unit, accepted, left = self.unit, accepted.copy(), [int(q) for q in admitted]
    out: list[int] = []
    while left:
        total = with_loops(fixed, unit, pending[accepted]).error(current)
        costs = []
        for q in left:
            others = accepted.copy()
            others[q] = False
            without = with_loops(fixed, unit, pending[others])
            try:
                costs.append(total - without.error(self._solve(without, current)))
            except RuntimeError:
                costs.append(-np.inf)
        worst = int(np.argmax(costs))
        if not costs[worst] > self._c:
            break
        q = left.pop(worst)
        out.append(q)
        accepted[q] = False
        if left:
            current = self._solve(with_loops(fixed, unit, pending[accepted]), current)
    return np.array(out, dtype=np.int64)


def _old_turned_back(self, factors, current, removed, held=False):
    """As first written: the iSAM2 prefix dropped, batch solves for the rest of the pass
    (a pass whose admission stopped iSAM2 converging marked folded, refusal or not)."""
    self.folded = self.folded or held
    self._isam = None
    return self._solve(factors, current), None


def _position(pose: np.ndarray) -> np.ndarray:
    """Position of a planar (x, y, theta) or spatial (4x4) pose [m]."""
    return pose[:2] if pose.ndim == 1 else pose[:3, 3]


def versus(label: str, first: tuple, cpu: float, obeyed: np.ndarray, poses: dict) -> str:
    """`; vs LABEL: same loops B, D m apart, CPU xR`: a run (its CPU seconds, obeyed-loop
    mask and poses) against `first` = (cpu, obeyed, poses) of the run it is compared with
    (D the largest position difference [m], R the CPU ratio)."""
    apart = max(float(np.linalg.norm(_position(poses[k]) - _position(first[2][k])))
                for k in poses)
    return (f"; vs {label}: same loops {bool((obeyed == first[1]).all())}, "
            f"{apart:.2g} m apart, CPU x{cpu / first[0]:.2f}")


def _head(graph: PoseGraph, n: int) -> PoseGraph:
    """The first `n` poses of `graph` with the constraints among them."""
    head = PoseGraph(dim=graph.dim)
    keep = set(graph.keys[:n])
    for k in sorted(keep):
        head.add_pose(k, graph.initial[k])
    head.fixed.update(k for k in graph.fixed if k in keep)
    for c in graph.odometry:
        if c.i in keep and c.j in keep:
            head.add_odometry(c.i, c.j, c.measurement, c.information)
    for c in graph.loops:
        if c.i in keep and c.j in keep:
            head.add_loop(c.i, c.j, c.measurement, c.information)
    return head


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--modes", default="off,old,new")
    args = parser.parse_args()
    graph, reference, corrupted, is_false = read_cell(args)
    # Untimed: numba's kernels are loaded (or compiled) on their first call, which would
    # otherwise be charged to the first mode.
    optimize(_head(corrupted, 200), "none", "gnc", init="odometry", gnc_start="incremental")
    first = None
    for mode in args.modes.split(","):
        AdmissionPass._unconfirmed, AdmissionPass._turned_back = (
            (_old_unconfirmed, _old_turned_back) if mode == "old" else NEW)
        cpu = time.process_time()
        result = optimize(corrupted, "none", "gnc", init="odometry", gnc_start="incremental",
                          confirm=mode != "off")
        cpu = time.process_time() - cpu
        out = cell_outcome(graph, reference, corrupted, is_false, result.poses)
        if first is None:
            first = previous = (cpu, out.obeyed, result.poses)
        apart = max(float(np.linalg.norm(_position(result.poses[k])
                                         - _position(previous[2][k]))) for k in result.poses)
        print(f"{args.graph} x{args.scale:g} {args.policy} {args.ratio:g}% seed {args.seed} "
              f"confirm={mode}: ATE {out.ate:.3g} m, {len(out.false_obeyed)} F "
              f"({out.consistent}), {out.true_rejected} T, gap {out.gap:+.1f}, {cpu:.1f} s CPU "
              f"(x{cpu / first[0]:.2f}), same loops as before: "
              f"{bool((out.obeyed == previous[1]).all())}, {apart:.2g} m apart", flush=True)
        previous = (cpu, out.obeyed, result.poses)
    AdmissionPass._unconfirmed, AdmissionPass._turned_back = NEW


if __name__ == "__main__":
    main()
