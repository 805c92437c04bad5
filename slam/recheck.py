"""Loop decisions of a TLS solution judged under calibrated odometry.

The time-ordered admission (`slam.consistency`) decides loops against the graph's
*stated* covariances.  A false loop whose innovation against the rest of the graph is
below the TLS threshold ``c`` under those covariances lowers the stated TLS objective,
so every exact solver of that objective admits it; where the stated odometry is far
looser than its residuals show (a short false loop between poses a few metres apart in
the sequence, or any false loop on a graph whose odometry information is stated ten or
a hundred times too small), such loops are common.  Judged against odometry whose
information is what the data supports, most are many sigma off.

Calibration: with a set of decided loops, the odometry's variance factor ``s`` (actual
/ stated variance) is the fixed point of `odometry_variance_step` (`own_factor`: the
estimate of `slam.variance_components`, capped at 1, so odometry is never made looser
than stated); the odometry information is divided by ``s`` and the accepted graph
solved.

`calibrated_choice` (`calibrated_choices`' stiff start; `slam.optimize` uses both starts
through `slam.offer_back`) picks among the candidate
solutions of the time-ordered admission (`slam.consistency.incremental_tls`'s odometry
ladder and gates) by their TLS cost under calibrated odometry instead of the stated one:
at the variance factor the winner's own loops support, found by starting from the
candidate whose own factor is stiffest with confidence (smallest upper confidence bound)
and moving to whichever candidate is cheapest there until the winner stays.  A stated
winner whose false loops fold a loosely stated stretch then loses to a rung that
rejected them.  The winner from the stated winner is kept too: the loops it has and the
stiff one lacks are offered back (`slam.offer_back`).

`recheck_loops` (``optimize(..., recheck=True)``) then re-decides the chosen loops one by
one.  At the calibrated solution ``x*`` (whitened Jacobian ``A``, information
``H = A^T A`` *including* every accepted loop), removing an accepted loop ``k``
(whitened residual ``b``, Jacobian ``B``, ``M = B H^-1 B^T``) lowers the least-squares
cost, to first order, by the leave-one-out innovation::

    rho_k = 0.5 b^T (I - M)^-1 b          (gtsam error units)

(the innovation of ``k`` against the graph without it, written with the quantities of
the graph with it).  Keeping ``k`` is worth it under TLS iff ``rho_k < c``; since all
``n`` accepted loops are tested at once, a loop is removed only above the family-wise
gate `removal_gate` (``c`` at the per-loop level ``p^(1/n)``, Sidak), so that a graph of
true loops loses none with probability ``p``.  Loops are removed greedily, largest
``rho`` first while ``rho`` exceeds the gate; after each removal the others' ``b``,
``M`` and ``H^-1 B^T`` are updated exactly for it by the rank-``dof`` Woodbury downdate
``H'^-1 = H^-1 + Y (I - M)^-1 Y^T`` (``Y = H^-1 B^T``) and the Gauss-Newton step it
causes, ``dx = -Y (I - M)^-1 b``, so a false loop that props up another is judged after
it is gone.  Then the loops rejected earlier (and not removed here) whose innovation
alone is below ``c`` are offered back (`slam.consistency.greedy_admission` at ``c``),
``s`` is re-estimated with the new decisions, and the rounds repeat until no decision
changes (at most `MAX_ROUNDS`).  A loop removed by the re-check is never re-admitted by
it, so the rounds end.  The caller solves the *stated* graph with the decisions.

Cost: `own_factor` takes, per round, a calibrated solve, one sparse LU and the marginal
covariance blocks of every accepted loop's two poses (`InnovationTest.blocks`); the
choice runs it for one or two candidates, only when the candidates' loops differ.  The
re-check runs it every round, even when nothing changes, which on large graphs costs many
times the admission (off by default for that reason); the Woodbury updates' ``H^-1 B^T``
rows (`InnovationTest.gains`, memory of loops x touched rows x dof) are built only when
some ``rho`` exceeds the gate, and for the rejected loops admissible alone.

Limits of one factor for all the odometry: a graph whose odometry is noisier in some
stretches than others (heavy-tailed loop residuals under one calibrated factor) keeps
both the choice and the family-wise gate from rejecting a false loop whose calibrated
innovation is no larger than its worst true loop's; a group of false loops that agree
with one another can bend a loose stretch so that its own factor still makes it the
cheapest candidate.

`segment_recheck` (``optimize(..., segments=True)``, the default) therefore re-checks
the final decisions under one odometry factor per segment of consecutive poses
(`slam.segment_variance`): a false loop on a quiet stretch is judged against that
stretch's own, small, factor instead of a pooled one inflated by the noisy stretches.
With the odometry so calibrated, every accepted loop's leave-one-out innovation ``rho``
(above) is computed at the calibrated solution; the `SUSPECTS` largest above ``c`` are
then tested against the graph without all of them, with its segment factors
re-estimated without them (a false loop inflates its own segment's factor by bending
it) and re-solved, by their innovation ``delta`` (`slam.consistency`), and those above
the family-wise gate `removal_gate` are removed.  The caller bars them and re-decides
the stated graph.

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

Cost of the segment re-check: a few calibrated solves, the marginal covariance blocks of
the tested loops' poses and of every group's endpoint poses (`InnovationTest.blocks`,
`joint_costs`: selected entries of ``H^-1``, `slam.selected_inverse`, one sparse solve per
distinct pose along its path of the elimination tree instead of full solves per loop),
and per segment estimate a few sparse LUs with 64-column solves.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from slam import innovation
from slam.innovation import (
    InnovationTest,
    _Gains,
    greedy_admission,
    solve_columns,
    tls_threshold,
)
from slam.least_squares import StickySolver
from slam.pose_graph import Constraint, PoseGraph, chi2_quantile, pose_dof
from slam.segment_variance import SEGMENT, SegmentFactors, calibrated_odometry, segment_factors
from slam.variance_components import BOUNDS

Array = NDArray[np.float64]
MAX_ROUNDS = 20  # re-check rounds (each: a calibrated solve, a factor step, maybe decisions)
FACTOR_TOLERANCE = 0.01  # decide once a round changes the odometry factor by less than this
OWN_ROUNDS = 5  # calibrated solves of `own_factor`


def removal_costs(gains: _Gains) -> Array:
    """``rho_q = 0.5 b^T (I - M)^-1 b`` of every accepted loop (gtsam error units), with
    `gains` linearised at the solution of the graph that includes them."""
    return _quadratic(gains.b, -gains.M)


def _quadratic(b: Array, m: Array) -> Array:
    """``0.5 b^T (I + m)^-1 b`` per row: the admission cost for ``m = M``, the removal cost
    for ``m = -M``."""
    s = np.eye(b.shape[1]) + m
    return 0.5 * np.einsum("ma,ma->m", b, np.linalg.solve(s, b[..., None])[..., 0])


def greedy_removal(gains: _Gains, gate: float) -> tuple[list[int], Array]:
    """Remove accepted loops largest ``rho`` first while ``rho > gate`` (module docstring).

    Returns the removed indices in order and the final ``rho`` of every loop (of the
    removed ones meaningless).  `gains` is consumed."""
    m = len(gains.b)
    open_ = np.ones(m, dtype=bool)
    removed: list[int] = []
    eye = np.eye(gains.b.shape[1])
    while open_.any():
        rho = removal_costs(gains)
        rho[~open_] = -np.inf
        k = int(np.argmax(rho))
        if not rho[k] > gate:
            break
        removed.append(k)
        open_[k] = False
        gain = np.linalg.inv(eye - gains.M[k])
        c = gains.cross(gains.Y[k])  # B_q H^-1 B_k^T
        gains.b = gains.b + np.einsum("mab,bc,c->ma", c, gain, gains.b[k])
        gains.M = gains.M + np.einsum("mab,bc,mdc->mad", c, gain, c)
        gains.Y = gains.Y + np.einsum("nb,bc,mdc->mnd", gains.Y[k], gain, c)
        # The removed loop's own rows are meaningless from here on; keep M_k off I.
        gains.M[k] = 0.0
    return removed, removal_costs(gains)


def odometry_variance_step(
    odometry_error: float, rows: int, unknowns: int, loop_traces: Array, dof: int
) -> float:
    """Variance factor of the odometry at a least-squares solution: ``2 E_o / r_o``.

    ``E_o``: the odometry's gtsam error (``0.5 r^T I r``); the odometry's redundancy is
    the total redundancy less the loops', ``r_o = (rows - unknowns) - sum_k (dof -
    tr M_k)``, with ``M_k = B_k H^-1 B_k^T`` of every accepted loop (`_Gains.M`) and
    `rows` counting every factor row (anchor priors too: their redundancy is 0).
    Multiplying the odometry's stated variance by this step and re-solving converges
    to the variance-component estimate (`slam.variance_components`).
    """
    r_loops = dof * len(loop_traces) - float(np.sum(loop_traces))
    return 2.0 * odometry_error / max(rows - unknowns - r_loops, 1e-12)


def removal_gate(n: int, dof: int, probability: float = 0.99) -> float:
    """Error level above which one of `n` accepted loops is removed: ``0.5 chi2_dof^-1(p^(1/n))``.

    The re-check tests all `n` accepted loops at once against "every one is an inlier";
    at this per-loop level (Sidak) the chance of removing any true loop of a Gaussian
    graph is ``1 - p``, as for one loop at the TLS threshold ``c`` (``n = 1``).
    """
    return 0.5 * chi2_quantile(probability ** (1.0 / max(n, 1)), dof)


def _calibrated_fixed(
    graph: PoseGraph, s: float, priors: Sequence[gtsam.NonlinearFactor]
) -> tuple[gtsam.NonlinearFactorGraph, list[gtsam.NonlinearFactor]]:
    """Anchors and odometry with the odometry information divided by `s`; and the
    odometry factors alone."""
    odometry = [graph.between_factor(Constraint(o.i, o.j, o.measurement, o.information / s))
                for o in graph.odometry]
    fixed = gtsam.NonlinearFactorGraph()
    for f in [*priors, *odometry]:
        fixed.add(f)
    return fixed, odometry


@dataclass(slots=True)
class Calibrated:
    """The accepted graph solved under calibrated odometry (`own_factor`).

    Attributes:
        s: the odometry variance factor of the solve (actual / stated variance).
        values: the solution.
        fixed: anchors and odometry with the information divided by `s`.
        gains: the accepted loops linearised at `values` (`InnovationTest.gains`), in
            the order of `kept`; None without accepted loops or when not asked for.
        kept: indices of the accepted loops.
        test: the `InnovationTest` of the accepted graph at `values` (None without
            accepted loops).
        redundancy: the odometry's redundancy ``r_o`` at `values`
            (`odometry_variance_step`; 0 without accepted loops).
        estimate: the variance factor the odometry's residuals at `values` show,
            ``s * step`` (equal to `s` at the fixed point; `s` without accepted loops).
    """

    s: float
    values: gtsam.Values
    fixed: gtsam.NonlinearFactorGraph
    gains: _Gains | None
    kept: NDArray[np.int64]
    test: InnovationTest | None
    redundancy: float = 0.0
    estimate: float = 1.0

    def upper_bound(self, probability: float = 0.99) -> float:
        """Upper confidence bound of the odometry's variance factor at level
        `probability`: ``estimate * r_o / chi2_{r_o}^-1(1 - p)`` (the estimate is
        ``s chi2_{r_o} / r_o`` when the accepted loops are inliers); infinite without
        redundancy."""
        if self.redundancy <= 0.0:
            return np.inf
        return self.estimate * self.redundancy / chi2_quantile(1.0 - probability,
                                                               self.redundancy)


def own_factor(
    graph: PoseGraph, values: gtsam.Values, weights: Array, *,
    unit: Sequence[gtsam.NonlinearFactor], solver: StickySolver, start: float = 1.0,
    max_rounds: int = OWN_ROUNDS, with_gains: bool = True,
) -> Calibrated:
    """The odometry variance factor the loops of weight 1 support, from `start`, and the
    calibrated solution there: `odometry_variance_step` to `FACTOR_TOLERANCE` by secant
    steps on ``log step`` against ``log s`` (as `slam.variance_components`; a plain
    re-weighting step first and where the secant is flat), capped at 1, at most
    `max_rounds` solves (the last one's factor is returned).  `with_gains`: linearise the
    accepted loops at the solution (`Calibrated.gains`, else None)."""
    d, keys = pose_dof(graph.dim), graph.keys
    priors = [graph.prior_factor(k) for k in graph.anchor_keys()]
    w = np.asarray(weights) > 0.5
    kept = np.flatnonzero(w)
    s, current, last = start, values, None
    for n in range(max_rounds):
        fixed, odometry = _calibrated_fixed(graph, s, priors)
        accepted = _accepted(fixed, unit, w.astype(float))
        current = solver(accepted, current)
        if not w.any():
            return Calibrated(s, current, fixed, None, kept, None, 0.0, s)
        test = InnovationTest(accepted, current, keys, d)
        traces = np.trace(test.blocks([unit[k] for k in kept])[1], axis1=1, axis2=2)
        rows, unknowns = d * accepted.size(), d * len(keys)
        step = odometry_variance_step(sum(f.error(current) for f in odometry), rows,
                                      unknowns, traces, d)
        if ((step >= 1.0 and s == 1.0) or abs(step - 1.0) < FACTOR_TOLERANCE
                or n == max_rounds - 1):
            gains = test.gains([unit[k] for k in kept]) if with_gains else None
            redundancy = rows - unknowns - (d * len(traces) - float(np.sum(traces)))
            return Calibrated(s, current, fixed, gains, kept, test, max(redundancy, 0.0),
                              s * step)
        x, y = np.log(s), np.log(max(step, BOUNDS[0]))  # a noise-free odometry: step 0
        slope = (y - last[1]) / (x - last[0]) if last is not None and x != last[0] else -1.0
        last = (x, y)
        if not -20.0 < slope < -0.05:
            slope = -1.0
        s = float(np.clip(np.exp(x - y / slope), BOUNDS[0], 1.0))
    raise AssertionError("unreachable")


@dataclass(slots=True)
class Choices:
    """The calibrated choice among admission candidates from its two starts
    (`calibrated_choices`): indices into the candidates and the winners' own odometry
    variance factors (`own_factor`)."""

    stated: int  # from the candidate of lowest stated cost
    stiff: int  # from the candidate of smallest upper confidence bound: the choice
    stated_factor: float
    stiff_factor: float


def calibrated_choices(
    graph: PoseGraph, candidates: Sequence[tuple[gtsam.Values, Array, float]], *,
    probability: float = 0.99, solver: StickySolver | None = None,
    unit: Sequence[gtsam.NonlinearFactor] | None = None,
) -> Choices | None:
    """The calibrated choice among candidate TLS solutions (values, loop weights, stated
    TLS cost) from two starts; None when a calibrated solve fails (gtsam finds the
    system indeterminate: odometry far stiffer than stated on a nearly noise-free graph).

    Every candidate's own variance factor ``s`` (`own_factor`) is estimated.  From a
    start, with the odometry information divided by the current candidate's ``s``, every
    candidate is re-solved with its loops and the cheapest by the calibrated odometry's
    error plus ``min(e_k, c)`` over every loop wins; this repeats with the winner's own
    factor until the winner is the candidate whose factor it was judged at (or a winner
    recurs).  A candidate whose false loops bend the odometry shows a larger ``s`` than
    the outlier-free one, and loses to it at the stiffer ``s`` that one supports.  Both
    can be fixed points (at the bent candidate's ``s`` the stiff one's rejected loops
    cost more than the bending saves), so the start matters:

    - *stated*: the candidate of lowest stated cost (often the bent one);
    - *stiff*: the candidate whose factor has the smallest upper confidence bound
      (`Calibrated.upper_bound` at `probability`: ``s r / chi2_r^-1(1 - p)``, ``r`` the
      odometry's redundancy, so a candidate that shows a small ``s`` by chance from
      little redundancy is discounted; ties, and no finite bound: lowest stated cost).

    The stiff start's winner is the choice; the stated start's keeps the loops a stiff
    candidate may have left out on a stretch noisier than the rest (`slam.offer_back`).
    Candidates with the same loops are judged once (ties keep the first); each judgement
    (one calibrated solve per candidate) is shared by both starts.
    """
    solve = solver or StickySolver()
    if unit is None:
        unit = [graph.between_factor(lp) for lp in graph.loops]
    c = tls_threshold(graph.dim, probability)
    distinct: dict[bytes, int] = {}
    for n, (_, w, _) in enumerate(candidates):
        distinct.setdefault((np.asarray(w) > 0.5).tobytes(), n)
    which = list(distinct.values())
    if len(which) == 1:
        return Choices(0, 0, 1.0, 1.0)
    try:
        owns = {n: own_factor(graph, candidates[n][0], candidates[n][1], unit=unit,
                              solver=solve, with_gains=False) for n in which}
        bounds = {n: owns[n].upper_bound(probability) for n in which}
        stated = min(which, key=lambda n: candidates[n][2])
        stiff = min(which, key=lambda n: (bounds[n], candidates[n][2]))
        if not np.isfinite(bounds[stiff]):
            stiff = stated
        step: dict[int, int] = {}  # candidate judged at -> winner there
        judge = _Judge(graph, candidates, which, c, solve, unit, owns, step)
        a, b = judge.fixed_point(stated), judge.fixed_point(stiff)
    except RuntimeError:  # gtsam IndeterminateLinearSystemException
        return None
    return Choices(a, b, owns[a].s, owns[b].s)


def calibrated_choice(
    graph: PoseGraph, candidates: Sequence[tuple[gtsam.Values, Array, float]], *,
    probability: float = 0.99, solver: StickySolver | None = None,
    unit: Sequence[gtsam.NonlinearFactor] | None = None, factor: list[float] | None = None,
) -> int:
    """Index of the candidate TLS solution (values, loop weights, stated TLS cost) that is
    the cheapest under the odometry calibrated by its own loops: the stiff start's winner
    of `calibrated_choices`; -1 when a calibrated solve fails.  `factor`, when given,
    receives the winner's own variance factor (a start for `recheck_loops`)."""
    choices = calibrated_choices(graph, candidates, probability=probability, solver=solver,
                                 unit=unit)
    if choices is None:
        return -1
    if factor is not None:
        factor.append(choices.stiff_factor)
    return choices.stiff


@dataclass(slots=True)
class _Judge:
    """The iteration of `calibrated_choices` among the candidates `which`."""

    graph: PoseGraph
    candidates: Sequence[tuple[gtsam.Values, Array, float]]
    which: list[int]
    c: float
    solve: StickySolver
    unit: Sequence[gtsam.NonlinearFactor]
    owns: dict[int, Calibrated]
    step: dict[int, int]

    def winner_at(self, chosen: int) -> int:
        """The cheapest candidate with the odometry calibrated by `chosen`'s own factor."""
        if chosen in self.step:
            return self.step[chosen]
        own = self.owns[chosen]
        priors = [self.graph.prior_factor(k) for k in self.graph.anchor_keys()]
        fixed, _ = _calibrated_fixed(self.graph, own.s, priors)
        best, best_cost = chosen, np.inf
        for n in self.which:
            w = np.asarray(self.candidates[n][1], dtype=float)
            x = own.values if n == chosen else self.solve(_accepted(fixed, self.unit, w),
                                                          self.candidates[n][0])
            cost = fixed.error(x) + float(np.minimum([f.error(x) for f in self.unit],
                                                     self.c).sum())
            if cost < best_cost * (1.0 - 1e-9):
                best, best_cost = n, cost
        self.step[chosen] = best
        return best

    def fixed_point(self, chosen: int) -> int:
        """Judge at the winner's own factor from `chosen` until it stays (or recurs)."""
        judged: set[int] = set()
        while chosen not in judged:
            judged.add(chosen)
            best = self.winner_at(chosen)
            if best == chosen:
                break
            chosen = best
        return chosen


def _accepted(
    fixed: gtsam.NonlinearFactorGraph, unit: Sequence[gtsam.NonlinearFactor], w: Array
) -> gtsam.NonlinearFactorGraph:
    graph = gtsam.NonlinearFactorGraph(fixed)
    for k in np.flatnonzero(w > 0.5):
        graph.add(unit[k])
    return graph


def recheck_loops(
    graph: PoseGraph,
    values: gtsam.Values,
    weights: Array,
    *,
    probability: float = 0.99,
    solver: StickySolver | None = None,
    unit: Sequence[gtsam.NonlinearFactor] | None = None,
    max_rounds: int = MAX_ROUNDS,
    start: float = 1.0,
) -> tuple[Array, float]:
    """Re-checked loop weights of a TLS solution (`values`, `weights`) and the last
    odometry variance factor used (module docstring); `weights` unchanged (factor 1) when
    a calibrated solve fails (as in `calibrated_choice`).

    `unit`: the loops' Gaussian factors (computed when None); `solver`: the least-squares
    solver for the calibrated solves; `start`: a first guess of the odometry factor.
    """
    try:
        return _recheck(graph, values, weights, probability, solver or StickySolver(),
                        unit, max_rounds, start)
    except RuntimeError:  # gtsam IndeterminateLinearSystemException
        return (np.asarray(weights) > 0.5).astype(float), 1.0


def _recheck(
    graph: PoseGraph, values: gtsam.Values, weights: Array, probability: float,
    solve: StickySolver, unit: Sequence[gtsam.NonlinearFactor] | None, max_rounds: int,
    start: float,
) -> tuple[Array, float]:
    """`recheck_loops`' rounds."""
    if unit is None:
        unit = [graph.between_factor(lp) for lp in graph.loops]
    c = tls_threshold(graph.dim, probability)
    d = pose_dof(graph.dim)
    keys = graph.keys
    w = (np.asarray(weights) > 0.5).astype(float)
    removed = np.zeros(len(w), dtype=bool)
    current, s = values, start
    for _ in range(max_rounds):
        if not (w > 0.5).any():
            break
        cal = own_factor(graph, current, w, unit=unit, solver=solve, start=s,
                         with_gains=False)
        s, current, fixed, kept = cal.s, cal.values, cal.fixed, cal.kept
        assert cal.test is not None
        gate = removal_gate(len(kept), d, probability)
        b, gram = cal.test.blocks([unit[k] for k in kept])
        drop: list[int] = []
        if (_quadratic(b, -gram) > gate).any():  # only then the (m, r, d) gains
            drop, _ = greedy_removal(cal.test.gains([unit[k] for k in kept]), gate)
        changed = bool(drop)
        test = cal.test
        if drop:
            w[kept[drop]] = 0.0
            removed[kept[drop]] = True
            current = solve(_accepted(fixed, unit, w), current)
            test = InnovationTest(_accepted(fixed, unit, w), current, keys, d)
        offer = np.flatnonzero((w < 0.5) & ~removed)
        if len(offer):
            b, gram = test.blocks([unit[k] for k in offer])
            offer = offer[_quadratic(b, gram) < c]  # admissible alone, before any other
        if len(offer):
            admitted, _ = greedy_admission(test.gains([unit[k] for k in offer]), c)
            if admitted:
                w[offer[admitted]] = 1.0
                changed = True
        if not changed:
            break
    return w, s


SUSPECTS = 4  # loops the segment re-check tests against the graph without them
GROUP_WINDOW = 2  # pose ids: loops this close on both ends are in one group
GROUP_SUSPECTS = 4  # groups tested per round against the graph without them
GROUP_ROUNDS = 10  # at most this many rounds of the group test


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


def _segment_calibrated(
    graph: PoseGraph, factors: SegmentFactors, unit: Sequence[gtsam.NonlinearFactor],
    weights: Array,
) -> gtsam.NonlinearFactorGraph:
    """Anchors, the odometry calibrated by `factors` and the loops of ``weights > 0.5``."""
    fixed = gtsam.NonlinearFactorGraph()
    for k in graph.anchor_keys():
        fixed.add(graph.prior_factor(k))
    for o in calibrated_odometry(graph, factors):
        fixed.add(graph.between_factor(o))
    return _accepted(fixed, unit, np.asarray(weights, dtype=float))
