"""The innovation test: first-order cost of adding loops to a solved pose graph.

Adding loop ``k`` (whitened Jacobian ``B``, whitened residual ``b`` at the solution ``x*``
of the accepted graph, whose information is ``H = A^T A`` over the poses' tangent
coordinates) raises the least-squares cost, to first order, by the innovation (Schur
complement) form (gtsam error units, ``e = 0.5 r^T I r``)::

    delta_k = 0.5 b^T (I + M)^-1 b,     M = B H^-1 B^T

the individual-compatibility test of Neira & Tardos (IEEE T-RA 2001).  `greedy_admission`
admits candidates smallest ``delta`` first while ``delta`` is below a gate, updating the
others' ``b``, ``M`` and ``H^-1 B^T`` after each admission by the rank-``dof``
(Sherman-Morrison-Woodbury) update of ``H^-1``, so that two loops that contradict each
other are never both admitted on the strength of the same slack.

``H`` is factorised once per test (`InnovationTest`: sparse LU of the whitened normal
equations, `slam.least_squares.factor_information`).  ``M`` alone needs only the marginal
covariance blocks of each loop's two poses, ``M = B_i S_ii B_i^T + B_i S_ij B_j^T +
B_j S_ji B_i^T + B_j S_jj B_j^T`` with ``S = H^-1``, taken from selected entries of the
inverse (`slam.selected_inverse`); the Woodbury updates need ``H^-1 B^T`` on every row
some candidate touches, ``S_ai B_i^T + S_aj B_j^T`` on the rows of each touched pose ``a``:
from the blocks of every pair of touched poses while they are few, else solved in full
(`solve_columns`).

`tls_threshold` is the cost ``c`` of a rejected loop under the truncated-least-squares
loss (`slam.consistency`): admitting ``k`` lowers that objective iff ``delta_k < c``.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.linalg import SuperLU

from slam.least_squares import factor_information
from slam.pose_graph import chi2_quantile, pose_dof
from slam.selected_inverse import SelectedInverse

Array = NDArray[np.float64]
SOLVE_WIDTH = 6  # right-hand sides per SuperLU solve (`solve_columns`)
# `InnovationTest.blocks` from selected entries of H^-1 (`slam.selected_inverse`); False:
# from full solves of H^-1 B^T (the same numbers to rounding; `benchmarks/recheck_speed.py`).
SELECTED_INVERSE = True
# `InnovationTest.gains` reads ``H^-1 B^T`` from selected entries of H^-1 when the
# candidates touch more poses than the first number and at most the second (one sparse
# product per pair of them); outside, full solves (`solve_columns`) cost less.
SELECTED_GAINS_POSES = (16, 128)


def tls_threshold(dim: int, probability: float = 0.99) -> float:
    """TLS cost ``c`` of a rejected loop: 0.5 * chi2 quantile of its dof (3 in 2D, 6 in 3D)."""
    return 0.5 * chi2_quantile(probability, pose_dof(dim))


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
        ``H^-1 B^T`` rows, which take (m, r, d) memory.  ``M`` from the marginal covariance
        blocks of each candidate's two poses (`_gram`), or, with `SELECTED_INVERSE` False,
        from full solves of ``H^-1 B^T``, `SOLVE_WIDTH` columns per solve."""
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

    def _selected_columns(
        self, bi: Array, bj: Array, pi: NDArray[np.int64], pj: NDArray[np.int64],
        poses: NDArray[np.int64],
    ) -> Array:
        """``Y_q = H^-1 B_q^T`` (m, r, d) on the r rows of the touched `poses` (first rows in
        ``H``, ascending; ``pi``, ``pj``: each candidate's rows among them) from the
        marginal covariance blocks ``S_ab`` of every pair of touched poses (selected
        entries of ``H^-1``, `slam.selected_inverse`)::

            Y_q[a] = S_{a i} B_i^T + S_{a j} B_j^T     (rows of pose a, i and j the
                                                        candidate's two poses)
        """
        d, t = self.dof, len(poses)
        a, b = np.triu_indices(t)
        blocks = self.selected.blocks(poses[a], poses[b], d)  # (K, d, d)
        s = np.empty((t, t, d, d))
        s[a, b] = blocks
        s[b, a] = blocks.transpose(0, 2, 1)
        full = s.transpose(0, 2, 1, 3).reshape(t * d, t * d)  # S on the touched rows
        return np.einsum("rmc,mac->mra", full[:, pi], bi) + np.einsum(
            "rmc,mac->mra", full[:, pj], bj)

    def gains(self, candidates: Sequence[gtsam.NonlinearFactor]) -> _Gains:
        """Linearise `candidates` (binary factors on poses of `keys`) at the solution."""
        d, m = self.dof, len(candidates)
        b, bi, bj, ci, cj = self._linearised(candidates)
        span = np.arange(d)
        ri, rj = ci[:, None] + span, cj[:, None] + span  # (m, d) rows of H
        touched, where = np.unique(np.concatenate([ri, rj], axis=1), return_inverse=True)
        where = where.reshape(m, 2 * d)
        pi, pj = where[:, :d], where[:, d:]
        poses = touched[::d]  # first rows of the touched poses, ascending
        if SELECTED_INVERSE and SELECTED_GAINS_POSES[0] < len(poses) <= SELECTED_GAINS_POSES[1]:
            y = self._selected_columns(bi, bj, pi, pj, poses)
        else:
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


def removal_costs(b: Array, gram: Array) -> Array:
    """Linearised leave-one-out cost of factors already in a solved graph (gtsam error
    units): for factor ``q`` with whitened residual ``b_q`` (d,) and ``M_q = B_q H^-1 B_q^T``
    (d, d) at the optimum ``x*`` of a graph whose information ``H`` includes ``q``
    (`InnovationTest.blocks` of the graph with ``q``), the drop of the graph's minimum
    when ``q`` is taken out, by the Gauss-Newton model of the cost at ``x*``::

        rho_q = 0.5 b_q^T (I - M_q)^-1 b_q

    the downdate form of the innovation ``delta`` (module docstring): on a linear
    problem ``rho_q`` equals ``q``'s ``delta`` against the graph without it, bit for
    rounding.  ``I - M_q`` is positive definite when the other factors alone constrain
    ``q``'s relative pose; where it is not (``q`` is all that fixes it, or rounding),
    ``rho_q`` is ``inf``.  Shapes (m, d) and (m, d, d); returns (m,)."""
    m, d = b.shape
    eye = np.eye(d)
    rest = eye - gram
    out = np.full(m, np.inf)
    ok = np.linalg.eigvalsh(0.5 * (rest + rest.transpose(0, 2, 1)))[:, 0] > 1e-9
    if ok.any():
        x = np.linalg.solve(rest[ok], b[ok][..., None])[..., 0]
        out[ok] = 0.5 * np.einsum("ma,ma->m", b[ok], x)
    return out


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
