"""Compiled kernels of `slam.selected_inverse` (numba, ``cache=True``: compiled once per
machine).

`sparse_block_solves` solves ``T X = [e_s1 ... e_sd]`` for a lower-triangular ``T`` (CSC in
any order of rows within a column; its diagonal given apart) and many blocks of ``d`` start
columns (a pose's ``d`` coordinates), visiting only the columns the solution reaches;
`sparse_block_dots` forms the ``d x d`` products ``Y_a^T X_b`` of two such solutions.
Units are those of the matrix entries.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
Index = NDArray[np.int64]


@numba.njit(cache=True)
def _reach_counts(indptr: Index, indices: Index, starts: Index, n: int) -> Index:
    """Number of rows reached from the start columns ``starts[t]`` (t's block), the union
    over the block's columns: the non-zero rows of ``T^-1 [e_s1 ... e_sd]``."""
    mark = np.full(n, -1, np.int64)
    counts = np.zeros(starts.shape[0], np.int64)
    for t in range(starts.shape[0]):
        first = n
        for c in range(starts.shape[1]):
            mark[starts[t, c]] = t
            first = min(first, starts[t, c])
        count = 0
        for k in range(first, n):
            if mark[k] != t:
                continue
            count += 1
            for e in range(indptr[k], indptr[k + 1]):
                if indices[e] > k:
                    mark[indices[e]] = t
        counts[t] = count
    return counts


@numba.njit(cache=True)
def _solves(
    indptr: Index, indices: Index, data: Array, diag: Array, starts: Index, n: int,
    ptr: Index,
) -> tuple[Index, Array]:
    """Rows (increasing) and values (rows, d) of ``T^-1 [e_s1 ... e_sd]`` of every block
    ``t``, at ``ptr[t]:ptr[t + 1]``: forward substitution column by column,
    ``x_k /= T_kk``, then ``x_i -= T_ik x_k`` for the rows ``i > k`` of column ``k``."""
    d = starts.shape[1]
    idx = np.empty(ptr[-1], np.int64)
    val = np.empty((ptr[-1], d), np.float64)
    x = np.zeros((n, d))
    mark = np.full(n, -1, np.int64)
    for t in range(starts.shape[0]):
        first = n
        for c in range(d):
            s = starts[t, c]
            mark[s] = t
            x[s, c] = 1.0
            first = min(first, s)
        o = ptr[t]
        for k in range(first, n):
            if mark[k] != t:
                continue
            pivot = diag[k]
            idx[o] = k
            for c in range(d):
                val[o, c] = x[k, c] / pivot
                x[k, c] = 0.0
            for e in range(indptr[k], indptr[k + 1]):
                i = indices[e]
                if i <= k:
                    continue
                mark[i] = t
                v = data[e]
                for c in range(d):
                    x[i, c] -= v * val[o, c]
            o += 1
    return idx, val


def sparse_block_solves(
    indptr: Index, indices: Index, data: Array, diag: Array, starts: Index, n: int
) -> tuple[Index, Index, Array]:
    """``T^-1 [e_s1 ... e_sd]`` for every row ``(s1 ... sd)`` of `starts` (P, d), ``T``
    lower triangular (n, n) in CSC (`indptr`, `indices`, `data`: entries above the
    diagonal and the diagonal itself are skipped) with diagonal `diag`: compressed
    blocks ``(ptr, idx, val)``, block ``t`` at ``ptr[t]:ptr[t + 1]`` with increasing rows
    ``idx`` and values ``val`` (rows, d)."""
    starts = np.ascontiguousarray(starts, dtype=np.int64)
    counts = _reach_counts(indptr, indices, starts, n)
    ptr = np.zeros(len(starts) + 1, np.int64)
    np.cumsum(counts, out=ptr[1:])
    idx, val = _solves(indptr, indices, data, diag, starts, n, ptr)
    return ptr, idx, val


@numba.njit(cache=True)
def sparse_block_dots(
    aptr: Index, aidx: Index, aval: Array, bptr: Index, bidx: Index, bval: Array,
    ia: Index, ib: Index,
) -> Array:
    """``A_{ia[t]}^T B_{ib[t]}`` (d, d) for every ``t``, of compressed blocks with
    increasing rows (`sparse_block_solves`): a merge of the two row lists."""
    d = aval.shape[1]
    out = np.zeros((len(ia), d, d))
    for t in range(len(ia)):
        i, i_end = aptr[ia[t]], aptr[ia[t] + 1]
        j, j_end = bptr[ib[t]], bptr[ib[t] + 1]
        while i < i_end and j < j_end:
            ri, rj = aidx[i], bidx[j]
            if ri == rj:
                for r in range(d):
                    a = aval[i, r]
                    for c in range(d):
                        out[t, r, c] += a * bval[j, c]
                i += 1
                j += 1
            elif ri < rj:
                i += 1
            else:
                j += 1
    return out
