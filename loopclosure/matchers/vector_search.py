"""Float32 Euclidean nearest-neighbour search over fixed-length descriptors.

The cheap matchers (FFT amplitudes, ring-projection profiles) describe a polygon by
one short vector and compare vectors with the Euclidean distance; the place database
screens every keyframe with them.  This module is the one place that does that
arithmetic, for the matchers (`VectorStack`, `euclidean_distances`) and for the
database (`VectorStore`, a growing matrix, and `smallest_k`).

Arithmetic
----------
For a query q and rows x_i of a float32 matrix X with precomputed squared norms
n_i = ||x_i||^2,

    d_i^2 = n_i + ||q||^2 - 2 x_i . q

is one float32 matrix-vector product over the database (`_matvec`, single-threaded;
memory bound: one pass over X).  Its float32 rounding error is about
1e-7 (n_i + ||q||^2), which swamps d_i^2 when x_i is (nearly) q: entries with
d_i^2 <= 1e-4 (n_i + ||q||^2) are recomputed exactly in float64 from the
difference, so identical descriptors give exactly 0
and near-duplicates keep their order.  Distances are returned as float64, >= 0.

`VectorStore` additionally subtracts a fixed reference row (the first vector it
stores) from every row and every query: distances do not change, but the norms
become those of descriptor differences, so the cancellation above is small for all
entries, not only near-duplicates.

Units are those of the descriptors (metres for FFT amplitudes and ring arc lengths,
unitless when the matcher is scale invariant).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError

Array = NDArray[np.float64]
Array32 = NDArray[np.float32]

RECOMPUTE_REL = 1e-4
"""Relative threshold below which a squared distance is recomputed in float64."""


@dataclass(slots=True, frozen=True)
class VectorStack:
    """Many fixed-length descriptors packed for `euclidean_distances`.

    Attributes:
        matrix: ``(M, D)`` float32 rows, C-contiguous.
        sqnorms: ``(M,)`` float32 squared norms of the rows.
    """

    matrix: Array32
    sqnorms: Array32

    def __len__(self) -> int:
        return len(self.matrix)


def stack_vectors(rows: Sequence[ArrayLike], dim: int) -> VectorStack:
    """Stack ``D = dim``-long vectors into a `VectorStack` (an empty one for no rows)."""
    if len(rows) == 0:
        return VectorStack(np.zeros((0, dim), np.float32), np.zeros(0, np.float32))
    m = np.ascontiguousarray(np.stack([np.asarray(r, np.float32) for r in rows]), np.float32)
    if m.ndim != 2 or m.shape[1] != dim:
        raise UserError(f"stack_vectors: expected rows of length dim={dim}, got shape {m.shape}")
    return VectorStack(m, np.einsum("ij,ij->i", m, m))


def _matvec(matrix: Array32, vector: Array32, out: Array32 | None = None) -> Array32:
    """``matrix @ vector`` in float32 on the calling thread (`np.einsum`'s own loop).

    Not BLAS: a multithreaded BLAS matrix-vector product, memory bound anyway, ran an
    order of magnitude slower than this single-threaded loop on a loaded two-core
    machine, and a place query must not depend on idle cores.
    """
    if out is None:
        return np.einsum("ij,j->i", matrix, vector)
    return np.einsum("ij,j->i", matrix, vector, out=out)


def euclidean_distances(query: ArrayLike, matrix: Array32, sqnorms: Array32) -> Array:
    """``(M,)`` float64 Euclidean distances of `query` ``(D,)`` to every row of `matrix`.

    `matrix` is ``(M, D)`` float32 and `sqnorms` its float32 squared row norms
    (see the module docstring for the arithmetic and the exact recomputation of
    near-duplicates).
    """
    q = np.asarray(query, np.float32)
    qq = np.float32(q @ q)
    d2 = _matvec(matrix, (-2.0 * q).astype(np.float32))
    d2 += sqnorms
    d2 += qq
    near = np.flatnonzero(d2 <= RECOMPUTE_REL * (sqnorms + qq))
    if len(near):
        diff = matrix[near].astype(np.float64) - q.astype(np.float64)
        d2[near] = np.einsum("ij,ij->i", diff, diff)
    np.maximum(d2, 0.0, out=d2)
    return np.sqrt(d2, dtype=np.float64)


def stack_distances(query: ArrayLike, stacked: VectorStack) -> Array:
    """`euclidean_distances` of `query` against a `VectorStack` (any object with
    ``matrix`` and ``sqnorms``)."""
    return euclidean_distances(query, stacked.matrix, stacked.sqnorms)


def smallest_k(values: NDArray[np.floating], k: int) -> NDArray[np.intp]:
    """Indices of the `k` smallest `values`, in increasing order of value (ties by index).

    For a small k in a large array, a threshold from a strided sample of about 2,048
    values (its 9th smallest: about 9 M / 2,048 values lie below it) first cuts the
    array to a few hundred survivors with one comparison pass; when fewer than k
    survive (rare) or k is large, ``np.argpartition`` runs over everything (O(M)).
    Either way the result is exact; among values equal to the k-th, the lowest
    indices are taken.
    """
    v = np.asarray(values)
    m = len(v)
    if k <= 0 or m == 0:
        return np.zeros(0, np.intp)
    if k >= m:
        idx = np.arange(m)
    else:
        idx = None
        step = m // 2048
        if step >= 8 and k <= 2 * step:
            sample = v[::step].copy()
            thr = np.partition(sample, 8)[8]
            survivors = np.flatnonzero(v <= thr)
            if len(survivors) >= k:
                idx = survivors
        if idx is None:
            idx = np.arange(m)
        if len(idx) > k:
            sub = v[idx]
            kth = np.partition(sub, k - 1)[k - 1]
            below = idx[sub < kth]
            tied = idx[sub == kth][: k - len(below)]
            idx = np.concatenate([below, tied])
    return idx[np.lexsort((idx, v[idx]))]


class VectorStore:
    """A growing ``(M, D)`` float32 matrix with squared row norms (amortised doubling).

    Rows are stored relative to a fixed reference row (the first vector appended),
    which leaves Euclidean distances unchanged and keeps float32 cancellation small.
    Appending is O(D) amortised: the capacity doubles when full, rows are never
    re-stacked per insertion.
    """

    def __init__(self, dim: int, capacity: int = 64) -> None:
        if dim < 1:
            raise UserError(f"VectorStore: dim must be >= 1, got {dim}")
        self.dim = int(dim)
        self._rows = np.zeros((max(int(capacity), 1), self.dim), np.float32)
        self._sqnorms = np.zeros(len(self._rows), np.float32)
        self._size = 0
        self._ref: Array | None = None

    def __len__(self) -> int:
        return self._size

    @property
    def capacity(self) -> int:
        """Rows allocated (>= len)."""
        return len(self._rows)

    @property
    def reference(self) -> Array:
        """``(D,)`` float64 row subtracted from every stored row (zeros before the first)."""
        return np.zeros(self.dim) if self._ref is None else self._ref

    def _grow(self, needed: int) -> None:
        cap = self.capacity
        while cap < needed:
            cap *= 2
        rows = np.zeros((cap, self.dim), np.float32)
        rows[: self._size] = self._rows[: self._size]
        norms = np.zeros(cap, np.float32)
        norms[: self._size] = self._sqnorms[: self._size]
        self._rows, self._sqnorms = rows, norms

    def append(self, vector: ArrayLike) -> None:
        """Store one ``(D,)`` vector (finite values only)."""
        self.extend(np.asarray(vector, dtype=float)[None, :])

    def extend(self, vectors: ArrayLike) -> None:
        """Store ``(n, D)`` vectors at once."""
        v = np.asarray(vectors, dtype=float)
        if v.ndim != 2 or v.shape[1] != self.dim:
            raise UserError(
                f"VectorStore: expected vectors of length {self.dim}, got shape {v.shape}"
            )
        if not np.isfinite(v).all():
            raise UserError("VectorStore: descriptor vectors must be finite")
        if self._ref is None and len(v):
            self._ref = v[0].copy()
        n = len(v)
        if self._size + n > self.capacity:
            self._grow(self._size + n)
        rows = (v - self.reference).astype(np.float32)
        self._rows[self._size : self._size + n] = rows
        self._sqnorms[self._size : self._size + n] = np.einsum("ij,ij->i", rows, rows)
        self._size += n

    @property
    def matrix(self) -> Array32:
        """``(M, D)`` view of the stored rows (relative to `reference`)."""
        return self._rows[: self._size]

    @property
    def sqnorms(self) -> Array32:
        """``(M,)`` view of the squared norms of `matrix` rows."""
        return self._sqnorms[: self._size]

    def relative(self, query: ArrayLike) -> Array32:
        """The query expressed like the stored rows (minus `reference`), float32."""
        return (np.asarray(query, dtype=float) - self.reference).astype(np.float32)

    def distances(self, query: ArrayLike, rows: NDArray[np.intp] | None = None) -> Array:
        """``(M,)`` (or ``(len(rows),)``) float64 Euclidean distances of `query` to the rows.

        Float32 BLAS arithmetic with the exact recomputation of near-duplicates
        (`euclidean_distances`).
        """
        q = self.relative(query)
        if rows is None:
            return euclidean_distances(q, self.matrix, self.sqnorms)
        return euclidean_distances(q, self._rows[rows], self._sqnorms[rows])

    def fast_distances(self, query: ArrayLike, out: Array32 | None = None) -> Array32:
        """``(M,)`` float32 distances to every row, no recomputation (the screening pass).

        Five passes over M float32 values after the matrix-vector product; absolute
        error about 3e-4 times the norm of the rows relative to `reference` (rows are
        stored relative to it, so this is the scale of descriptor differences).  `out`
        (float32, at least M long) avoids allocating fresh pages on every query.
        """
        q = self.relative(query)
        m = self._size
        d2 = np.empty(m, np.float32) if out is None else out[:m]
        _matvec(self.matrix, -2.0 * q, out=d2)
        d2 += self.sqnorms
        d2 += np.float32(q @ q)
        np.maximum(d2, 0.0, out=d2)
        return np.sqrt(d2, out=d2)

    def set_distances(self, queries: ArrayLike, rows: NDArray[np.intp]) -> Array:
        """``(A, len(rows))`` float64 Euclidean distances of A queries ``(A, D)`` to the
        stored rows `rows`: the float32 rows and the queries rounded like them
        (`relative`), then ``|x|^2 - 2 x.q + |q|^2`` in float64, the rows gathered once
        for all queries (a few rows asked by several query vectors; one
        matrix-vector `np.einsum` per query, as `_matvec`: a BLAS matrix product's
        threads cost more than they save on so small a product).  Absolute error
        about 1e-8 times the norm of the rows relative to `reference` (a stored
        vector is at distance below that, not exactly 0: `exact_distances` is)."""
        q = self.relative(np.atleast_2d(np.asarray(queries, float))).astype(np.float64)
        x = self._rows[np.asarray(rows, np.intp)].astype(np.float64)
        d2 = np.empty((len(q), len(x)))
        for a, qa in enumerate(q):  # per query vector (a few), not per row
            np.einsum("ij,j->i", x, -2.0 * qa, out=d2[a])
        d2 += np.einsum("ij,ij->i", x, x)[None, :]
        d2 += np.einsum("ij,ij->i", q, q)[:, None]
        np.maximum(d2, 0.0, out=d2)
        return np.sqrt(d2, out=d2)

    def exact_distances(self, query: ArrayLike, rows: NDArray[np.intp] | None = None) -> Array:
        """Float64 distances of `query` to the stored (float32) rows, from their differences.

        The query is rounded like a stored row first, so a stored vector is at distance 0.
        """
        q = self.relative(query).astype(np.float64)
        x = self.matrix if rows is None else self._rows[rows]
        diff = x.astype(np.float64)
        diff -= q
        return np.sqrt(np.einsum("ij,ij->i", diff, diff))

    def row(self, index: int) -> Array:
        """Stored vector `index` in its original coordinates (float64)."""
        if not 0 <= index < self._size:
            raise IndexError(index)
        return self._rows[index].astype(float) + self.reference
