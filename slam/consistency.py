"""Time-ordered admission of loop closures under the truncated-least-squares loss.

The truncated-least-squares (TLS) objective of a pose graph with loop constraints
``k`` is (gtsam error units, ``e = 0.5 r^T I r``)::

    J(x, w) = sum_odometry e(x) + sum_k [ w_k e_k(x) + (1 - w_k) c ],   w_k in {0, 1}

with ``c = 0.5 chi2_dof^-1(p)`` (`tls_threshold`): a loop is worth keeping when it
costs less than ``c``.  Graduated non-convexity (Yang, Antonante, Tzoumas &
Carlone, "Graduated Non-Convexity for Robust Spatial Perception", RA-L 2020)
approaches this optimum through a convex surrogate; at small ``mu`` that
surrogate is close to an L1 loss, in which every loop pulls with the same force
whatever its residual.  With half the loops false (plausible measurements between
random poses) those pulls fold a graph such as M3500 before the surrogate turns
robust: GNC can fail on M3500 at 50% false loops from every start, including the
outlier-free optimum itself.

This module reaches the TLS optimum the way a mapper meets its loops: in time
order.  Poses are added in blocks of `block` ids (odometry composed onto the
solved prefix); every loop whose later end falls in the block is then decided
against the solved prefix, which earlier decisions already made consistent:

1. *Residual admission*: a loop whose error at the current solution is at most
   ``c`` is an inlier (the GNC-TLS weight rule in its limit ``mu -> inf``); the
   prefix is re-solved and the rule re-applied until nothing changes.
2. *Innovation admission* for the rest.  Adding loop ``k`` (whitened Jacobian ``B``,
   whitened residual ``b`` at the solution ``x*`` of the accepted graph, whose
   information is ``H = A^T A``) raises the least-squares cost, to first order, by
   the innovation (Schur complement) form::

       delta_k = 0.5 b^T (I + B H^-1 B^T)^-1 b

   the individual-compatibility test of Neira & Tardós (IEEE T-RA 2001), here the
   exact linearised TLS criterion: admitting ``k`` lowers ``J`` iff ``delta_k < c``.
   Candidates are admitted greedily, smallest ``delta`` first; after each
   admission the others' ``delta`` are updated exactly by the rank-``dof``
   (Sherman-Morrison-Woodbury) update of ``H^-1``, so two loops that contradict
   each other are never both admitted on the strength of the same slack.
   ``H`` is factorised once per round (sparse LU of the whitened normal equations).
   A candidate whose test has no power against a wrong place of the map (the prefix
   ties its poses only through a long, loosely stated odometry chain, so the gate
   would admit almost any measurement) is not admitted in its own block but deferred
   and decided by consensus with the loops that arrive later (`slam.deferral`).
3. Decisions are final for the incremental pass; `refine_tls` then re-decides every
   loop on the whole graph by the residual rule until the weights are stable.

`incremental_tls` wraps the pass in two local searches on the stated TLS objective:

* an *odometry ladder*: the pass decides on the graph with its odometry information
  multiplied by 1, 10 and 100 (a loose stated odometry makes the solved prefix floppy,
  and early false loops bend it onto themselves), each result refined under the
  stated covariances, the lowest stated `tls_cost` kept;
* a *bar search* (`bar_search`): the pass is repeated with the most strained
  accepted loop barred, kept when the stated cost drops (a false loop admitted early
  can fold a graph with few loops beyond what any residual rule recovers).

The innovation gate is where the noise model matters.  ``delta`` measures a loop
against the uncertainty the graph's own covariances claim; when they are far
more pessimistic than the data (M3500: the a-posteriori variance factor of the
outlier-free solution is 0.024), a stretch of trajectory tied to the map only
by a long odometry chain can be bent onto any false loop at a cost below ``c``.
`admit_incrementally` therefore has two gates: ``"stated"`` (``c``) and
``"calibrated"``, ``c`` times the a-posteriori variance factor of the accepted
prefix, ``s0^2 = 2 J_accepted / (m - n)`` (the estimated variance of unit weight
of least-squares adjustment, e.g. Förstner & Wrobel, *Photogrammetric Computer
Vision*, 2016), capped at 1 and used once the prefix has a redundancy ``m - n`` of
at least `MIN_REDUNDANCY_LOOPS` loops' worth.  Heavy-tailed graphs (Intel: a few
true loops with innovations near ``c`` although ``s0^2 = 0.2``) need the stated
gate; `incremental_tls` runs both and keeps the solution with the lower TLS
objective `tls_cost` (under the stated covariances), a plain two-start local
search.  Limitation: judged by the stated covariances, bending a loose tail onto
a lone false loop can be cheaper than rejecting it; when the stated run makes
no other mistake it then wins the comparison and keeps that loop (see
``test_calibrated_gate_refuses_a_false_loop_on_a_loose_tail``).

Related: pairwise consistency maximisation (PCM, Mangelson, Dominic, Eustice &
Vasudevan, ICRA 2018) tests pairs of loops through odometry chains; with
covariances as pessimistic as M3500's those chains are uninformative, which is
why the test here is against the solved prefix, as incremental robust back ends
do (riSAM, McGann, Rogers & Kaess, ICRA 2023; IPC, arXiv 2405.08503), here in
batch form.

Cost: a factorisation and ``dof`` sparse solves per candidate and round, and a
prefix solve per admission round.  The prefix solves are updates of one iSAM2 per
pass, which re-eliminate only what the new factors touch, until iSAM2's undamped
updates stop converging (admitted false loops folded the prefix); the pass then
goes on with batch solves (LM, dogleg-QR where LM fails), whose damping copes
(`admit_incrementally`'s ``prefix_solver``; ``benchmarks/tls_speed.py`` measures
the passes against an earlier revision).  Passes that share their first blocks share
their work: the calibrated pass is the stated one on the same graph until the first
block in which the calibrated gate admits less, and a `bar_search` trial is the pass it
improves on until the block that decides its barred loop; each resumes a snapshot of
the other (`AdmissionPass.resumed`; the same computation, bit for bit).

Requirements: the smallest pose id is an anchor and every later pose is reached by
odometry from an earlier one (the odometry spine of a mapper or a g2o file);
`incremental_tls` raises `UserError` otherwise.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.linalg import SuperLU

from data import se2
from data.errors import UserError
from slam.deferral import (
    MIN_POWER,
    alternative_offsets,
    alternative_places,
    consensus,
    power,
    whitened_offsets,
)
from slam.least_squares import StickySolver, factor_information
from slam.pose_graph import (
    Constraint,
    PoseGraph,
    RobustKernel,
    chi2_quantile,
    pose_dof,
    poses_from_values,
    to_gtsam_pose,
)
from slam.selected_inverse import SelectedInverse

Array = NDArray[np.float64]
GATES = ("stated", "calibrated")
MIN_REDUNDANCY_LOOPS = 10  # the calibrated gate needs this many loops' worth of redundancy
ODOMETRY_LADDER = (1.0, 10.0, 100.0)  # odometry information factors `incremental_tls` decides at
BAR_TRIES = 5  # at most this many trials of `incremental_tls`'s `bar_search`
PREFIX_SOLVERS = ("auto", "batch", "isam2")  # `admit_incrementally`'s prefix_solver
LM_BUDGET = 25  # LM iterations of a warm-started solve before dogleg (`StickySolver`)
RELINEARIZE = 1e-3  # iSAM2 relinearisation threshold of the prefix (tangent units)
SOLVE_WIDTH = 6  # right-hand sides per SuperLU solve (`solve_columns`)
# `InnovationTest.blocks` from selected entries of H^-1 (`slam.selected_inverse`); False:
# from full solves of H^-1 B^T (the same numbers to rounding; `benchmarks/recheck_speed.py`).
SELECTED_INVERSE = True
POLISH_TOLERANCE = 1e-10  # `polish` stops below this relative decrease of the error
DEFER_MODES = ("off", "candidate", "all")  # `incremental_tls`'s deferral of powerless tests
SNAPSHOTS = 2  # at most this many snapshots of a recorded `AdmissionPass` (each an iSAM2 copy)


def tls_threshold(dim: int, probability: float = 0.99) -> float:
    """TLS cost ``c`` of a rejected loop: 0.5 * chi2 quantile of its dof (3 in 2D, 6 in 3D)."""
    return 0.5 * chi2_quantile(probability, pose_dof(dim))


# -- the innovation test ---------------------------------------------------------------------


@dataclass(slots=True)
class _Gains:
    """Linearised candidates: whitened residuals ``b`` (m, d), Jacobian blocks ``Bi``, ``Bj``
    (m, d, d), ``Y = H^-1 B^T`` (m, r, d) restricted to the r variable rows that some
    candidate touches (the only rows any update reads), the positions ``ri``, ``rj``
    (m, d) of each candidate's rows among them, and ``M = B H^-1 B^T`` (m, d, d)."""

    b: Array
    Bi: Array
    Bj: Array
    ri: NDArray[np.int64]
    rj: NDArray[np.int64]
    Y: Array
    M: Array

    def cross(self, y: Array) -> Array:
        """``B_q y`` for every candidate ``q``, for one ``y`` of shape (r, d): (m, d, d)."""
        return np.einsum("mab,mbc->mac", self.Bi, y[self.ri]) + np.einsum(
            "mab,mbc->mac", self.Bj, y[self.rj]
        )

    def subset(self, index: NDArray[np.int64]) -> _Gains:
        """The candidates `index` alone (copies; ``Y`` keeps every touched row)."""
        return _Gains(self.b[index].copy(), self.Bi[index].copy(), self.Bj[index].copy(),
                      self.ri[index].copy(), self.rj[index].copy(), self.Y[index].copy(),
                      self.M[index].copy())


class InnovationTest:
    """First-order cost of adding factors to a solved graph.

    `factors` (the accepted graph, whose optimum is `values`) is linearised at
    `values`; its whitened Jacobian ``A`` gives the information ``H = A^T A`` over the
    poses `keys` (tangent coordinates, gtsam order), factorised once with a sparse LU.
    """

    def __init__(
        self,
        factors: gtsam.NonlinearFactorGraph,
        values: gtsam.Values,
        keys: Sequence[int],
        dof: int,
    ) -> None:
        triplets = factors.linearize(values).sparseJacobian_()
        rows = triplets[0].astype(np.int64) - 1  # 1-based, columns in sorted-key order
        cols = triplets[1].astype(np.int64) - 1
        n = len(keys) * dof
        keep = cols < n  # the last column is the right-hand side
        jac = coo_matrix(
            (triplets[2][keep], (rows[keep], cols[keep])), shape=(int(rows.max()) + 1, n)
        ).tocsc()
        self._lu = factor_information(jac)
        self._selected: SelectedInverse | None = None
        self._values = values
        self._column = {k: n_ * dof for n_, k in enumerate(sorted(keys))}
        self.dof = dof
        self.n = n

    def covariance(self, rhs: Array) -> Array:
        """``H^-1 rhs`` for ``rhs`` of shape (n, d)."""
        return self._lu.solve(rhs)

    @property
    def selected(self) -> SelectedInverse:
        """Selected entries of ``H^-1`` (marginal covariance blocks) from the same LU."""
        if self._selected is None:
            self._selected = SelectedInverse(self._lu, symmetric=True)
        return self._selected

    def pose_index(self, key: int) -> int:
        """First row of pose `key` in ``H`` (tangent coordinates, gtsam order)."""
        return self._column[key]

    def _linearised(
        self, candidates: Sequence[gtsam.NonlinearFactor]
    ) -> tuple[Array, Array, Array, NDArray[np.int64], NDArray[np.int64]]:
        """Whitened residuals ``b`` (m, d), Jacobian blocks ``B_i``, ``B_j`` (m, d, d)
        and the first rows in ``H`` of both poses of every candidate, at the solution."""
        d, m = self.dof, len(candidates)
        b = np.empty((m, d))
        bi, bj = np.empty((m, d, d)), np.empty((m, d, d))
        ci, cj = np.empty(m, np.int64), np.empty(m, np.int64)
        for q, factor in enumerate(candidates):
            linear = factor.linearize(self._values)
            a, b[q] = linear.jacobian()
            k1, k2 = list(linear.keys())
            bi[q], bj[q] = a[:, :d], a[:, d:]
            ci[q], cj[q] = self._column[k1], self._column[k2]
        return b, bi, bj, ci, cj

    def _solved(
        self, bi: Array, bj: Array, ci: NDArray[np.int64], cj: NDArray[np.int64]
    ) -> Iterator[tuple[int, Array]]:
        """``(q, H^-1 B_q^T)`` ((n, d), valid until the next item) of every candidate ``q``,
        `SOLVE_WIDTH` columns per solve (`solve_columns`)."""
        d, m = self.dof, len(bi)
        k = max(1, SOLVE_WIDTH // d)
        rhs = np.zeros((self.n, k * d))
        span = np.arange(d)
        for start in range(0, m, k):
            qs = range(start, min(start + k, m))
            for c, q in enumerate(qs):
                cols = slice(c * d, (c + 1) * d)
                rhs[ci[q] + span, cols] += bi[q].T
                rhs[cj[q] + span, cols] += bj[q].T
            y = self.covariance(rhs[:, : len(qs) * d])
            for c, q in enumerate(qs):
                cols = slice(c * d, (c + 1) * d)
                rhs[ci[q] + span, cols] = 0.0
                rhs[cj[q] + span, cols] = 0.0
                yield q, y[:, cols]

    def blocks(self, candidates: Sequence[gtsam.NonlinearFactor]) -> tuple[Array, Array]:
        """Whitened residuals ``b`` (m, d) and ``M = B H^-1 B^T`` (m, d, d) of every candidate
        (binary factors on poses of `keys`): `gains`' ``b`` and ``M`` without its
        ``H^-1 B^T`` rows, which take (m, r, d) memory."""
        d = self.dof
        b, bi, bj, ci, cj = self._linearised(candidates)
        if SELECTED_INVERSE:
            return b, self._gram(bi, bj, ci, cj)
        gram = np.empty((len(b), d, d))
        for q, y in self._solved(bi, bj, ci, cj):
            gram[q] = bi[q] @ y[ci[q] : ci[q] + d] + bj[q] @ y[cj[q] : cj[q] + d]
        return b, gram

    def _gram(
        self, bi: Array, bj: Array, ci: NDArray[np.int64], cj: NDArray[np.int64]
    ) -> Array:
        """``M = B H^-1 B^T`` (m, d, d) of binary factors with Jacobian blocks ``B_i``,
        ``B_j`` on the poses of first rows ``ci``, ``cj`` from the marginal covariance
        blocks of their two poses alone (``S = H^-1``)::

            M = B_i S_ii B_i^T + B_i S_ij B_j^T + B_j S_ji B_i^T + B_j S_jj B_j^T
        """
        d, m = self.dof, len(bi)
        s = self.selected.blocks(np.concatenate([ci, ci, cj, cj]),
                                 np.concatenate([ci, cj, ci, cj]), d).reshape(4, m, d, d)
        left, right = (bi, bi, bj, bj), (bi, bj, bi, bj)
        return sum(np.einsum("mab,mbc,mdc->mad", left[t], s[t], right[t]) for t in range(4))

    def gains(self, candidates: Sequence[gtsam.NonlinearFactor]) -> _Gains:
        """Linearise `candidates` (binary factors on poses of `keys`) at the solution."""
        d, m = self.dof, len(candidates)
        b, bi, bj, ci, cj = self._linearised(candidates)
        span = np.arange(d)
        ri, rj = ci[:, None] + span, cj[:, None] + span  # (m, d) rows of H
        touched, where = np.unique(np.concatenate([ri, rj], axis=1), return_inverse=True)
        where = where.reshape(m, 2 * d)
        pi, pj = where[:, :d], where[:, d:]
        y = np.empty((m, len(touched), d))  # (m, r, d)
        for q, column in self._solved(bi, bj, ci, cj):
            y[q] = column[touched]
        own = np.arange(m)[:, None]
        # M_q = B_q H^-1 B_q^T = B_q Y_q: candidate q's own rows of its Y only.
        gram = np.einsum("mab,mbc->mac", bi, y[own, pi]) + np.einsum(
            "mab,mbc->mac", bj, y[own, pj]
        )
        return _Gains(b, bi, bj, pi, pj, y, gram)


def solve_columns(lu: SuperLU, rhs: Array, width: int = SOLVE_WIDTH) -> Array:
    """``H^-1 rhs`` for ``rhs`` of shape (n, k) by the factorisation `lu`, `width` columns
    per solve: SuperLU's solve costs several times more per column with many right-hand
    sides at once than with a few (on pose graphs of thousands of poses)."""
    out = np.empty_like(rhs)
    for start in range(0, rhs.shape[1], width):
        out[:, start : start + width] = lu.solve(rhs[:, start : start + width])
    return out


def admission_costs(gains: _Gains) -> Array:
    """``delta_q = 0.5 b^T (I + M)^-1 b`` of every candidate (gtsam error units)."""
    s = np.eye(gains.b.shape[1]) + gains.M
    return 0.5 * np.einsum("ma,ma->m", gains.b, np.linalg.solve(s, gains.b[..., None])[..., 0])


def greedy_admission(
    gains: _Gains, gate: float, costs: list[float] | None = None
) -> tuple[list[int], Array]:
    """Admit candidates smallest ``delta`` first while ``delta < gate``.

    After each admission the remaining candidates' ``b``, ``M`` and ``Y`` are updated
    for the admitted factor (rank-``dof`` Woodbury update of ``H^-1`` and the
    Gauss-Newton step it causes), so every later ``delta`` is conditioned on the
    admissions before it.  Returns the admitted indices in order and the final
    ``delta`` of every candidate.  `gains` is consumed.  `costs`, when given, receives
    each admitted candidate's ``delta`` at its admission (a lower gate would have
    stopped at the first of them it does not exceed).
    """
    m = len(gains.b)
    open_ = np.ones(m, dtype=bool)
    admitted: list[int] = []
    eye = np.eye(gains.b.shape[1])
    while open_.any():
        delta = admission_costs(gains)
        delta[~open_] = np.inf
        k = int(np.argmin(delta))
        if not delta[k] < gate:
            break
        admitted.append(k)
        if costs is not None:
            costs.append(float(delta[k]))
        open_[k] = False
        gain = np.linalg.inv(eye + gains.M[k])
        c = gains.cross(gains.Y[k])  # B_q H^-1 B_k^T
        gains.b = gains.b - np.einsum("mab,bc,c->ma", c, gain, gains.b[k])
        gains.M = gains.M - np.einsum("mab,bc,mdc->mad", c, gain, c)
        gains.Y = gains.Y - np.einsum("nb,bc,mdc->mnd", gains.Y[k], gain, c)
    return admitted, admission_costs(gains)


# -- the incremental pass --------------------------------------------------------------------


@dataclass(slots=True)
class Admission:
    """Result of a TLS solve by time-ordered admission.

    Attributes:
        values: solution (gtsam Values of every pose).
        weights: 1 for loops kept, 0 for loops rejected (order of `graph.loops`).
        tls_cost: `tls_cost` of the solution under the graph's stated covariances.
        blocks: prefix solves of the incremental pass.
        gate: ``"stated"`` or ``"calibrated"`` (see the module docstring).
        prefix: how the prefix was solved, ``"batch"``, ``"isam2"`` or
            ``"isam2-then-batch"`` (iSAM2 until its updates stopped converging; see
            `_IsamPrefix`).
    """

    values: gtsam.Values
    weights: Array
    tls_cost: float
    blocks: int
    gate: str
    prefix: str = "batch"


StatedFactors = tuple[gtsam.NonlinearFactorGraph, list[int]]  # `PoseGraph.factor_graph`'s result


def tls_cost(
    graph: PoseGraph, values: gtsam.Values, probability: float = 0.99,
    factors: StatedFactors | None = None,
) -> float:
    """TLS objective at `values`: odometry and prior error plus ``min(e_k, c)`` per loop.

    `factors`: ``graph.factor_graph(RobustKernel("none"))`` when the caller already built
    it (a few milliseconds per thousand constraints, which a search over many runs of the
    same graph would otherwise repeat).
    """
    base, loop_index = factors or graph.factor_graph(RobustKernel("none"))
    c = tls_threshold(graph.dim, probability)
    n_fixed = base.size() - len(loop_index)
    fixed = sum(base.at(k).error(values) for k in range(n_fixed))
    loops = sum(min(base.at(k).error(values), c) for k in loop_index)
    return float(fixed + loops)


def has_odometry_spine(graph: PoseGraph) -> bool:
    """The first pose is anchored and odometry reaches every other pose from an earlier
    one: what the time-ordered admission needs (a graph of two sessions joined by
    loops alone has no spine)."""
    try:
        _check_spine(graph)
    except UserError:
        return False
    return True


def _check_spine(graph: PoseGraph) -> list[int]:
    """Pose ids in order, after checking the anchor and the odometry spine."""
    keys = graph.keys
    if keys[0] not in graph.anchor_keys():
        raise UserError(f"time-ordered admission needs the first pose ({keys[0]}) anchored")
    reached = {max(o.i, o.j) for o in graph.odometry if o.i != o.j}
    missing = len(set(keys[1:]) - reached)
    if missing:
        raise UserError(
            f"time-ordered admission needs odometry from an earlier pose to every pose; "
            f"{missing} poses have none"
        )
    return keys


def _extend(
    solved: dict[int, Array], given: dict[int, Array], ref: int | None, new: list[int], dim: int
) -> None:
    """New poses keep their given pose relative to `ref`, which moved to its solved pose."""
    if ref is None:
        solved.update((k, given[k]) for k in new)
        return
    if dim == 2:
        moved = se2.compose(solved[ref], se2.inverse(given[ref]))
        solved.update(zip(new, se2.compose(moved, np.array([given[k] for k in new])), strict=True))
    else:
        moved = solved[ref] @ np.linalg.inv(given[ref])
        solved.update((k, moved @ given[k]) for k in new)


def _with(
    fixed: gtsam.NonlinearFactorGraph, factors: list, indices: NDArray[np.int64]
) -> gtsam.NonlinearFactorGraph:
    """A copy of `fixed` plus ``factors[k]`` for every k in `indices`."""
    graph = gtsam.NonlinearFactorGraph(fixed)
    for k in indices:
        graph.add(factors[k])
    return graph


def _variance_factor(
    factors: gtsam.NonlinearFactorGraph, values: gtsam.Values, poses: int, dof: int
) -> float | None:
    """A-posteriori variance of unit weight ``2 J / (m - n)``; None without enough redundancy."""
    redundancy = dof * factors.size() - dof * poses
    if redundancy < dof * MIN_REDUNDANCY_LOOPS:
        return None
    return 2.0 * factors.error(values) / redundancy


class _IsamPrefix:
    """The solved prefix of `admit_incrementally`, kept by one gtsam ISAM2.

    Factors and poses are handed over once (`add`, `insert`); `solve` updates iSAM2 with
    them and repeats ``update`` until no variable is relinearised any more (at most
    `max_updates`), so each solve re-eliminates only the part of the Bayes tree that the
    new factors and the relinearised poses touch, instead of a batch solve of the whole
    prefix.  Cholesky factorisation; when it finds the system indeterminate (Intel's
    near-singular information matrices), iSAM2 is rebuilt once with QR from every factor
    it was given and its latest estimate.

    iSAM2's updates are undamped Gauss-Newton steps.  When admitted false loops fold the
    prefix, they stop converging: every update relinearises every pose and the estimate
    oscillates (M3500 at half false loops: all `max_updates` updates of each later solve
    relinearise the whole prefix).  `converged` is then False, and `admit_incrementally`
    finishes that pass with damped batch solves (`_isam_or_batch`).
    """

    def __init__(self, max_updates: int = 20) -> None:
        self.factorization = "CHOLESKY"
        self._isam = self._new()
        self._all = gtsam.NonlinearFactorGraph()  # every factor handed over, for a rebuild
        self._estimate = gtsam.Values()
        self._factors = gtsam.NonlinearFactorGraph()
        self._values = gtsam.Values()
        self.max_updates = max_updates
        self.converged = True  # the last `solve` stopped relinearising within max_updates

    def _new(self) -> gtsam.ISAM2:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(RELINEARIZE)
        params.relinearizeSkip = 1
        params.setFactorization(self.factorization)
        return gtsam.ISAM2(params)

    def copy(self) -> _IsamPrefix:
        """An independent copy (gtsam's ISAM2 copy constructor copies the Bayes tree: the
        copy and the original updated alike give the same estimates, bit for bit)."""
        other = _IsamPrefix.__new__(_IsamPrefix)
        other.factorization = self.factorization
        other._isam = gtsam.ISAM2(self._isam)
        other._all = gtsam.NonlinearFactorGraph(self._all)
        other._estimate = gtsam.Values(self._estimate)
        other._factors = gtsam.NonlinearFactorGraph(self._factors)
        other._values = gtsam.Values(self._values)
        other.max_updates = self.max_updates
        other.converged = self.converged
        return other

    def add(self, factor: gtsam.NonlinearFactor) -> None:
        self._factors.add(factor)

    def insert(self, key: int, pose: object) -> None:
        self._values.insert(key, pose)

    def solve(self) -> gtsam.Values:
        factors, values = self._factors, self._values
        self._factors, self._values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        for k in range(factors.size()):
            self._all.add(factors.at(k))
        try:
            self._converge(factors, values)
        except RuntimeError:  # gtsam IndeterminateLinearSystemException
            if self.factorization == "QR":
                raise
            self.factorization = "QR"
            self._isam = self._new()
            start = gtsam.Values(self._estimate)
            start.insert_or_assign(values)
            self._converge(self._all, start)
        self._estimate = self._isam.calculateEstimate()
        return self._estimate

    def _converge(self, factors: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
        result = self._isam.update(factors, values)
        for _ in range(self.max_updates):
            if result.getVariablesRelinearized() == 0:
                self.converged = True
                return
            result = self._isam.update()
        self.converged = result.getVariablesRelinearized() == 0


def _isam_or_batch(
    isam: _IsamPrefix, solve: StickySolver, factors: gtsam.NonlinearFactorGraph,
    current: gtsam.Values,
) -> tuple[gtsam.Values, _IsamPrefix | None]:
    """The prefix solved by `isam`, or, when its updates did not converge, by `solve` on
    the accepted graph `factors` from the better of iSAM2's estimate and `current`; the
    second value is the iSAM2 to use next (None: batch solves for the rest of the pass)."""
    estimate = isam.solve()
    if isam.converged:
        return estimate, isam
    start = estimate if factors.error(estimate) < factors.error(current) else current
    return solve(factors, start), None


def admit_incrementally(
    graph: PoseGraph,
    values: gtsam.Values,
    *,
    probability: float = 0.99,
    block: int = 50,
    gate: str = "stated",
    max_rounds: int = 50,
    solver: StickySolver | None = None,
    barred: Sequence[int] = (),
    prefix_solver: str = "auto",
    unit: list[gtsam.NonlinearFactor] | None = None,
    defer: bool = False,
) -> Admission:
    """One time-ordered TLS pass (module docstring, steps 1-3) from initial `values`.

    Args:
        graph: the pose graph (2D or 3D); its loops are the candidates.
        values: initial guess of every pose (e.g. the odometry chain); only the poses'
            relative placement within each new block is used.
        probability: chi-square probability of the TLS threshold ``c``.
        block: poses added per step (ids in increasing order).
        gate: ``"stated"`` or ``"calibrated"`` innovation gate.
        max_rounds: admission rounds per block (each ends with a prefix solve).
        solver: least-squares solver (shared by the calls of `incremental_tls`).
        barred: loops never admitted (weight 0).
        prefix_solver: ``"batch"`` (`solver` on the whole accepted prefix after every
            admission round) or ``"isam2"`` (`_IsamPrefix`, handing over to batch solves
            for the rest of the pass once its updates stop converging); ``"auto"`` is
            ``"isam2"``: on a prefix that stays consistent its updates cost a fraction
            of the batch solves, and a folded prefix costs about what batch does.
        unit: the Gaussian factor of every loop (computed when None).
        defer: loops whose innovation test has no power are deferred and decided by
            consensus (`slam.deferral`); loops still deferred at the end are rejected.
            False (the default) decides every loop in its own block.
    """
    run = AdmissionPass(graph, values, probability=probability, block=block, gate=gate,
                        max_rounds=max_rounds, solver=solver, barred=barred,
                        prefix_solver=prefix_solver, unit=unit, defer=defer)
    run.advance()
    return run.result()


@dataclass(slots=True)
class _Snapshot:
    """The state of an `AdmissionPass` before block `step` (index into its block ends),
    taken while its prefix had not folded; never mutated (`AdmissionPass.resumed` copies
    it)."""

    step: int
    last: int
    blocks: int
    current: gtsam.Values
    weights: Array
    fixed: gtsam.NonlinearFactorGraph
    isam: _IsamPrefix | None
    deferred: NDArray[np.int64]


class AdmissionPass:
    """The state of one `admit_incrementally` pass, which can stop after a fold.

    `advance` adds blocks until the end of the graph, or, with ``until_fold``, until the
    end of the block in which the iSAM2 prefix stopped converging (`_IsamPrefix`: the
    admitted loops folded the prefix); `folded` then says so, and a later `advance`
    goes on with the batch solves the pass would have used anyway, so a resumed pass
    equals one that never stopped.  `incremental_tls` uses this to finish a folded pass
    only when its decided prefix is still cheaper than the best finished pass's
    (`prefix_cost`).  Arguments as `admit_incrementally`.

    `record`: keep `SNAPSHOTS` snapshots of the state before evenly spaced blocks (while
    the prefix has not folded), from which `resumed` starts a pass that differs from
    this one only from a given block on: one more barred loop (`bar_search`: every block
    before the barred loop's is decided as here) or the calibrated gate (`calibrated_step`:
    a stated pass tracks the first block in which the calibrated gate would have admitted
    less).  A resumed pass computes what a new pass would, bit for bit.
    """

    def __init__(
        self, graph: PoseGraph, values: gtsam.Values, *, probability: float = 0.99,
        block: int = 50, gate: str = "stated", max_rounds: int = 50,
        solver: StickySolver | None = None, barred: Sequence[int] = (),
        prefix_solver: str = "auto", unit: list[gtsam.NonlinearFactor] | None = None,
        record: bool = False, defer: bool = False,
    ) -> None:
        if prefix_solver not in PREFIX_SOLVERS:
            raise UserError(f"unknown prefix solver {prefix_solver!r}; use "
                            f"{', '.join(PREFIX_SOLVERS)}")
        if gate not in GATES:
            raise UserError(f"unknown gate {gate!r}; use {', '.join(GATES)}")
        self.prefix_solver = "isam2" if prefix_solver == "auto" else prefix_solver
        self._isam = _IsamPrefix() if self.prefix_solver == "isam2" else None
        self._solve = solver or StickySolver()
        self.graph, self.gate, self.barred = graph, gate, barred
        self._max_rounds = max_rounds
        self.keys = _check_spine(graph)
        self._d, self._c = pose_dof(graph.dim), tls_threshold(graph.dim, probability)
        self.position = {k: n for n, k in enumerate(self.keys)}
        self._given = poses_from_values(values, graph.dim)
        self.unit = unit if unit is not None else [graph.between_factor(lp) for lp in graph.loops]
        self.odometry_end = np.array([max(self.position[o.i], self.position[o.j])
                                      for o in graph.odometry], dtype=int)
        self.loop_end = np.array([max(self.position[lp.i], self.position[lp.j])
                                  for lp in graph.loops], dtype=int)
        self._anchors = set(graph.anchor_keys())
        self.weights = np.zeros(len(graph.loops))
        self.defer = defer
        self.deferred = np.zeros(0, dtype=np.int64)  # loops whose test had no power yet
        self._fixed = gtsam.NonlinearFactorGraph()
        self.current = gtsam.Values()  # the solved prefix, then the new block composed onto it
        self.last, self.blocks = -1, 0  # position of the last pose added; blocks solved
        self._ends = [*range(block - 1, len(self.keys) - 1, block), len(self.keys) - 1]
        self._step = 0
        self.folded = False  # the iSAM2 prefix stopped converging (batch solves from then on)
        self._released = False  # the iSAM2 prefix dropped by `release_prefix` (not folded)
        self.snapshots: list[_Snapshot] | None = [] if record else None
        self._stride = max(1, -(-len(self._ends) // SNAPSHOTS))
        # A stated pass: the first block in which the calibrated gate would admit less.
        self.calibrated_step: int | None = None

    @property
    def done(self) -> bool:
        return self._step == len(self._ends)

    def release_prefix(self) -> None:
        """Drop the iSAM2 of the solved prefix (memory: one per pass, and
        `incremental_tls` keeps several passes until it chooses among them); only for a
        pass that will not `advance` again."""
        if self._isam is not None:
            self._isam = None
            self._released = True

    def advance(self, until_fold: bool = False, blocks: int | None = None) -> None:
        """Add blocks to the end, or until the block that folded (`until_fold`), or
        `blocks` more blocks."""
        n = 0
        while not self.done and (blocks is None or n < blocks):
            if (self.snapshots is not None and not self.folded
                    and self._step % self._stride == 0
                    and (not self.snapshots or self.snapshots[-1].step < self._step)):
                self.snapshots.append(self._snapshot())
            self._add_block(self._ends[self._step])
            self._step += 1
            n += 1
            if until_fold and self.folded:
                return

    def _snapshot(self) -> _Snapshot:
        return _Snapshot(self._step, self.last, self.blocks, gtsam.Values(self.current),
                         self.weights.copy(), gtsam.NonlinearFactorGraph(self._fixed),
                         None if self._isam is None else self._isam.copy(),
                         self.deferred.copy())

    def block_of(self, loop: int) -> int:
        """Index of the block in which `loop` (index into `graph.loops`) is decided."""
        return int(np.searchsorted(self._ends, self.loop_end[loop]))

    def resumed(
        self, step: int, *, barred: Sequence[int] | None = None, gate: str | None = None
    ) -> AdmissionPass:
        """A new pass with `barred` (default this pass's) and `gate` (default this pass's),
        from this pass's latest snapshot before block `step` or earlier: right when the new
        pass decides every block before `step` as this one did.  It keeps the snapshots it
        shares with this pass and records its own."""
        if self.snapshots is None:
            raise ValueError("resumed() needs a pass made with record=True")
        earlier = [snap for snap in self.snapshots if snap.step <= step]
        run = copy.copy(self)  # the graph, factors and positions are shared, never mutated
        run.barred = self.barred if barred is None else barred
        run.gate = self.gate if gate is None else gate
        run.folded, run._released, run.calibrated_step = False, False, None
        run.snapshots = earlier
        if not earlier:  # before the first block: a new pass
            run.last, run.blocks, run._step = -1, 0, 0
            run.current, run.weights = gtsam.Values(), np.zeros(len(self.graph.loops))
            run.deferred = np.zeros(0, dtype=np.int64)
            run._fixed = gtsam.NonlinearFactorGraph()
            run._isam = _IsamPrefix() if self.prefix_solver == "isam2" else None
            return run
        snap = earlier[-1]
        run.last, run.blocks, run._step = snap.last, snap.blocks, snap.step
        run.current, run.weights = gtsam.Values(snap.current), snap.weights.copy()
        run.deferred = np.setdiff1d(snap.deferred, run.barred).astype(np.int64)
        run._fixed = gtsam.NonlinearFactorGraph(snap.fixed)
        run._isam = None if snap.isam is None else snap.isam.copy()
        return run

    def _add_block(self, end: int) -> None:
        graph, keys, unit, c = self.graph, self.keys, self.unit, self._c
        last, current, fixed, isam = self.last, self.current, self._fixed, self._isam
        new = keys[last + 1 : end + 1]
        ref = keys[last] if last >= 0 else None
        solved = {} if ref is None else {ref: _pose_of(current, ref, graph.dim)}
        _extend(solved, self._given, ref, new, graph.dim)
        for k in new:
            pose = to_gtsam_pose(solved[k], graph.dim)
            current.insert(k, pose)
            if k in self._anchors:
                fixed.add(graph.prior_factor(k))
                if isam is not None:
                    isam.add(graph.prior_factor(k))
            if isam is not None:
                isam.insert(k, pose)
        for n in np.flatnonzero((self.odometry_end > last) & (self.odometry_end <= end)):
            fixed.add(graph.between_factor(graph.odometry[n]))
            if isam is not None:
                isam.add(fixed.at(fixed.size() - 1))
        arrived = np.setdiff1d(
            np.flatnonzero((self.loop_end > last) & (self.loop_end <= end)), self.barred)
        final = end == len(keys) - 1
        self.last = end
        # Deferred loops are re-tested with every block that brings loops, and at the end.
        if len(arrived) == 0 and not (final and len(self.deferred)):
            return
        pending = np.union1d(arrived, self.deferred).astype(np.int64)
        self.blocks += 1
        prefix = keys[: end + 1]
        accepted = np.zeros(len(pending), dtype=bool)
        waiting = np.zeros(0, dtype=np.int64)  # positions in `pending` deferred (`slam.deferral`)
        factors = fixed  # the accepted graph, whose solution is `current`
        for _ in range(self._max_rounds):
            errors = np.array([unit[k].error(current) for k in pending])
            newly = ~accepted & (errors <= c)
            if newly.any():  # step 1
                accepted |= newly
                factors = _with(fixed, unit, pending[accepted])
                current, isam = self._prefix_solve(factors, current, pending[newly])
                continue
            rest = np.flatnonzero(~accepted)
            waiting = np.zeros(0, dtype=np.int64)
            if len(rest) == 0:
                break
            # Step 2, at the solution of the accepted graph.
            limit = c
            if self.gate == "calibrated":
                s0 = _variance_factor(factors, current, len(prefix), self._d)
                limit = c * min(1.0, s0) if s0 is not None else c
            try:
                test = InnovationTest(factors, current, prefix, self._d)
            except RuntimeError:  # singular information: no innovation test possible
                break
            gains = test.gains([unit[pending[q]] for q in rest])
            decide = np.arange(len(rest))
            weak = np.zeros(0, dtype=np.int64)
            white = None
            if self.defer:
                # The deferral's classes use the stated ``c`` whatever the gate, so a stated
                # and a calibrated pass defer alike until they admit differently.
                ends = [unit[pending[q]].keys()[1] for q in rest]
                white = whitened_offsets(gains, alternative_offsets(
                    current, ends, alternative_places(prefix), graph.dim))
                eye = np.eye(self._d)
                strong = power(eye + gains.M, white, c) >= MIN_POWER
                weak = np.flatnonzero(~strong & (admission_costs(gains) < c))
                decide = np.flatnonzero(strong)
            costs: list[float] = []
            admitted: list[int] = []
            if len(decide):
                chosen, _ = greedy_admission(gains.subset(decide), limit, costs)
                admitted = [int(decide[q]) for q in chosen]
            if not admitted and len(weak):
                agreeing = consensus(gains.subset(weak), white[weak], c)
                if len(agreeing):
                    pick = weak[agreeing]
                    chosen, _ = greedy_admission(gains.subset(pick), limit, costs)
                    admitted = [int(pick[q]) for q in chosen]
            if self.gate == "stated" and self.calibrated_step is None and admitted:
                s0 = _variance_factor(factors, current, len(prefix), self._d)
                if s0 is not None and max(costs) >= c * min(1.0, s0):
                    self.calibrated_step = self._step
            if not admitted:
                waiting = rest[weak] if not final else waiting
                break
            accepted[rest[admitted]] = True
            factors = _with(fixed, unit, pending[accepted])
            current, isam = self._prefix_solve(factors, current, pending[rest[admitted]])
        self.current = current
        self.weights[pending] = accepted
        self.deferred = pending[waiting[~accepted[waiting]]]
        for q in np.flatnonzero(accepted):
            fixed.add(unit[pending[q]])

    def _prefix_solve(
        self, factors: gtsam.NonlinearFactorGraph, current: gtsam.Values,
        added: NDArray[np.int64],
    ) -> tuple[gtsam.Values, _IsamPrefix | None]:
        """The accepted prefix `factors` solved from `current` after the loops `added`."""
        if self._isam is None:
            return self._solve(factors, current), None
        for k in added:
            self._isam.add(self.unit[k])
        current, self._isam = _isam_or_batch(self._isam, self._solve, factors, current)
        if self._isam is None:
            self.folded = True
        return current, self._isam

    def prefix_cost(
        self, values: gtsam.Values, factors: StatedFactors, probability: float = 0.99
    ) -> float:
        """`tls_cost` at `values` of the part of `factors` (the stated graph of the same
        poses, odometry and loops) that this pass has decided: anchors and odometry
        among the poses added so far, and the loops that end among them."""
        base, loop_index = factors
        c = tls_threshold(self.graph.dim, probability)
        n_priors = base.size() - len(loop_index) - len(self.graph.odometry)
        seen = set(self.keys[: self.last + 1])
        cost = sum(base.at(k).error(values) for k in range(n_priors)
                   if base.at(k).keys()[0] in seen)
        n_odometry = np.flatnonzero(self.odometry_end <= self.last)
        cost += sum(base.at(n_priors + int(n)).error(values) for n in n_odometry)
        cost += sum(min(base.at(loop_index[k]).error(values), c)
                    for k in np.flatnonzero(self.loop_end <= self.last))
        return float(cost)

    def result(self) -> Admission:
        """The pass's `Admission` (after `advance` reached the end)."""
        errors = np.array([f.error(self.current) for f in self.unit])
        w = self.weights
        cost = self._fixed.error(self.current) - errors[w > 0.5].sum() + np.minimum(
            errors, self._c).sum()
        prefix = self.prefix_solver
        if prefix == "isam2" and self._isam is None and not self._released:
            prefix = "isam2-then-batch"
        return Admission(self.current, w, float(cost), self.blocks, self.gate, prefix)


def needs_qr(graph: PoseGraph, values: gtsam.Values) -> bool:
    """True when sparse Cholesky cannot eliminate the anchors and odometry of `graph`
    linearised at `values` (Intel's near-singular information matrices; milliseconds)."""
    factors = gtsam.NonlinearFactorGraph()
    for k in graph.anchor_keys():
        factors.add(graph.prior_factor(k))
    for o in graph.odometry:
        factors.add(graph.between_factor(o))
    try:
        factors.linearize(values).eliminateMultifrontal()  # Cholesky
    except RuntimeError:  # gtsam IndeterminateLinearSystemException
        return True
    return False


def _pose_of(values: gtsam.Values, key: int, dim: int) -> Array:
    """Pose `key` of `values` as (x, y, theta) or a 4x4 matrix."""
    if dim == 2:
        p = values.atPose2(key)
        return np.array([p.x(), p.y(), p.theta()])
    return values.atPose3(key).matrix()


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
) -> tuple[gtsam.Values, Array]:
    """Re-decide every loop by the TLS residual rule on the whole graph until stable.

    Solve with the loops of weight 1, set ``w_k = [e_k <= c]``, repeat (iteratively
    re-weighted least squares of the TLS loss from a start inside its basin).  Loops
    in `barred` keep weight 0.  `solved`: `values` already solve the graph with
    `weights` (an `admit_incrementally` result), so the first solve is skipped.
    `factors`: as in `tls_cost`.
    """
    solve = solver or StickySolver()
    base, loop_index = factors or graph.factor_graph(RobustKernel("none"))
    c = tls_threshold(graph.dim, probability)
    n_fixed = base.size() - len(loop_index)
    w = np.asarray(weights, dtype=float).copy()
    w[list(barred)] = 0.0
    result = values
    for n in range(max_rounds):
        if not (solved and n == 0):
            kept = gtsam.NonlinearFactorGraph()
            for k in range(n_fixed):
                kept.add(base.at(k))
            for k in np.flatnonzero(w > 0.5):
                kept.add(base.at(loop_index[k]))
            result = solve(kept, result)
        new = np.array([base.at(k).error(result) <= c for k in loop_index], dtype=float)
        new[list(barred)] = 0.0
        if np.array_equal(new, w):
            break
        w = new
    return result, w


def bar_search(
    graph: PoseGraph,
    decide: PoseGraph,
    values: gtsam.Values,
    best: Admission,
    *,
    probability: float = 0.99,
    block: int = 50,
    tries: int = 3,
    solver: StickySolver | None = None,
    prefix_solver: str = "auto",
    unit: list[gtsam.NonlinearFactor] | None = None,
    factors: StatedFactors | None = None,
    gate: str = "stated",
    source: AdmissionPass | None = None,
    defer: bool = False,
) -> Admission:
    """Local search on the TLS objective: re-run the admission without one accepted loop.

    A false loop admitted early can fold the map so far that the true loops it
    contradicts sit at errors of ``1e6 c``: neither `refine_tls` nor a solve without the
    false loop leaves that basin (the map stays folded).  A trial bars one accepted
    loop and repeats the time-ordered admission of the winning run (on `decide`, the
    graph it decided on, with its `gate`) from `values`, then `refine_tls` on `graph`
    with the loop still barred.  Trials take the accepted loops in decreasing order of
    factor error at the solution of `best` (the false loop of a fold is the most
    strained): a trial that lowers `tls_cost` (stated covariances) is kept, its loop
    stays barred and the ranking is redone at the new solution; the search ends at the
    first trial that does not, or after `tries` (one extra admission run when there is
    nothing to fix).  A trial whose prefix folds (`AdmissionPass`) and whose decided
    part already costs more than `best` on the same part has failed, and stops there.
    `factors`: as in `tls_cost`.  `source`: the pass (made with ``record=True``) that
    gave `best`, on `decide` with `gate`: a trial resumes it from before the block that
    decides its barred loop (`AdmissionPass.resumed`), as is the next trial from a kept
    one, instead of deciding every block again.
    """
    solve = solver or StickySolver()
    factors = factors or graph.factor_graph(RobustKernel("none"))
    if unit is None:
        unit = [factors[0].at(k) for k in factors[1]]
    barred: list[int] = []
    done: set[int] = set()
    while len(done) < tries:
        errors = np.array([f.error(best.values) for f in unit])
        accepted = [int(k) for k in np.argsort(-errors) if best.weights[k] > 0.5
                    and int(k) not in done]
        if not accepted:
            break
        k = accepted[0]
        done.add(k)
        trial = [*barred, k]
        if source is not None and source.snapshots is not None:
            run = source.resumed(source.block_of(k), barred=trial)
        else:
            run = AdmissionPass(decide, values, probability=probability, block=block,
                                gate=gate, solver=solve, barred=trial,
                                prefix_solver=prefix_solver, unit=unit, defer=defer)
        if not _finish_unless_behind(run, best, factors, probability):
            break
        refined, weights = refine_tls(graph, run.current, run.weights,
                                      probability=probability, solver=solve, barred=trial,
                                      solved=decide is graph, factors=factors)
        cost = tls_cost(graph, refined, probability, factors)
        if not cost < best.tls_cost * (1.0 - 1e-9):
            break
        barred, source = trial, run
        best = Admission(refined, weights, cost, run.blocks, f"{_gate_of(best)}-barred")
    return best


def _gate_of(admission: Admission) -> str:
    """The innovation gate of an `incremental_tls` run from its label (``"calibrated"``,
    ``"stated-odometry-x10"``, ``"stated-barred"`` ...)."""
    return admission.gate.split("-")[0]


def _finish_unless_behind(
    run: AdmissionPass, best: Admission | None, factors: StatedFactors, probability: float
) -> bool:
    """Advance `run` to its end, unless, once its prefix has folded, its decided part
    costs more than `best` on the same part (`AdmissionPass.prefix_cost`, checked after
    every block); True when it finished.

    Why: a pass whose admitted loops folded its prefix goes on with damped batch solves
    (several times the cost of the iSAM2 updates), and the time-ordered pass's decisions
    are final, so a folded pass that trails the best finished run on the poses it has
    decided is not worth finishing."""
    if not run.folded:
        run.advance(until_fold=True)
    while not run.done:
        if best is not None and (run.prefix_cost(run.current, factors, probability)
                                 > run.prefix_cost(best.values, factors, probability)):
            return False
        run.advance(blocks=1)
    return True


def incremental_tls(
    graph: PoseGraph,
    values: gtsam.Values,
    *,
    probability: float = 0.99,
    block: int = 50,
    ladder: Sequence[float] = ODOMETRY_LADDER,
    tries: int = BAR_TRIES,
    prefix_solver: str = "auto",
    choose: Callable[..., int | tuple[int, Array | None]] | None = None,
    defer: str = "off",
) -> Admission:
    """TLS solution by time-ordered admission over an odometry ladder, then `refine_tls`.

    For every factor ``m`` of `ladder` the loops are *decided* by `admit_incrementally`
    on the graph whose odometry information is multiplied by ``m`` (both gates at
    ``m = 1``, the stated gate elsewhere: above 1 the calibrated gate's variance factor
    is mostly capped and it repeats the stated run), and the decisions are refined by
    `refine_tls` on the graph *as stated*; the run with the lowest stated `tls_cost`
    is returned (the module docstring's local search, over ``len(ladder) + 1`` starts;
    every rung is run, since the costs along the ladder need not be monotone).

    Why: the TLS objective under the stated covariances is the criterion, but deciding
    loops under odometry covariances that are far more pessimistic than the data
    lets early false loops bend the solved prefix onto themselves (step 2's gate is
    only as sharp as the prefix is stiff).  A rung ``m`` decides as if the odometry
    were ``m`` times more precise; the stated refinement re-admits every loop the
    stated model accepts at that solution (``e_k <= c``), so at 0% outliers every rung
    ends at the plain optimum and ties keep the first.  A run whose iSAM2 prefix folds
    (`AdmissionPass`) stops at the fold and is finished after the others only if the
    part it has decided is still cheaper than the best finished run's on the same
    part.  The best run is then improved by `bar_search` with `tries` trials (0: none),
    which repeats the winning run's graph and gate.

    `defer` (`DEFER_MODES`): ``"off"`` (the default) decides every loop in its own block;
    ``"all"``: every run defers the loops whose innovation test has no power and decides
    them by consensus (`slam.deferral`); ``"candidate"``: one more run, on the graph as
    stated with the stated gate, does (label ``"stated-deferred"``) and replaces the chosen
    run (`choose`, or the lowest stated cost) when it dominates it: a lower stated
    `tls_cost` with more loops admitted.  Off by default: ``"all"`` rejects true loops that
    have no consensus to wait for on a graph of few, far-apart loops, and ``"candidate"``
    lets false loops that lower the stated objective in.

    `choose`: picks the winner among the refined runs instead of the lowest stated cost,
    called as ``choose(graph, [(values, weights, stated cost), ...], probability=...,
    solver=..., unit=...)`` and returning an index, or -1 to keep the lowest stated cost
    (`slam.recheck.calibrated_choice`); or ``(index, weights)``, weights (or None) that
    replace the chosen run's loop decisions (`slam.offer_back.choose_and_offer_back`),
    the stated graph re-solved with them.
    """
    if not ladder:
        raise UserError("the odometry ladder needs at least one factor")
    if defer not in DEFER_MODES:
        raise UserError(f"unknown deferral {defer!r}; use {', '.join(DEFER_MODES)}")
    best: Admission | None = None
    decided: PoseGraph | None = None
    # Dogleg-QR from the start where the odometry needs QR (Intel: LM runs out its
    # iterations there without raising); elsewhere an LM that does not converge hands only
    # that solve to dogleg (M3500: one bad start made every later solve dogleg, 2-4x
    # slower).
    solver = StickySolver(lm_budget=LM_BUDGET, sticky=False)
    solver.dogleg = needs_qr(graph, values)
    stated = graph.factor_graph(RobustKernel("none"))  # built once for every run below
    base, loop_index = stated
    unit = [base.at(k) for k in loop_index]  # the loops' factors, the same on every rung
    runs = []
    for factor in ladder:
        decide = graph if factor == 1.0 else _odometry_scaled(graph, factor)
        for gate in GATES if factor == 1.0 else GATES[:1]:
            label = gate if factor == 1.0 else f"{gate}-odometry-x{factor:g}"
            if gate == "calibrated" and runs and runs[-1][1] is decide:
                # The same as the stated pass on this graph up to the first block in which
                # the calibrated gate admits less (`AdmissionPass.calibrated_step`).
                stated_run = runs[-1][2]
                step = stated_run.calibrated_step
                run = stated_run.resumed(stated_run._step if step is None else step,
                                         gate=gate)
            else:
                run = AdmissionPass(decide, values, probability=probability, block=block,
                                    gate=gate, solver=solver, prefix_solver=prefix_solver,
                                    unit=unit, record=tries > 0 or gate == "stated",
                                    defer=defer == "all")
            run.advance(until_fold=True)
            if run.done:
                run.release_prefix()
            runs.append((label, decide, run))
    if defer == "candidate":
        run = AdmissionPass(graph, values, probability=probability, block=block,
                            solver=solver, prefix_solver=prefix_solver, unit=unit,
                            record=True, defer=True)
        run.advance(until_fold=True)
        if run.done:
            run.release_prefix()
        runs.append(("stated-deferred", graph, run))
    # Finished runs first, then the folded ones in ladder order, each only if still ahead.
    finished: list[tuple[Admission, PoseGraph, AdmissionPass]] = []
    source: AdmissionPass | None = None
    for label, decide, run in sorted(runs, key=lambda r: not r[2].done):
        finishes = _finish_unless_behind(run, best, stated, probability)
        run.release_prefix()  # decided: the pass is never advanced again
        if not finishes:
            continue
        refined, weights = refine_tls(
            graph, run.current, run.weights, probability=probability, solver=solver,
            solved=decide is graph, factors=stated,
        )
        cost = tls_cost(graph, refined, probability, stated)
        finished.append((Admission(refined, weights, cost, run.blocks, label), decide, run))
        if best is None or cost < best.tls_cost * (1.0 - 1e-9):
            best, decided, source = finished[-1]
    assert best is not None and decided is not None
    if choose is not None and len(finished) > 1:
        pick = choose(graph, [(a.values, a.weights, a.tls_cost) for a, _, _ in finished],
                      probability=probability, solver=solver, unit=unit)
        pick, offered = pick if isinstance(pick, tuple) else (pick, None)
        if pick >= 0:
            best, decided, source = finished[pick]
        if pick >= 0 and offered is not None:
            kept = _with_loops(stated, offered)
            refined = solver(kept, best.values)
            best = Admission(refined, np.asarray(offered, dtype=float),
                             tls_cost(graph, refined, probability, stated), best.blocks,
                             f"{best.gate}-offered")
    for admission, graph_of, run in finished:
        # The deferred run dominates a choice that explains fewer loops at a higher cost.
        if (run.defer and admission.tls_cost < best.tls_cost
                and admission.weights.sum() > best.weights.sum()):
            best, decided, source = admission, graph_of, run
    if tries:
        best = bar_search(graph, decided, values, best, probability=probability, block=block,
                          tries=tries, solver=solver, prefix_solver=prefix_solver, unit=unit,
                          factors=stated, gate=_gate_of(best), source=source,
                          defer=source is not None and source.defer)
    # The winner may be an unpolished admission (refine_tls's `solved`): one batch solve
    # with its weights, by dogleg-QR, which stops closer to the optimum along M3500's flat
    # directions than LM at the same tolerance (0% outliers: 0.9 mm from the plain optimum
    # with LM).
    polished = polish(stated, best.weights, best.values, solver.max_iterations)
    return Admission(polished, best.weights, tls_cost(graph, polished, probability, stated),
                     best.blocks, best.gate)


def polish(
    factors: StatedFactors, weights: Array, values: gtsam.Values, max_iterations: int = 100
) -> gtsam.Values:
    """The stated graph `factors` with the loops of ``weights > 0.5`` solved from `values`
    by Powell's dogleg with multifrontal QR, until an iteration lowers the error by less
    than `POLISH_TOLERANCE` of it (relative decrease ``(E_old - E_new) / E_old``; no
    absolute criterion, so a graph whose error is small in gtsam units, as one with
    loosely stated information, is solved as far as one with a large error).

    Why so tight: along the flat directions of a loosely stated graph a solve that stops
    at ``1e-6``, or at gtsam's default absolute decrease of ``1e-5``, can end visibly
    short of the optimum (MITb with odometry information scaled by 0.01: decimetres).
    """
    kept = _with_loops(factors, weights)
    params = gtsam.DoglegParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(POLISH_TOLERANCE)
    params.setAbsoluteErrorTol(0.0)
    params.setLinearSolverType("MULTIFRONTAL_QR")
    return gtsam.DoglegOptimizer(kept, values, params).optimize()


def _with_loops(factors: StatedFactors, weights: Array) -> gtsam.NonlinearFactorGraph:
    """The stated graph `factors` with only the loops of ``weights > 0.5``."""
    base, loop_index = factors
    kept = gtsam.NonlinearFactorGraph()
    for k in range(base.size() - len(loop_index)):
        kept.add(base.at(k))
    for k in np.flatnonzero(np.asarray(weights) > 0.5):
        kept.add(base.at(loop_index[k]))
    return kept


def _odometry_scaled(graph: PoseGraph, factor: float) -> PoseGraph:
    """A copy of `graph` with every odometry information matrix multiplied by `factor`."""
    odometry = [Constraint(c.i, c.j, c.measurement, c.information * factor)
                for c in graph.odometry]
    return PoseGraph(graph.dim, dict(graph.initial), odometry, list(graph.loops),
                     set(graph.fixed))
