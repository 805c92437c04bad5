"""Re-deciding an early admitted loop against a later group of rejected loops that
contradicts it, judged on the TLS objective.

The time-ordered admission (`slam.consistency.incremental_tls`) decides the first loop
of a return against a prefix that ties its two poses only through a long odometry
chain: a false first closure can pass there, bend the map onto itself, and make every
true loop of the same return, arriving a block later, fail (each alone cannot pay for
pushing the false one out).  Those true loops agree with one another: they come in a
*group* (both ends within a few pose ids, `slam.group_recheck.loop_groups`) whose
members close short cycles with each other through the odometry, and the false loop,
whose ends lie near theirs, closes short cycles with them that fail.

`regroup` looks for that pattern in a finished admission and re-decides it:

1. the groups of at least `MIN_GROUP` rejected loops, largest first;
2. a group's *contradicted* loops: the admitted loops whose two ends lie within
   `NEAR` pose ids of the two ends of some member and whose pairwise cycle with at
   least half of those near members fails the chi-square test of
   `slam.pairwise_consistency` (the cycle ``z_a (odometry) z_g^-1 (odometry)`` over
   the short odometry stretches between their ends: a test with power, unlike the one
   against the whole prefix the loop was admitted by); a group none of whose members
   agree with one another (the same test) is skipped;
3. the hypothesis: the contradicted loops out, the group in, the stated graph solved
   from the current solution and from the odometry chain (the lower stated error
   kept), then every loop re-decided by the residual rule with the contradicted ones
   barred (`slam.consistency.refine_tls`);
4. it replaces the admission only when the stated TLS objective
   (`slam.consistency.tls_cost`, ``sum min(e_k, c)`` over every loop at the solution)
   is lower: the search never raises the objective.

Groups are taken again from the new decisions after each kept hypothesis (a kept one
usually admits the other groups of the same return through the residual rule).

Cost: nothing beyond the grouping when no rejected group has a contradicted loop; per
hypothesis two solves and `refine_tls`'s rounds.  2D only (the pairwise test);
3D admissions are returned unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np
from numpy.typing import NDArray

from slam.consistency import (
    Admission,
    StatedFactors,
    refine_tls,
    stated_with_loops,
    tls_cost,
)
from slam.group_recheck import loop_groups
from slam.least_squares import StickySolver
from slam.pairwise_consistency import LoopCycles, loop_cycles
from slam.pose_graph import PoseGraph, RobustKernel, chi2_quantile

Array = NDArray[np.float64]
MIN_GROUP = 3  # rejected loops a group needs to be tried
NEAR = 50  # pose ids: an admitted loop this close to a member on both ends is tested with it
MAX_TRIALS = 8  # hypotheses tested at most


@dataclass(slots=True)
class Regroup:
    """Outcome of `regroup`: the admission (replaced when a hypothesis was kept), and per
    hypothesis tested its group, its contradicted loops (indices into `graph.loops`),
    the drop of the TLS objective (negative: a rise) and whether it was kept."""

    admission: Admission
    trials: list[tuple[list[int], list[int], float, bool]] = field(default_factory=list)


def near_pairs(a: NDArray[np.int64], b: NDArray[np.int64], group: NDArray[np.int64],
               admitted: NDArray[np.int64], near: int) -> tuple[NDArray[np.int64],
                                                                NDArray[np.int64]]:
    """Pairs (admitted loop, group member) whose earlier ends (`a`, chain positions) and
    later ends (`b`) are both within `near` of each other: two index arrays into the
    loops, one entry per pair."""
    if not len(group) or not len(admitted):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    close = ((np.abs(a[admitted][:, None] - a[group][None, :]) <= near)
             & (np.abs(b[admitted][:, None] - b[group][None, :]) <= near))
    i, j = np.nonzero(close)
    return admitted[i], group[j]


def contradicted(cycles: LoopCycles, group: NDArray[np.int64], admitted: NDArray[np.int64],
                 *, near: int = NEAR, probability: float = 0.99) -> list[int]:
    """The admitted loops (indices into the loops of `cycles`) that fail the pairwise
    cycle test (squared Mahalanobis distance above ``chi2_3^-1(probability)``) with at
    least half of the members of `group` near them (`near_pairs`); sorted."""
    ai, gj = near_pairs(cycles.a, cycles.b, group, admitted, near)
    if not len(ai):
        return []
    fails = cycles.distances(ai, gj) > chi2_quantile(probability, 3)
    loops = np.unique(ai)
    out = [int(k) for k in loops if fails[ai == k].sum() * 2 >= (ai == k).sum()]
    return out


def agrees(cycles: LoopCycles, group: NDArray[np.int64], probability: float = 0.99) -> bool:
    """The members of `group` pass the pairwise cycle test with one another in at least
    half of their pairs (a group of loops that agree, as the loops of one return do)."""
    i, j = np.triu_indices(len(group), k=1)
    if not len(i):
        return False
    ok = cycles.distances(group[i], group[j]) <= chi2_quantile(probability, 3)
    return bool(ok.sum() * 2 >= len(ok))


def rejected_groups(graph: PoseGraph, weights: Array, min_size: int = MIN_GROUP
                    ) -> list[NDArray[np.int64]]:
    """Groups (`slam.group_recheck.loop_groups`) of at least `min_size` loops of weight 0,
    largest first (ties in order of their first loop)."""
    rejected = np.flatnonzero(np.asarray(weights) < 0.5)
    groups = [g for g in loop_groups(graph.loops, rejected) if len(g) >= min_size]
    return [np.array(g, dtype=np.int64) for g in sorted(groups, key=len, reverse=True)]


def regroup(
    graph: PoseGraph,
    admission: Admission,
    chain: gtsam.Values,
    *,
    probability: float = 0.99,
    solver: StickySolver | None = None,
    factors: StatedFactors | None = None,
    min_group: int = MIN_GROUP,
    near: int = NEAR,
    max_trials: int = MAX_TRIALS,
) -> Regroup:
    """The module docstring's search on `admission` (a solution of `graph` with its
    weights and stated `tls_cost`); `chain`: the odometry chain (the second start of a
    hypothesis' solve).  Returns the admission unchanged for a 3D graph."""
    out = Regroup(admission)
    if graph.dim != 2 or not len(graph.loops):
        return out
    groups = rejected_groups(graph, admission.weights, min_group)
    if not groups:
        return out
    solve = solver or StickySolver()
    stated = factors or graph.factor_graph(RobustKernel("none"))
    cycles = loop_cycles(graph)
    best = admission
    tried: set[tuple[int, ...]] = set()
    while len(out.trials) < max_trials:
        admitted = np.flatnonzero(best.weights > 0.5)
        todo = []
        for group in rejected_groups(graph, best.weights, min_group):
            if tuple(group) in tried:
                continue
            tried.add(tuple(group))
            against = contradicted(cycles, group, admitted, near=near, probability=probability)
            if against and agrees(cycles, group, probability):
                todo.append((group, against))
                break
        if not todo:
            break
        group, against = todo[0]
        w = best.weights.copy()
        w[against] = 0.0
        w[group] = 1.0
        kept = stated_with_loops(stated, w)
        here, there = solve(kept, best.values), solve(kept, chain)
        start = there if kept.error(there) < kept.error(here) else here
        refined, new = refine_tls(graph, start, w, probability=probability, solver=solve,
                                  barred=against, solved=True, factors=stated)
        cost = tls_cost(graph, refined, probability, stated)
        keep = bool(cost < best.tls_cost * (1.0 - 1e-9))
        out.trials.append(([int(k) for k in group], against, best.tls_cost - cost, keep))
        if keep:
            best = Admission(refined, new, cost, best.blocks, f"{best.gate}-regrouped",
                             best.prefix)
    out.admission = best
    return out
