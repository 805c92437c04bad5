"""Swap search: groups of rejected loops admitted together, judged on the TLS objective.

The time-ordered admission (`slam.consistency.incremental_tls`) decides each loop once,
against the prefix solved with the loops admitted before it.  When false loops were
admitted early (each cheap alone against a loosely stated prefix), the true loops that
contradict them arrive at errors far above ``c`` and are rejected one by one, though
together they outweigh the false ones: a single true loop cannot pay for pushing a
false loop out, a group of them can.  True loops come in groups (a revisit closes a
loop at several consecutive poses, both ends within a few ids: `slam.group_recheck.loop_groups`),
while loops injected or found at random rarely do.

`swap_search` therefore tries every group of at least `MIN_GROUP` rejected loops: the
group is admitted, the graph solved from the current solution, and every loop then
re-decided by the residual rule (`slam.consistency.refine_tls`, the group included).  The
swap is kept only when

* the stated TLS objective (`slam.consistency.tls_cost`) drops,
* it pushes out at least one previously admitted loop (a group the residual rule could
  simply add was the refinement's business, not a swap's), and
* the drop is at least `GAIN_PER_LOOP` per loop pushed out: a swap that trades an
  admitted loop for a group at nearly the same cost is a coin toss between two readings
  of the data, not evidence (without this rule true grouped loops of MITb were pushed
  out by a group of false ones for a small gain).

After the groups, a *final replay*: the time-ordered admission is run again with every
loop pushed out barred (`slam.consistency.admit_incrementally`) and refined on the stated
graph; it replaces the swapped solution when cheaper (the swaps were decided on a map
the pushed-out loops had bent, the replay decides every loop without them).

Cost: per group one solve and the refinement's solves; the replay, a whole admission
pass, only when some swap was kept.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import gtsam
import numpy as np
from numpy.typing import NDArray

from slam.consistency import (
    Admission,
    StatedFactors,
    admit_incrementally,
    refine_tls,
    stated_with_loops,
    tls_cost,
)
from slam.group_recheck import loop_groups
from slam.least_squares import StickySolver
from slam.pose_graph import PoseGraph, RobustKernel

Array = NDArray[np.float64]
MIN_GROUP = 3  # rejected loops a group needs to be tried
GAIN_PER_LOOP = 10.0  # least drop of the TLS objective (gtsam error units) per loop pushed out


@dataclass(slots=True)
class SwapSearch:
    """Outcome of `swap_search`: the solution, the groups tried and kept (indices into
    `graph.loops`), the loops pushed out and whether the final replay replaced the
    swapped solution; `trials`: per group tried, the admitted loops it pushed out and the
    drop of the TLS objective (negative: a rise)."""

    admission: Admission
    tried: list[list[int]] = field(default_factory=list)
    trials: list[tuple[list[int], float]] = field(default_factory=list)
    kept: list[list[int]] = field(default_factory=list)
    pushed: list[int] = field(default_factory=list)
    replayed: bool = False


def rejected_groups(graph: PoseGraph, weights: Array, min_size: int = MIN_GROUP) -> list[list[int]]:
    """Groups (`slam.group_recheck.loop_groups`) of at least `min_size` loops of weight 0, largest
    first (ties in order of their first loop)."""
    rejected = np.flatnonzero(np.asarray(weights) < 0.5)
    groups = [g for g in loop_groups(graph.loops, rejected) if len(g) >= min_size]
    return sorted(groups, key=len, reverse=True)


def swap_search(
    graph: PoseGraph,
    admission: Admission,
    start: gtsam.Values,
    *,
    probability: float = 0.99,
    solver: StickySolver | None = None,
    factors: StatedFactors | None = None,
    unit: list[gtsam.NonlinearFactor] | None = None,
    min_group: int = MIN_GROUP,
    gain_per_loop: float = GAIN_PER_LOOP,
    replay: bool = True,
    progress: Callable[[int, int], None] | None = None,
) -> SwapSearch:
    """Swap search on `admission` (module docstring); `start`: the initial guess the
    admission ran from (for the replay).  `progress(done, total)` is called before each
    group and once at the end."""
    solve = solver or StickySolver()
    stated = factors or graph.factor_graph(RobustKernel("none"))
    base, loop_index = stated
    if unit is None:
        unit = [base.at(k) for k in loop_index]
    best = admission
    out = SwapSearch(admission)
    groups = rejected_groups(graph, best.weights, min_group)
    pushed: set[int] = set()
    for n, group in enumerate(groups):
        if progress is not None:
            progress(n, len(groups))
        if (best.weights[group] > 0.5).any():  # an earlier swap re-admitted some of it
            continue
        out.tried.append(group)
        w = best.weights.copy()
        w[group] = 1.0
        solved = solve(stated_with_loops(stated, w), best.values)
        refined, new = refine_tls(graph, solved, w, probability=probability, solver=solve,
                                  solved=True, factors=stated)
        out_now = [int(k) for k in np.flatnonzero((best.weights > 0.5) & (new < 0.5))]
        cost = tls_cost(graph, refined, probability, stated)
        out.trials.append((out_now, best.tls_cost - cost))
        if out_now and best.tls_cost - cost >= gain_per_loop * len(out_now):
            best = Admission(refined, new, cost, best.blocks, f"{best.gate}-swapped",
                             best.prefix)
            out.kept.append(group)
            pushed.update(out_now)
    if progress is not None:
        progress(len(groups), len(groups))
    pushed -= {int(k) for k in np.flatnonzero(best.weights > 0.5)}
    out.pushed = sorted(pushed)
    if replay and out.pushed:
        run = admit_incrementally(graph, start, probability=probability, solver=solve,
                                  barred=out.pushed, unit=unit)
        refined, new = refine_tls(graph, run.values, run.weights, probability=probability,
                                  solver=solve, barred=out.pushed, solved=True,
                                  factors=stated)
        cost = tls_cost(graph, refined, probability, stated)
        if cost < best.tls_cost * (1.0 - 1e-9):
            best = Admission(refined, new, cost, best.blocks, f"{best.gate}-replayed",
                             best.prefix)
            out.replayed = True
    out.admission = best
    return out
