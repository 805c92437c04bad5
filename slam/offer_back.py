"""Loops a stiff candidate left out, offered back under per-segment odometry factors.

`slam.calibrated_choice.calibrated_choices` picks among the admission's candidates from two starts:
*B*, from the candidate whose odometry variance factor is stiffest with confidence (the
choice: a candidate bent by agreeing false loops cannot hold it at its own inflated
factor), and *A*, from the candidate of lowest stated cost.  One factor for all the
odometry is B's weakness: on a graph whose odometry is noisier in one stretch than
elsewhere, B can be the candidate that left that stretch's true loops out, since its
factor, estimated on the quiet stretches, is confidently small, and under it the noisy
stretch's loops look inconsistent.  A, calibrated on its own loops, kept them.

`offer_back` therefore offers the loops A kept and B left out back to B, each judged
against B's graph under odometry calibrated per segment of consecutive poses
(`slam.segment_variance`): a segment's factor is B's own where B's loops give that
segment any redundancy (at least `MIN_REDUNDANCY`; a stretch no loop spans has none, as
its odometry rows are fully determined), and A's elsewhere, where B has no evidence of
its own.  A loop of the noisy stretch is judged against that stretch's (A's, large)
factor; a false loop that A kept by bending a stretch B's loops span is
judged against B's stiff factor there.  With the calibrated graph solved (B's loops and
the ones admitted so far) and linearised at its solution, every offered loop's
innovation is, in gtsam error units::

    delta_k = 0.5 b_k^T (I + M_k)^-1 b_k,   M_k = B_k H^-1 B_k^T

(``b_k`` its whitened residual, ``B_k`` its whitened Jacobian, ``H`` the calibrated
graph's information; `slam.consistency`); loops are admitted greedily, smallest
``delta`` first, each admission updating the others' ``delta`` (rank-``dof`` Woodbury,
`slam.consistency.greedy_admission`), while the smallest stays below the TLS threshold
``c`` (`slam.consistency.tls_threshold`).  B's segment factors are then re-estimated
with the admitted loops and the rounds repeat until one admits nothing (at most
`ROUNDS`).

B's factors are its segments' own estimates shrunk toward B's pooled factor *before any
offer* (`shrunk`, the prior of `slam.segment_variance` with a fixed target): a segment
that few of B's loops span then keeps about the pooled factor of B's loops, not a
noisy estimate of its own, and once the noisy stretch's loops are admitted, the pooled
factor, now the noisy stretch's, does not lift the quiet segments by an order of
magnitude (as `slam.segment_variance`'s own prior would, enough to let a false loop
there pass in the next round).  Why any redundancy rather than several dof: on a graph
with few, long loops, false loops bend stretches that B's loops span only thinly, and
A's factors there, inflated by that very bending, would admit them.
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from slam.calibrated_choice import calibrated_choices
from slam.consistency import InnovationTest, greedy_admission, tls_threshold
from slam.least_squares import StickySolver
from slam.loop_recheck import _quadratic
from slam.pose_graph import PoseGraph, pose_dof
from slam.segment_variance import (
    FLOOR,
    PRIOR_DOF,
    SEGMENT,
    SegmentFactors,
    _segment_calibrated,
    segment_factors,
)

Array = NDArray[np.float64]
ROUNDS = 5  # at most this many rounds of offers, each with B's factors re-estimated
MIN_REDUNDANCY = 0.5  # dof: B's loops say something about the segment (0 without loops)
OWN_PRIOR_DOF = 1e-6  # B's factors: its own evidence, not shrunk toward its pooled factor


def mixed_factors(own: SegmentFactors, other: SegmentFactors,
                  min_redundancy: float = MIN_REDUNDANCY) -> SegmentFactors:
    """`own`'s factor where its segment's redundancy is at least `min_redundancy`, `other`'s
    elsewhere (both from `slam.segment_variance.segment_factors` on the same graph)."""
    mine = own.redundancy >= min_redundancy
    return SegmentFactors(np.where(mine, own.factors, other.factors),
                          np.where(mine, own.raw, other.raw),
                          np.where(mine, own.redundancy, other.redundancy),
                          own.pooled, own.segment)


def shrunk(factors: SegmentFactors, target: float, prior_dof: float = PRIOR_DOF
           ) -> SegmentFactors:
    """`factors` with every segment's factor shrunk toward `target` with a prior of
    `prior_dof` degrees of freedom, ``(q_k + nu t) / (red_k + nu)`` (``q_k = raw_k red_k``,
    the segment's ``r^T W r`` in stated units), clipped to ``[FLOOR, 1]`` as
    `slam.segment_variance.segment_factors` does toward its own pooled factor."""
    red = factors.redundancy
    q = np.where(red > 0, np.where(red > 0, factors.raw, 0.0) * red, 0.0)
    value = (q + prior_dof * target) / (red + prior_dof)
    return SegmentFactors(np.clip(value, FLOOR, 1.0), factors.raw, factors.redundancy,
                          target, factors.segment)


def offer_back(
    graph: PoseGraph,
    values: gtsam.Values,
    weights: Array,
    other_values: gtsam.Values,
    other_weights: Array,
    *,
    probability: float = 0.99,
    solver: StickySolver | None = None,
    unit: Sequence[gtsam.NonlinearFactor] | None = None,
    length: int = SEGMENT,
    rounds: int = ROUNDS,
    min_redundancy: float = MIN_REDUNDANCY,
) -> Array:
    """Weights of B (`values`, `weights`) with the loops of A (`other_values`,
    `other_weights`) that B left out admitted where they pass (module docstring).

    `values`, `other_values`: least-squares solutions (stated covariances) of the graph
    with each one's loops of weight above 0.5.  `unit`: the loops' Gaussian factors
    (computed when None).  Returns 0/1 weights in the order of `graph.loops`; a loop B
    kept is never taken out.
    """
    w = (np.asarray(weights) > 0.5).astype(float)
    offered = np.flatnonzero((np.asarray(other_weights) > 0.5) & (w < 0.5))
    if not len(offered):
        return w
    solve = solver or StickySolver()
    if unit is None:
        unit = [graph.between_factor(lp) for lp in graph.loops]
    d, keys = pose_dof(graph.dim), graph.keys
    c = tls_threshold(graph.dim, probability)
    other = segment_factors(graph, other_values, other_weights, length=length)
    current, pooled = values, None
    for _ in range(rounds):
        offered = offered[w[offered] < 0.5]
        if not len(offered):
            break
        own = segment_factors(graph, current, w, length=length, prior_dof=OWN_PRIOR_DOF)
        pooled = own.pooled if pooled is None else pooled  # B's own, before any offer
        own = shrunk(own, pooled)
        accepted = _segment_calibrated(graph, mixed_factors(own, other, min_redundancy),
                                       unit, w)
        current = solve(accepted, current)
        test = InnovationTest(accepted, current, keys, d)
        b, gram = test.blocks([unit[k] for k in offered])
        alone = offered[_quadratic(b, gram) < c]  # admissible before any other
        if not len(alone):
            break
        admitted, _ = greedy_admission(test.gains([unit[k] for k in alone]), c)
        if not admitted:
            break
        w[alone[admitted]] = 1.0
    return w


def choose_and_offer_back(
    graph: PoseGraph,
    candidates: Sequence[tuple[gtsam.Values, Array, float]],
    *,
    probability: float = 0.99,
    solver: StickySolver | None = None,
    unit: Sequence[gtsam.NonlinearFactor] | None = None,
    factor: list[float] | None = None,
) -> tuple[int, Array | None]:
    """`slam.consistency.incremental_tls`'s `choose`: the stiff start's choice B of
    `slam.calibrated_choice.calibrated_choices` and its weights with A's loops offered back
    (`offer_back`; None when nothing changed).  ``(-1, None)`` when a calibrated solve
    fails.  `factor`, when given, receives B's own variance factor."""
    solve = solver or StickySolver()
    if unit is None:
        unit = [graph.between_factor(lp) for lp in graph.loops]
    choices = calibrated_choices(graph, candidates, probability=probability, solver=solve,
                                 unit=unit)
    if choices is None:
        return -1, None
    if factor is not None:
        factor.append(choices.stiff_factor)
    if choices.stated == choices.stiff:
        return choices.stiff, None
    b_values, b_weights, _ = candidates[choices.stiff]
    a_values, a_weights, _ = candidates[choices.stated]
    try:
        w = offer_back(graph, b_values, b_weights, a_values, a_weights,
                       probability=probability, solver=solve, unit=unit)
    except RuntimeError:  # gtsam IndeterminateLinearSystemException
        return choices.stiff, None
    if np.array_equal(w, np.asarray(b_weights) > 0.5):
        return choices.stiff, None
    return choices.stiff, w
