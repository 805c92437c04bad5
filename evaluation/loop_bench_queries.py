"""The per-query rows of ``loopclosure bench loops`` (`evaluation.loop_bench`).

Every planned keyframe queries a database of its older keyframes, rebuilt in key
order as the mapping made them (`query_all`), and each row of the benchmark records
its top-1 proposal, score and time (`QueryRecords`): the prefilter stages (exact
distances over every stored keyframe; with the wide view, the two views interleaved
by rank, `interleaved_order`), each verifier over the cascade's K, the fused query,
the ``NAME-alone`` rows, and the final place after the geometric check as the loop
detector runs it.  `evaluation.loop_bench` judges the records against the reference.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from evaluation.loop_bench_misses import nearest_place, submap_overlap
from loopclosure.place_choice import merge_views
from loopclosure.place_database import PlaceDatabase
from loopclosure.place_shortlist import rank_interleave_with_distance, vote_fused_order
from slam.config import PipelineConfig
from slam.pipeline import Mapper

Array = NDArray[np.float64]
Progress = Callable[[str, int, int], None]

RECALL_KS: tuple[int, ...] = (1, 10, 50)
"""K of the prefilter's recall@K."""
#: The geometric check's figures recorded for each query's final place.
CHECK_FIGURES: tuple[str, ...] = ("fitness", "consistency", "matched_length", "margin",
                                  "degeneracy", "axis_length", "axis_hold", "pinned_length")
ALONE = "-alone"
VOTE_ROW = "prefilter+vote"
"""Recall@K row of the pair vote (`PlaceDatabaseConfig.vote`)."""
"""Suffix of a row that runs one matcher over the whole database (``flirt-alone``)."""


class RecordingMapper(Mapper):
    """A `Mapper` that keeps each keyframe's submap as it was when it was the newest."""

    def __init__(self, config: PipelineConfig) -> None:
        super().__init__(config)
        self.query_submaps: dict[int, Array] = {}

    def submap(self, key: int) -> Array:
        pts = super().submap(key)
        if key == len(self.keyframes.keyframes) - 1:
            self.query_submaps.setdefault(key, pts)
        return pts


def _take(stacked: Any, rows: NDArray[np.intp]) -> Any:
    """Rows of a matcher's stack: an array, or a dataclass of arrays with a leading axis."""
    if isinstance(stacked, np.ndarray):
        return stacked[rows]
    if dataclasses.is_dataclass(stacked):
        return dataclasses.replace(stacked, **{
            f.name: getattr(stacked, f.name)[rows] for f in dataclasses.fields(stacked)
        })
    raise UserError(f"cannot select rows of a {type(stacked).__name__} stack")



@dataclass(slots=True)
class QueryRecords:
    """Per-query records of `query_all` (lists, one entry per query)."""

    keys: list[int] = field(default_factory=list)
    revisit: list[bool] = field(default_factory=list)
    size: list[int] = field(default_factory=list)
    match: dict[str, list[int]] = field(default_factory=dict)
    score: dict[str, list[float]] = field(default_factory=dict)
    seconds: dict[str, list[float]] = field(default_factory=dict)
    hits: dict[str, list[NDArray[np.bool_]]] = field(default_factory=dict)
    candidate_hit: list[bool] = field(default_factory=list)
    nearest: list[tuple[int, float, float, float]] = field(default_factory=list)
    candidate_count: list[int] = field(default_factory=list)
    accepted: list[bool] = field(default_factory=list)
    final_match: list[int] = field(default_factory=list)
    final_score: list[float] = field(default_factory=list)
    relative: list[Array] = field(default_factory=list)
    reason: list[str] = field(default_factory=list)
    figures: list[Array] = field(default_factory=list)
    accepted_places: list[int] = field(default_factory=list)
    # key -> the query's own views' matches, for its successors' trails (recent only)
    answers: dict[int, list] = field(default_factory=dict)

    def put(self, row: str, match: int, score: float) -> None:
        self.match.setdefault(row, []).append(int(match))
        self.score.setdefault(row, []).append(float(score))

    def time(self, row: str, seconds: float) -> None:
        self.seconds.setdefault(row, []).append(float(seconds))


def query_all(
    mapper: RecordingMapper,
    ref: Array,
    covered: NDArray[np.bool_],
    poses: Array,
    rows: Sequence[str],
    plan: NDArray[np.bool_],
    timing_every: int,
    radius: float,
    progress: Progress,
    cascade: bool = True,
    label: str = "queries",
) -> QueryRecords:
    """Every planned, covered keyframe queries the database of its older keyframes.

    `cascade`: the rows of the cascade and the final check are computed (else only
    the ``-alone`` rows of `rows`)."""
    detector = mapper.detector
    source = detector.database
    cfg = source.config
    db = PlaceDatabase(cfg, matchers=source.matchers)
    wide_source = detector.wide_database
    wide = None if wide_source is None else _View(
        PlaceDatabase(wide_source.config, matchers=source.matchers), np.zeros(0, np.intp))
    alone = {r: r[: -len(ALONE)] for r in rows if r.endswith(ALONE)}
    stacks = {
        r: source.matchers[m].stack([source.descriptors(k)[m] for k in source.keys])
        for r, m in alone.items()
    }  # rows of `source` in insertion order: the rows `db` gets, in the same order
    keys = np.zeros(0, np.intp)  # key of every row of `db`
    n_kf = len(ref)
    kmax = max(RECALL_KS)
    out = QueryRecords()
    n_plan = int((plan & covered).sum())
    done = 0
    for k in range(n_kf):
        desc = source.descriptors(k) if k in source else None
        if desc is not None:  # a keyframe without a polygon is never a candidate
            db.add_descriptors(k, desc)
            keys = np.append(keys, k)
            if wide is not None and k in wide_source:
                wide.db.add_descriptors(k, wide_source.descriptors(k))
                wide.keys = np.append(wide.keys, k)
        if not (plan[k] and covered[k]):
            continue
        done += 1
        if done % 10 == 0 or done == n_plan:
            progress(label, done, n_plan)
        eligible = detector.eligible(k)
        older = keys < k
        mask = np.zeros(len(keys), bool)
        mask[older] = eligible[keys[older]] & covered[keys[older]]
        _one_query(out, k, desc, db, detector, mapper, keys, mask, ref, poses, alone, stacks,
                   timing_every, radius, kmax, cascade, wide)
    return out


def _nearest(mapper: RecordingMapper, ref: Array, k: int, true_keys: NDArray[np.intp]
             ) -> tuple[int, float, float, float]:
    """The query's nearest true place: key, distance [m], heading difference [deg] and
    the overlap of their submaps at their reference poses (`evaluation.loop_bench_misses`)."""
    key, dist, dtheta = nearest_place(ref, k, true_keys)
    query_points = mapper.query_submaps.get(k)
    overlap = float("nan")
    if key >= 0 and query_points is not None:
        overlap = submap_overlap(query_points, mapper.submap(key), ref[k], ref[key])
    return key, dist, dtheta, overlap


@dataclass(slots=True)
class _View:
    """The wide view's database as the queries see it (`query_all`): the loop
    detector's wide descriptors re-added in key order, and the key of every row."""

    db: PlaceDatabase
    keys: NDArray[np.intp]


def _one_query(
    out: QueryRecords, k: int, desc: dict[str, Any] | None, db: PlaceDatabase, detector: Any,
    mapper: RecordingMapper, keys: NDArray[np.intp], mask: NDArray[np.bool_], ref: Array,
    poses: Array, alone: dict[str, str], stacks: dict[str, Any],
    timing_every: int, radius: float, kmax: int, cascade: bool, wide: _View | None = None,
) -> None:
    """One query's proposals of every row (module docstring), appended to `out`; only
    the ``-alone`` rows unless `cascade`."""
    cfg = db.config
    sel = np.flatnonzero(mask)
    out.keys.append(k)
    out.size.append(len(sel))
    near = np.hypot(*(ref[keys[sel], :2] - ref[k, :2]).T) <= radius
    out.revisit.append(bool(near.any()))
    if cascade:
        out.nearest.append(_nearest(mapper, ref, k, keys[sel][near]))
    none = (-1, -np.inf)
    verifier_rows = [f"{v}@{cfg.top_k}" for v in cfg.verifiers]
    if len(sel) == 0 or desc is None:  # empty database / no descriptor: no candidate
        cascade_rows = (*cfg.prefilter, "prefilter", *verifier_rows) if cascade else ()
        for r in dict.fromkeys((*cascade_rows, *alone, *(["fused"] if cascade else []))):
            out.put(r, *none)
        if not cascade:
            return
        for r in (*cfg.prefilter, "prefilter", *vote_rows(cfg)):
            out.hits.setdefault(r, []).append(np.zeros(kmax, bool))
        out.candidate_hit.append(False)
        out.candidate_count.append(0)
        out.accepted.append(False)
        out.final_match.append(-1)
        out.final_score.append(-np.inf)
        out.relative.append(np.full(3, np.nan))
        out.reason.append("empty database" if desc is not None else "no descriptor")
        out.figures.append(np.full(len(CHECK_FIGURES), np.nan))
        out.accepted_places.append(0)
        return
    if cascade:
        _cascade_rows(out, k, desc, db, detector, mapper, keys, sel, mask, near, poses,
                      timing_every, kmax, wide)
    for r, m in alone.items():
        sub = _take(stacks[r], sel)
        t = time.perf_counter()
        d = np.asarray(db.matchers[m].distances(desc[m], sub), float)
        out.time(r, time.perf_counter() - t)
        d = np.where(np.isfinite(d), d, np.inf)
        j = int(np.argmin(d))
        out.put(r, int(keys[sel[j]]), -float(d[j]))


def _cascade_rows(
    out: QueryRecords, k: int, desc: dict[str, Any], db: PlaceDatabase, detector: Any,
    mapper: RecordingMapper, keys: NDArray[np.intp], sel: NDArray[np.intp],
    mask: NDArray[np.bool_], near: NDArray[np.bool_], poses: Array, timing_every: int,
    kmax: int, wide: _View | None = None,
) -> None:
    """The prefilter, verifier, fused and final rows of one query with candidates.

    With the detector's wide view (`wide`, when the query has a wide description):
    a prefilter row orders the keyframes by their two views' ranks interleaved
    (`interleaved_order`; the own view's two lists with
    ``viewpoint_order="interleave"``, `PlaceDatabase.prefilter_lists`), and ``fused``
    is the union of the two views' queries (`loopclosure.place_choice.merge_views`),
    as the detector asks."""
    cfg = db.config
    verifier_rows = [f"{v}@{cfg.top_k}" for v in cfg.verifiers]
    db.scales  # noqa: B018 -- a due re-estimate of the scales runs here, outside the timers
    wide_desc, wide_mask = None, None
    asked = detector.wide_key(k) if wide is not None else None
    if asked is not None and asked in wide.db:
        wide.db.scales  # noqa: B018 -- as above
        wide_desc = wide.db.descriptors(asked)
        wide_mask = np.isin(wide.keys, keys[sel])
    t = time.perf_counter()
    combined, raw = db.prefilter_distances(desc, sel)
    views = {r: [d] for r, d in (*raw.items(), ("prefilter", combined))}
    if wide_desc is not None:
        w_sel = np.flatnonzero(wide_mask)
        w_combined, w_raw = wide.db.prefilter_distances(wide_desc, w_sel)
        at = np.searchsorted(keys[sel], wide.keys[w_sel])  # both in key order
        for r, d in (*w_raw.items(), ("prefilter", w_combined)):
            scattered = np.full(len(sel), np.inf)
            scattered[at] = d
            views[r].append(scattered)
    t_pre = time.perf_counter() - t
    if cfg.viewpoint_order != "min":  # the own view ranks by two lists (place_shortlist)
        views["prefilter"][:1] = db.prefilter_lists(desc, sel)
    for r, per_view in views.items():
        order, d = interleaved_order(per_view)
        top = order[:kmax]
        out.put(r, int(keys[sel[top[0]]]), -float(d[top[0]]))
        hit = np.zeros(kmax, bool)
        hit[: len(top)] = near[top]
        out.hits.setdefault(r, []).append(hit)
        out.time(r, t_pre)
        if r == "prefilter" and cfg.vote == "fuse":
            _vote_row(out, db, desc, sel, order, near, kmax)
    t = time.perf_counter()
    matches = db.query(desc, allowed=mask)
    if wide_desc is not None:
        matches = merge_views([matches, wide.db.query_stored(asked, allowed=wide_mask)])
    t_query = time.perf_counter() - t
    out.time("fused", t_query)
    out.candidate_hit.append(bool(np.isin([int(m.key) for m in matches], keys[sel][near]).any()))
    out.candidate_count.append(len(matches))
    best = matches[0]
    out.put("fused", int(best.key), best.score)
    timed = timing_every <= 1 or len(out.keys) % timing_every == 1
    for v, r in zip(cfg.verifiers, verifier_rows, strict=True):
        d = np.array([m.distances[v] for m in matches])
        j = int(np.argmin(d))
        out.put(r, int(matches[j].key), -float(d[j]))
        if timed:
            matcher = db.matchers[v]
            stacked = matcher.stack([db.descriptors(m.key)[v] for m in matches])
            t = time.perf_counter()
            matcher.distances(desc[v], stacked)
            out.time(r, t_pre + time.perf_counter() - t)
    t = time.perf_counter()
    out.answers[k] = matches
    for old in [j for j in out.answers if j < k - detector.config.trail_keyframes]:
        del out.answers[old]
    trailed = detector.with_trail(k, matches, poses, out.answers, keys[sel])
    checked = detector.verify_places(k, detector.places(trailed, poses), poses,
                                     mapper.query_submaps.get(k), allowed=keys[sel])
    out.time("final", t_query + time.perf_counter() - t)
    accepted = [c for c in checked if c.accepted]
    # Of several accepted places, the one the check measures nearest (protocol step 3).
    cand = min(accepted, key=lambda c: float(np.hypot(*c.relative[:2])), default=checked[0])
    out.accepted.append(bool(cand.accepted))
    out.final_match.append(int(cand.match))
    out.final_score.append(float(cand.fused_score) if cand.accepted else -np.inf)
    out.relative.append(np.asarray(cand.relative, float))
    out.reason.append(str(cand.reason))
    v = cand.verification
    out.figures.append(np.array([float(getattr(v, f)) if v is not None else np.nan
                                 for f in CHECK_FIGURES]))
    out.accepted_places.append(len(accepted))


def vote_rows(cfg: Any) -> tuple[str, ...]:
    """The recall@K row of the pair vote (`PlaceDatabaseConfig.vote`), if on."""
    return (VOTE_ROW,) if cfg.vote == "fuse" else ()


def _vote_row(out: QueryRecords, db: PlaceDatabase, desc: dict[str, Any],
              sel: NDArray[np.intp], order: NDArray[np.intp], near: NDArray[np.bool_],
              kmax: int) -> None:
    """The recall@K hits of the ``prefilter+vote`` row: the prefilter row's order
    with the vote's places among its first K as the database picks its candidates
    (`loopclosure.place_shortlist.vote_fused_order`)."""
    cfg = db.config
    fused = vote_fused_order(order, db.vote_scores(desc, sel), cfg.vote_split, cfg.top_k)
    top = fused[:kmax]
    hit = np.zeros(kmax, bool)
    hit[: len(top)] = near[top]
    out.hits.setdefault(VOTE_ROW, []).append(hit)


def interleaved_order(per_view: Sequence[Array]) -> tuple[NDArray[np.intp], Array]:
    """Database rows ordered across several views of one query.

    ``per_view[v]`` holds view v's distance to every row (``inf``: the view does not
    hold that row).  A row's place in the order is its best rank in any view (0 =
    that view's nearest); rows of equal rank go by the smaller of those views'
    distances, then by row.  So the first 2K rows of two views hold both views' K
    best, and the first row is the one with the smallest distance in any view.  The
    views' distances are normalised by different databases, so their values do not
    compare beyond that tie-break: merging by the smaller distance alone lets the
    view whose distances run lower crowd the other's best rows out.

    Returns:
        ``(order, distance)``: the row order, and each row's distance in the view
        that ranks it best (the smaller on ties).
    """
    return rank_interleave_with_distance(np.vstack([np.asarray(v, dtype=float)
                                                    for v in per_view]))
