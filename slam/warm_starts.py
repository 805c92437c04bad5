"""Starts of a sequence of related least-squares solves: the nearest solution held.

The robust back end solves many graphs that differ from one another only a little: the
same candidate's loops at several odometry variance factors (`slam.calibrated_choice`),
the same graph with a few loops more or fewer (`slam.consistency.refine_tls` on every
rung of the odometry ladder).  A solve from a start far from its optimum (a candidate's
solution at factor 1 judged at a factor well below 1, a rung's solution under odometry
ten times stiffer) costs many more iterations of the solver than one from a solution
already found for a neighbouring graph.  `WarmStarts` holds the solutions found so far
and starts each solve from the one at which the graph to solve has the least error.

Not bit-identical: where the own start and the held solution lie in the same basin, both
solves end at its optimum to the solver's tolerance, so values differ at that tolerance;
a held solution is taken only where the graph's error is lower there, but on a nonconvex
graph nothing guarantees the same basin (`benchmarks/warm_starts.md` compares the loops
decided and the poses with and without).  Units: gtsam errors (``0.5 r^T I r``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import gtsam
import numpy as np


class WarmStarts:
    """Solutions already found, offered as starts of the next solves.

    `start` picks, among a solve's own start and every solution held, the one at which
    the graph to solve has the least error (the own start on ties); `hold` adds a
    solution.  Cost: one error evaluation of the graph per solution held and solve.
    """

    def __init__(self, values: Iterable[gtsam.Values] = ()) -> None:
        self.values: list[gtsam.Values] = list(values)

    def start(self, factors: gtsam.NonlinearFactorGraph, own: gtsam.Values) -> gtsam.Values:
        """The start of a solve of `factors` whose own start is `own`."""
        tried = [own, *self.values]
        return tried[int(np.argmin([factors.error(v) for v in tried]))]

    def hold(self, values: gtsam.Values) -> gtsam.Values:
        """Hold the solution `values` (returned as is)."""
        self.values.append(values)
        return values


def solve_from(
    starts: WarmStarts | None,
    solve: Callable[[gtsam.NonlinearFactorGraph, gtsam.Values], gtsam.Values],
    factors: gtsam.NonlinearFactorGraph,
    own: gtsam.Values,
) -> gtsam.Values:
    """`solve` of `factors` from `own` (``starts`` None), or from `starts`' nearest
    held solution, the result then held too."""
    if starts is None:
        return solve(factors, own)
    return starts.hold(solve(factors, starts.start(factors, own)))
