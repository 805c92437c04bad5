"""Re-check of the final loop decisions under odometry calibrated per segment.

One odometry variance factor for all the odometry (`slam.calibrated_choice`,
`slam.loop_recheck`) has limits: a graph whose odometry is noisier in some stretches
than others (heavy-tailed loop residuals under one calibrated factor) keeps
both the choice and the family-wise gate from rejecting a false loop whose calibrated
innovation is no larger than its worst true loop's; a group of false loops that agree
with one another can bend a loose stretch so that its own factor still makes it the
cheapest candidate.

`segment_recheck` (``optimize(..., segments=True)``, the default) therefore re-checks
the final decisions under one odometry factor per segment of consecutive poses
(`slam.segment_variance`): a false loop on a quiet stretch is judged against that
stretch's own, small, factor instead of a pooled one inflated by the noisy stretches.
With the odometry so calibrated, every accepted loop's leave-one-out innovation ``rho``
(`slam.loop_recheck`) is computed at the calibrated solution; the `SUSPECTS` largest above ``c`` are
then tested against the graph without all of them, with its segment factors
re-estimated without them (a false loop inflates its own segment's factor by bending
it) and re-solved, by their innovation ``delta`` (`slam.consistency`), and those above
the family-wise gate `removal_gate` are removed.  The caller bars them and re-decides
the stated graph.

A group of false loops that agree with one another holds each member up, so after the
single-loop test the group test `slam.group_recheck.group_recheck` runs on the loops left.

Cost: a few calibrated solves, the marginal covariance blocks of the tested loops' poses
(`InnovationTest.blocks`), and per segment estimate a few sparse LUs with 64-column
solves.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from slam.group_recheck import GroupRecheck, group_recheck
from slam.innovation import InnovationTest, tls_threshold
from slam.least_squares import StickySolver
from slam.loop_recheck import _quadratic, removal_gate
from slam.pose_graph import PoseGraph, pose_dof
from slam.segment_variance import SEGMENT, SegmentFactors, _segment_calibrated, segment_factors

Array = NDArray[np.float64]
SUSPECTS = 4  # loops the segment re-check tests against the graph without them


@dataclass(slots=True)
class SegmentRecheck:
    """Outcome of `segment_recheck`.

    Attributes:
        removed: indices (into `graph.loops`) of the loops to remove.
        suspects: the accepted loops tested, largest leave-one-out innovation first.
        leave_one_out: ``rho`` of every suspect under the segment-calibrated odometry,
            with the loop in (its own bending included), gtsam error units.
        against_rest: ``delta`` of every suspect against the calibrated graph solved
            without all the suspects (gtsam error units).
        gate: the family-wise gate (`removal_gate` over the accepted loops).
        factors: the segment variance factors used (None without accepted loops).
        groups: the group test (`group_recheck`) after the single-loop one (None when
            not run).
    """

    removed: list[int]
    suspects: list[int]
    leave_one_out: Array
    against_rest: Array
    gate: float
    factors: SegmentFactors | None
    groups: GroupRecheck | None = None


def segment_recheck(
    graph: PoseGraph,
    values: gtsam.Values,
    weights: Array,
    *,
    probability: float = 0.99,
    solver: StickySolver | None = None,
    unit: Sequence[gtsam.NonlinearFactor] | None = None,
    suspects: int = SUSPECTS,
    length: int = SEGMENT,
    groups: bool = True,
) -> SegmentRecheck:
    """Accepted loops that fail a test under segment-calibrated odometry.

    `values`: the least-squares solution of the accepted graph (stated covariances,
    loops of ``weights > 0.5``).  The odometry information is divided by per-segment
    variance factors (`slam.segment_variance.segment_factors`, segments of `length`
    poses) and the accepted graph re-solved; at that solution every accepted loop's
    leave-one-out innovation ``rho_k = 0.5 b^T (I - M)^-1 b`` is computed (module
    docstring).  The `suspects` largest above the TLS threshold ``c`` are each tested,
    as a new loop, against the graph without all of them, its segment factors
    re-estimated without them and re-solved under those::

        delta_k = 0.5 b'^T (I + M')^-1 b'

    (``b'``, ``M'`` at that solution), so a false loop is judged without the bending it
    caused (which inflates its own segment's factor) and without the other suspects'.
    A suspect is removed when ``delta_k`` exceeds the family-wise gate
    ``0.5 chi2_dof^-1(p^(1/n))`` (`removal_gate`, ``n`` accepted loops).  `unit`: the
    loops' Gaussian factors (computed when None).  `groups`: then, on the loops left,
    the group test `group_recheck` (module docstring); its removals join `removed`.
    """
    solve = solver or StickySolver()
    if unit is None:
        unit = [graph.between_factor(lp) for lp in graph.loops]
    d, keys = pose_dof(graph.dim), graph.keys
    kept = np.flatnonzero(np.asarray(weights) > 0.5)
    gate = removal_gate(len(kept), d, probability)
    none = SegmentRecheck([], [], np.zeros(0), np.zeros(0), gate, None)
    if not len(kept):
        return none
    factors = segment_factors(graph, values, weights, length=length)
    accepted = _segment_calibrated(graph, factors, unit, weights)
    current = solve(accepted, values)
    b, gram = InnovationTest(accepted, current, keys, d).blocks([unit[k] for k in kept])
    rho = _quadratic(b, -gram)
    order = np.argsort(-rho)[:suspects]
    order = order[rho[order] > tls_threshold(graph.dim, probability)]
    none.factors = factors
    result = none
    if len(order):
        tested = kept[order]
        rest = np.asarray(weights, dtype=float).copy()
        rest[tested] = 0.0
        # The graph without the suspects, with its own segment factors.
        own = segment_factors(graph, values, rest, length=length)
        without = _segment_calibrated(graph, own, unit, rest)
        b, gram = InnovationTest(without, solve(without, current), keys, d).blocks(
            [unit[k] for k in tested])
        delta = _quadratic(b, gram)
        removed = [int(k) for k in tested[delta > gate]]
        result = SegmentRecheck(removed, [int(k) for k in tested], rho[order], delta, gate,
                                factors)
    if groups:
        left = (np.asarray(weights) > 0.5).astype(float)
        left[result.removed] = 0.0
        result.groups = group_recheck(graph, current, left, probability=probability,
                                      solver=solve, unit=unit, length=length,
                                      before=[([k], gate) for k in result.removed])
        result.removed = result.groups.removed
    return result

