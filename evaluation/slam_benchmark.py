"""`loopclosure bench slam`: our pipeline, wheel odometry and KISS-ICP on one log, side by side.

`run_slam_benchmark` runs every method (`evaluation.slam_methods`: ``pipeline``,
``wheel``, ``kiss-icp``) over the same scans, read once into memory before any
timing (`evaluation.slam_input.load_input`; ``limit`` keeps the first N scans), then
measures each.  All methods report poses of the sensor in the odometry frame of the
first scan (``(x, y, theta)`` [m, m, rad]), one per scan.  Per method: wall seconds
of the run (reading excluded) and milliseconds per scan.  A method that raises (a
bug, not bad input) is reported as failed and the other methods still run.
`evaluation.slam_report` turns the result into the table, the JSON document and the
output folder.

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

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from data.types import Relation, Trajectory
from evaluation.loop_verdicts import loop_counts, loop_evaluation
from evaluation.relations_metric import relations_metric
from evaluation.slam_input import Progress, SlamInput, evaluation_stamps, no_progress
from evaluation.slam_methods import MethodRun, run_method
from evaluation.slam_reference import (
    RELATION_TOLERANCE,
    RelationsReference,
    keyframe_reference,
    relations_in_range,
    relations_reference,
    trajectory_at_stamps,
)
from evaluation.trajectory_error import associate, trajectory_errors
from slam.config import PipelineConfig

Array = NDArray[np.float64]


@dataclass(slots=True)
class SlamBenchmark:
    """Everything one `run_slam_benchmark` produced.

    Attributes:
        input: the scans; eval_stamps, stamp_rule: `evaluation_stamps` of them.
        runs: one `MethodRun` per method, in the order asked; reports: their measures
            (the ``methods`` entries of `evaluation.slam_report.json_document`).
        config: the pipeline's parameters.
        relations_file, relations_in_file, relations_used: the relations given, their
            count in the file, and those with both stamps among the scans.
        reference_name, reference: the reference trajectory (eval-stamped), if any.
        relations_ref: keyframe reference poses solved from the relations, if any.
    """

    input: SlamInput
    eval_stamps: Array
    stamp_rule: str
    runs: list[MethodRun]
    reports: list[dict[str, Any]]
    config: PipelineConfig
    relations_file: str | None = None
    relations_in_file: int = 0
    relations_used: list[Relation] = field(default_factory=list)
    reference_name: str | None = None
    reference: Trajectory | None = None
    relations_ref: RelationsReference | None = None

    def run_of(self, method: str) -> MethodRun | None:
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
) -> SlamBenchmark:
    """Run every method on `data`, then measure each (module docstring).

    `reference` is stamped like the evaluated trajectories (`evaluation_stamps`).
    Inputs are checked before the (slow) runs: relations with no pair of stamps among
    the scans, or a reference sharing fewer than two stamps with them, raise `UserError`.
    """
    eval_stamps, rule = evaluation_stamps(data.stamps)
    used = _relations_among_scans(relations, relations_file, data.stamps)
    if reference is not None:
        _check_reference(reference, eval_stamps, rule, reference_name or "reference")
    runs = [run_method(name, data, config, progress) for name in methods]
    bench = SlamBenchmark(
        data, eval_stamps, rule, runs, [], config, relations_file,
        len(relations) if relations is not None else 0, used, reference_name, reference,
    )
    bench.relations_ref = _reference_from_relations(bench)
    bench.reports = [_method_report(bench, run) for run in runs]
    return bench


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


def _reference_from_relations(bench: SlamBenchmark) -> RelationsReference | None:
    """Keyframe reference poses solved from the relations, with the pipeline's front-end
    odometry filling the gaps; None without relations or a pipeline run."""
    pipeline = bench.run_of("pipeline")
    if pipeline is None or pipeline.result is None or not bench.relations_used:
        return None
    result = pipeline.result
    gap, gap_name = result.odometry_poses, f"front end ({bench.config.odometry})"
    return relations_reference(
        bench.input.stamps, bench.relations_used, [k.scan_index for k in result.keyframes],
        gap, gap_odometry=gap_name,
    )


def _method_report(bench: SlamBenchmark, run: MethodRun) -> dict[str, Any]:
    """One entry of the JSON document's ``methods``: cost, relations, ATE, loops."""
    n = len(bench.input.scans)
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
    if bench.relations_used:
        traj = trajectory_at_stamps(bench.input.stamps, run.poses)
        doc["relations"] = relations_metric(traj, bench.relations_used,
                                            RELATION_TOLERANCE).to_json()
    if bench.reference is not None:
        est = trajectory_at_stamps(bench.eval_stamps, run.poses)
        doc["ate"] = trajectory_errors(est, bench.reference).to_json()
    if run.result is not None:
        doc["loops"] = _loop_report(bench, run)
    return doc


def _loop_report(bench: SlamBenchmark, run: MethodRun) -> dict[str, Any]:
    """Loop counts of the pipeline and their precision / recall against each reference."""
    loops = loop_counts(run.result)
    against: dict[str, Any] = {}
    kf_index = [k.scan_index for k in run.result.keyframes]
    if bench.reference is not None:
        against["reference"] = loop_evaluation(
            run.result, keyframe_reference(bench.reference, bench.eval_stamps, kf_index))
    if bench.relations_ref is not None:
        against["relations"] = loop_evaluation(run.result, bench.relations_ref.trajectory())
    primary = "reference" if "reference" in against else (
        "relations" if "relations" in against else None)
    loops["precision"] = against[primary]["precision"] if primary else None
    loops["recall"] = against[primary]["recall"] if primary else None
    loops["evaluated_against"] = primary
    loops["against"] = against
    return loops
