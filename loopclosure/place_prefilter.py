"""The place database's prefilter: stored vectors and the screening of a query.

Step 1 of `loopclosure.place_database`: every prefilter stage s is a fixed-length
vector compared by the Euclidean distance (`loopclosure.matchers.vector_search`),
and the stages are combined into one unitless distance

    p(j) = sum_s w_s d_s(q, j) / scale_s

(w_s: `PlaceDatabaseConfig.prefilter_weights`, default 1; scale_s: the database's
current stage scales, `loopclosure.place_scales`).  `PrefilterIndex` holds the
vectors of every stored keyframe (one `VectorStore` per stage, grown by amortised
doubling) and its offset viewpoints (`loopclosure.place_views.ViewpointRows`), and
computes p two ways: `screen` (float32, every stored keyframe, the hot path: one
pass over M x D float32 values per stage) and `exact_lists` (float64, a few rows,
from the vectors' differences).  A row's p is its smallest over its own
description and its offset viewpoints, and over the query's viewpoints with
``query_viewpoints``; with ``viewpoint_order="interleave"`` these are kept as
separate lists (`loopclosure.place_shortlist.rank_interleave` orders them); with
``viewpoint_order="rerank"`` the own descriptions alone screen the database and the
viewpoints rank only the pool of its smallest p again (`reranked`; `exact` still
gives the plain smallest p over every pair, the distances
`PlaceDatabase.prefilter_distances` reports and the vote's extra candidates carry).
`shortlist` picks the rows a query chooses its candidates from: the n smallest
screened p, recomputed exactly and re-sorted (`loopclosure.place_shortlist`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from loopclosure.matchers.vector_search import VectorStore, smallest_k
from loopclosure.place_config import PlaceDatabaseConfig
from loopclosure.place_match import Descriptors
from loopclosure.place_shortlist import Shortlist, rank_interleave
from loopclosure.place_views import (
    VIEWPOINTS,
    ViewpointRows,
    prefilter_vector,
    rank_normalised,
    screen_sets,
    viewpoint_sets,
    with_viewpoints,
)

Array = NDArray[np.float64]


class PrefilterIndex:
    """Prefilter vectors of the stored keyframes and the distances p of a query to
    them (module docstring).  Every distance method takes the database's current
    ``(S,)`` stage scales (prefilter stages first: only those are read)."""

    def __init__(self, config: PlaceDatabaseConfig) -> None:
        self.config = config
        self.stages = config.prefilter
        self.weights = np.asarray(config.prefilter_weights or [1.0] * len(config.prefilter),
                                  float)
        self.stores: dict[str, VectorStore] = {}
        self.views = ViewpointRows(config.prefilter)  # offset viewpoints (`place_views`)
        self._scratch = np.empty(0, np.float32)

    def append(self, descriptors: Descriptors) -> None:
        """Store one keyframe's prefilter vectors (and its viewpoints' when
        ``stored_viewpoints``)."""
        for s in self.stages:
            vec = np.asarray(prefilter_vector(descriptors[s]), dtype=float)
            if s not in self.stores:
                self.stores[s] = VectorStore(len(vec))
            self.stores[s].append(vec)
        self.views.append(descriptors.get(VIEWPOINTS) if self.config.stored_viewpoints
                          else None)

    def factors(self, scales: Array) -> dict[str, float]:
        """``w_s / scale_s`` per prefilter stage."""
        return {s: self.weights[i] / scales[i] for i, s in enumerate(self.stages)}

    def combine(self, raw: Mapping[str, ArrayLike], scales: Array) -> Any:
        """``sum_s w_s d_s / scale_s`` of per-stage distances (float32 in, float32 out)."""
        combined = None
        for i, s in enumerate(self.stages):
            d = raw[s]
            factor = self.weights[i] / scales[i]
            term = d * np.asarray(factor, dtype=np.asarray(d).dtype)
            combined = term if combined is None else np.add(combined, term, out=combined)
        return combined

    def query_vectors(self, q: Descriptors) -> list[dict[str, Any]]:
        """The query's prefilter vectors: its own, then (``query_viewpoints``) those of
        each of its offset viewpoints."""
        own = {s: prefilter_vector(q[s]) for s in self.stages}
        if not self.config.query_viewpoints:
            return [own]
        return [own, *viewpoint_sets(q.get(VIEWPOINTS), self.stages)]

    def interleaved(self, q: Descriptors) -> bool:
        """Whether query `q` ranks by several lists (``viewpoint_order="interleave"``,
        and viewpoints on either side)."""
        return self.config.viewpoint_order == "interleave" and (
            len(self.views) > 0
            or (self.config.query_viewpoints and q.get(VIEWPOINTS) is not None))

    def pooled(self, q: Descriptors) -> bool:
        """Whether query `q` ranks its pool again by viewpoints
        (``viewpoint_order="rerank"``, and viewpoints on either side)."""
        return self.config.viewpoint_order == "rerank" and (
            len(self.views) > 0
            or (self.config.query_viewpoints and q.get(VIEWPOINTS) is not None))

    def own_distances(self, q: Descriptors, mask: NDArray[np.bool_] | None, m: int,
                      scales: Array) -> Array:
        """p of the two own descriptions to each of the `m` stored keyframes (inf
        outside `mask`): float32 screened values, or exact ones when the mask
        holds under a quarter of the rows."""
        sets = self.query_vectors(q)[:1]
        if mask is not None and mask.sum() * 4 < m:
            rows = np.flatnonzero(mask)
            out = np.full(m, np.inf)
            raw = {s: self.stores[s].exact_distances(v, rows) for s, v in sets[0].items()}
            out[rows] = self.combine(raw, scales)
            return out
        out = screen_sets(self.stores, sets, self.factors(scales)).astype(np.float64)
        if mask is not None:
            out[~mask] = np.inf
        return out

    def reranked(self, q: Descriptors, pool: NDArray[np.intp], scales: Array,
                 scored: bool = False) -> tuple[Array, dict[str, Array]]:
        """Exact p and raw stage distances of the `pool` rows ranked again by the
        viewpoints (``viewpoint_order="rerank"``): per query description (own,
        then its viewpoints with ``query_viewpoints``) the smallest p over each
        row's own description and stored viewpoints, combined by
        `loopclosure.place_views.rank_normalised` over the pool (rank
        ``viewpoint_rank``).  The raw distances are the two own descriptions'
        when `scored` and not ``viewpoint_scores``, else those of the pair that
        gave p (unscaled).  All query descriptions at once: one matrix product
        per stage for the pool's own rows and one for their viewpoints'
        (`VectorStore.set_distances`, float64)."""
        def combine(raw: Mapping[str, ArrayLike]) -> Any:
            return self.combine(raw, scales)

        pool = np.asarray(pool, np.intp)
        sets = self.query_vectors(q)
        own_raw = {s: self.stores[s].set_distances(
            np.stack([np.asarray(v[s], float) for v in sets]), pool) for s in self.stages}
        per = np.asarray(combine(own_raw), float)
        best_raw = own_raw
        want_raw = not scored or self.config.viewpoint_scores
        if len(self.views):
            p_view, raw_view = self.views.exact_sets(sets, pool, combine, want_raw)
            use = p_view < per
            per = np.where(use, p_view, per)
            if want_raw:
                best_raw = {s: np.where(use, raw_view[s], d) for s, d in own_raw.items()}
        p, which = rank_normalised(per, self.config.viewpoint_rank)
        if not want_raw:
            return p, {s: d[0] for s, d in own_raw.items()}
        cols = np.arange(len(pool))
        return p, {s: d[which, cols] for s, d in best_raw.items()}

    def reranked_all(self, q: Descriptors, own: Array, scales: Array) -> Array:
        """``(M,)`` the order a ``"rerank"`` query ranks by: `own` (p of the own
        descriptions, inf: not allowed) with the pool's rows (the
        ``viewpoint_pool`` smallest) replaced by their `reranked` p.  A pool row's
        p is at most its own p, so the pool stays ahead of every other row."""
        pool = smallest_k(own, min(self.config.viewpoint_pool,
                                   int(np.isfinite(own).sum())))
        out = np.array(own, float)
        out[pool] = self.reranked(q, pool, scales)[0]
        return out

    def screen(self, q: Descriptors, m: int, scales: Array) -> NDArray[np.float32]:
        """Float32 combined prefilter distance of every one of the `m` stored keyframes.

        Written into scratch buffers kept between queries (no fresh pages per query):
        the result is only valid until the next query.
        """
        n_stages = len(self.stages)
        if len(self._scratch) < m * n_stages:
            self._scratch = np.empty(2 * m * n_stages, np.float32)
        factors = self.factors(scales)
        sets = self.query_vectors(q)
        combined = screen_sets(self.stores, sets, factors, self._scratch)
        if len(self.views):
            np.minimum(combined, self.views.screen(sets, factors, m), out=combined)
        return combined

    def screen_lists(self, q: Descriptors, m: int, scales: Array
                     ) -> list[NDArray[np.float32]]:
        """Float32 screens of the lists of `exact_lists` (fresh arrays)."""
        factors = self.factors(scales)
        sets = self.query_vectors(q)
        own = screen_sets(self.stores, sets[:1], factors)
        lists = [own]
        if len(sets) > 1:
            lists.append(np.minimum(own, screen_sets(self.stores, sets[1:], factors)))
        if len(self.views):
            lists.append(np.minimum(own, self.views.screen(sets[:1], factors, m)))
        return lists

    def exact(self, q: Descriptors, rows: NDArray[np.intp], scales: Array,
              scored: bool = False) -> tuple[Array, dict[str, Array]]:
        """Exact p and raw stage distances of `rows`, each row's smallest over its own
        description and its offset viewpoints, and over the query's own viewpoints
        with ``query_viewpoints`` (`loopclosure.place_views`).  `scored`: the raw
        distances the fused score sees, which are those of the two own descriptions
        unless ``viewpoint_scores``."""
        return self.exact_lists(q, rows, scales, scored)[1:]

    def exact_lists(self, q: Descriptors, rows: NDArray[np.intp], scales: Array,
                    scored: bool = False) -> tuple[list[Array], Array, dict[str, Array]]:
        """`exact` with, first, the exact distance lists a query ranks `rows` by:
        ``[p]``; with ``viewpoint_order="interleave"`` p of the own descriptions,
        then (with the query's viewpoints) the smallest of it and the query's
        viewpoints' p to the stored own descriptions, then (with stored viewpoints)
        the smallest of it and the query's own description's p to the stored
        viewpoints."""
        def combine(raw: Mapping[str, ArrayLike]) -> Any:
            return self.combine(raw, scales)

        sets = self.query_vectors(q)
        own_raw = {s: self.stores[s].exact_distances(v, rows) for s, v in sets[0].items()}
        own = (combine(own_raw), own_raw)
        lists = [own[0]]
        best = own
        stored = None
        if len(self.views):
            stored = self.views.exact(sets[0], rows, combine)
            best = with_viewpoints(own, stored)
        from_query = own
        for vectors in sets[1:]:
            raw = {s: self.stores[s].exact_distances(v, rows) for s, v in vectors.items()}
            cur = (combine(raw), raw)
            from_query = with_viewpoints(from_query, cur)
            if len(self.views):
                cur = with_viewpoints(cur, self.views.exact(vectors, rows, combine))
            best = with_viewpoints(best, cur)
        if self.interleaved(q):
            if len(sets) > 1:
                lists.append(from_query[0])
            if stored is not None:
                lists.append(np.minimum(own[0], stored[0]))
        if scored and not self.config.viewpoint_scores:
            return lists, best[0], own_raw
        return lists, best[0], best[1]

    def shortlist(self, q: Descriptors, mask: NDArray[np.bool_] | None, n: int, m: int,
                  scales: Array, keep_prefilter: bool,
                  similarity: Callable[[NDArray[np.intp]], Array] | None) -> Shortlist:
        """The `n` rows of the `m` stored (those of `mask`, None: all) a query chooses
        its candidates from: the smallest p, exact p and stage distances, in
        increasing p (ties by row), or in `rank_interleave` order of the lists when
        the query ranks by several; with `similarity` (the grids' candidates) each
        row's grid similarity c; with `keep_prefilter` p of every row."""
        if self.interleaved(q):
            return self._interleaved_shortlist(q, mask, n, m, scales, keep_prefilter,
                                               similarity)
        if self.pooled(q):
            return self._reranked_shortlist(q, mask, n, m, scales, keep_prefilter,
                                            similarity)
        if mask is not None and mask.sum() * 4 < m:
            rows = np.flatnonzero(mask)
            part, _ = self.exact(q, rows, scales)
            pick = rows[smallest_k(part, n)]
            combined = np.full(m, np.inf)
            combined[rows] = part
        else:
            screened = self.screen(q, m, scales)
            if mask is not None:
                screened[~mask] = np.inf
                n = min(n, int(mask.sum()))
            pick = smallest_k(screened, n)
            combined = screened.astype(np.float64) if keep_prefilter else None
        pre, raw = self.exact(q, pick, scales, scored=True)
        order = np.lexsort((pick, pre))
        c = similarity(pick[order]) if similarity is not None else None
        return Shortlist(pick[order], pre[order], {s: d[order] for s, d in raw.items()},
                         c, combined)

    def _reranked_shortlist(self, q: Descriptors, mask: NDArray[np.bool_] | None, n: int,
                            m: int, scales: Array, keep_prefilter: bool,
                            similarity: Callable[[NDArray[np.intp]], Array] | None
                            ) -> Shortlist:
        """`shortlist` of a ``"rerank"`` query: the own descriptions' ``max(n,
        viewpoint_pool)`` smallest p ranked again (`reranked`), the first `n`."""
        own = self.own_distances(q, mask, m, scales)
        size = min(max(n, self.config.viewpoint_pool), int(np.isfinite(own).sum()))
        pool = smallest_k(own, size)
        pre, raw = self.reranked(q, pool, scales, scored=True)
        order = np.lexsort((pool, pre))[:n]
        pick = pool[order]
        c = similarity(pick) if similarity is not None else None
        every = None
        if keep_prefilter:
            every = own
            every[pool] = pre
        return Shortlist(pick, pre[order], {s: d[order] for s, d in raw.items()}, c, every)

    def _interleaved_shortlist(self, q: Descriptors, mask: NDArray[np.bool_] | None, n: int,
                               m: int, scales: Array, keep_prefilter: bool,
                               similarity: Callable[[NDArray[np.intp]], Array] | None
                               ) -> Shortlist:
        """`shortlist` of a query ranking by several lists: the first `n` rows of the
        lists' interleave (`rank_interleave`), taken from the union of each list's
        `n` smallest (screened, then exact)."""
        if mask is not None and mask.sum() * 4 < m:
            rows = np.flatnonzero(mask)
            lists = []
            for part in self.exact_lists(q, rows, scales)[0]:
                full = np.full(m, np.inf)
                full[rows] = part
                lists.append(full)
        else:
            lists = self.screen_lists(q, m, scales)
            if mask is not None:
                for d in lists:
                    d[~mask] = np.inf
        n = min(n, m if mask is None else int(mask.sum()))
        pick = np.unique(np.concatenate([smallest_k(d, n) for d in lists])).astype(np.intp)
        exact, pre, raw = self.exact_lists(q, pick, scales, scored=True)
        order = rank_interleave(exact)[:n]
        pick = pick[order]
        c = similarity(pick) if similarity is not None else None
        every = np.min(np.vstack(lists), axis=0).astype(np.float64) if keep_prefilter else None
        return Shortlist(pick, pre[order], {s: d[order] for s, d in raw.items()}, c,
                         every, ordered=True)


__all__ = ["PrefilterIndex"]
