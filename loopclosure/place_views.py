"""A place database's extra prefilter vectors: stored keyframes described from offset
viewpoints (`loopclosure.viewpoints`), the distance to a keyframe the smallest over
its viewpoints.

A stored keyframe's descriptors may carry, under `VIEWPOINTS`, the prefilter vectors
of V further descriptions of its place ``{stage: (V, D) array}`` (its submap seen
from beside it).  The database keeps them here, one row per viewpoint, rows of one
keyframe contiguous and in insertion order of the keyframes (`ViewpointRows`).  The
combined prefilter distance of a query q to stored keyframe j becomes

    p(j) = min( p_own(j), min_v p_v(j) ),   p_v(j) = sum_s w_s d_s(q, v) / scale_s

(`loopclosure.place_database`, step 1; the scales and weights are the database's).
The query keeps its single description, unless `PlaceDatabaseConfig.query_viewpoints`
(a query that carries its own viewpoints, as a stored keyframe asking with its
stored descriptors does): then p(j) is the smallest over every pair of a query
description and a stored one, so two viewpoints of radius r cover revisits up to
2 r apart.  A keyframe's stage distances are those
of its viewpoint of smallest p; the fused score sees them only with
`PlaceDatabaseConfig.viewpoint_scores` (by default it sees the distances of the own
descriptions, the feature its logistic model was fitted on: a minimum over several
descriptions is smaller for wrong places too, and would raise their scores).

Screening (`ViewpointRows.screen`): one float32 pass per stage over all viewpoint
rows (a matrix-vector product; with the query's viewpoints, one matrix product with
all its vector sets, `stacked_distances`), the minimum over the query's sets, then
the minimum per keyframe by one `np.minimum.reduceat` over the contiguous runs: no
Python loop over keyframes.  The cost grows with the number of viewpoint rows
(about V times the keyframes').
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError
from loopclosure.matchers.vector_search import VectorStore
from loopclosure.place_rows import FloatRows

Array = NDArray[np.float64]
VIEWPOINTS = "viewpoints"
"""Descriptor key of a keyframe's offset viewpoints: ``{stage: (V, D) array}``."""


def prefilter_vector(descriptor: Any) -> ArrayLike:
    """The Euclidean vector of a prefilter stage's descriptor (an `FFTDescriptor`'s
    amplitudes, a ring profile, or an already extracted vector)."""
    return getattr(descriptor, "amplitudes", descriptor)


class ViewpointRows:
    """Offset viewpoints' prefilter vectors of every stored keyframe (module docstring)."""

    def __init__(self, stages: tuple[str, ...]) -> None:
        self.stages = tuple(stages)
        self._stores: dict[str, VectorStore] = {}
        self._span = FloatRows(2, dtype=np.int64)  # per keyframe row: first view row, count
        self._size = 0

    def __len__(self) -> int:
        """Viewpoint rows stored (all keyframes together)."""
        return self._size

    def append(self, vectors: Mapping[str, ArrayLike] | None) -> None:
        """The viewpoints of the next keyframe row (None or V = 0: none)."""
        n = 0
        if vectors is not None:
            arrays = {s: np.asarray(vectors[s], float) for s in self.stages if s in vectors}
            missing = [s for s in self.stages if s not in arrays]
            sizes = {a.shape[0] for a in arrays.values() if a.ndim == 2}
            if missing or len(sizes) != 1 or any(a.ndim != 2 for a in arrays.values()):
                raise UserError(
                    "viewpoint descriptors need a (V, D) array of every prefilter stage "
                    f"({', '.join(self.stages)}), V alike")
            n = sizes.pop()
            for s, a in arrays.items():
                if n == 0:
                    continue
                if s not in self._stores:
                    self._stores[s] = VectorStore(a.shape[1])
                self._stores[s].extend(a)
        self._span.append([self._size, n])
        self._size += n

    def vectors(self, row: int) -> dict[str, Array] | None:
        """``{stage: (V, D)}`` of keyframe row `row` (None without viewpoints)."""
        first, n = (int(v) for v in self._span.data[row])
        if n == 0:
            return None
        return {s: np.array([st.row(first + i) for i in range(n)]) for s, st in
                self._stores.items()}

    def screen(self, queries: list[Mapping[str, ArrayLike]], factors: Mapping[str, float],
               rows: int) -> NDArray[np.float32]:
        """``(rows,)`` float32 smallest combined distance over each keyframe row's
        viewpoints and the query vector sets `queries` (inf: no viewpoint);
        `factors` holds w_s / scale_s per stage."""
        best = np.full(rows, np.inf, np.float32)
        if self._size == 0:
            return best
        combined = screen_sets(self._stores, queries, factors)
        span = self._span.data
        has = np.flatnonzero(span[:, 1] > 0)
        best[has] = np.minimum.reduceat(combined, span[has, 0])
        return best

    def exact(
        self, query: Mapping[str, ArrayLike], rows: NDArray[np.intp],
        combine: Callable[[dict[str, Array]], Array],
    ) -> tuple[Array, dict[str, Array]]:
        """Per keyframe row of `rows`, its viewpoint of smallest combined distance
        p_v (float64): ``(p, raw)`` with ``p`` ``(len(rows),)`` (inf: no viewpoint)
        and ``raw`` stage -> that viewpoint's distances (inf: none)."""
        rows = np.asarray(rows, np.intp)
        p = np.full(len(rows), np.inf)
        raw = {s: np.full(len(rows), np.inf) for s in self.stages}
        if self._size == 0 or len(rows) == 0:
            return p, raw
        first, count = self._span.data[rows, 0], self._span.data[rows, 1]
        group = np.repeat(np.arange(len(rows)), count)
        if len(group) == 0:
            return p, raw
        start = np.repeat(np.cumsum(count) - count, count)
        idx = np.repeat(first, count) + (np.arange(len(group)) - start)
        dist = {s: self._stores[s].exact_distances(query[s], idx) for s in self.stages}
        pv = np.asarray(combine(dist), float)
        order = np.lexsort((pv, group))
        lead = order[np.r_[True, group[order][1:] != group[order][:-1]]]
        p[group[lead]] = pv[lead]
        for s in self.stages:
            raw[s][group[lead]] = dist[s][lead]
        return p, raw


    def exact_sets(
        self, queries: list[Mapping[str, ArrayLike]], rows: NDArray[np.intp],
        combine: Callable[[dict[str, Array]], Array], with_raw: bool = True,
    ) -> tuple[Array, dict[str, Array]]:
        """`exact` for A query vector sets at once (`VectorStore.set_distances`: one
        matrix product per stage): ``(p, raw)``, ``p`` ``(A, len(rows))`` each
        row's smallest combined distance over its viewpoints (inf: none) and
        ``raw`` stage -> ``(A, len(rows))`` that viewpoint's distances (inf: none;
        left empty unless `with_raw`)."""
        rows = np.asarray(rows, np.intp)
        shape = (len(queries), len(rows))
        p = np.full(shape, np.inf)
        raw: dict[str, Array] = {}
        if with_raw:
            raw = {s: np.full(shape, np.inf) for s in self.stages}
        if self._size == 0 or len(rows) == 0:
            return p, raw
        first, count = self._span.data[rows, 0], self._span.data[rows, 1]
        has = np.flatnonzero(count > 0)
        if len(has) == 0:
            return p, raw
        n = count[has]
        start = np.cumsum(n) - n  # each row's first column among the viewpoint columns
        idx = np.repeat(first[has], n) + (np.arange(int(n.sum())) - np.repeat(start, n))
        dist = {s: self._stores[s].set_distances(np.stack([np.asarray(q[s], float)
                                                           for q in queries]), idx)
                for s in self.stages}
        pv = np.asarray(combine(dist), float)
        p[:, has] = np.minimum.reduceat(pv, start, axis=1)
        if with_raw:
            group = np.repeat(np.arange(len(has)), n)
            for a in range(len(queries)):
                order = np.lexsort((pv[a], group))
                lead = order[np.r_[True, group[order][1:] != group[order][:-1]]]
                for s in self.stages:
                    raw[s][a, has] = dist[s][a, lead]
        return p, raw


def stacked_distances(store: VectorStore, queries: ArrayLike) -> NDArray[np.float32]:
    """``(Q, M)`` float32 Euclidean distances of Q queries ``(Q, D)`` to every row of
    `store`, from one pass over its rows (``|x|^2 - 2 x.q + |q|^2``, as
    `VectorStore.fast_distances` for one query; `np.einsum`'s own loop, not BLAS)."""
    q = (np.atleast_2d(np.asarray(queries, float)) - store.reference).astype(np.float32)
    d2 = np.einsum("ij,kj->ki", store.matrix, -2.0 * q)
    d2 += store.sqnorms[None, :]
    d2 += np.einsum("kj,kj->k", q, q)[:, None]
    np.maximum(d2, 0.0, out=d2)
    return np.sqrt(d2, out=d2)


def screen_sets(stores: Mapping[str, VectorStore], queries: list[Mapping[str, ArrayLike]],
                factors: Mapping[str, float], scratch: NDArray[np.float32] | None = None
                ) -> NDArray[np.float32]:
    """``(M,)`` float32 smallest over the query vector sets `queries` of the combined
    distance ``sum_s factors[s] d_s`` to every row of `stores` (one per stage).

    `scratch`: a float32 buffer of at least ``M`` times the stages that a single query
    set's distances are written into (no fresh pages per query; the result is then a
    view of it, valid until the buffer is written again)."""
    combined: NDArray[np.float32] | None = None
    for i, (s, store) in enumerate(stores.items()):
        if len(queries) == 1:
            m = len(store)
            out = None if scratch is None else scratch[i * m : (i + 1) * m]
            d = store.fast_distances(queries[0][s], out=out)
        else:
            d = stacked_distances(store, np.stack([np.asarray(q[s], float) for q in queries]))
        d *= np.float32(factors[s])
        combined = d if combined is None else np.add(combined, d, out=combined)
    assert combined is not None
    return combined if combined.ndim == 1 else combined.min(axis=0)


def rank_normalised(p: ArrayLike, rank: int) -> tuple[Array, NDArray[np.intp]]:
    """Combine the prefilter distances of several query descriptions over a pool.

    ``p`` is ``(A, n)``: row a holds p_a(j) of query description a (row 0 the own
    description, then its offset viewpoints) to each of n stored keyframes, each
    already the smallest over that keyframe's own description and viewpoints.
    Each row is rescaled so that its `rank`-th smallest value equals the own row's,

        p(j) = min_a p_a(j) s_0 / s_a,   s_a = rank-th smallest finite p_a over the pool

    (the largest finite value when fewer; a row with no positive finite s_a keeps
    its scale; `rank` 0: no rescaling).  A description seen from a metre aside may
    lie close to many stored places at once (a generic view, e.g. a corridor seen
    along its axis): the plain minimum lets all of them overtake the own
    description's best, the rescaled one only the places that description ranks
    unusually near.  Unitless, as p.

    Returns:
        ``(p, a)``: ``(n,)`` the combined distance and the row that gave it (the
        first on ties).
    """
    d = np.atleast_2d(np.asarray(p, float))
    if rank > 0 and d.shape[0] > 1 and d.shape[1] > 0:
        fin = np.where(np.isfinite(d), d, np.inf)
        kth = np.sort(fin, axis=1)[:, : min(rank, d.shape[1])]
        kth = np.where(np.isfinite(kth), kth, -np.inf).max(axis=1)
        ok = np.isfinite(kth) & (kth > 0)
        if ok[0]:
            factor = np.where(ok, kth[0] / np.where(ok, kth, 1.0), 1.0)
            d = d * factor[:, None]
    a = np.argmin(d, axis=0)
    return d[a, np.arange(d.shape[1])], a.astype(np.intp)


def viewpoint_sets(views: Mapping[str, ArrayLike] | None, stages: tuple[str, ...]
                   ) -> list[dict[str, Array]]:
    """A keyframe's viewpoint vectors ``{stage: (V, D)}`` as V query vector sets
    ``{stage: (D,)}`` (none for None)."""
    if views is None:
        return []
    arrays = {s: np.asarray(views[s], float) for s in stages}
    n = len(next(iter(arrays.values())))
    return [{s: a[i] for s, a in arrays.items()} for i in range(n)]


def with_viewpoints(
    own: tuple[Array, dict[str, Array]], views: tuple[Array, dict[str, Array]]
) -> tuple[Array, dict[str, Array]]:
    """``(p, raw)`` of each row from its own description or, where smaller, its best
    viewpoint's (`ViewpointRows.exact`)."""
    p_own, raw_own = own
    p_view, raw_view = views
    use = p_view < p_own
    if not use.any():
        return p_own, raw_own
    return (np.where(use, p_view, p_own),
            {s: np.where(use, raw_view[s], d) for s, d in raw_own.items()})


__all__ = ["VIEWPOINTS", "ViewpointRows", "prefilter_vector", "rank_normalised", "screen_sets",
           "stacked_distances", "viewpoint_sets", "with_viewpoints"]
