"""What `loopclosure bench slam` shows and writes: the table, the JSON document, the folder.

`table_rows` gives the side-by-side table (one column per method), `summary_lines`
the lines about the inputs and references printed under it, `json_document` the
``--json`` document, and `write_outputs` the output folder: ``report.md``,
``results.json``, ``trajectories.png``, ``<method>.tum`` and the pipeline's usual
outputs in ``pipeline/`` with its per-loop verdicts.  Every file is written
atomically (`data.atomic_write`).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.errors import DataWarning
from evaluation.loop_verdicts import loop_verdicts, write_loop_verdicts
from evaluation.slam_benchmark import SlamBenchmark
from evaluation.slam_reference import keyframe_reference, trajectory_at_stamps
from evaluation.trajectory_error import associate, umeyama

Array = NDArray[np.float64]


def json_document(bench: SlamBenchmark) -> dict[str, Any]:
    """The ``--json`` document: ``{"input", "scans", "methods": [...], ...}``."""
    rel = None
    if bench.relations_file is not None:
        rel = {"file": bench.relations_file, "in_file": bench.relations_in_file,
               "in_range": len(bench.relations_used)}
    return {
        "input": bench.input.name,
        "scans": len(bench.input.scans),
        "read_s": bench.input.read_s,
        "trajectory_stamps": bench.stamp_rule,
        "odometry_noise": bench.input.odometry_noise,
        "relations": rel,
        "reference": bench.reference_name,
        "relations_reference": bench.relations_ref.to_json() if bench.relations_ref else None,
        "methods": bench.reports,
    }


def _pm(mean: float | None, std: float | None, digits: int) -> str:
    if mean is None or not np.isfinite(mean):
        return "-"
    return f"{mean:.{digits}f} ± {std:.{digits}f}"


def _num(value: Any, fmt: str) -> str:
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "-"
    return format(value, fmt)


def _loop_cells(reps: list[dict[str, Any]], ref: str) -> list[list[str]]:
    """Precision / recall / verifiable rows of the loops evaluated against `ref`."""
    def ev(r: dict[str, Any]) -> dict[str, Any] | None:
        return r["loops"]["against"].get(ref) if r["loops"] else None

    def ratio(e: dict[str, Any] | None, value: str, num: int, den: int) -> str:
        return "-" if e is None else f"{e[value]:.3f} ({num}/{den})"

    rows = [[f"loop precision ({ref})"], [f"loop recall ({ref})"],
            [f"loops verifiable ({ref})"], [f"loop precision before GNC ({ref})"]]
    for r in reps:
        e = ev(r)
        b = e["before_gnc"] if e else None
        rows[0].append(ratio(e, "precision", *(
            (e["true_positives"], e["true_positives"] + e["false_positives"]) if e else (0, 0))))
        rows[1].append(ratio(e, "recall", *(
            (e["queries_recalled"], e["queries_with_loop"]) if e else (0, 0))))
        rows[2].append(f"{e['verifiable']}/{e['proposals']}" if e else "-")
        rows[3].append(ratio(b, "precision", *(
            (b["true_positives"], b["true_positives"] + b["false_positives"]) if b else (0, 0))))
    return rows


def table_rows(bench: SlamBenchmark) -> tuple[list[str], list[list[str]]]:
    """Headers (``measure``, then one column per method) and rows of the side-by-side table."""
    reps = bench.reports

    def row(label: str, cell: Callable[[dict[str, Any]], str]) -> list[str]:
        return [label, *[cell(r) for r in reps]]

    def sub(key: str, cell: Callable[[dict[str, Any]], str]) -> Callable[[dict[str, Any]], str]:
        return lambda r: cell(r[key]) if r[key] else "-"

    headers = ["measure", *[r["method"] for r in reps]]
    rows: list[list[str]] = []
    if any(r["error"] for r in reps):
        rows.append(row("status", lambda r: f"failed ({r['error'].split(':')[0]})"
                        if r["error"] else "ok"))
    rows += [row("wall [s]", lambda r: _num(r["wall_s"], ".2f")),
             row("ms / scan", lambda r: _num(r["ms_per_scan"], ".2f"))]
    if bench.relations_used:
        rows += [
            row("relations trans [m]", sub("relations", lambda m: _pm(
                m["trans_abs_mean"], m["trans_abs_std"], 4))),
            row("relations rot [deg]", sub("relations", lambda m: _pm(
                m["rot_abs_mean_deg"], m["rot_abs_std_deg"], 3))),
            row("relations used", sub("relations", lambda m: (
                f"{m['relations_used']}/{m['relations_total']}"))),
        ]
    if bench.reference is not None:
        rows += [
            row("ATE rmse [m]", sub("ate", lambda a: _num(a["ate_rmse"], ".4f"))),
            row("RPE rmse [m / deg]", sub("ate", lambda a: (
                f"{_num(a['rpe_trans_rmse'], '.4f')} / {_num(a['rpe_rot_rmse_deg'], '.3f')}"))),
        ]
    if any(r["loops"] for r in reps):
        for label, key in (("keyframes", "keyframes"), ("loops proposed", "proposed"),
                           ("loops accepted", "accepted"),
                           ("rejected by check", "rejected_by_check"),
                           ("rejected by GNC", "rejected_by_gnc")):
            rows.append(row(label, sub("loops", lambda m, key=key: str(m[key]))))
        for ref in ("reference", "relations"):
            if any(r["loops"] and ref in r["loops"]["against"] for r in reps):
                rows += _loop_cells(reps, ref)
    return headers, rows


def summary_lines(bench: SlamBenchmark) -> list[str]:
    """Plain-text lines about the inputs and references (printed under the table)."""
    data = bench.input
    lines = [f"{data.name}: {len(data.scans)} scans read in {data.read_s:.1f} s; "
             f"trajectories stamped by {bench.stamp_rule}"]
    if data.odometry_noise is not None:
        lines.append(f"odometry replaced by the simulator's drifting model (seed "
                     f"{data.odometry_noise}) of the logged poses")
    if bench.relations_file:
        lines.append(f"relations {bench.relations_file}: {len(bench.relations_used)} of "
                     f"{bench.relations_in_file} have both stamps among the scans")
    if bench.relations_ref is not None:
        r = bench.relations_ref
        lines.append(
            f"reference from relations: {r.nodes} nodes, {r.relations} relations, gap odometry "
            f"{r.gap_odometry}; fits the relations to {r.fit_trans_mean_m:.4f} m / "
            f"{r.fit_rot_mean_deg:.3f} deg; {len(r.scan_index)} of {r.keyframes} keyframes "
            "have a reference pose"
        )
    if bench.reference_name:
        lines.append(f"reference trajectory: {bench.reference_name}")
    return lines


def _plot(bench: SlamBenchmark, out: Path) -> Path:
    """Every method's trajectory (first-scan odometry frame) and the references, aligned."""
    from evaluation.plots import plot_trajectories

    done = [r for r in bench.runs if r.poses is not None]
    curves: dict[str, Array] = {r.method: r.poses[:, :2] for r in done}
    base = done[0] if done else None
    if bench.reference is not None and base is not None:
        est = trajectory_at_stamps(bench.eval_stamps, base.poses)
        i_est, i_ref = associate(est.stamps, bench.reference.stamps)
        ref_xy = bench.reference.poses[:, :3, 3]
        rot, t, _ = umeyama(ref_xy[i_ref], est.poses[i_est, :3, 3])
        curves["reference"] = (ref_xy @ rot.T + t)[:, :2]
    if bench.relations_ref is not None and bench.relations_ref.nodes:
        curves["reference (relations)"] = bench.relations_ref.node_poses[:, :2]
    loops = []
    pipeline = bench.run_of("pipeline")
    if pipeline is not None and pipeline.result is not None:
        res = pipeline.result
        for e in res.accepted_loops:
            a = res.keyframes[e.candidate.match].scan_index
            b = res.keyframes[e.candidate.query].scan_index
            loops.append((pipeline.poses[a, :2], pipeline.poses[b, :2]))
    return plot_trajectories(out / "trajectories.png", curves,
                             f"{Path(bench.input.name).name}: {len(bench.input.scans)} scans",
                             loops=loops)


def write_outputs(bench: SlamBenchmark, out: Path, *, write_map: bool = True) -> dict[str, Path]:
    """``report.md``, ``results.json``, ``trajectories.png``, ``<method>.tum`` and the
    pipeline's usual outputs in ``pipeline/`` (`slam.results.write_results`).

    Raises:
        DataError: `out` cannot be made or a file cannot be written.
    """
    from data.atomic_write import output_dir
    from data.trajectory_io import write_tum
    from slam.json_io import write_json

    output_dir(out)
    paths = _write_method_trajectories(bench, out)
    paths.update(_write_pipeline_folder(bench, out / "pipeline", write_map))
    if bench.reference is not None and bench.reference_name == "logged poses":
        paths["reference_tum"] = out / "reference_logged.tum"
        write_tum(paths["reference_tum"], bench.reference)
    paths["plot"] = _plot(bench, out)
    paths["results"] = write_json(out / "results.json", json_document(bench))
    paths["report"] = _write_report(bench, out, paths["plot"])
    return paths


def _write_method_trajectories(bench: SlamBenchmark, out: Path) -> dict[str, Path]:
    """``<method>.tum`` of every method that did not fail (evaluation stamps)."""
    from data.trajectory_io import write_tum

    paths: dict[str, Path] = {}
    for run in bench.runs:
        if run.poses is None:
            continue
        path = out / f"{run.method}.tum"
        write_tum(path, trajectory_at_stamps(bench.eval_stamps, run.poses))
        paths[f"{run.method}_tum"] = path
    return paths


def _write_pipeline_folder(bench: SlamBenchmark, folder: Path, write_map: bool) -> dict[str, Path]:
    """The pipeline's config and results (as `loopclosure run` writes them) and its loop
    verdicts against each reference; nothing when the pipeline did not run."""
    from data.atomic_write import output_dir
    from slam.config_io import dump_config
    from slam.results import write_results

    pipeline = bench.run_of("pipeline")
    if pipeline is None or pipeline.result is None:
        return {}
    paths: dict[str, Path] = {}
    output_dir(folder)
    dump_config(bench.config, folder / "config.yaml")
    with warnings.catch_warnings():  # the stamp rule is reported once, by us
        warnings.simplefilter("ignore", DataWarning)
        write_results(folder, pipeline.result, bench.input.name, wall_s=pipeline.wall_s,
                      write_map=write_map, map_config=bench.config.map)
    paths["pipeline"] = folder
    kf_index = [k.scan_index for k in pipeline.result.keyframes]
    if bench.reference is not None:
        ref = keyframe_reference(bench.reference, bench.eval_stamps, kf_index)
        paths["loops_vs_reference"] = write_loop_verdicts(
            folder / "loops_vs_reference.csv", loop_verdicts(pipeline.result, ref))
    if bench.relations_ref is not None:
        paths["loops_vs_relations"] = write_loop_verdicts(
            folder / "loops_vs_relations.csv",
            loop_verdicts(pipeline.result, bench.relations_ref.trajectory()))
    return paths


def _write_report(bench: SlamBenchmark, out: Path, plot: Path) -> Path:
    """``report.md``: inputs, the table, the protocol and the trajectory plot."""
    from evaluation.report import image, table, write_report

    headers, rows = table_rows(bench)
    return write_report(out / "report.md", "SLAM benchmark", [
        ("Inputs", "\n".join(f"- {line}" for line in summary_lines(bench))),
        ("Results", table(headers, rows)),
        ("Protocol", "Relations metric (Kümmerle et al. 2009) of each method's per-scan "
         "trajectory; ATE/RPE against the reference after SE(2) alignment; loop precision "
         "and recall of the pipeline's loops (2 m, 0.2 m, 2 deg) against the reference poses "
         "(see `evaluation/slam_benchmark.py`). Wall time excludes reading the log."),
        ("Trajectories", image(plot, out)),
    ])
