"""Place database: keyframes screened by cheap descriptors, verified by expensive matchers.

Every keyframe is a `Polygon` in its sensor frame [m]; it is described once, at
insertion, by every configured stage (`loopclosure.place_config.PlaceDatabaseConfig`),
and a query runs three steps:

1. Prefilter (all stored keyframes, vectorised).  Each prefilter stage s is a
   fixed-length descriptor compared by the Euclidean distance (the surface-pair
   histogram, the default; FFT amplitudes, of the whole polygon or of its near field
   with the whole one's appended (``fft-near``), ring-projection profiles:
   `loopclosure.matchers.vector_search`).  The stages are combined by normalising
   each distance by a robust scale of the database and summing with weights w_s
   (default 1):

       p(j) = sum_s w_s d_s(q, j) / scale_s          (unitless)

   scale_s = median distance of 256 random pairs of stored keyframes, re-estimated
   (seeded sample over all stored keyframes) on the first query after the size
   reached a new power of two, so O(log M) refreshes in all; or fixed in the config
   (`fixed_scales`).  A normalised sum, not rank fusion, because ranks need a full
   sort of the database (O(M log M)) while the sum keeps the screening at one float32
   matrix-vector product per stage, a few float32 passes and one selection
   (`vector_search.smallest_k`).  The screening is memory bound (one pass over
   M x D float32 values: D = 320 for the pair histogram, 1.3 kB a keyframe; 8 FFT
   amplitudes + 12 rings when those are the stages, `fft_harmonics`, `ring_rings`).
   The K smallest p(j) (``top_k``, default 10) are the
   candidates; their stage distances and p are then recomputed exactly (float64) and
   they are re-sorted: their prefilter rank is their order by p.  With the polar
   grids of the heading hypotheses stored (below), the ``grid_shortlist`` (50)
   smallest p are recomputed so, and up to ``grid_extra`` (5) more of them join the K:
   the best by p - w c, c the similarity of the two places' polar occupancy grids
   (`loopclosure.grid_rerank`: the pair histogram is blind to where things are, the
   grid is not, and the two rankings miss different revisits).
2. Verify: each verifier (any registered matcher; default FLIRT) computes
   its `distances` over the K candidates only
   (their descriptors stacked on demand: the database never holds a stacked copy
   of an expensive descriptor).
3. Fuse (`loopclosure.place_fusion`, `loopclosure.fusion`): ``fusion="logistic"``
   (default): P(same place) = sigma(b + sum_s w_s log(d_s / scale_s + eps)) over
   every stage (prefilter and verifier) with the coefficients of `PlaceDatabaseConfig.logistic`
   (`DEFAULT_LOGISTIC`: fitted on the simulated Box world and three real logs, see
   `loopclosure.place_config`); a verifier's scale is the median
   over 64 random stored pairs (8 anchors x 8 others), refreshed like the prefilter's.
   ``"rank"``: reciprocal rank fusion of the stages over the K candidates.
   ``"verifier"``: exp(-mean_v d_v / scale_v) over the verifiers only (the
   prefilter only selects).  ``"prefilter"``: exp(-p(j)) (no verifier needed).
   ``"auto"``: logistic unless ``scale_invariant`` (then rank; `resolved_fusion`).
   Candidates are returned by decreasing score (ties: prefilter order).

Keypoint-pair vote (``vote="fuse"``, default off): every keyframe is also described
by FLIRT keypoints (`loopclosure.place_vote.vote_keypoints`, descriptor ``vote``) and
stored in an incremental inverted index of keypoint pairs (`PairVoteIndex`); a query's
K candidates are then the prefilter's first ``vote_split`` and the vote's best other
places up to K (the grids' extras kept after them), so a revisit that shares only
part of its view with a stored keyframe can still be a candidate.

Heading hypotheses: for every candidate, headings of the query in the candidate's
frame, the starting rotations of the geometric check, best first: the peaks of the
correlation of the two places' polar occupancy grids (``grid_headings``), then those
of their range functions (``n_headings``) (`loopclosure.place_headings`).

Where the pieces live: result types `loopclosure.place_match`; the prefilter vectors
and step 1's screening `loopclosure.place_prefilter`; the shortlist and the vote's
candidate merge `loopclosure.place_shortlist`; steps 2-3 (verify, fuse)
`loopclosure.place_fusion`; scales `loopclosure.place_scales`; polar grids and their
similarity `loopclosure.place_grids`; offset viewpoints `loopclosure.place_views`;
this module holds the storage and the query steps' order.

Storage (`loopclosure.place_rows`) grows with amortised doubling (`VectorStore` for
prefilter vectors, `FloatRows` for range functions, a list of every keyframe's
descriptors): adding a keyframe never re-stacks the database.  The descriptors of
every stored key stay retrievable (`descriptors`): querying with them is querying
with the keyframe itself.

Gating: ``allowed`` (keys, or a boolean mask over insertion order) restricts a query
to a subset (e.g. keyframes inside a pose-uncertainty ellipse; keyframes newer than
a window excluded), ``exclude_keys`` removes a few keys.  Keys are any hashable
values (keyframe ids; `loopclosure.place_rows.KeyIndex`).

Units: descriptors carry the units of their matchers (metres unless
``scale_invariant``); prefilter distances are unitless after normalisation; scores
are in [0, 1]; headings in radians.
"""

from __future__ import annotations

from collections.abc import Hashable, Iterable, Mapping, Sequence
from dataclasses import fields, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError
from loopclosure.matchers.base import Matcher
from loopclosure.matchers.fft import FFTMatcher
from loopclosure.place_config import PlaceDatabaseConfig, stage_matcher
from loopclosure.place_fusion import StageFusion, stage_distances
from loopclosure.place_grids import GRID, DilatedGrids, polar_grid
from loopclosure.place_headings import HEADING, as_hypotheses, candidate_headings
from loopclosure.place_match import CandidateSet, Descriptors, PlaceMatch
from loopclosure.place_prefilter import PrefilterIndex
from loopclosure.place_rows import FloatRows, KeyIndex
from loopclosure.place_scales import stage_scales
from loopclosure.place_shortlist import Shortlist, rows_mask, with_votes
from loopclosure.place_views import VIEWPOINTS
from loopclosure.place_vote import PairVoteConfig, PairVoteIndex, vote_keypoints
from loopclosure.polygon import Polygon

Array = NDArray[np.float64]
VOTE = "vote"
"""Descriptor key of the vote's keypoints ``(points, orientations, labels)``."""


class PlaceDatabase:
    """Keyframes as polygons; prefilter over all, verify the top K, fuse (module docstring)."""

    def __init__(
        self,
        config: PlaceDatabaseConfig | None = None,
        *,
        matchers: Mapping[str, Matcher] | None = None,
        **overrides: Any,
    ) -> None:
        """Build an empty database.

        Args:
            config: parameters (defaults if None).
            matchers: prebuilt matchers by stage name (others are built from the
                registry with ``scale_invariant`` of the config).
            **overrides: `PlaceDatabaseConfig` fields.
        """
        cfg = config or PlaceDatabaseConfig()
        if overrides:
            known = {f.name for f in fields(PlaceDatabaseConfig)}
            unknown = set(overrides) - known
            if unknown:
                raise UserError(
                    f"unknown PlaceDatabaseConfig fields: {', '.join(sorted(unknown))}"
                )
            cfg = replace(cfg, **overrides)
        self.config = cfg
        given = dict(matchers or {})
        self.matchers: dict[str, Matcher] = {
            s: given[s] if s in given else stage_matcher(s, cfg) for s in cfg.stages}
        self._heading_matcher: FFTMatcher | None = None
        if cfg.n_headings > 0:
            fft = self.matchers.get("fft")
            self._heading_matcher = fft if isinstance(fft, FFTMatcher) else FFTMatcher()
        self._grid_on = cfg.grid_headings > 0 and not cfg.scale_invariant
        self._prefilter = PrefilterIndex(cfg)  # prefilter vectors (`place_prefilter`)
        self._stores = self._prefilter.stores
        self._descriptors: list[Descriptors] = []  # per row: what `descriptors` returns
        self._ranges: FloatRows | None = None  # range functions of the heading hypotheses
        # Per row, its dilated polar grid (`place_grids`): made once, at insertion.
        self._dilated = DilatedGrids(cfg) if self._grid_on else None
        self._keys = KeyIndex()
        self._stamps: list[float | None] = []
        self._poses: list[Any] = []
        self._scales = np.ones(len(cfg.stages))
        self._scales_at = 0
        self._last_stored: tuple | None = None  # `query_stored`'s previous answer
        if cfg.fixed_scales:
            self._scales = np.asarray(cfg.fixed_scales, float)
        self._fusion = StageFusion(cfg)
        self._vote = (PairVoteIndex(PairVoteConfig(stop_share=cfg.vote_stop_share))
                      if cfg.vote == "fuse" else None)

    # -- contents ---------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self._keys)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._keys

    @property
    def keys(self) -> list[Hashable]:
        """Stored keys in insertion order (a copy)."""
        return self._keys.keys

    @property
    def scales(self) -> dict[str, float]:
        """Current normalisation scale of every stage (unit of that matcher's distance)."""
        self._refresh_scales()
        return dict(zip(self.config.stages, self._scales.tolist(), strict=True))

    def describe(self, polygon: Polygon) -> Descriptors:
        """Descriptors of every stage (and the heading FFT descriptor) of one polygon."""
        out: Descriptors = {s: m.describe(polygon) for s, m in self.matchers.items()}
        if self._heading_matcher is not None and "fft" not in out:
            out[HEADING] = self._heading_matcher.describe(polygon)
        if self._grid_on:
            out[GRID] = polar_grid(polygon, self.config)
        if self._vote is not None:
            cfg = self.config
            out[VOTE] = vote_keypoints(polygon, cfg.vote_step, cfg.vote_range,
                                       cfg.vote_features)
        return out

    def descriptors(self, key: Hashable) -> Descriptors:
        """The descriptors stored under `key`, as given to `add_descriptors` (the objects
        themselves, every stage and the heading descriptor): `query` with them is the
        query with the keyframe's own polygon."""
        return dict(self._descriptors[self._keys.row(key)])

    def add(
        self,
        key: Hashable,
        polygon: Polygon,
        *,
        stamp: float | None = None,
        pose: Any = None,
    ) -> None:
        """Describe `polygon` (sensor frame [m]) by every stage and store it under `key`."""
        self.add_descriptors(key, self.describe(polygon), stamp=stamp, pose=pose)

    def add_descriptors(
        self,
        key: Hashable,
        descriptors: Descriptors,
        *,
        stamp: float | None = None,
        pose: Any = None,
    ) -> None:
        """Store precomputed descriptors (from `describe` of this database's config).

        Raises:
            UserError: `key` is already stored, or a stage's descriptor is missing.
        """
        self._keys.check_new(key)
        missing = [s for s in self.config.stages if s not in descriptors]
        if self._heading_matcher is not None and "fft" not in descriptors:
            if HEADING not in descriptors:
                missing.append(HEADING)
        if missing:
            raise UserError(f"descriptors of key {key!r} lack stage(s) {', '.join(missing)}")
        self._prefilter.append(descriptors)
        kept = {s: descriptors[s] for s in self.config.stages}
        if descriptors.get(VIEWPOINTS) is not None:
            kept[VIEWPOINTS] = descriptors[VIEWPOINTS]
        if self._heading_matcher is not None:
            fft = descriptors.get("fft", descriptors.get(HEADING))
            if "fft" not in kept:
                kept[HEADING] = fft
            r = np.asarray(fft.range_function, dtype=np.float32)
            if self._ranges is None:
                self._ranges = FloatRows(len(r))
            self._ranges.append(r)
        if self._grid_on:
            if descriptors.get(GRID) is not None:
                kept[GRID] = descriptors[GRID]
            assert self._dilated is not None
            self._dilated.append(descriptors.get(GRID))
        if self._vote is not None:  # a keyframe without keypoints gets no votes
            none = (np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.int64))
            kept[VOTE] = descriptors.get(VOTE, none)
            self._vote.add(*kept[VOTE])
        self._descriptors.append(kept)
        self._keys.add(key)
        self._stamps.append(stamp)
        self._poses.append(pose)

    # -- scales -----------------------------------------------------------------------

    def _refresh_scales(self) -> None:
        """Re-estimate stage scales when the size reached a power of two (>= 2), from
        the first that many rows: the scales depend on the stored descriptors only,
        not on when the database was first asked after growing past the power."""
        if self.config.fixed_scales or len(self) < 2:
            return
        m = 1 << (len(self).bit_length() - 1)  # largest power of two <= the size
        if m <= self._scales_at:
            return
        self._scales = stage_scales(self.config, self._stores, self.matchers,
                                    self._descriptors, m)
        self._scales_at = m

    # -- queries ----------------------------------------------------------------------

    def _query_descriptors(self, polygon_or_descriptors: Polygon | Descriptors) -> Descriptors:
        if isinstance(polygon_or_descriptors, Polygon):
            return self.describe(polygon_or_descriptors)
        if not isinstance(polygon_or_descriptors, Mapping):
            raise UserError(
                "a place query needs a Polygon or a dict of stage descriptors, got "
                f"{type(polygon_or_descriptors).__name__}"
            )
        return dict(polygon_or_descriptors)

    def _selection(
        self,
        allowed: ArrayLike | None,
        exclude_keys: Iterable[Hashable] | None,
    ) -> NDArray[np.bool_] | None:
        """Boolean mask over insertion order, or None for everything."""
        m = len(self)
        mask: NDArray[np.bool_] | None = None
        if allowed is not None:
            a = np.asarray(allowed)
            if a.dtype == bool:
                if a.shape != (m,):
                    raise UserError(f"allowed mask must have shape ({m},), got {a.shape}")
                mask = a.copy()
            else:
                mask = np.zeros(m, bool)
                mask[self._keys.rows(a)] = True
        if exclude_keys is not None:
            ex = list(exclude_keys)
            if ex:
                idx = self._keys.rows([k for k in ex if k in self._keys])
                if mask is None:
                    mask = np.ones(m, bool)
                mask[idx] = False
        return mask

    def prefilter_distances(
        self,
        query: Polygon | Descriptors,
        rows: NDArray[np.intp] | None = None,
    ) -> tuple[Array, dict[str, Array]]:
        """Combined normalised prefilter distance p ``(M,)`` and each stage's raw distances.

        Exact float64 arithmetic (for reporting and tests; `candidates` screens with
        the float32 pass and recomputes its K exactly).  `rows` restricts the
        computation to those insertion indices (the result then has their length).
        """
        q = self._query_descriptors(query)
        self._refresh_scales()
        return self._prefilter.exact(q, np.arange(len(self)) if rows is None else rows,
                                     self._scales)

    def prefilter_lists(self, query: Polygon | Descriptors, rows: NDArray[np.intp] | None = None
                        ) -> list[Array]:
        """The exact distance lists a query ranks `rows` (default: all) by: ``[p]``;
        with ``viewpoint_order="interleave"`` p of the own descriptions, then (with
        the query's viewpoints) the smallest of it and the query's viewpoints' p to
        the stored own descriptions, then (with stored viewpoints) the smallest of
        it and the query's own description's p to the stored viewpoints
        (`loopclosure.place_shortlist.rank_interleave` orders them); with
        ``viewpoint_order="rerank"`` ``[p]`` of the own descriptions with the pool
        of `rows` ranked again by the viewpoints (`PrefilterIndex.reranked_all`)."""
        q = self._query_descriptors(query)
        self._refresh_scales()
        rows = np.arange(len(self)) if rows is None else rows
        if self._prefilter.pooled(q):
            own = self._prefilter.own_distances(q, rows_mask(rows, len(self)), len(self),
                                                self._scales)
            return [self._prefilter.reranked_all(q, own, self._scales)[rows]]
        lists, p, _ = self._prefilter.exact_lists(q, rows, self._scales)
        return lists if self._prefilter.interleaved(q) else [p]

    def candidates(
        self,
        polygon_or_descriptors: Polygon | Descriptors,
        *,
        allowed: ArrayLike | None = None,
        exclude_keys: Iterable[Hashable] | None = None,
        top_k: int | None = None,
        keep_prefilter: bool = False,
    ) -> CandidateSet:
        """Prefilter, verify and fuse, as arrays (`query` wraps this in `PlaceMatch` objects).

        Same arguments as `query`; the candidates are in prefilter order.  Screening
        uses float32 distances (`VectorStore.fast_distances`); the shortlist's stage
        distances and p are then recomputed exactly in float64 and re-sorted.  With
        grids (`PlaceDatabaseConfig.grid_extra`) the K smallest p are joined by up to
        ``grid_extra`` more of the ``grid_shortlist`` smallest
        (`loopclosure.grid_rerank`).  With `keep_prefilter` the result carries p of
        every stored keyframe (a copy).
        """
        q = self._query_descriptors(polygon_or_descriptors)
        k = self.config.top_k if top_k is None else int(top_k)
        if k < 1:
            raise UserError(f"top_k must be >= 1, got {k}")
        mask = self._selection(allowed, exclude_keys)
        short = self._shortlist(q, mask, k, keep_prefilter)
        keep = short.chosen(k, self.config)
        pick, pre = short.rows[keep], short.prefilter[keep]
        raw = {s: d[keep] for s, d in short.raw.items()}
        if self._vote is not None and q.get(VOTE) is not None:
            pick, pre, raw = self._with_votes(q, mask, min(k, len(pick)), pick, pre, raw)
        dist = stage_distances(self.config, self.matchers, self._descriptors, q, pick, raw)
        return CandidateSet(pick, pre, dist, self._fuse(dist, pre), short.prefilter_all)

    def vote_scores(self, query: Polygon | Descriptors,
                    rows: NDArray[np.intp] | None = None) -> Array:
        """The pair vote's score of `rows` (default: all) for a query (0: no vote; the
        database needs ``vote="fuse"``; `loopclosure.place_vote`)."""
        if self._vote is None:
            raise UserError("place database: vote_scores needs vote='fuse'")
        q = self._query_descriptors(query)
        scores = self._vote.scores(*q[VOTE])
        return scores if rows is None else scores[rows]

    def _with_votes(self, q: Descriptors, mask: NDArray[np.bool_] | None, k: int,
                    pick: NDArray[np.intp], pre: Array, raw: dict[str, Array]
                    ) -> tuple[NDArray[np.intp], Array, dict[str, Array]]:
        """The candidates with the vote's (module docstring; `place_shortlist.with_votes`):
        the first ``vote_split`` of the prefilter's K, the vote's best allowed rows not
        among the candidates (decreasing score, ties by row) up to K, then the
        prefilter's next ones, and the grids' extras (positions K and on) last."""
        split = min(self.config.vote_split, k)
        if split >= k:
            return pick, pre, raw
        scores = self._vote.scores(*q[VOTE])
        if mask is not None:
            scores[~mask] = 0.0
        take, voted = with_votes(pick, scores, split, k)
        new_pre, new_raw = self._prefilter.exact(q, voted, self._scales, scored=True)
        head, tail = take[:split], take[split:]
        rows = np.concatenate([pick[head], voted, pick[tail]]).astype(np.intp)
        pre = np.concatenate([pre[head], new_pre, pre[tail]])
        raw = {s: np.concatenate([d[head], new_raw[s], d[tail]]) for s, d in raw.items()}
        return rows, pre, raw

    def _shortlist(
        self, q: Descriptors, mask: NDArray[np.bool_] | None, k: int, keep_prefilter: bool
    ) -> Shortlist:
        """The rows a query chooses its candidates from (`PrefilterIndex.shortlist`):
        the K smallest p, or with grids the ``grid_shortlist`` smallest and their grid
        similarities; exact p and stage distances, in increasing p (ties by row)."""
        self._refresh_scales()
        similarity = (lambda rows: self._grid_similarity(q, rows)) if self._extra_on(q) else None
        return self._prefilter.shortlist(q, mask, self._shortlist_size(q, k), len(self),
                                         self._scales, keep_prefilter, similarity)

    def _shortlist_size(self, q: Descriptors, k: int) -> int:
        """Rows a query with K candidates ranks exactly: K, or the grids' shortlist."""
        return max(k, self.config.grid_shortlist) if self._extra_on(q) else k

    def _extra_on(self, q: Descriptors) -> bool:
        """Whether a query adds the grids' candidates (module docstring, step 1)."""
        return self._grid_on and self.config.grid_extra > 0 and q.get(GRID) is not None

    def _grid_similarity(self, q: Descriptors, rows: NDArray[np.intp]) -> Array:
        """``(len(rows),)`` grid similarity c of the query with those rows (0 where a
        row has no grid: its dilated grid is empty)."""
        if self._dilated is None:
            return np.zeros(len(rows))
        return self._dilated.similarity(q[GRID], rows)

    def query(
        self,
        polygon_or_descriptors: Polygon | Descriptors,
        *,
        allowed: ArrayLike | None = None,
        exclude_keys: Iterable[Hashable] | None = None,
        top_k: int | None = None,
        headings: bool = True,
    ) -> list[PlaceMatch]:
        """Verified candidates of a query polygon (sensor frame [m]) or its descriptors.

        Args:
            polygon_or_descriptors: the query `Polygon`, or `describe` of it.
            allowed: keys to search, or a boolean mask over insertion order (None: all).
            exclude_keys: keys never returned (e.g. the query's own recent keyframes).
            top_k: K (default `PlaceDatabaseConfig.top_k`).
            headings: compute the heading hypotheses of every candidate; False leaves
                them empty, for a caller that needs them for a few candidates only
                (`with_headings`: a candidate checked from a pose prior needs none).

        Returns:
            Up to K `PlaceMatch`, by decreasing fused score (ties: prefilter order).
        """
        if len(self) == 0:
            return []
        q = self._query_descriptors(polygon_or_descriptors)
        c = self.candidates(q, allowed=allowed, exclude_keys=exclude_keys, top_k=top_k)
        if len(c.indices) == 0:
            return []
        hyps = self._hypotheses(q, c.indices) if headings else [()] * len(c.indices)
        return [self._match(int(c.indices[j]), float(c.prefilter[j]), j, c.distances[:, j],
                            float(c.scores[j]), hyps[j]) for j in c.order().tolist()]

    def _match(self, row: int, prefilter: float, rank: int, distances: Array, score: float,
               headings: tuple[tuple[float, float], ...]) -> PlaceMatch:
        """The `PlaceMatch` of stored row `row` (`distances`: one per stage)."""
        return PlaceMatch(
            key=self._keys.key(row), prefilter_distance=prefilter, prefilter_rank=rank,
            distances={s: float(distances[t]) for t, s in enumerate(self.config.stages)},
            score=score, headings=headings, stamp=self._stamps[row], pose=self._poses[row])

    def query_stored(self, key: Hashable, *, allowed: ArrayLike | None = None
                     ) -> list[PlaceMatch]:
        """`query` (no headings) of the stored keyframe `key`'s own descriptors over
        `allowed` (keys, a boolean mask over insertion order, or None: all).

        The previous call's shortlist and answer are kept.  When it was for the same
        `key`, with the same normalisation scales, over rows that `allowed` still
        holds (a host asking again as more keyframes become eligible), only the newly
        allowed rows are screened: the shortlist of all allowed rows is the one of
        the previous shortlist and the new rows' (candidates are chosen from the
        smallest exact prefilter distances and each row's own grid similarity), and
        only candidates the previous answer did not hold are verified (the fused
        score of a candidate does not depend on the others).
        """
        q = self.descriptors(key)
        self._refresh_scales()
        mask = self._selection(allowed, None)
        rows = np.arange(len(self)) if mask is None else np.flatnonzero(mask)
        k = self.config.top_k
        last = self._last_stored
        if (last is None or last[0] != key or last[1] != self._scales_at
                or self._prefilter.interleaved(q) or self._prefilter.pooled(q)
                or not np.isin(last[2], rows, assume_unique=True).all()):
            short = self._shortlist(q, rows_mask(rows, len(self)), k, False)
            known: dict[int, PlaceMatch] = {}
        else:
            new = np.setdiff1d(rows, last[2], assume_unique=True)
            short = last[3]
            if len(new):
                short = short.merged(self._shortlist(q, rows_mask(new, len(self)), k, False),
                                     self._shortlist_size(q, k))
            known = last[4]
        keep = short.chosen(k, self.config)
        pick = short.rows[keep]
        todo = np.array([i for i in pick.tolist() if i not in known], np.intp)
        if len(todo):
            by_row = np.argsort(short.rows)
            at = by_row[np.searchsorted(short.rows, todo, sorter=by_row)]
            raw = {s: d[at] for s, d in short.raw.items()}
            dist = stage_distances(self.config, self.matchers, self._descriptors, q, todo,
                                   raw)
            scores = self._fuse(dist, short.prefilter[at])
            for j, i in enumerate(todo.tolist()):
                known[i] = self._match(i, float(short.prefilter[at[j]]), 0, dist[:, j],
                                       float(scores[j]), ())
        known = {i: known[i] for i in pick.tolist()}
        pool = [known[i] if known[i].prefilter_rank == j else known[i].with_rank(j)
                for j, i in enumerate(pick.tolist())]
        matches = sorted(pool, key=lambda m: -m.score)  # stable: prefilter order
        self._last_stored = (key, self._scales_at, rows, short, known)
        return matches

    def with_headings(
        self, polygon_or_descriptors: Polygon | Descriptors, matches: Sequence[PlaceMatch]
    ) -> list[PlaceMatch]:
        """`matches` of a query (`query` with ``headings=False``) with their heading
        hypotheses, computed for these candidates only, as `query` computes them."""
        if not matches:
            return []
        q = self._query_descriptors(polygon_or_descriptors)
        hyps = self._hypotheses(q, self._keys.rows([m.key for m in matches]))
        return [replace(m, headings=h) for m, h in zip(matches, hyps, strict=True)]

    def _hypotheses(
        self, q: Descriptors, cand: NDArray[np.intp]
    ) -> list[tuple[tuple[float, float], ...]]:
        """Per candidate row, its ``(heading, score)`` hypotheses, best first."""
        angles, corr = candidate_headings(q, cand, self._descriptors, self._ranges,
                                          self.config, self._grid_on)
        return as_hypotheses(angles, corr)

    def _fuse(self, dist: Array, pre: Array) -> Array:
        """``(K,)`` fused scores in [0, 1] of ``(S, K)`` stage distances (`place_fusion`)."""
        return self._fusion.scores(dist, pre, self._scales)



__all__ = [
    "CandidateSet",
    "Descriptors",
    "PlaceDatabase",
    "PlaceDatabaseConfig",
    "PlaceMatch",
]
