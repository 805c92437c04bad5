"""Joint re-check of groups of agreeing loops under segment-calibrated odometry.

A group of false loops that agree with one another (several closures between the same
two places with one wrong transform: perceptual aliasing) holds each member up: left
out alone, each is still predicted by the rest of its group, so no ``rho`` stands out.
`group_recheck` (part of `segment_recheck`, ``groups=True``) therefore clusters the
accepted loops into *groups*, connected components of loops whose endpoints are within
`GROUP_WINDOW` pose ids of one another's on both ends (`loop_groups`), and tests every
group of two or more as a whole.  For a group ``G`` of ``g`` loops, stacked whitened
residuals ``b_G`` (``3g``, or ``6g`` in 3D) and ``M_GG = B_G H^-1 B_G^T`` (the joint
block, cross-terms between members included), the leave-group-out innovation and the
group's innovation against a graph without it are::

    rho_G   = 0.5 b_G^T (I - M_GG)^-1 b_G        (at the solution with G in)
    delta_G = 0.5 b_G^T (I + M_GG)^-1 b_G        (at the solution without G)

both ``0.5 chi2`` with ``dof * g`` degrees of freedom when every member is an inlier.  A
round ranks the groups by ``rho_G`` over its gate, re-estimates the segment factors
without the `GROUP_SUSPECTS` first, re-solves, and removes those whose ``delta_G``
exceeds ``0.5 chi2_{dof g}^-1(p^(1/G))`` (`group_gate`: Sidak over the ``G`` groups of
the round); rounds repeat until one removes nothing (at most `GROUP_ROUNDS`).  A true
group judged while false groups still bend the map can fail, so at the end every removed
group is tested again (``delta_G``, same gate) against the graph without all removed
groups, re-calibrated, and re-admitted when it passes; and every loop rejected before
(removed groups aside) whose innovation against that graph is below ``c`` is offered in.

Cost: a few calibrated solves, the marginal covariance blocks of every group's endpoint
poses (`joint_costs`: selected entries of ``H^-1``, `slam.selected_inverse`, one sparse
solve per distinct pose along its path of the elimination tree instead of full solves per
loop), and per segment estimate a few sparse LUs with 64-column solves.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from slam import innovation
from slam.innovation import InnovationTest, greedy_admission, solve_columns, tls_threshold
from slam.least_squares import StickySolver
from slam.loop_recheck import _quadratic
from slam.pose_graph import Constraint, PoseGraph, chi2_quantile, pose_dof
from slam.segment_variance import SEGMENT, _segment_calibrated, segment_factors

Array = NDArray[np.float64]
GROUP_WINDOW = 2  # pose ids: loops this close on both ends are in one group
GROUP_SUSPECTS = 4  # groups tested per round against the graph without them
GROUP_ROUNDS = 10  # at most this many rounds of the group test


@dataclass(slots=True)
class GroupTest:
    """One group tested by `group_recheck`: its loops (indices into `graph.loops`), its
    leave-group-out innovation ``rho_G`` and innovation ``delta_G`` against the graph
    without the round's suspect groups (gtsam error units), its gate, and whether it was
    removed (after the final offer back)."""

    loops: list[int]
    rho: float
    delta: float
    gate: float
    removed: bool


@dataclass(slots=True)
class GroupRecheck:
    """Outcome of `group_recheck`: the loops removed (indices into `graph.loops`, the
    groups `before` included unless re-admitted), every group tested (in test order), the
    number of rounds run, and the loops of weight 0 in `weights` (neither removed nor
    offered back) that the graph without the removed groups admits (`readmitted`)."""

    removed: list[int]
    tested: list[GroupTest]
    rounds: int
    readmitted: list[int]


def loop_groups(
    loops: Sequence[Constraint], which: Sequence[int], window: int = GROUP_WINDOW
) -> list[list[int]]:
    """Connected components of the loops `which` (indices into `loops`) under "both ends
    within `window` pose ids": loops ``(i1, j1)`` and ``(i2, j2)``, each written with its
    smaller id first, are linked when ``|i1 - i2| <= window`` and ``|j1 - j2| <= window``.
    Components in order of their first loop, loops in the order of `which`."""
    which = [int(k) for k in which]
    ends = np.array([sorted((loops[k].i, loops[k].j)) for k in which], dtype=np.int64)
    parent = list(range(len(which)))

    def root(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    order = np.argsort(ends[:, 0], kind="stable") if len(which) else np.zeros(0, np.int64)
    for x, p in enumerate(order):
        for q in order[x + 1:]:
            if ends[q, 0] - ends[p, 0] > window:
                break
            if abs(ends[q, 1] - ends[p, 1]) <= window:
                parent[root(int(p))] = root(int(q))
    members: dict[int, list[int]] = {}
    for a in range(len(which)):
        members.setdefault(root(a), []).append(which[a])
    return sorted(members.values(), key=lambda g: which.index(g[0]))


def group_gate(size: int, groups: int, dof: int, probability: float = 0.99) -> float:
    """Error level above which one of `groups` groups of `size` loops is removed:
    ``0.5 chi2_{dof size}^-1(p^(1/groups))`` (Sidak, as `removal_gate`)."""
    return 0.5 * chi2_quantile(probability ** (1.0 / max(groups, 1)), dof * size)


def joint_costs(
    test: InnovationTest, unit: Sequence[gtsam.NonlinearFactor],
    groups: Sequence[Sequence[int]], *, removal: bool,
) -> Array:
    """Joint innovation of every group of loops (indices into `unit`) at `test`'s solution,
    gtsam error units: ``rho_G = 0.5 b_G^T (I - M_GG)^-1 b_G`` (`removal`: the groups are
    in the solved graph) or ``delta_G = 0.5 b_G^T (I + M_GG)^-1 b_G`` (they are not), with
    ``b_G`` the stacked whitened residuals and ``M_GG = B_G H^-1 B_G^T`` the joint block
    (module docstring).

    ``M_GG = J_G S_EE J_G^T``: ``S_EE`` the marginal covariance of the members' ``2g``
    endpoint poses (``H^-1`` blocks, `slam.selected_inverse`: every group's blocks in one
    request), ``J_G`` (``d g`` x ``2 d g``) the members' Jacobian blocks, ``B_i`` of member
    ``p`` at endpoint ``2p`` and ``B_j`` at ``2p + 1``.  With
    ``slam.innovation.SELECTED_INVERSE`` False: one sparse solve per loop instead."""
    linear = [test._linearised([unit[k] for k in members]) for members in groups]
    if not innovation.SELECTED_INVERSE:
        return np.array([_joint_cost(test, *lin, removal) for lin in linear])
    d = test.dof
    ends = [np.stack([ci, cj], axis=1).ravel() for *_, ci, cj in linear]  # (2g,) first rows
    rows = np.concatenate([np.repeat(e, len(e)) for e in ends]) if ends else np.zeros(0, int)
    cols = np.concatenate([np.tile(e, len(e)) for e in ends]) if ends else np.zeros(0, int)
    blocks = test.selected.blocks(rows, cols, d)
    out, start = np.zeros(len(groups)), 0
    for n, ((b, bi, bj, _, _), e) in enumerate(zip(linear, ends, strict=True)):
        g, size = len(b), len(e)
        cov = blocks[start:start + size * size].reshape(size, size, d, d)
        cov = cov.transpose(0, 2, 1, 3).reshape(size * d, size * d)
        start += size * size
        jac = np.zeros((g, d, size, d))
        jac[np.arange(g), :, 2 * np.arange(g), :] = bi
        jac[np.arange(g), :, 2 * np.arange(g) + 1, :] = bj
        jac = jac.reshape(g * d, size * d)
        m = jac @ cov @ jac.T
        s = np.eye(g * d) + (-m if removal else m)
        r = b.ravel()
        out[n] = 0.5 * r @ np.linalg.solve(s, r)
    return out


def _joint_cost(
    test: InnovationTest, b: Array, bi: Array, bj: Array, ci: NDArray[np.int64],
    cj: NDArray[np.int64], removal: bool,
) -> float:
    """`joint_costs` of one group by full solves of ``H^-1 B_G^T`` (one per loop)."""
    d, g = test.dof, len(b)
    span = np.arange(d)
    rhs = np.zeros((test.n, g * d))
    for q in range(g):
        rhs[ci[q] + span, q * d:(q + 1) * d] += bi[q].T
        rhs[cj[q] + span, q * d:(q + 1) * d] += bj[q].T
    y = solve_columns(test._lu, rhs)
    m = np.concatenate([bi[q] @ y[ci[q] + span] + bj[q] @ y[cj[q] + span] for q in range(g)])
    s = np.eye(g * d) + (-m if removal else m)
    r = b.ravel()
    return float(0.5 * r @ np.linalg.solve(s, r))


def group_recheck(
    graph: PoseGraph,
    values: gtsam.Values,
    weights: Array,
    *,
    probability: float = 0.99,
    solver: StickySolver | None = None,
    unit: Sequence[gtsam.NonlinearFactor] | None = None,
    window: int = GROUP_WINDOW,
    suspects: int = GROUP_SUSPECTS,
    rounds: int = GROUP_ROUNDS,
    length: int = SEGMENT,
    before: Sequence[tuple[list[int], float]] = (),
) -> GroupRecheck:
    """Groups of accepted loops that fail the joint test under segment-calibrated odometry
    (module docstring).

    `values`: a least-squares solution (or close to one) of the graph with the loops of
    ``weights > 0.5``.  Each round: the accepted loops' groups of two or more
    (`loop_groups`, `window`), the segment factors (`slam.segment_variance`) and the
    calibrated solution; ``rho_G`` of every group there; the `suspects` groups of largest
    ``rho_G / gate`` left out together, the segment factors re-estimated without them,
    the graph re-solved, and ``delta_G`` of each suspect against it; those above
    `group_gate` (Sidak over the round's groups) are removed.  Rounds end when one
    removes nothing (at most `rounds`).  Last, the removed groups are tested against the
    re-calibrated graph without all of them and re-admitted when ``delta_G`` is below
    their gate, as are the groups `before` (loops already removed, each with its gate,
    as `segment_recheck`'s single suspects: they are out of `weights` and
    in `GroupRecheck.removed` unless re-admitted) once the rounds removed any group.
    Then, whether or not any group was removed, the other loops of weight 0 in `weights`
    (rejected before the group test: for disagreeing with a false group, or by a gate
    far below ``c``, as the calibrated admission's, which can leave out true loops whose
    innovation lies between its gate and ``c``) whose innovation ``delta`` against the
    calibrated graph without the removed groups is below ``c`` are offered in, smallest
    first (`slam.consistency.greedy_admission` at ``c``): `GroupRecheck.readmitted`.
    """
    solve = solver or StickySolver()
    if unit is None:
        unit = [graph.between_factor(lp) for lp in graph.loops]
    d, keys = pose_dof(graph.dim), graph.keys
    w = (np.asarray(weights) > 0.5).astype(float)
    tested: list[GroupTest] = []
    removed: list[GroupTest] = []
    current = values
    n_rounds = 0
    for _ in range(rounds):
        n_rounds += 1
        kept = np.flatnonzero(w > 0.5)
        groups = [g for g in loop_groups(graph.loops, kept, window) if len(g) > 1]
        if not groups:
            break
        gates = np.array([group_gate(len(g), len(groups), d, probability) for g in groups])
        accepted = _segment_calibrated(graph, segment_factors(graph, current, w, length=length),
                                       unit, w)
        current = solve(accepted, current)
        rho = joint_costs(InnovationTest(accepted, current, keys, d), unit, groups,
                          removal=True)
        order = np.argsort(-rho / gates, kind="stable")[:suspects]
        rest = w.copy()
        for k in order:
            rest[groups[k]] = 0.0
        without = _segment_calibrated(graph, segment_factors(graph, current, rest,
                                                             length=length), unit, rest)
        x = solve(without, current)
        delta = joint_costs(InnovationTest(without, x, keys, d), unit,
                            [groups[k] for k in order], removal=False)
        fail = []
        for k, dl in zip(order, delta, strict=True):
            t = GroupTest(list(groups[k]), float(rho[k]), float(dl), float(gates[k]),
                          bool(dl > gates[k]))
            tested.append(t)
            if t.removed:
                fail.append(t)
                w[t.loops] = 0.0
        if not fail:
            break
        removed.extend(fail)
        current = x if len(fail) == len(order) else solve(
            _segment_calibrated(graph, segment_factors(graph, x, w, length=length), unit, w),
            x)
    earlier = [GroupTest(list(g), np.nan, np.nan, gate, True) for g, gate in before]
    readmitted: list[int] = []
    without = _segment_calibrated(graph, segment_factors(graph, current, w, length=length),
                                  unit, w)
    x = solve(without, current)
    test = InnovationTest(without, x, keys, d)
    if removed:
        offered = earlier + removed
        delta = joint_costs(test, unit, [t.loops for t in offered], removal=False)
        for t, dl in zip(offered, delta, strict=True):
            if dl <= t.gate:
                t.removed = False
    out = {k for t in earlier + removed for k in t.loops}
    rejected = [k for k in np.flatnonzero(np.asarray(weights) < 0.5) if k not in out]
    if rejected:
        b, gram = test.blocks([unit[k] for k in rejected])
        rejected = [k for k, e in zip(rejected, _quadratic(b, gram), strict=True)
                    if e < tls_threshold(graph.dim, probability)]
    if rejected:
        admitted, _ = greedy_admission(test.gains([unit[k] for k in rejected]),
                                       tls_threshold(graph.dim, probability))
        readmitted = sorted(int(rejected[q]) for q in admitted)
    return GroupRecheck([k for t in earlier + removed if t.removed for k in t.loops], tested,
                        n_rounds, readmitted)
