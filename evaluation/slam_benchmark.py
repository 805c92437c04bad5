"""`loopclosure bench slam`: our pipeline, wheel odometry and KISS-ICP on one log, side by side.

`run_slam_benchmark` runs every method (`evaluation.slam_methods`: ``pipeline``,
``wheel``, ``kiss-icp``) over the same scans, read into memory before any timing
(`evaluation.slam_input.load_input`; ``limit`` keeps the first N scans), then
measures each.  All methods report poses of the sensor in the odometry frame of the
first scan (``(x, y, theta)`` [m, m, rad]), one per scan.  Per method: wall seconds
of the run (reading excluded) and milliseconds per scan.  A method that raises (a
bug, not bad input) is reported as failed and the other methods still run.
`evaluation.slam_report` turns the result into the table, the JSON document and the
output folder.

Unit of work
------------
One method on one log is one task (`MethodTask`, run by `method_task`): it runs the
method, measures it and, with an output folder, writes that method's files there
(``<method>.tum``; for the pipeline also ``pipeline/``), and returns a small
`MethodSummary` (the measures, the paths it wrote, the accepted loops' end points
for the plot, the relations reference); the report is built from the summaries
only.  Without a cluster the tasks run here, in the order asked, on the scans
already in memory; with ``cluster`` (`evaluation.cluster`) each worker reads the
input itself from the paths of a `SlamSource` (a real cluster needs them at the
same paths on every node), so the figures are the same, only the seconds differ.

Measures
--------
* **Relations metric** (`evaluation.relations_metric`, Kümmerle et al. 2009) of the
  per-scan trajectory, over the relations whose two stamps are both among the scans
  read (within 1 ms); ``relations_total`` counts those, the file's count is in the
  document's ``relations`` section.  Duplicate stamps keep their first scan.
* **ATE / RPE** (`evaluation.trajectory_error`) against a reference trajectory
  (``reference``: a TUM file, or ``reference_from_log``: the poses logged in the
  input, for GMapping-corrected logs, which needs ``odometry_noise``).  Trajectories
  are stamped as `loopclosure run` stamps its output (`slam.outputs.output_stamps`):
  the scan stamps when they are unique, else the scan index (0, 1, ...), so a
  reference written from such a log must use the scan index too.
* **Loop closures** of the pipeline (`evaluation.loop_verdicts`, default tolerances
  of `evaluation.loop_metrics.evaluate_loops`: 2 m, 0.2 m, 2 deg): counts (proposed
  = every candidate verified, accepted = kept after the final GNC, rejected by the
  check, rejected by GNC) and precision / recall against each reference available,
  for the final loops and for the loops the geometric check accepted
  (``before_gnc``); with an output folder, every candidate's verdict and error
  against each reference in ``pipeline/loops_vs_reference.csv`` /
  ``loops_vs_relations.csv``.  Loops are evaluated in scan-index time: every
  keyframe is stamped with its scan index and the reference pose of a keyframe is
  looked up at its scan's (output) stamp, so a log whose clock runs backwards still
  orders queries correctly.  With relations, the keyframes' reference poses are
  solved from them (`evaluation.slam_reference.relations_reference`, independent of
  the pipeline's loop closures; its docstring gives the graph).
"""

from __future__ import annotations

import uuid
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError, warn
from data.types import Relation, Trajectory
from evaluation.loop_verdicts import loop_counts, loop_evaluation
from evaluation.relations_metric import relations_metric
from evaluation.slam_input import (
    Progress,
    SlamInput,
    evaluation_stamps,
    load_input,
    no_progress,
)
from evaluation.slam_methods import MethodRun, run_method
from evaluation.slam_reference import (
    RELATION_TOLERANCE,
    RelationsReference,
    keyframe_reference,
    logged_reference,
    relations_in_range,
    relations_reference,
    trajectory_at_stamps,
)
from evaluation.trajectory_error import associate, trajectory_errors
from slam.config import PipelineConfig

Array = NDArray[np.float64]


@dataclass(slots=True)
class SlamContext:
    """The scans every method maps and what each is measured against.

    Attributes:
        data: the scans; eval_stamps, stamp_rule: `evaluation_stamps` of them.
        relations_file, relations_in_file, relations_used: the relations given, their
            count in the file, and those with both stamps among the scans.
        reference_name, reference: the reference trajectory (eval-stamped), if any.
    """

    data: SlamInput
    eval_stamps: Array
    stamp_rule: str
    relations_file: str | None = None
    relations_in_file: int = 0
    relations_used: list[Relation] = field(default_factory=list)
    reference_name: str | None = None
    reference: Trajectory | None = None


def slam_context(
    data: SlamInput,
    *,
    relations: Sequence[Relation] | None = None,
    relations_file: str | None = None,
    reference: Trajectory | None = None,
    reference_name: str | None = None,
) -> SlamContext:
    """`data` with its evaluation stamps, the relations among its scans and the reference.

    `reference` is stamped like the evaluated trajectories (`evaluation_stamps`).
    Relations with no pair of stamps among the scans, or a reference sharing fewer
    than two stamps with them, raise `UserError` (before any slow run).
    """
    eval_stamps, rule = evaluation_stamps(data.stamps)
    used = _relations_among_scans(relations, relations_file, data.stamps)
    if reference is not None:
        _check_reference(reference, eval_stamps, rule, reference_name or "reference")
    return SlamContext(data, eval_stamps, rule, relations_file,
                       len(relations) if relations is not None else 0, used, reference_name,
                       reference)


@dataclass(frozen=True, slots=True)
class SlamSource:
    """Where the benchmark's input is read from: the log or bag with the options of
    `load_input`, and the relations / reference files.

    Relative paths are taken from `folder` (the caller's working folder, so that a
    worker started elsewhere finds them) and reported as given.
    """

    path: str
    limit: int | None = None
    odometry_noise: int | None = None
    topic: str | None = None
    odom_topic: str | None = None
    strict: bool = False
    relations: str | None = None
    reference: str | None = None
    reference_from_log: bool = False
    folder: str = "."

    def open(self, progress: Progress = no_progress) -> SlamContext:
        """Read everything and check it (`slam_context`); `UserError` / `DataError`."""
        from data.relations import read_relations
        from data.trajectory_io import read_tum

        here = Path(self.folder)
        rels = read_relations(here / self.relations) if self.relations is not None else None
        ref = read_tum(here / self.reference) if self.reference is not None else None
        ref_name = self.reference
        data = load_input(here / self.path, limit=self.limit,
                          odometry_noise=self.odometry_noise, topic=self.topic,
                          odom_topic=self.odom_topic, strict=self.strict, progress=progress)
        data.name = self.path
        if self.reference_from_log:
            ref, ref_name = logged_reference(data), "logged poses"
        return slam_context(data, relations=rels, relations_file=self.relations, reference=ref,
                            reference_name=ref_name)


@dataclass(frozen=True, slots=True)
class MethodTask:
    """One task: `method` on the input `source` names (a `SlamSource`, or the key of an
    input held in this process's memory), writing its files into `out` when given."""

    method: str
    source: SlamSource | str
    config: PipelineConfig
    out: str | None = None
    write_map: bool = True


@dataclass(slots=True)
class MethodSummary:
    """What one `MethodTask` returns.

    Attributes:
        method: its name; report: its measures (an entry of the JSON document's
            ``methods``).
        files: the files it wrote (``tum``: ``<method>.tum``; the pipeline's
            ``pipeline``, ``loops_vs_reference``, ``loops_vs_relations``), as paths.
        relations_ref: the keyframe reference solved from the relations (pipeline).
        loops: every accepted loop as the ``(x, y)`` [m] of its two scans (pipeline).
    """

    method: str
    report: dict[str, Any]
    files: dict[str, str] = field(default_factory=dict)
    relations_ref: RelationsReference | None = None
    loops: list[tuple[tuple[float, float], tuple[float, float]]] = field(default_factory=list)


@dataclass(slots=True)
class SlamBenchmark:
    """Everything one `run_slam_benchmark` produced.

    Attributes:
        input: the scans; eval_stamps, stamp_rule: `evaluation_stamps` of them.
        runs: one `MethodSummary` per method, in the order asked; reports: their
            measures (the ``methods`` entries of `evaluation.slam_report.json_document`).
        config: the pipeline's parameters.
        relations_file, relations_in_file, relations_used: the relations given, their
            count in the file, and those with both stamps among the scans.
        reference_name, reference: the reference trajectory (eval-stamped), if any.
        relations_ref: keyframe reference poses solved from the relations, if any.
        out: the output folder the methods wrote their files into, if any.
    """

    input: SlamInput
    eval_stamps: Array
    stamp_rule: str
    runs: list[MethodSummary]
    reports: list[dict[str, Any]]
    config: PipelineConfig
    relations_file: str | None = None
    relations_in_file: int = 0
    relations_used: list[Relation] = field(default_factory=list)
    reference_name: str | None = None
    reference: Trajectory | None = None
    relations_ref: RelationsReference | None = None
    out: Path | None = None

    def run_of(self, method: str) -> MethodSummary | None:
        """The run of `method`, if it ran."""
        return next((r for r in self.runs if r.method == method), None)


def run_slam_benchmark(
    data: SlamInput,
    methods: Sequence[str],
    config: PipelineConfig,
    *,
    relations: Sequence[Relation] | None = None,
    relations_file: str | None = None,
    reference: Trajectory | None = None,
    reference_name: str | None = None,
    progress: Progress = no_progress,
    out: Path | None = None,
    write_map: bool = True,
) -> SlamBenchmark:
    """Run every method on `data` here, one after the other, then measure each
    (module docstring); `slam_context` checks the inputs first."""
    context = slam_context(data, relations=relations, relations_file=relations_file,
                           reference=reference, reference_name=reference_name)
    return benchmark(context, methods, config, progress=progress, out=out,
                     write_map=write_map)


_CONTEXTS: dict[SlamSource | str, tuple[SlamContext, Progress]] = {}
"""The inputs this process holds, by the `MethodTask.source` that names them."""


def benchmark(
    context: SlamContext,
    methods: Sequence[str],
    config: PipelineConfig,
    *,
    source: SlamSource | None = None,
    cluster: str | None = None,
    progress: Progress = no_progress,
    out: Path | None = None,
    write_map: bool = True,
) -> SlamBenchmark:
    """Every method on `context`, one `MethodTask` each, in the order asked.

    Without `cluster` the tasks run here on the scans of `context`, with `progress`;
    with it (an `evaluation.cluster` address) on Dask, each worker reading `source`
    (the source `context` was opened from: required).  `out`: the output folder the
    tasks write their files into (`evaluation.slam_report.write_outputs` adds the rest).
    """
    if cluster is not None and source is None:
        raise UserError("a cluster run needs the input as files (a SlamSource), not scans "
                        "in memory")
    from evaluation.cluster import map_tasks

    key: SlamSource | str = source if source is not None else f"memory-{uuid.uuid4().hex}"
    tasks = [MethodTask(m, key, config, None if out is None else str(out), write_map)
             for m in methods]
    _CONTEXTS[key] = (context, progress)  # the tasks run here read nothing again
    try:
        summaries = [_summary(o, context, cluster) for o in map_tasks(
            method_task, tasks, cluster=cluster, retries=0, description="bench slam",
            progress=cluster is not None)]
    finally:
        _CONTEXTS.pop(key, None)
    pipeline = next((s for s in summaries if s.method == "pipeline"), None)
    data = context.data
    return SlamBenchmark(
        data, context.eval_stamps, context.stamp_rule, summaries,
        [s.report for s in summaries], config, context.relations_file,
        context.relations_in_file, context.relations_used, context.reference_name,
        context.reference, pipeline.relations_ref if pipeline else None, out,
    )


def _summary(outcome: Any, context: SlamContext, cluster: str | None) -> MethodSummary:
    """The summary of one finished task; Ctrl-C and bad input stop the benchmark, and a
    method whose workers all died is reported as failed."""
    task: MethodTask = outcome.item
    if outcome.status == "interrupted":
        raise KeyboardInterrupt
    if outcome.status == "done":
        summary: MethodSummary = outcome.value
        if cluster is not None and summary.report["error"]:  # the worker's warning is lost
            warn(f"{task.method} failed on {context.data.name}: {summary.report['error']}")
        return summary
    if not outcome.error.startswith("KilledWorker"):
        raise UserError(f"bench slam, {task.method}: {outcome.error}")
    warn(f"{task.method} failed on {context.data.name}: {outcome.error}")
    return MethodSummary(task.method, {
        "method": task.method, "wall_s": None, "ms_per_scan": None, "relations": None,
        "ate": None, "loops": None, "odometry_status": {}, "error": outcome.error,
    })


def _context_of(source: SlamSource | str) -> tuple[SlamContext, Progress]:
    """The input `source` names: held here already, or read now (once per process)."""
    if source not in _CONTEXTS:
        if not isinstance(source, SlamSource):
            raise UserError("bench slam: this worker does not hold the scans in memory; "
                            "give the input as a SlamSource")
        _CONTEXTS.clear()  # a worker holds one input at a time
        _CONTEXTS[source] = (source.open(), no_progress)
    return _CONTEXTS[source]


def method_task(task: MethodTask) -> MethodSummary:
    """One method on one log (`MethodTask`): run, measure, write its files; a summary."""
    context, progress = _context_of(task.source)
    run = run_method(task.method, context.data, task.config, progress)
    relations_ref = _reference_from_relations(context, run, task.config)
    summary = MethodSummary(run.method, _method_report(context, run, relations_ref),
                            relations_ref=relations_ref, loops=_loop_ends(run))
    if task.out is not None:
        summary.files = _write_method_files(context, run, relations_ref, task)
    return summary


def _relations_among_scans(
    relations: Sequence[Relation] | None, relations_file: str | None, stamps: Array
) -> list[Relation]:
    """The relations with both stamps among the scans; `UserError` when none has."""
    if relations is None:
        return []
    used = relations_in_range(relations, stamps)
    if not used:
        raise UserError(
            f"{relations_file or 'relations'}: none of its {len(relations)} relations has "
            f"both stamps among the {len(stamps)} scans read (stamps {stamps.min():.3f} .. "
            f"{stamps.max():.3f} s, matched within {RELATION_TOLERANCE * 1e3:g} ms)"
        )
    return used


def _check_reference(reference: Trajectory, eval_stamps: Array, rule: str, name: str) -> None:
    i_est, _ = associate(np.sort(eval_stamps), reference.stamps)
    if len(i_est) < 2:
        raise UserError(
            f"{name}: only {len(i_est)} of its {len(reference)} stamps match the stamps of the "
            f"{len(eval_stamps)} scans (within 0.01 s; the scans are stamped by {rule})"
        )


def _reference_from_relations(
    context: SlamContext, run: MethodRun, config: PipelineConfig
) -> RelationsReference | None:
    """Keyframe reference poses solved from the relations, with the pipeline's front-end
    odometry filling the gaps; None without relations or for a run without a pipeline
    result."""
    if run.result is None or not context.relations_used:
        return None
    result = run.result
    gap, gap_name = result.odometry_poses, f"front end ({config.odometry})"
    return relations_reference(
        context.data.stamps, context.relations_used, [k.scan_index for k in result.keyframes],
        gap, gap_odometry=gap_name,
    )


def _method_report(
    context: SlamContext, run: MethodRun, relations_ref: RelationsReference | None
) -> dict[str, Any]:
    """One entry of the JSON document's ``methods``: cost, relations, ATE, loops."""
    n = len(context.data.scans)
    doc: dict[str, Any] = {
        "method": run.method,
        "wall_s": run.wall_s,
        "ms_per_scan": 1000.0 * run.wall_s / n,
        "relations": None,
        "ate": None,
        "loops": None,
        "odometry_status": run.statuses,
        "error": run.error,
    }
    if run.poses is None:
        return doc
    if context.relations_used:
        traj = trajectory_at_stamps(context.data.stamps, run.poses)
        doc["relations"] = relations_metric(traj, context.relations_used,
                                            RELATION_TOLERANCE).to_json()
    if context.reference is not None:
        est = trajectory_at_stamps(context.eval_stamps, run.poses)
        doc["ate"] = trajectory_errors(est, context.reference).to_json()
    if run.result is not None:
        doc["loops"] = _loop_report(context, run, relations_ref)
    return doc


def _loop_report(
    context: SlamContext, run: MethodRun, relations_ref: RelationsReference | None
) -> dict[str, Any]:
    """Loop counts of the pipeline and their precision / recall against each reference."""
    loops = loop_counts(run.result)
    against: dict[str, Any] = {}
    kf_index = [k.scan_index for k in run.result.keyframes]
    if context.reference is not None:
        against["reference"] = loop_evaluation(
            run.result, keyframe_reference(context.reference, context.eval_stamps, kf_index))
    if relations_ref is not None:
        against["relations"] = loop_evaluation(run.result, relations_ref.trajectory())
    primary = "reference" if "reference" in against else (
        "relations" if "relations" in against else None)
    loops["precision"] = against[primary]["precision"] if primary else None
    loops["recall"] = against[primary]["recall"] if primary else None
    loops["evaluated_against"] = primary
    loops["against"] = against
    return loops


def _loop_ends(run: MethodRun) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """The ``(x, y)`` of the two scans of every accepted loop (pipeline; for the plot)."""
    if run.result is None or run.poses is None:
        return []
    ends = []
    for e in run.result.accepted_loops:
        a = run.result.keyframes[e.candidate.match].scan_index
        b = run.result.keyframes[e.candidate.query].scan_index
        ends.append(((float(run.poses[a, 0]), float(run.poses[a, 1])),
                     (float(run.poses[b, 0]), float(run.poses[b, 1]))))
    return ends


def _write_method_files(
    context: SlamContext, run: MethodRun, relations_ref: RelationsReference | None,
    task: MethodTask,
) -> dict[str, str]:
    """``<method>.tum`` (evaluation stamps) of a method that did not fail and, for the
    pipeline, ``pipeline/``: its config and results as `loopclosure run` writes them and
    its loop verdicts against each reference."""
    import warnings

    from data.atomic_write import output_dir
    from data.errors import DataWarning
    from data.trajectory_io import write_tum
    from evaluation.loop_verdicts import loop_verdicts, write_loop_verdicts
    from slam.config_io import dump_config
    from slam.results import write_results

    out = output_dir(Path(task.out))
    if run.poses is None:
        return {}
    files = {"tum": out / f"{run.method}.tum"}
    write_tum(files["tum"], trajectory_at_stamps(context.eval_stamps, run.poses))
    if run.result is not None:
        folder = files["pipeline"] = output_dir(out / "pipeline")
        dump_config(task.config, folder / "config.yaml")
        with warnings.catch_warnings():  # the stamp rule is reported once, by the report
            warnings.simplefilter("ignore", DataWarning)
            write_results(folder, run.result, context.data.name, wall_s=run.wall_s,
                          write_map=task.write_map, map_config=task.config.map)
        kf_index = [k.scan_index for k in run.result.keyframes]
        if context.reference is not None:
            ref = keyframe_reference(context.reference, context.eval_stamps, kf_index)
            files["loops_vs_reference"] = write_loop_verdicts(
                folder / "loops_vs_reference.csv", loop_verdicts(run.result, ref))
        if relations_ref is not None:
            files["loops_vs_relations"] = write_loop_verdicts(
                folder / "loops_vs_relations.csv",
                loop_verdicts(run.result, relations_ref.trajectory()))
    return {k: str(v) for k, v in files.items()}
