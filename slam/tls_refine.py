"""TLS re-decision of every loop on the whole graph, and the stated graph with chosen loops.

The truncated-least-squares objective of `slam.consistency` is ``sum_k min(e_k, c)`` over
the loops (``e_k`` a loop factor's error ``0.5 r^T Omega r`` at the solution, ``c`` the
chi-square quantile of `slam.innovation.tls_threshold`).  `refine_tls` minimises it from
a start inside its basin by iteratively re-weighted least squares; `stated_with_loops`
builds the graph as stated with a chosen set of loops.  Both are shared by the admission
driver (`slam.consistency`) and the searches that re-decide its result (`slam.regroup`).
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from slam.admission import StatedFactors
from slam.innovation import tls_threshold
from slam.least_squares import StickySolver
from slam.pose_graph import PoseGraph, RobustKernel
from slam.warm_starts import WarmStarts, solve_from

__all__ = ["refine_tls", "stated_with_loops"]

Array = NDArray[np.float64]


def refine_tls(
    graph: PoseGraph,
    values: gtsam.Values,
    weights: Array,
    *,
    probability: float = 0.99,
    max_rounds: int = 30,
    solver: StickySolver | None = None,
    barred: Sequence[int] = (),
    solved: bool = False,
    factors: StatedFactors | None = None,
    starts: WarmStarts | None = None,
) -> tuple[gtsam.Values, Array]:
    """Re-decide every loop by the TLS residual rule on the whole graph until stable.

    Solve with the loops of weight 1, set ``w_k = [e_k <= c]``, repeat (iteratively
    re-weighted least squares of the TLS loss from a start inside its basin).  Loops
    in `barred` keep weight 0.  `solved`: `values` already solve the graph with
    `weights` (an `admit_incrementally` result), so the first solve is skipped.
    `factors`: as in `tls_cost`.  `starts`: each solve starts from the nearest solution
    held there (`WarmStarts.start`: least error on the graph to solve, the current
    solution on ties) and holds its own (and `values`, when `solved`).
    """
    solve = solver or StickySolver()
    base, loop_index = factors or graph.factor_graph(RobustKernel("none"))
    c = tls_threshold(graph.dim, probability)
    n_fixed = base.size() - len(loop_index)
    w = np.asarray(weights, dtype=float).copy()
    w[list(barred)] = 0.0
    result = values
    if solved and starts is not None:
        starts.hold(values)
    for n in range(max_rounds):
        if not (solved and n == 0):
            kept = gtsam.NonlinearFactorGraph()
            for k in range(n_fixed):
                kept.add(base.at(k))
            for k in np.flatnonzero(w > 0.5):
                kept.add(base.at(loop_index[k]))
            result = solve_from(starts, solve, kept, result)
        new = np.array([base.at(k).error(result) <= c for k in loop_index], dtype=float)
        new[list(barred)] = 0.0
        if np.array_equal(new, w):
            break
        w = new
    return result, w


def stated_with_loops(factors: StatedFactors, weights: Array) -> gtsam.NonlinearFactorGraph:
    """The stated graph `factors` with only the loops of ``weights > 0.5``."""
    base, loop_index = factors
    kept = gtsam.NonlinearFactorGraph()
    for k in range(base.size() - len(loop_index)):
        kept.add(base.at(k))
    for k in np.flatnonzero(np.asarray(weights) > 0.5):
        kept.add(base.at(loop_index[k]))
    return kept
