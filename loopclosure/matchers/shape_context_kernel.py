"""Compiled shape-context matching: exact chi^2 costs and the assignment as numba loops.

`shape_context.ShapeContextMatcher` with ``kernel="numba"`` compares descriptors here
instead of with the float32 factor product and scipy.  Per pair of shapes a, b with
point-count histograms ``A_ik``, ``B_jk`` (n points, bins k; h = A / (n - 1)):

- chi^2 cost (Belongie's eq. 1), exactly, in float64::

      C_ij = 1/2 sum_k (h_ik - g_jk)^2 / (h_ik + g_jk)
           = (1/2 (S_i + T_j) - 2 sum_k F(A_ik, B_jk)) / (n - 1)

  with the row sums ``S_i = sum_k A_ik``, ``T_j = sum_k B_jk`` [counts] and the table
  ``F(a, b) = a b / (a + b)`` (0 when a + b = 0), which is 0 unless both counts are
  positive: the sum runs over the bins where row i of a is non-zero only (a shape
  context has at most n - 1 non-zero bins of ``n_radial * n_angular``);
- the optimal one-to-one assignment ``min_pi sum_i C_{i, pi(i)}`` by the Hungarian
  method with row and column potentials (Kuhn-Munkres, shortest augmenting paths,
  O(n^3)): the same optimum as `scipy.optimize.linear_sum_assignment` (an exact
  solver too), so the distance agrees with scipy's to rounding; only which of several
  equally cheap assignments is chosen may differ;
- dummy rows and columns as in `shape_context` (cost ``dummy_cost`` against real
  points, 0 among themselves).

The costs are symmetric, ``C(a, b) = C(b, a)^T`` bit for bit (the same terms in the
same order), so `all_pairs` solves each unordered pair once and mirrors it.

numba is imported with this module, which `shape_context` loads on the first
``kernel="numba"`` matcher; kernels are cached on disk (``cache=True``).
"""

from __future__ import annotations

import numba
import numpy as np


def harmonic_table(max_count: int) -> np.ndarray:
    """``F(a, b) = a b / (a + b)`` for counts 0..max_count, 0 where a + b = 0 (float64)."""
    c = np.arange(max_count + 1, dtype=float)
    s = c[:, None] + c[None, :]
    return np.divide(c[:, None] * c[None, :], s, out=np.zeros_like(s), where=s > 0)


@numba.njit(cache=True)
def _costs(a, b_t, sa, sb, table, out):
    """chi^2 costs ``out[i, j]`` of histograms `a` (n, K) against `b_t` (K, n) (module
    docstring); `sa`, `sb` the row sums [counts]."""
    n, n_bins = a.shape
    m = b_t.shape[1]
    scale = 1.0 / (n - 1)
    for i in range(n):
        for j in range(m):
            out[i, j] = 0.0
        for k in range(n_bins):
            ca = a[i, k]
            if ca == 0:
                continue
            row = table[ca]
            bk = b_t[k]
            for j in range(m):
                out[i, j] += row[bk[j]]
        for j in range(m):
            c = (0.5 * (sa[i] + sb[j]) - 2.0 * out[i, j]) * scale
            out[i, j] = c if c > 0.0 else 0.0


@numba.njit(cache=True, fastmath={"nnan", "nsz"})
def _least(key, n):
    """``min(key[1..n])`` (exact: a minimum rounds nothing; no NaN here, and the sign
    of a zero minimum, which the flags leave open, changes no comparison)."""
    d = np.inf
    for j in range(1, n + 1):
        x = key[j]
        d = x if x < d else d
    return d


@numba.njit(cache=True)
def _hungarian(c, u, v, p, way, minv, used, visited, key, row):
    """Sum of matched costs of the optimal assignment of the square matrix `c`.

    Kuhn-Munkres with potentials ``u`` (rows), ``v`` (columns), kept feasible
    (``c_ij - u_i - v_j >= 0``, 0 on matched pairs).  Start: row reduction
    ``u_i = min_j c_ij``, column reduction ``v_j = min_i (c_ij - u_i)``, and the pairs
    of zero reduced cost matched greedily (row order, lowest free column); then each
    row left free is added by a shortest augmenting path in the reduced costs (the
    potentials stay feasible, so the result is optimal); each step of the path search
    moves to the lowest-numbered column of least ``minv`` off the tree.  Work arrays
    have length ``len(c) + 1`` (index 0 is the virtual start column).

    Each step runs over all columns without branches (columns on the tree keep their
    ``minv`` and get key infinity; the loops vectorise), defers the ``minv -= delta``
    of the columns off the tree to the next step, and updates the potentials of the
    columns on the tree only: every number goes through the same floating-point
    operations in the same order as in the textbook loop (which the first
    implementation was; ``tests/test_shape_context_kernel.py``), so the assignment
    chosen among equally cheap ones, and hence the sum, are the same to the bit.
    """
    n = c.shape[0]
    for j in range(n + 1):
        p[j] = 0
        way[j] = 0
    u[0] = 0.0
    v[0] = 0.0
    for i in range(1, n + 1):
        best = np.inf
        for j in range(n):
            if c[i - 1, j] < best:
                best = c[i - 1, j]
        u[i] = best
    for j in range(1, n + 1):
        best = np.inf
        for i in range(1, n + 1):
            r = c[i - 1, j - 1] - u[i]
            if r < best:
                best = r
        v[j] = best
    for i in range(1, n + 1):
        for j in range(1, n + 1):
            if p[j] == 0 and c[i - 1, j - 1] - u[i] - v[j] <= 0.0:
                p[j] = i
                used[i] = True  # row i matched (reset below)
                break
        else:
            used[i] = False
    free = np.empty(n, np.int64)
    n_free = 0
    for i in range(1, n + 1):
        if not used[i]:
            free[n_free] = i
            n_free += 1
    for f in range(n_free):
        p[0] = free[f]
        for j in range(n + 1):
            minv[j] = np.inf
            used[j] = False  # column j on the tree
        n_visited = 0
        j0 = 0
        delta = 0.0
        while True:
            used[j0] = True
            visited[n_visited] = j0
            n_visited += 1
            i0 = p[j0]
            ui = u[i0]
            previous = delta  # the last step's delta, not yet taken off minv
            row[1:] = c[i0 - 1]
            for j in range(1, n + 1):
                m = minv[j] - previous
                cur = row[j] - ui - v[j]
                off = not used[j]
                better = off and cur < m
                way[j] = j0 if better else way[j]
                m = cur if better else m
                minv[j] = m if off else minv[j]
                key[j] = m if off else np.inf
            delta = _least(key, n)
            j1 = 0
            for j in range(1, n + 1):
                if key[j] == delta:
                    j1 = j
                    break
            for k in range(n_visited):
                j = visited[k]
                u[p[j]] += delta
                v[j] -= delta
            j0 = j1
            if p[j0] == 0:
                break
        while True:
            j1 = way[j0]
            p[j0] = p[j1]
            j0 = j1
            if j0 == 0:
                break
    total = 0.0
    for j in range(1, n + 1):
        total += c[p[j] - 1, j - 1]
    return total


@numba.njit(cache=True)
def assignment_cost(c):
    """Sum of matched costs of the optimal assignment of the square float64 matrix `c`."""
    n = c.shape[0]
    return _hungarian(c, np.zeros(n + 1), np.zeros(n + 1), np.zeros(n + 1, np.int64),
                      np.zeros(n + 1, np.int64), np.zeros(n + 1), np.zeros(n + 1, np.bool_),
                      np.zeros(n + 1, np.int64), np.zeros(n + 1), np.zeros(n + 1))


@numba.njit(cache=True)
def _pair(a, b_t, sa, sb, table, n_dummy, dummy_cost, full, u, v, p, way, minv, used,
          visited, key, row):
    """Mean matched chi^2 cost of one pair; `full` is the (n + n_dummy)^2 work matrix."""
    n = a.shape[0]
    _costs(a, b_t, sa, sb, table, full[:n, :n])
    for i in range(n, n + n_dummy):
        for j in range(n + n_dummy):
            full[i, j] = 0.0 if j >= n else dummy_cost
            full[j, i] = 0.0 if j >= n else dummy_cost
    d = _hungarian(full, u, v, p, way, minv, used, visited, key, row) / n
    return d if d > 0.0 else 0.0


@numba.njit(cache=True)
def _workspace(size):
    """`_pair`'s work arrays for shapes of ``size`` points with their dummies: the
    ``(size, size)`` cost matrix `full` and `_hungarian`'s ``u, v, p, way, minv, used,
    visited, key, row`` (length ``size + 1``; ``p, way, visited`` int64, ``used``
    bool, the rest float64), uninitialised (`_pair` and `_hungarian` set them)."""
    return (np.empty((size, size)), np.empty(size + 1), np.empty(size + 1),
            np.empty(size + 1, np.int64), np.empty(size + 1, np.int64), np.empty(size + 1),
            np.empty(size + 1, np.bool_), np.empty(size + 1, np.int64), np.empty(size + 1),
            np.empty(size + 1))


@numba.njit(cache=True)
def chi2_costs(query, db, table):
    """``(M, n, n)`` exact chi^2 costs of `query` (n, K) against each of `db` (M, n, K)."""
    m, n = db.shape[0], db.shape[1]
    sa = query.sum(axis=1).astype(np.float64)
    out = np.empty((m, n, n))
    for e in range(m):
        b_t = np.ascontiguousarray(db[e].T)
        _costs(query, b_t, sa, db[e].sum(axis=1).astype(np.float64), table, out[e])
    return out


@numba.njit(cache=True)
def distances(query, db, table, n_dummy, dummy_cost):
    """``(M,)`` mean matched costs of `query` (n, K) against each of `db` (M, n, K)."""
    m, n = db.shape[0], db.shape[1]
    full, u, v, p, way, minv, used, visited, key, row = _workspace(n + n_dummy)
    sa = query.sum(axis=1).astype(np.float64)
    out = np.empty(m)
    for e in range(m):
        b_t = np.ascontiguousarray(db[e].T)
        sb = db[e].sum(axis=1).astype(np.float64)
        out[e] = _pair(query, b_t, sa, sb, table, n_dummy, dummy_cost, full,
                       u, v, p, way, minv, used, visited, key, row)
    return out


@numba.njit(cache=True)
def all_pairs(db, table, n_dummy, dummy_cost):
    """``(M, M)`` symmetric distance matrix of `db` (M, n, K): each unordered pair once."""
    m, n, n_bins = db.shape
    full, u, v, p, way, minv, used, visited, key, row = _workspace(n + n_dummy)
    sums = np.empty((m, n))
    b_t = np.empty((m, n_bins, n), db.dtype)
    for e in range(m):
        sums[e] = db[e].sum(axis=1).astype(np.float64)
        b_t[e] = db[e].T
    out = np.zeros((m, m))
    for i in range(m):
        for j in range(i + 1, m):
            d = _pair(db[i], b_t[j], sums[i], sums[j], table, n_dummy, dummy_cost, full,
                      u, v, p, way, minv, used, visited, key, row)
            out[i, j] = d
            out[j, i] = d
        out[i, i] = _pair(db[i], b_t[i], sums[i], sums[i], table, n_dummy, dummy_cost,
                          full, u, v, p, way, minv, used, visited, key, row)
    return out
