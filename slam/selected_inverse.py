"""Selected entries of the inverse of a sparse matrix from its LU factors.

SuperLU factorises ``Pr H Pc = L U`` (``L`` unit lower triangular, ``U`` upper
triangular, ``Pr`` and ``Pc`` the row and column permutations of `SuperLU.perm_r` and
`SuperLU.perm_c`).  Hence ``H^-1 = Pc U^-1 L^-1 Pr`` and one entry of the inverse is::

    (H^-1)_ab = (U^-T e_p)^T (L^-1 e_q),     p = perm_c[a],  q = perm_r[b]

(the same operators as a full solve ``H^-1 e_b`` read at row ``a``).  Both vectors are
sparse: ``L^-1 e_q`` is non-zero only on the rows that column ``q`` reaches in the graph of
``L`` (on a factor of a symmetric matrix, the path from ``q`` to the root of the
elimination tree), and likewise ``U^-T e_p``.  A marginal covariance block of a few poses
therefore costs the columns of ``L`` and ``U`` on those paths, on a pose graph a small
part of the two full triangular solves per column that ``SuperLU.solve`` makes.  A
request of ``d x d`` blocks solves the ``d`` columns of each distinct pose once (one
reach for the ``d`` of them), then forms one sparse product ``Y_a^T X_b`` per distinct
pair of poses.  For a symmetric ``H`` factorised with one permutation,
``U = D L^T`` (``D`` the diagonal of ``U``), so ``U^-T e_p = D^-1 L^-1 e_p``: one solve by
``L`` serves both sides, and each unordered pair is formed once (``S_ba = S_ab^T``).

The triangular solves and dot products are compiled kernels
(`slam.selected_inverse_kernel`, numba, imported on first use).

Units: those of ``H^-1``; for the information matrix of a whitened pose graph, the
covariance in tangent coordinates (m^2, m rad, rad^2 in 2D).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import sparray, spmatrix
from scipy.sparse.linalg import SuperLU

Array = NDArray[np.float64]
Index = NDArray[np.int64]
Triangle = tuple[Index, Index, Array, Array]  # CSC indptr, indices, data; the diagonal


class SelectedInverse:
    """Entries of ``H^-1`` for a matrix ``H`` factorised by SuperLU (module docstring).

    `lu`: the factorisation (`slam.least_squares.factor_information`, or any `splu`).
    `symmetric`: ``H`` is symmetric; when the LU kept one permutation for rows and
    columns (``perm_r == perm_c``: no off-diagonal pivot), ``U = D L^T`` (``D`` the
    diagonal of ``U``) and ``U^-T e_p = D^-1 L^-1 e_p``, so only ``L`` is solved.
    """

    def __init__(self, lu: SuperLU, symmetric: bool = False) -> None:
        upper = lu.U
        self._lower = _triangle(lu.L)
        self.n = len(self._lower[3])
        self._perm_r = np.asarray(lu.perm_r, dtype=np.int64)
        self._perm_c = np.asarray(lu.perm_c, dtype=np.int64)
        self._pivots: Array | None = None
        self._upper_t: Triangle | None = None
        if symmetric and np.array_equal(self._perm_r, self._perm_c):
            self._pivots = np.asarray(upper.diagonal(), dtype=np.float64)
        else:
            self._upper_t = _triangle(upper.T)  # U^T: lower triangular, column k = row k of U

    def entries(self, rows: Index, cols: Index) -> Array:
        """``(H^-1)[rows[t], cols[t]]`` for every ``t`` (original, unpermuted indices)."""
        return self.blocks(rows, cols, 1)[:, 0, 0]

    def blocks(self, a: Index, b: Index, d: int) -> Array:
        """The (K, d, d) blocks ``H^-1[a_t : a_t + d, b_t : b_t + d]`` for the first indices
        `a`, `b` (K,) of pairs of variables (e.g. the tangent coordinates of two poses:
        their cross-covariance).  One sparse solve of ``d`` columns per distinct first
        index of `a` (by ``U^T``) and of `b` (by ``L``), one sparse product per distinct
        pair (of the two orders of a pair, once, when ``H`` is `symmetric`)."""
        a, b = np.asarray(a, dtype=np.int64), np.asarray(b, dtype=np.int64)
        if not len(a):
            return np.zeros((0, d, d))
        if self._pivots is not None:  # H^-1 symmetric: block (b, a) is block (a, b)^T
            swap = a > b
            out = self._blocks(np.where(swap, b, a), np.where(swap, a, b), d)
            out[swap] = out[swap].transpose(0, 2, 1)
            return out
        return self._blocks(a, b, d)

    def _blocks(self, a: Index, b: Index, d: int) -> Array:
        """`blocks`, every pair as asked."""
        from slam.selected_inverse_kernel import sparse_block_dots, sparse_block_solves

        pairs, where = np.unique(a * self.n + b, return_inverse=True)
        rows, ia = np.unique(pairs // self.n, return_inverse=True)
        cols, ib = np.unique(pairs % self.n, return_inverse=True)
        span = np.arange(d)
        if self._pivots is None:
            y = sparse_block_solves(*self._upper_t, self._perm_c[rows[:, None] + span], self.n)
            x = sparse_block_solves(*self._lower, self._perm_r[cols[:, None] + span], self.n)
        else:  # U^-T e_p = D^-1 L^-1 e_p: one solve per pose of either side
            both, where_both = np.unique(np.concatenate([rows, cols]), return_inverse=True)
            ia, ib = where_both[ia], where_both[len(rows) + ib]
            x = sparse_block_solves(*self._lower, self._perm_r[both[:, None] + span], self.n)
            y = (x[0], x[1], x[2] / self._pivots[x[1], None])
        values = sparse_block_dots(*y, *x, ia.astype(np.int64), ib.astype(np.int64))
        return values[where.reshape(-1)]


def _triangle(matrix: sparray | spmatrix) -> Triangle:
    """A triangular factor as the kernels take it: CSC arrays (rows within a column in any
    order) and its diagonal."""
    csc = matrix.tocsc()
    return (csc.indptr.astype(np.int64), csc.indices.astype(np.int64),
            csc.data.astype(np.float64), np.asarray(csc.diagonal(), dtype=np.float64))
