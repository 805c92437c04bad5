"""Re-deciding the unsupported loops admitted just before a return whose loops were
all rejected, judged on the TLS objective.

The time-ordered admission (`slam.consistency.incremental_tls`) decides the first loop
of a return against a prefix that ties its two poses only through a long odometry
chain: a false first closure can pass there, bend the map onto itself, and make every
true loop of the same return, arriving a block later, fail (each alone cannot pay for
pushing the false one out).  Those true loops agree with one another and come in
*groups* (both ends within a few pose ids, `slam.group_recheck.loop_groups`); the false
loop that locked them out is typically *lone*: no other admitted loop lies within
`slam.group_recheck.GROUP_WINDOW` pose ids of both its ends (its support was rejected).

`regroup` looks for that pattern in a finished admission and re-decides it:

1. the groups of at least `MIN_GROUP` rejected loops whose members pass the pairwise
   cycle test of `slam.pairwise_consistency` with one another in at least half of
   their pairs (a return's loops agree);
2. *returns*: those groups' loops in order of their later pose, split where two
   consecutive later poses are more than `NEAR` ids apart;
3. per return, its *suspects* (none, possibly): the lone admitted loops whose later
   pose lies from `NEAR` ids before the return's first later pose to its last
   (admitted just before or during the return);
4. the hypotheses, every return's loops in and all suspects out (when there are two
   returns or more), then each return alone with its own suspects, largest first: the
   stated graph solved from the current solution and from the odometry chain (the lower
   stated error kept), then every loop re-decided by the residual rule from there
   (`slam.consistency.refine_tls`: a suspect that the new map satisfies comes back);
5. a hypothesis is screened first (`predicted_cost`): one Gauss-Newton step of its
   stated graph from the current solution, and the TLS objective of the linearised graph
   there (every loop capped at ``c``); when that is not below the current objective the
   hypothesis is skipped unsolved (a return of false loops pulls against the whole map,
   and the step shows it);
6. a hypothesis replaces the admission only when the stated TLS objective
   (`slam.consistency.tls_cost`, ``sum min(e_k, c)`` over every loop at the solution) is
   lower, and the calibrated choice between the two (`slam.calibrated_choice`: each
   judged under odometry calibrated by the loops it keeps) picks the hypothesis too: the
   search never raises the stated objective, and where the stated odometry is loose
   enough for a group of agreeing false loops to lower it by bending the map, the
   bent map's larger odometry variance factor gives it away.  After a kept one the
   returns are found again from the new decisions.

A return without suspects is tried as well: its loops, forced in, can move a map that
false loops had bent into a basin where the residual rule alone does not re-admit them.

Cost: the grouping only, when no agreeing group of rejected loops exists; per hypothesis
one linear solve (the screen), and for one that passes it two solves and `refine_tls`'s
rounds (and the calibrated choice's solves when it lowers the stated objective).  2D
only (the pairwise test); 3D admissions are returned unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np
from numpy.typing import NDArray

from slam.admission import Admission, StatedFactors, tls_cost
from slam.calibrated_choice import calibrated_choice
from slam.group_recheck import GROUP_WINDOW, loop_groups
from slam.innovation import tls_threshold
from slam.least_squares import StickySolver
from slam.pairwise_consistency import LoopCycles, loop_cycles
from slam.pose_graph import PoseGraph, RobustKernel, chi2_quantile
from slam.tls_refine import refine_tls, stated_with_loops

Array = NDArray[np.float64]
MIN_GROUP = 3  # rejected loops a group needs to count
NEAR = 50  # pose ids: gap that splits returns, and how early a suspect may arrive
MAX_TRIALS = 6  # hypotheses tested at most


@dataclass(slots=True)
class Regroup:
    """Outcome of `regroup`: the admission (replaced when a hypothesis was kept), and per
    hypothesis tested the loops it admitted and the suspects it took out (indices into
    `graph.loops`), the drop of the TLS objective (negative: a rise) and whether it was
    kept; per hypothesis the screen skipped (`predicted_cost`), its loops, suspects and
    predicted drop (negative: a rise)."""

    admission: Admission
    trials: list[tuple[list[int], list[int], float, bool]] = field(default_factory=list)
    screened: list[tuple[list[int], list[int], float]] = field(default_factory=list)


def agrees(cycles: LoopCycles, group: NDArray[np.int64], probability: float = 0.99) -> bool:
    """The members of `group` pass the pairwise cycle test (squared Mahalanobis distance
    at most ``chi2_3^-1(probability)``) with one another in at least half of their pairs."""
    i, j = np.triu_indices(len(group), k=1)
    if not len(i):
        return False
    ok = cycles.distances(group[i], group[j]) <= chi2_quantile(probability, 3)
    return bool(ok.sum() * 2 >= len(ok))


def rejected_groups(graph: PoseGraph, weights: Array, min_size: int = MIN_GROUP,
                    window: int = GROUP_WINDOW
                    ) -> list[NDArray[np.int64]]:
    """Groups (`slam.group_recheck.loop_groups`) of at least `min_size` loops of weight 0,
    largest first (ties in order of their first loop)."""
    rejected = np.flatnonzero(np.asarray(weights) < 0.5)
    groups = [g for g in loop_groups(graph.loops, rejected, window) if len(g) >= min_size]
    return [np.array(g, dtype=np.int64) for g in sorted(groups, key=len, reverse=True)]


def lone_loops(graph: PoseGraph, weights: Array, window: int = GROUP_WINDOW
               ) -> NDArray[np.int64]:
    """The loops of weight 1 no other loop of weight 1 lies within `window` pose ids of
    on both ends (groups of one, `slam.group_recheck.loop_groups`); sorted."""
    admitted = np.flatnonzero(np.asarray(weights) > 0.5)
    return np.array(sorted(g[0] for g in loop_groups(graph.loops, admitted, window)
                           if len(g) == 1), dtype=np.int64)


def returns(later: Array, loops: NDArray[np.int64], gap: int = NEAR
            ) -> list[NDArray[np.int64]]:
    """`loops` (indices) split into runs of their later poses `later[loops]` in increasing
    order, a new run wherever two consecutive ones are more than `gap` apart; largest
    run first (ties in time order)."""
    if not len(loops):
        return []
    order = loops[np.argsort(later[loops], kind="stable")]
    cuts = np.flatnonzero(np.diff(later[order]) > gap) + 1
    runs = np.split(order, cuts)
    return sorted(runs, key=len, reverse=True)


def hypotheses(graph: PoseGraph, weights: Array, cycles: LoopCycles, *,
               probability: float = 0.99, min_group: int = MIN_GROUP, near: int = NEAR
               ) -> list[tuple[NDArray[np.int64], NDArray[np.int64]]]:
    """The module docstring's hypotheses (steps 1-4) on the decisions `weights`: pairs
    (loops to admit, suspects to take out), indices into `graph.loops`."""
    groups = [g for g in rejected_groups(graph, weights, min_group)
              if agrees(cycles, g, probability)]
    if not groups:
        return []
    later = np.array([max(lp.i, lp.j) for lp in graph.loops])
    lone = lone_loops(graph, weights)
    out = []
    for run in returns(later, np.concatenate(groups), near):
        first, last = later[run].min(), later[run].max()
        out.append((run, lone[(later[lone] >= first - near) & (later[lone] <= last)]))
    if len(out) > 1:
        out.insert(0, (np.concatenate([r for r, _ in out]),
                       np.unique(np.concatenate([s for _, s in out]))))
    return out


def predicted_cost(graph: PoseGraph, values: gtsam.Values, weights: Array,
                   factors: StatedFactors, probability: float = 0.99) -> float:
    """Screen of a hypothesis (decisions `weights`) from `values`: the TLS objective of the
    stated graph linearised at `values` after one Gauss-Newton step of the hypothesis.

    ``dx = argmin 0.5 |A_w dx - b_w|^2`` over the odometry, the prior and the loops of
    weight 1 (``A``, ``b``: whitened Jacobian and residual at `values`); the prediction
    is ``sum_f 0.5 |A_f dx - b_f|^2`` over the odometry and prior plus
    ``sum_k min(0.5 |A_k dx - b_k|^2, c)`` over every loop (the hypothesis' suspects
    included: the residual rule re-admits those the new map satisfies).  At a solution
    of the hypothesis' stated graph (``dx = 0``) it is `tls_cost`.  Gtsam error units
    (half squared Mahalanobis); ``-inf`` when the step is indeterminate.  The step is
    eliminated by QR (stiff odometry breaks Cholesky)."""
    base, loop_index = factors
    linear = base.linearize(values)
    n_fixed = base.size() - len(loop_index)
    step = gtsam.GaussianFactorGraph()
    for k in range(n_fixed):
        step.push_back(linear.at(k))
    for k in np.flatnonzero(np.asarray(weights) > 0.5):
        step.push_back(linear.at(loop_index[k]))
    try:
        delta = step.optimize(gtsam.EliminateQR)
    except RuntimeError:  # indeterminate even by QR: no prediction, the hypothesis is solved
        return float("-inf")
    c = tls_threshold(graph.dim, probability)
    fixed = sum(linear.at(k).error(delta) for k in range(n_fixed))
    loops = sum(min(linear.at(k).error(delta), c) for k in loop_index)
    return float(fixed + loops)


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
    screen: bool = True,
) -> Regroup:
    """The module docstring's search on `admission` (a solution of `graph` with its
    weights and stated `tls_cost`); `chain`: the odometry chain (the second start of a
    hypothesis' solve); `screen`: skip the hypotheses `predicted_cost` finds unable to
    lower the objective (step 5), recorded in `Regroup.screened` with their predicted
    drop.  Returns the admission unchanged for a 3D graph."""
    out = Regroup(admission)
    if graph.dim != 2 or not len(graph.loops):
        return out
    if not rejected_groups(graph, admission.weights, min_group):
        return out
    solve = solver or StickySolver()
    stated = factors or graph.factor_graph(RobustKernel("none"))
    cycles = loop_cycles(graph)
    best = admission
    tried: set[tuple[tuple[int, ...], tuple[int, ...]]] = set()
    while len(out.trials) < max_trials:
        todo = [(r, s) for r, s in hypotheses(graph, best.weights, cycles,
                                              probability=probability, min_group=min_group,
                                              near=near)
                if (tuple(r), tuple(s)) not in tried]
        if not todo:
            break
        kept_one = False
        for run, suspects in todo[:max_trials - len(out.trials)]:
            tried.add((tuple(run), tuple(suspects)))
            w = best.weights.copy()
            w[suspects] = 0.0
            w[run] = 1.0
            if screen:
                predicted = predicted_cost(graph, best.values, w, stated, probability)
                if predicted >= best.tls_cost:
                    out.screened.append(([int(k) for k in run], [int(k) for k in suspects],
                                         best.tls_cost - predicted))
                    continue
            kept = stated_with_loops(stated, w)
            here, there = solve(kept, best.values), solve(kept, chain)
            start = there if kept.error(there) < kept.error(here) else here
            refined, new = refine_tls(graph, start, w, probability=probability, solver=solve,
                                      solved=True, factors=stated)
            cost = tls_cost(graph, refined, probability, stated)
            keep = bool(cost < best.tls_cost * (1.0 - 1e-9)) and calibrated_choice(
                graph, [(best.values, best.weights, best.tls_cost), (refined, new, cost)],
                probability=probability, solver=solve,
                unit=[stated[0].at(k) for k in stated[1]]) == 1
            out.trials.append(([int(k) for k in run], [int(k) for k in suspects],
                               best.tls_cost - cost, keep))
            if keep:
                best = Admission(refined, new, cost, best.blocks, f"{best.gate}-regrouped",
                                 best.prefix)
                kept_one = True
                break
        if not kept_one:
            break
    out.admission = best
    return out
