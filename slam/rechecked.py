"""Re-checks of the incremental admission's TLS solution, and the stated graph re-solved.

`slam.optimize.optimize` (``gnc_start="incremental"``) passes the admission's decisions
through `_rechecked` (``recheck``: under calibrated odometry, `slam.loop_recheck`) and
`_segment_rechecked` (``segments``: under odometry calibrated per segment,
`slam.segment_recheck`); each re-solves the stated graph only when its re-check changes
the decisions.
"""

from __future__ import annotations

import gtsam
import numpy as np
from numpy.typing import NDArray

from slam.consistency import LM_BUDGET, needs_qr, polish, refine_tls, tls_threshold
from slam.initial_poses import initial_guess
from slam.least_squares import StickySolver, dogleg_qr
from slam.loop_recheck import recheck_loops
from slam.pose_graph import PoseGraph
from slam.segment_recheck import segment_recheck

Array = NDArray[np.float64]
POLISH_ROUNDS = 5  # re-decisions at the polished solution after the segment re-check


def _rechecked(
    graph: PoseGraph, factors: gtsam.NonlinearFactorGraph, loop_index: list[int],
    values: gtsam.Values, weights: Array, probability: float, solver: str, start: float,
) -> tuple[gtsam.Values, Array, str]:
    """`slam.loop_recheck.recheck_loops` on an admission; the stated graph re-solved with the
    re-checked loops when they differ (dogleg-QR, as `incremental_tls` polishes)."""
    unit = [factors.at(k) for k in loop_index]
    new, _ = recheck_loops(graph, values, weights, probability=probability, unit=unit,
                           start=start)
    if np.array_equal(new > 0.5, np.asarray(weights) > 0.5):
        return values, weights, solver
    kept = gtsam.NonlinearFactorGraph()
    loops = set(loop_index)
    for k in range(factors.size()):
        if k not in loops:
            kept.add(factors.at(k))
    for k in np.flatnonzero(new > 0.5):
        kept.add(unit[k])
    return dogleg_qr(kept, values, 100).optimize(), new, f"{solver}-rechecked"


def _segment_rechecked(
    graph: PoseGraph, factors: gtsam.NonlinearFactorGraph, loop_index: list[int],
    values: gtsam.Values, weights: Array, probability: float, solver: str,
    groups: bool = True,
) -> tuple[gtsam.Values, Array, str]:
    """`slam.segment_recheck.segment_recheck` on a TLS solution (`groups`: with its group test);
    when it removes loops or offers rejected ones back (`slam.group_recheck.group_recheck`'s
    readmitted loops, weight 1 from here on), the removed ones are barred, the rest
    re-decided on the stated graph by
    `slam.consistency.refine_tls` and the result polished (`slam.consistency.polish`), as
    is the odometry chain with the same loops; the solution of lower stated error is kept
    (the map the false loops bent can hold the polish in a local minimum the chain is
    free of).  The decisions are then re-made at the polished solution
    (``w_k = [e_k <= c]``, barred loops out) and re-polished until they hold (at most
    `POLISH_ROUNDS` times): on a loosely stated graph `refine_tls`'s solves can stop short
    of the optimum, where a true loop that a group of false ones had kept out still shows
    an error above ``c``."""
    unit = [factors.at(k) for k in loop_index]
    solve = StickySolver(lm_budget=LM_BUDGET, sticky=False)
    solve.dogleg = needs_qr(graph, values)
    check = segment_recheck(graph, values, weights, probability=probability, solver=solve,
                            unit=unit, groups=groups)
    if not check.removed and not (check.groups is not None and check.groups.readmitted):
        return values, weights, solver
    stated = (factors, loop_index)
    if check.groups is not None and check.groups.readmitted:
        weights = np.asarray(weights, dtype=float).copy()
        weights[check.groups.readmitted] = 1.0
    refined, new = refine_tls(graph, values, weights, probability=probability, solver=solve,
                              barred=check.removed, factors=stated)
    c = tls_threshold(graph.dim, probability)
    result = polish(stated, new, refined, solve.max_iterations)
    chain = polish(stated, new, graph.gtsam_values(initial_guess(graph, "odometry")),
                   solve.max_iterations)
    if _stated_error(stated, new, chain) < _stated_error(stated, new, result):
        result = chain
    for _ in range(POLISH_ROUNDS):
        again = np.array([unit[k].error(result) <= c for k in range(len(unit))], dtype=float)
        again[check.removed] = 0.0
        if np.array_equal(again, new):
            break
        new = again
        result = polish(stated, new, result, solve.max_iterations)
    return result, new, f"{solver}-segments"


def _stated_error(factors: tuple[gtsam.NonlinearFactorGraph, list[int]], weights: Array,
                  values: gtsam.Values) -> float:
    """Error (gtsam units) of the stated graph `factors` with the loops of ``weights > 0.5``
    at `values`."""
    base, loop_index = factors
    loops = set(loop_index)
    fixed = sum(base.at(k).error(values) for k in range(base.size()) if k not in loops)
    return float(fixed + sum(base.at(loop_index[k]).error(values)
                             for k in np.flatnonzero(np.asarray(weights) > 0.5)))
