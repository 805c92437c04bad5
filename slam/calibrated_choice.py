"""The calibrated choice among the candidate solutions of the time-ordered admission.

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
through `slam.offer_back`) picks among the candidate solutions of the time-ordered
admission (`slam.consistency.incremental_tls`'s odometry ladder and gates) by their TLS
cost under calibrated odometry instead of the stated one: at the variance factor the
winner's own loops support, found by starting from the candidate whose own factor is
stiffest with confidence (smallest upper confidence bound) and moving to whichever
candidate is cheapest there until the winner stays.  A stated winner whose false loops
fold a loosely stated stretch then loses to a rung that rejected them.  The winner from
the stated winner is kept too: the loops it has and the stiff one lacks are offered back
(`slam.offer_back`).

Cost: `own_factor` takes, per round, a calibrated solve, one sparse LU and the marginal
covariance blocks of every accepted loop's two poses (`InnovationTest.blocks`); the
choice runs it for every candidate whose loops differ from an earlier one's, and judges
each candidate once per factor it is judged at.  Each of those solves starts from the
solution found so far that is nearest (least error on the graph to solve,
`slam.warm_starts.WarmStarts`; `WARM_STARTS`): a candidate judged at another's factor
starts from its own solution at the nearest factor instead of its stated one.

Units: variance factors are dimensionless (actual / stated variance); costs are gtsam
errors (``0.5 chi2``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from slam.innovation import InnovationTest, _Gains, tls_threshold
from slam.least_squares import StickySolver
from slam.pose_graph import Constraint, PoseGraph, chi2_quantile, pose_dof
from slam.variance_components import BOUNDS
from slam.warm_starts import WarmStarts, solve_from

Array = NDArray[np.float64]
FACTOR_TOLERANCE = 0.01  # decide once a round changes the odometry factor by less than this
OWN_ROUNDS = 5  # calibrated solves of `own_factor`
# `calibrated_choices` starts each calibrated solve from the solution it already holds
# (any candidate, any factor) that is cheapest on the graph to solve
# (`slam.warm_starts.WarmStarts`); False: from the candidate's own values (or the previous
# round's solution).
WARM_STARTS = True


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



def _loops_key(weights: Array) -> bytes:
    """The loops of weight 1 of `weights`, as a dictionary key."""
    return (np.asarray(weights) > 0.5).tobytes()


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
    max_rounds: int = OWN_ROUNDS, with_gains: bool = True, starts: WarmStarts | None = None,
) -> Calibrated:
    """The odometry variance factor the loops of weight 1 support, from `start`, and the
    calibrated solution there: `odometry_variance_step` to `FACTOR_TOLERANCE` by secant
    steps on ``log step`` against ``log s`` (as `slam.variance_components`; a plain
    re-weighting step first and where the secant is flat), capped at 1, at most
    `max_rounds` solves (the last one's factor is returned).  `with_gains`: linearise the
    accepted loops at the solution (`Calibrated.gains`, else None).  `starts`: each round
    solves from the nearest solution held there (`WarmStarts.start`) and holds its own."""
    d, keys = pose_dof(graph.dim), graph.keys
    priors = [graph.prior_factor(k) for k in graph.anchor_keys()]
    w = np.asarray(weights) > 0.5
    kept = np.flatnonzero(w)
    s, current, last = start, values, None
    for n in range(max_rounds):
        fixed, odometry = _calibrated_fixed(graph, s, priors)
        accepted = _accepted(fixed, unit, w.astype(float))
        current = solve_from(starts, solver, accepted, current)
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
        distinct.setdefault(_loops_key(w), n)
    which = list(distinct.values())
    if len(which) == 1:
        return Choices(0, 0, 1.0, 1.0)
    starts = WarmStarts(candidates[n][0] for n in which) if WARM_STARTS else None
    try:
        owns = {n: own_factor(graph, candidates[n][0], candidates[n][1], unit=unit,
                              solver=solve, with_gains=False, starts=starts) for n in which}
        bounds = {n: owns[n].upper_bound(probability) for n in which}
        stated = min(which, key=lambda n: candidates[n][2])
        stiff = min(which, key=lambda n: (bounds[n], candidates[n][2]))
        if not np.isfinite(bounds[stiff]):
            stiff = stated
        step: dict[int, int] = {}  # candidate judged at -> winner there
        judge = _Judge(graph, candidates, which, c, solve, unit, owns, step, starts)
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
    starts: WarmStarts | None = None  # solutions held as starts; None: own starts

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
            if n == chosen:
                x = own.values
            elif self.starts is not None and self.owns[n].s == own.s:
                x = self.owns[n].values  # this very graph, solved by `own_factor`
            else:
                x = solve_from(self.starts, self.solve, _accepted(fixed, self.unit, w),
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

