"""`loopclosure bench loops`: appearance-only loop detection, stage by stage, as published.

Protocol
--------
1. **Keyframes exactly as `loopclosure run` makes them.**  The log runs through
   `slam.pipeline.Mapper` with the given `PipelineConfig` but with the loop searches
   switched off (``loops.local_max = 0``, ``loops.global_every = 0``): same front end,
   same keyframes, and every keyframe described by the loop detector at insertion
   (its own polygon, or a virtual scan of its trailing submap for narrower lasers).
   The submap each keyframe had when it was the newest one (``k - n .. k``) is kept:
   it is the query submap the pipeline's geometric check uses at that keyframe.
2. **Reference poses** of the keyframes (``(x, y, theta)`` [m, m, rad]): a callback of
   the mapping result (relations-fitted, a TUM file, the log's own poses, or the
   simulator's ground truth; `evaluation.cli_loops`).  Keyframes without one are left
   out of queries *and* databases (a proposal to them could not be judged); a
   reference covering less than ``min_coverage`` of the keyframes is refused.
3. **Queries, no pose prior.**  A fresh `loopclosure.PlaceDatabase` (the config's
   ``loops.database``) receives the keyframes' descriptors in order; right after
   keyframe k is added it queries the database of the older keyframes the detector
   would search (`LoopClosureDetector.eligible`: outside ``exclude_recent`` keyframes
   / ``exclude_recent_s`` seconds, described; the time rule as the detector holds it at
   the end of the run) that have a reference pose.  So the
   database's normalisation scales are those `run` has at that keyframe.  A query
   against an empty database, or by a keyframe the detector could not describe (no
   polygon: no valid beams, a degenerate local map; such a keyframe is never a
   candidate either), proposes nothing: it can still have a revisit, which it then
   misses.  Per query:

   * prefilter stages on their own and combined (``fft``, ``ring``, ``prefilter``):
     exact distances to every database keyframe (`PlaceDatabase.prefilter_distances`,
     one vectorised pass); top-1 = smallest, score = minus the distance;
   * each verifier of the cascade (``<name>@K``): its distance over the K prefilter
     candidates of the database's own query; top-1 = smallest;
   * ``fused``: the database's query (`PlaceDatabase.query`, K = ``top_k``), top-1 =
     highest fused score;
   * with the detector's wide view (`LoopClosureDetector`, ``loops.wide_keyframes``;
     a keyframe of a narrower sensor is also described from the map of its last
     keyframes, or queries with a keyframe's a few keys older: `wide_key`): its
     database is mirrored the same way; a prefilter row interleaves the two views'
     orders by rank (`evaluation.loop_bench_queries.interleaved_order`: each view's
     K best are among the first 2K, as the detector's query takes each view's K
     best), ``fused`` is the union of both views' queries
     (`loopclosure.place_choice.merge_views`, as the detector's search), and the
     verifier rows read their distances from that union;
   * ``<name>-alone`` (optional, any stage matcher, e.g. ``flirt-alone``): that matcher
     over the whole database (stacked once, rows selected per query), no prefilter;
   * **final**: the database's candidates through the geometric check exactly as the
     global search runs it (`LoopClosureDetector.verify_places`), whatever their
     scores, joined as the detector joins them by the answers of the query's trail
     (`LoopClosureDetector.with_trail`: the earlier queries of the keyframes within
     ``loops.trail_radius`` of it on its way in, by the front end's poses): the
     places `LoopClosureDetector.places` picks (the best
     ``loops.global_verify`` distinct places of the prefilter's K in fused order, then
     the grids' extras), checked with no prior until ``loops.max_loops`` are accepted,
     accepted ones that put the query in places farther apart than
     ``loops.agree_distance`` rejected (the map's poses of the database keyframes,
     the front end's here, say where each place is; the query's own pose is never
     used).  The proposal is the accepted
     candidate whose checked relative pose is the shortest (of two verified places
     of one query the nearer overlaps more: the place the query is in), score = its
     fused score (none accepted: no proposal).  A check that finds the query nearer
     another keyframe moves to it only among the database's keyframes (those with a
     reference pose).

4. **Truth and measures**: `evaluation.loop_bench_truth` (revisit within 2 m; a
   proposal is correct within 2 m, after the check also within 0.2 m / 2 degrees).

Timing: milliseconds per query (wall clock, single thread as called) of the work
each row needs: the prefilter rows share one pass over the database (fft, ring and
their combination come out of it together); ``<v>@K`` = that pass + the verifier over
the K candidates (timed on every `timing_every`-th query, its own descriptors stacked
outside the timer); ``fused`` = the database's whole query (screening, every verifier,
fusion, headings); final = fused + the geometric check; ``-alone`` rows = the matcher
over every database keyframe.  The database's occasional re-estimate of its
normalisation scales (O(log M) times in a run) is left out of every row's time.
Database size = keyframes each query searched.  The queries and their rows are
`evaluation.loop_bench_queries`; this module maps, plans, judges and assembles.

Unit of work
------------
One stage block on one log is one task (`LoopTask`, run by `loop_task`;
`stage_blocks`): the cascade (every row but the ``-alone`` ones, and the final check,
which come out of one database query per keyframe), and each ``-alone`` row on its
own.  Each block maps the log (step 1) in the process it runs in, once per process
(the blocks run here share one mapping), so its keyframes are those of every other
block; it returns its rows (a `LoopBlock`), and the table is assembled from the
blocks in row order.  With ``cluster`` (`evaluation.cluster`) the workers read the
input themselves from a `LoopSource` (the same paths on every node of a real
cluster); the rows equal the serial ones, only the seconds differ.
"""

from __future__ import annotations

import dataclasses
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from evaluation.loop_bench_input import LoopInput, LoopSource
from evaluation.loop_bench_queries import (
    ALONE,
    CHECK_FIGURES,
    RECALL_KS,
    QueryRecords,
    RecordingMapper,
    query_all,
    vote_rows,
)
from evaluation.loop_bench_truth import (
    PRCurve,
    pose_correct,
    pose_errors,
    pr_curve,
    recall_at_k,
    within_reference_uncertainty,
)
from slam.config import PipelineConfig
from slam.pipeline import Mapper, MappingResult

Array = NDArray[np.float64]
Progress = Callable[[str, int, int], None]
ReferenceFn = Callable[[MappingResult], Array]
"""``reference(result) -> (K, 3)`` reference pose of every keyframe (NaN rows: none)."""


def _no_progress(stage: str, done: int, total: int) -> None:
    return None


@dataclass(slots=True)
class Tolerances:
    """Truth tolerances: revisit / place radius [m], relative pose [m], [deg]."""

    max_distance: float = 2.0
    trans_tol: float = 0.2
    rot_tol_deg: float = 2.0


@dataclass(slots=True)
class StageResult:
    """The top-1 proposals of one row, one per query.

    Attributes:
        name: row name.
        match: ``(n,)`` proposed keyframe id (-1: no proposal).
        score: ``(n,)`` its score, higher = more confident (-inf: no proposal).
        correct: ``(n,)`` the proposal is correct (module docstring).
        curve: precision-recall curve over the score threshold.
        ms_per_query: mean milliseconds per query (module docstring).
    """

    name: str
    match: NDArray[np.intp]
    score: Array
    correct: NDArray[np.bool_]
    curve: PRCurve
    ms_per_query: float


@dataclass(slots=True)
class LoopBench:
    """Everything one `run_loop_bench` produced.

    Attributes:
        name: the input as shown in reports.
        keyframes: keyframes mapped; covered: those with a reference pose.
        query_keys: ``(n,)`` keyframe id of every query (covered, in order).
        has_revisit: ``(n,)`` the query has a revisit.
        database_size: ``(n,)`` keyframes each query searched.
        stages: the rows before the geometric check, by name, in report order.
        final: the fused top-1 after the geometric check.
        accepted: ``(n,)`` the check accepted the fused top-1.
        final_errors: ``(n, 2)`` error [m], [deg] of the checked relative pose against
            the reference (NaN without a proposal).
        reasons: ``(n,)`` the check's verdict text.
        recall_at_k: prefilter stage -> {K: recall@K}.
        candidate_recall: share of the queries with a revisit whose verified
            candidates (the database's K and the grids' extras, both views) hold a
            true place: the most the fused and final rows can find.
        candidate_count: mean number of candidates verified per query.
        reference: ``(keyframes, 3)`` reference poses (NaN rows: none).
        scan_index: ``(keyframes,)`` scan index of every keyframe.
        min_score: the detector's fused-score threshold (the pipeline's operating point).
        tolerances: truth tolerances.
        wall_s: seconds of mapping and of the queries.
        config: the pipeline's parameters.
        prefilter_rank: ``(n,)`` rank (0-based) of the first true place in the
            combined prefilter's order, -1 when none is among the first
            ``max(RECALL_KS)`` (`evaluation.loop_bench_misses`).
        nearest: ``(n, 4)`` the nearest true place of every query: key, distance [m],
            heading difference [deg], submap overlap (key -1 and NaN without a revisit).
        check_figures: ``(n, len(CHECK_FIGURES))`` the geometric check's figures of the
            final row's place (`loopclosure.geometric_check.LoopVerification`; NaN
            without a check).
        accepted_places: ``(n,)`` places the check accepted for the query.
        reference_sigmas: ``(n, 3)`` standard deviations (x, y [m], theta [rad]) of the
            reference's relative pose of each accepted final detection's two keyframes
            (NaN elsewhere; None when the reference does not know them: only a
            relations reference does).
        unverifiable: ``(n,)`` wrong final detections within the reference's own
            uncertainty (`evaluation.loop_bench_truth.within_reference_uncertainty`);
            None with `reference_sigmas`.
    """

    name: str
    keyframes: int
    covered: int
    query_keys: NDArray[np.intp]
    has_revisit: NDArray[np.bool_]
    database_size: NDArray[np.intp]
    stages: dict[str, StageResult]
    final: StageResult
    accepted: NDArray[np.bool_]
    final_errors: Array
    reasons: list[str]
    recall_at_k: dict[str, dict[int, float]]
    candidate_recall: float
    candidate_count: float
    reference: Array
    scan_index: NDArray[np.intp]
    min_score: float
    tolerances: Tolerances
    wall_s: dict[str, float] = field(default_factory=dict)
    config: PipelineConfig | None = None
    prefilter_rank: NDArray[np.intp] | None = None
    nearest: Array | None = None
    check_figures: Array | None = None
    accepted_places: NDArray[np.intp] | None = None
    reference_sigmas: Array | None = None
    unverifiable: NDArray[np.bool_] | None = None

    @property
    def revisits(self) -> int:
        """Queries with a revisit."""
        return int(self.has_revisit.sum())


def default_stages(config: PipelineConfig) -> list[str]:
    """Every row of the database's config, and FLIRT alone when FLIRT is a stage."""
    db = config.loops.database
    rows = [*db.prefilter, "prefilter"]
    rows += [f"{v}@{db.top_k}" for v in db.verifiers]
    rows.append("fused")
    if "flirt" in db.stages:
        rows.append("flirt" + ALONE)
    return rows


def parse_stages(text: str | None, config: PipelineConfig) -> list[str]:
    """Row names from ``--stages`` (comma-separated, or ``all``/None for `default_stages`).

    A verifier may be written with or without ``@K``; ``NAME-alone`` needs NAME to be a
    stage of the database (its descriptors are what is stored).
    """
    default = default_stages(config)
    if text is None or text.strip().lower() in ("", "all"):
        return default
    db = config.loops.database
    out = []
    for part in (p.strip().lower() for p in text.split(",") if p.strip()):
        if part in db.verifiers:
            part = f"{part}@{db.top_k}"
        known = part in default or (part.endswith(ALONE) and part[: -len(ALONE)] in db.stages)
        if not known:
            raise UserError(
                f"--stages: unknown stage {part!r}; choose from {', '.join(default)} or "
                f"NAME{ALONE} for a stage NAME of {', '.join(db.stages)}"
            )
        out.append(part)
    if not out:
        raise UserError("--stages needs at least one stage")
    return list(dict.fromkeys(out))


def bench_config(config: PipelineConfig) -> PipelineConfig:
    """`config` with both loop searches switched off (keyframes and descriptors unchanged)."""
    loops = dataclasses.replace(config.loops, local_max=0, global_every=0)
    return dataclasses.replace(config, loops=loops)


def _query_plan(n: int, max_queries: int | None) -> NDArray[np.bool_]:
    """Which keyframes query: all, or `max_queries` spread evenly."""
    plan = np.ones(n, bool)
    if max_queries is not None:
        if max_queries < 1:
            raise UserError(f"--max-queries must be >= 1, got {max_queries}")
        if max_queries < n:
            plan[:] = False
            plan[np.unique(np.linspace(0, n - 1, max_queries).round().astype(int))] = True
    return plan


def run_loop_bench(
    name: str,
    scans: Sequence[Any],
    config: PipelineConfig,
    reference: ReferenceFn,
    *,
    stages: Sequence[str] | None = None,
    max_queries: int | None = None,
    min_coverage: float = 0.5,
    timing_every: int = 10,
    tolerances: Tolerances | None = None,
    progress: Progress = _no_progress,
) -> LoopBench:
    """Map `scans`, then query every keyframe's place with no pose prior (module docstring),
    here, one stage block after the other (`loop_benchmark`).

    Raises:
        UserError: fewer than two keyframes, or a reference covering less than
            `min_coverage` of them (the message gives the coverage).
    """
    return loop_benchmark(LoopInput(name, scans, reference), config, stages=stages,
                          max_queries=max_queries, min_coverage=min_coverage,
                          timing_every=timing_every, tolerances=tolerances, progress=progress)


def stage_blocks(rows: Sequence[str]) -> list[tuple[tuple[str, ...], bool]]:
    """The units of work of `rows`: ``(rows, cascade)`` blocks.

    The first block is the cascade (every row but the ``-alone`` ones, and the final
    check: they come out of one database query), then one block per ``-alone`` row
    (a matcher over the whole database, the costliest rows).
    """
    alone = [r for r in rows if r.endswith(ALONE)]
    return [(tuple(r for r in rows if r not in alone), True), *(((r,), False) for r in alone)]


@dataclass(frozen=True, slots=True)
class LoopTask:
    """One stage block (`stage_blocks`) of the benchmark on the input `source` names (a
    `LoopSource`, or the key of an input held in this process's memory)."""

    source: LoopSource | str
    config: PipelineConfig
    rows: tuple[str, ...]
    cascade: bool
    max_queries: int | None
    min_coverage: float
    timing_every: int
    tolerances: Tolerances


@dataclass(slots=True)
class LoopBlock:
    """What one `LoopTask` returns: its rows, its query seconds and, for the cascade
    block, the whole `LoopBench` of its rows (queries, final check, recall@K)."""

    stages: dict[str, StageResult]
    query_s: float
    bench: LoopBench | None = None


_INPUTS: dict[LoopSource | str, tuple[LoopInput, Progress]] = {}
"""The inputs this process holds, by the `LoopTask.source` that names them."""
_MAPPED: dict[tuple[Any, str], tuple[RecordingMapper, MappingResult, float]] = {}
"""The mapping of each input here (source, config), shared by its blocks."""


def loop_benchmark(
    inp: LoopInput,
    config: PipelineConfig,
    *,
    stages: Sequence[str] | None = None,
    max_queries: int | None = None,
    min_coverage: float = 0.5,
    timing_every: int = 10,
    tolerances: Tolerances | None = None,
    progress: Progress = _no_progress,
    source: LoopSource | None = None,
    cluster: str | None = None,
) -> LoopBench:
    """The benchmark of `inp`, one `LoopTask` per stage block (`stage_blocks`).

    Without `cluster` the blocks run here, on `inp`, sharing one mapping; with it (an
    `evaluation.cluster` address) on Dask, each worker reading `source` (the source
    `inp` was opened from: required) and mapping it once.  The rows are the same
    either way; only the seconds differ.
    """
    from evaluation.cluster import map_tasks

    if cluster is not None and source is None:
        raise UserError("a cluster run needs the input as a LoopSource, not scans in memory")
    _query_plan(1, max_queries)  # a bad --max-queries fails before the mapping
    tol = tolerances or Tolerances()
    rows = list(stages) if stages is not None else default_stages(config)
    key: LoopSource | str = source if source is not None else f"memory-{uuid.uuid4().hex}"
    tasks = [LoopTask(key, config, block, cascade, max_queries, min_coverage, timing_every, tol)
             for block, cascade in stage_blocks(rows)]
    _INPUTS[key] = (inp, progress)
    try:
        blocks = [_block(o) for o in map_tasks(loop_task, tasks, cluster=cluster, retries=0,
                                               description="bench loops",
                                               progress=cluster is not None)]
    finally:
        _INPUTS.pop(key, None)
        for mapped in [m for m in _MAPPED if m[0] == key]:
            del _MAPPED[mapped]
    bench = blocks[0].bench
    found = {name: stage for b in blocks for name, stage in b.stages.items()}
    bench.stages = {r: found[r] for r in rows}
    bench.wall_s = {"mapping": bench.wall_s["mapping"],
                    "queries": sum(b.query_s for b in blocks)}
    return bench


def _block(outcome: Any) -> LoopBlock:
    return outcome.result(f"bench loops, {', '.join(outcome.item.rows) or 'final'}")


def _input_of(source: LoopSource | str) -> tuple[LoopInput, Progress]:
    """The input `source` names: held here already, or read now (once per process)."""
    if source not in _INPUTS:
        if not isinstance(source, LoopSource):
            raise UserError("bench loops: this worker does not hold the scans in memory; "
                            "give the input as a LoopSource")
        _INPUTS.clear()  # a worker holds one input at a time
        _INPUTS[source] = (source.open(), _no_progress)
    return _INPUTS[source]


def _mapping(
    source: Any, inp: LoopInput, config: PipelineConfig, progress: Progress
) -> tuple[RecordingMapper, MappingResult, float]:
    """`inp` mapped with the loop searches off (protocol step 1), once per process."""
    key = (source, repr(config))
    if key not in _MAPPED:
        start = time.perf_counter()
        mapper = RecordingMapper(bench_config(config))
        total = len(inp.scans)

        def mapped(n: int, keyframes: int, loops: int) -> None:
            if n % 20 == 0 or n == total:
                progress("mapping", n, total)

        result = mapper.run(inp.scans, progress=mapped)
        _MAPPED.clear()  # a process holds one mapping at a time
        _MAPPED[key] = (mapper, result, time.perf_counter() - start)
    return _MAPPED[key]


def mapped_input(
    source: LoopSource, config: PipelineConfig, progress: Progress = _no_progress
) -> tuple[Mapper, MappingResult, Array]:
    """`source` read and mapped as the benchmark maps it (protocol step 1: the loop
    searches off), for diagnoses of single queries.

    Returns the mapper (its ``detector`` holds every keyframe's description and submap;
    ``query_submaps[k]`` is keyframe k's submap as it was when k was the newest), the
    mapping, and the reference poses of its keyframes ``(n, 3)`` (NaN rows: none)."""
    inp, _ = _input_of(source)
    mapper, result, _ = _mapping(source, inp, config, progress)
    ref = np.asarray(inp.reference(result), float).reshape(len(result.keyframes), 3)
    return mapper, result, ref


def loop_task(task: LoopTask) -> LoopBlock:
    """One stage block (`LoopTask`): the input mapped (once per process), its queries
    and their truth; a `LoopBlock`."""
    inp, progress = _input_of(task.source)
    mapper, result, map_s = _mapping(task.source, inp, task.config, progress)
    n_kf = len(result.keyframes)
    if n_kf < 2:
        raise UserError(f"{inp.label}: {n_kf} keyframe(s) mapped; the benchmark needs at "
                        "least 2")
    ref = np.asarray(inp.reference(result), float).reshape(n_kf, 3)
    covered = np.isfinite(ref).all(axis=1)
    if covered.sum() < max(2, task.min_coverage * n_kf):
        raise UserError(
            f"{inp.label}: the reference covers {int(covered.sum())} of {n_kf} keyframes "
            f"({100 * covered.mean():.1f}%); the benchmark needs at least "
            f"{100 * task.min_coverage:.0f}%"
        )
    tol = task.tolerances
    start = time.perf_counter()
    poses = np.array([result.keyframe_poses[kf.id] for kf in result.keyframes], float)
    raw = query_all(mapper, ref, covered, poses, task.rows,
                     _query_plan(n_kf, task.max_queries), task.timing_every, tol.max_distance,
                     progress, cascade=task.cascade,
                     label="queries" if task.cascade else task.rows[0])
    query_s = time.perf_counter() - start
    if not task.cascade:
        return LoopBlock(_stage_results(raw, ref, task.rows, tol), query_s)
    bench = _evaluate(inp.label, raw, ref, covered, task.rows, tol, result, task.config)
    sigmas = getattr(inp.reference, "sigmas", None)
    if sigmas is not None:
        _reference_uncertainty(bench, lambda pairs: sigmas(result, pairs))
    bench.wall_s = {"mapping": map_s, "queries": query_s}
    return LoopBlock(bench.stages, query_s, bench)


def _reference_uncertainty(bench: LoopBench, sigmas: Callable[[Array], Array]) -> None:
    """`bench.reference_sigmas` and `bench.unverifiable` of the accepted final
    detections; `sigmas` maps ``(m, 2)`` keyframe pairs (match, query) to the
    reference's ``(m, 3)`` relative-pose sigmas."""
    f = bench.final
    n = len(bench.query_keys)
    done = bench.accepted & (f.match >= 0)
    sig = np.full((n, 3), np.nan)
    if done.any():
        pairs = np.column_stack([f.match[done], bench.query_keys[done]])
        sig[done] = np.asarray(sigmas(pairs), float).reshape(-1, 3)
    place = np.full(n, np.nan)
    ref = bench.reference
    place[done] = np.hypot(*(ref[f.match[done], :2] - ref[bench.query_keys[done], :2]).T)
    tol = bench.tolerances
    bench.reference_sigmas = sig
    bench.unverifiable = done & ~f.correct & within_reference_uncertainty(
        bench.final_errors, place, sig, max_distance=tol.max_distance,
        trans_tol=tol.trans_tol, rot_tol_deg=tol.rot_tol_deg)


def _stage_results(
    raw: QueryRecords, ref: Array, rows: Sequence[str], tol: Tolerances
) -> dict[str, StageResult]:
    """The top-1 proposals of every row of `rows`, judged against `ref`."""
    q = np.asarray(raw.keys, np.intp)
    revisits = int(np.asarray(raw.revisit, bool).sum())
    stages: dict[str, StageResult] = {}
    for r in rows:
        match = np.asarray(raw.match.get(r, []), np.intp)
        score = np.asarray(raw.score.get(r, []), float)
        ok = match >= 0
        correct = np.zeros(len(q), bool)
        if ok.any():
            d = np.hypot(*(ref[q[ok], :2] - ref[match[ok], :2]).T)
            correct[ok] = d <= tol.max_distance
        secs = raw.seconds.get(r, [])
        stages[r] = StageResult(r, match, score, correct, pr_curve(score, correct, revisits),
                                1e3 * float(np.mean(secs)) if secs else float("nan"))
    return stages


def _evaluate(
    name: str, raw: QueryRecords, ref: Array, covered: NDArray[np.bool_], rows: Sequence[str],
    tol: Tolerances, result: MappingResult, config: PipelineConfig,
) -> LoopBench:
    """Truth of every proposal, the curves and recall@K (`evaluation.loop_bench_truth`)."""
    q = np.asarray(raw.keys, np.intp)
    has = np.asarray(raw.revisit, bool)
    revisits = int(has.sum())
    stages = _stage_results(raw, ref, rows, tol)
    match = np.asarray(raw.final_match, np.intp)
    accepted = np.asarray(raw.accepted, bool)
    relative = np.asarray(raw.relative, float).reshape(-1, 3)
    errors = np.full((len(q), 2), np.nan)
    final_ok = np.zeros(len(q), bool)
    has_match = match >= 0
    if has_match.any():
        errors[has_match] = pose_errors(ref[q[has_match]], ref[match[has_match]],
                                        relative[has_match])
        final_ok[has_match] = pose_correct(
            ref[q[has_match]], ref[match[has_match]], relative[has_match],
            max_distance=tol.max_distance, trans_tol=tol.trans_tol,
            rot_tol_deg=tol.rot_tol_deg) & accepted[has_match]
    final_score = np.asarray(raw.final_score, float)
    secs = raw.seconds.get("final", [])
    final = StageResult("final", np.where(accepted, match, -1), final_score, final_ok,
                        pr_curve(final_score, final_ok, revisits),
                        1e3 * float(np.mean(secs)) if secs else float("nan"))
    recall_k = {}
    for r in (*config.loops.database.prefilter, "prefilter", *vote_rows(config.loops.database)):
        hits = np.asarray(raw.hits.get(r, []), bool).reshape(len(q), max(RECALL_KS))
        recall_k[r] = recall_at_k(hits, has, RECALL_KS)
    pre = np.asarray(raw.hits.get("prefilter", []), bool).reshape(len(q), max(RECALL_KS))
    rank = np.where(pre.any(axis=1), pre.argmax(axis=1), -1)
    cand_hit = np.asarray(raw.candidate_hit, bool)
    cand_count = np.asarray(raw.candidate_count, float)
    return LoopBench(
        name=name, keyframes=len(ref), covered=int(covered.sum()), query_keys=q,
        has_revisit=has, database_size=np.asarray(raw.size, np.intp), stages=stages,
        final=final, accepted=accepted, final_errors=errors, reasons=list(raw.reason),
        recall_at_k=recall_k,
        candidate_recall=float(cand_hit[has].mean()) if has.any() else float("nan"),
        candidate_count=float(cand_count.mean()) if len(cand_count) else 0.0, reference=ref,
        scan_index=np.array([kf.scan_index for kf in result.keyframes], np.intp),
        min_score=config.loops.min_score, tolerances=tol, config=config,
        prefilter_rank=rank, nearest=np.asarray(raw.nearest, float).reshape(len(q), 4),
        check_figures=np.asarray(raw.figures, float).reshape(len(q), len(CHECK_FIGURES)),
        accepted_places=np.asarray(raw.accepted_places, np.intp),
    )
