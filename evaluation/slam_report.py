"""What `loopclosure bench slam` shows and writes: the table, the JSON document, the folder.

`table_rows` gives the side-by-side table (one column per method), `summary_lines`
the lines about the inputs and references printed under it, `json_document` the
``--json`` document, and `write_outputs` the rest of the output folder: ``report.md``,
``results.json`` and ``trajectories.png`` beside the files each method's task wrote
(``<method>.tum``, the pipeline's usual outputs in ``pipeline/`` with its per-loop
verdicts).  Everything here is built from the methods' summaries
(`evaluation.slam_benchmark.MethodSummary`) and the files they name, never from a
mapping result, so a cluster run and a serial run give the same report.  Every file
is written atomically (`data.atomic_write`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from evaluation.slam_benchmark import SlamBenchmark
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
    """Every method's trajectory (first-scan odometry frame, from its ``<method>.tum``)
    and the references, aligned."""
    from data.trajectory_io import read_tum
    from evaluation.plots import plot_trajectories

    written = {r.method: read_tum(r.files["tum"]) for r in bench.runs if "tum" in r.files}
    curves: dict[str, Array] = {m: t.poses[:, :2, 3] for m, t in written.items()}
    base = next(iter(written.values()), None)
    if bench.reference is not None and base is not None:
        i_est, i_ref = associate(base.stamps, bench.reference.stamps)
        ref_xy = bench.reference.poses[:, :3, 3]
        rot, t, _ = umeyama(ref_xy[i_ref], base.poses[i_est, :3, 3])
        curves["reference"] = (ref_xy @ rot.T + t)[:, :2]
    if bench.relations_ref is not None and bench.relations_ref.nodes:
        curves["reference (relations)"] = bench.relations_ref.node_poses[:, :2]
    pipeline = bench.run_of("pipeline")
    loops = [(np.array(a), np.array(b)) for a, b in pipeline.loops] if pipeline else []
    return plot_trajectories(out / "trajectories.png", curves,
                             f"{Path(bench.input.name).name}: {len(bench.input.scans)} scans",
                             loops=loops)


def write_outputs(bench: SlamBenchmark) -> dict[str, Path]:
    """``report.md``, ``results.json``, ``trajectories.png`` (and ``reference_logged.tum``)
    in ``bench.out``, beside the files the methods wrote there; every path, by name.

    Raises:
        UserError: the benchmark ran without an output folder.
        DataError: a file cannot be written.
    """
    from data.trajectory_io import write_tum
    from slam.json_io import write_json

    if bench.out is None:
        raise UserError("write_outputs: the benchmark ran without an output folder (out=)")
    out = bench.out
    paths: dict[str, Path] = {}
    for run in bench.runs:
        for name, path in run.files.items():
            key = f"{run.method}_tum" if name == "tum" else name
            paths[key] = Path(path)
    if bench.reference is not None and bench.reference_name == "logged poses":
        paths["reference_tum"] = out / "reference_logged.tum"
        write_tum(paths["reference_tum"], bench.reference)
    paths["plot"] = _plot(bench, out)
    paths["results"] = write_json(out / "results.json", json_document(bench))
    paths["report"] = _write_report(bench, out, paths["plot"])
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
