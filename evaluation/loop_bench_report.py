"""What `loopclosure bench loops` shows and writes: the table, the JSON document, the folder.

`json_document` is the ``--json`` document::

    {"input", "keyframes", "keyframes_with_reference", "queries", "revisits",
     "database_size": {"mean", "max"},
     "stages": {name: {"recall_at_p100", "recall_at_p99", "average_precision",
                       "ms_per_query", "top1_precision", "top1_recall"}},
     "final": {... the same ..., "accepted", "precision_at_min_score",
               "recall_at_min_score", "min_score",
               with a relations or trajectory reference also "unverifiable" and
               "verifiable":
               {"recall_at_p100", "recall_at_p99", "average_precision"}},
     "recall_at_k": {prefilter stage: {"1", "10", "50"}},
     "candidates": {"recall", "mean_count"}, "wall_s", "reference"}

(the measures are defined in `evaluation.loop_bench_truth`; ``candidates``: the share
of revisits with a true place among the candidates the verifiers saw, and their mean
number; ``top1_precision`` and
``top1_recall`` are the curve's end point, every proposal accepted: correct proposals
over proposals, and over queries with a revisit).
`table_rows` gives the terminal / report table, one row per stage.  `write_outputs`
writes ``results.json``, ``report.md``, ``pr_curves.png`` (every row's P-R curve in
one figure), ``detections.png`` (the reference keyframe positions with the final
detections drawn: true green, false red, missed revisits orange) and
``queries.csv`` (one row per query: its revisit, every row's proposal, score and
verdict, the check's verdict and pose error, the rank of its first true place in
the prefilter and its nearest true place's distance, heading difference and
overlap: `evaluation.loop_bench_misses`; the check's figures of the final place and
how many places it accepted; with a relations reference the reference's own sigmas
of the detection's relative pose, with a trajectory reference (a log's own poses, a
TUM file) those its disagreement with its own scans implies
(`evaluation.loop_bench_scan_truth`), and whether it is unverifiable, see
`evaluation.loop_bench_truth`), each atomically (`data.atomic_write`).
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

import numpy as np

from data.atomic_write import output_dir, write_text_atomic
from evaluation.loop_bench import LoopBench, StageResult
from evaluation.loop_bench_misses import miss_breakdown
from evaluation.loop_bench_queries import CHECK_FIGURES, RECALL_KS
from evaluation.loop_bench_truth import curve_summary, pr_curve, recall_at_precision
from slam.json_io import write_json


def _stage_doc(s: StageResult, revisits: int) -> dict[str, Any]:
    doc: dict[str, Any] = curve_summary(s.curve)
    doc["ms_per_query"] = s.ms_per_query
    doc["top1_precision"] = float(s.correct.sum() / max(int(np.isfinite(s.score).sum()), 1))
    doc["top1_recall"] = float(s.correct.sum() / revisits) if revisits else 0.0
    return doc


def operating_point(bench: LoopBench) -> dict[str, Any]:
    """Precision and recall of the final proposals with a fused score >= ``min_score``."""
    f = bench.final
    take = f.score >= bench.min_score
    tp = int((take & f.correct).sum())
    n = int(take.sum())
    return {
        "min_score": bench.min_score,
        "accepted": int(bench.accepted.sum()),
        "precision_at_min_score": tp / n if n else 1.0,
        "recall_at_min_score": tp / bench.revisits if bench.revisits else 0.0,
    }


def json_document(bench: LoopBench) -> dict[str, Any]:
    """The ``--json`` document (module docstring)."""
    final = _stage_doc(bench.final, bench.revisits)
    final.update(operating_point(bench))
    final.update(_verifiable(bench))
    size = bench.database_size
    return {
        "input": bench.name,
        "keyframes": bench.keyframes,
        "keyframes_with_reference": bench.covered,
        "queries": len(bench.query_keys),
        "revisits": bench.revisits,
        "database_size": {"mean": float(size.mean()) if len(size) else 0.0,
                          "max": int(size.max()) if len(size) else 0},
        "stages": {n: _stage_doc(s, bench.revisits) for n, s in bench.stages.items()},
        "final": final,
        "recall_at_k": {n: {str(k): v for k, v in r.items()}
                        for n, r in bench.recall_at_k.items()},
        "candidates": {"recall": bench.candidate_recall, "mean_count": bench.candidate_count},
        "tolerances": {"max_distance_m": bench.tolerances.max_distance,
                       "trans_tol_m": bench.tolerances.trans_tol,
                       "rot_tol_deg": bench.tolerances.rot_tol_deg},
        "wall_s": bench.wall_s,
        "prefilter_misses": {
            name: [{"bin": b, "queries": n, "recall_at_10": r} for b, n, r in rows]
            for name, rows in _misses(bench).items()
        },
    }


def _verifiable(bench: LoopBench) -> dict[str, Any]:
    """The final row's measures with the unverifiable detections set aside
    (`evaluation.loop_bench_truth`); empty without reference sigmas."""
    if bench.unverifiable is None:
        return {}
    f, keep = bench.final, ~bench.unverifiable
    curve = pr_curve(f.score[keep], f.correct[keep], bench.revisits)
    return {"unverifiable": int(bench.unverifiable.sum()), "verifiable": curve_summary(curve)}


def _misses(bench: LoopBench) -> dict[str, list[tuple[str, int, float]]]:
    """The prefilter's recall@10 per bin of the nearest true place's geometry, over
    the queries with a revisit (`evaluation.loop_bench_misses.miss_breakdown`)."""
    if bench.nearest is None or bench.prefilter_rank is None:
        return {}
    has = bench.has_revisit
    near = bench.nearest[has]
    return miss_breakdown(bench.prefilter_rank[has], near[:, 1], near[:, 2], near[:, 3])


TABLE_HEADERS = ["stage", "R@100%P", "R@99%P", "AP", "R (any score)", "ms/query"]


def table_rows(bench: LoopBench) -> list[list[str]]:
    """One row per stage and the final row: recall at 100% / 99% precision, AP, recall
    with every proposal accepted (the curve's end), milliseconds per query."""
    out = []
    for s in [*bench.stages.values(), bench.final]:
        doc = _stage_doc(s, bench.revisits)
        name = "final (after the check)" if s is bench.final else s.name
        out.append([name, f"{doc['recall_at_p100']:.3f}", f"{doc['recall_at_p99']:.3f}",
                    f"{doc['average_precision']:.3f}", f"{doc['top1_recall']:.3f}",
                    f"{s.ms_per_query:.1f}"])
    return out


def summary_lines(bench: LoopBench) -> list[str]:
    """The lines printed under the table: counts, recall@K, the operating point."""
    size = bench.database_size
    op = operating_point(bench)
    lines = [
        f"{bench.keyframes} keyframes, {bench.covered} with a reference pose; "
        f"{len(bench.query_keys)} queries, {bench.revisits} with a revisit; database "
        f"{size.mean() if len(size) else 0:.0f} keyframes on average "
        f"(max {size.max() if len(size) else 0})",
    ]
    for name, r in bench.recall_at_k.items():
        lines.append(f"{name} recall@K: " + ", ".join(f"@{k} {v:.3f}" for k, v in r.items()))
    units = {"nearest_m": "distance [m]", "nearest_dtheta_deg": "heading difference [deg]",
             "nearest_overlap": "submap overlap"}
    for name, rows in _misses(bench).items():
        lines.append(f"prefilter recall@10 by the nearest true place's {units[name]}: "
                     + ", ".join(f"{b} {r:.3f} ({n})" for b, n, r in rows))
    lines.append(f"verified candidates: {bench.candidate_count:.1f} per query, a true place "
                 f"among them for {bench.candidate_recall:.3f} of the revisits")
    lines.append(
        f"check accepted a proposal for {op['accepted']} queries; at fused score >= "
        f"{bench.min_score:g}: precision {op['precision_at_min_score']:.3f}, recall "
        f"{op['recall_at_min_score']:.3f}"
    )
    ver = _verifiable(bench)
    if ver:
        v = ver["verifiable"]
        lines.append(
            f"{ver['unverifiable']} wrong detections lie within the reference's own "
            f"uncertainty (tolerance + 3 sigma of its relative pose; a trajectory "
            f"reference: + its disagreement with its own scans); without them: recall "
            f"{v['recall_at_p100']:.3f} at 100% precision, {v['recall_at_p99']:.3f} at 99%")
    lines.append(f"mapping {bench.wall_s.get('mapping', 0):.0f} s, queries "
                 f"{bench.wall_s.get('queries', 0):.0f} s")
    return lines


QUERY_COLUMNS_HEAD = ("keyframe", "scan_index", "revisit", "database_size")


def queries_csv(bench: LoopBench) -> str:
    """One CSV row per query (module docstring); empty cells for no proposal."""
    rows = [*bench.stages.values(), bench.final]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    head = list(QUERY_COLUMNS_HEAD)
    for s in rows:
        head += [f"{s.name}_match", f"{s.name}_score", f"{s.name}_correct"]
    head += ["check_verdict", "error_m", "error_deg", "prefilter_rank", "nearest_key",
             "nearest_m", "nearest_dtheta_deg", "nearest_overlap"]
    head += [f"check_{f}" for f in CHECK_FIGURES] + ["accepted_places"]
    head += ["reference_sigma_m", "reference_sigma_deg", "unverifiable"]
    w.writerow(head)
    for i, k in enumerate(bench.query_keys.tolist()):
        line: list[Any] = [k, int(bench.scan_index[k]), int(bench.has_revisit[i]),
                           int(bench.database_size[i])]
        for s in rows:
            ok = np.isfinite(s.score[i])
            line += [int(s.match[i]) if ok else "", f"{s.score[i]:.6g}" if ok else "",
                     int(s.correct[i]) if ok else ""]
        err = bench.final_errors[i]
        line += [bench.reasons[i]] + [f"{e:.4f}" if np.isfinite(e) else "" for e in err]
        line += _nearest_cells(bench, i)
        line += _check_cells(bench, i)
        line += _sigma_cells(bench, i)
        w.writerow(line)
    return buf.getvalue()


def _check_cells(bench: LoopBench, i: int) -> list[Any]:
    """Query i's check figures of its final place and its accepted places' count."""
    if bench.check_figures is None or bench.accepted_places is None:
        return [""] * (len(CHECK_FIGURES) + 1)
    return [f"{x:.4g}" if np.isfinite(x) else "" for x in bench.check_figures[i]] + [
        int(bench.accepted_places[i])]


def _sigma_cells(bench: LoopBench, i: int) -> list[Any]:
    """Query i's reference sigmas [m], [deg] and unverifiable flag (empty: unknown)."""
    if bench.reference_sigmas is None or bench.unverifiable is None:
        return [""] * 3
    sig = bench.reference_sigmas[i]
    if not np.isfinite(sig).all():
        return [""] * 3
    return [f"{np.hypot(sig[0], sig[1]):.4f}", f"{np.degrees(sig[2]):.3f}",
            int(bench.unverifiable[i])]


def _nearest_cells(bench: LoopBench, i: int) -> list[Any]:
    """Query i's prefilter rank and nearest true place (empty cells without one)."""
    if bench.nearest is None or bench.prefilter_rank is None or not bench.has_revisit[i]:
        return [""] * 5
    key, dist, dtheta, overlap = bench.nearest[i]
    return [int(bench.prefilter_rank[i]), int(key), f"{dist:.3f}", f"{dtheta:.1f}",
            f"{overlap:.3f}" if np.isfinite(overlap) else ""]


def plot_pr_curves(bench: LoopBench, path: Path) -> Path:
    """Every row's top-1 precision-recall curve in one figure (recall over revisits)."""
    from evaluation.plots import plot_curves

    curves = {}
    for s in [*bench.stages.values(), bench.final]:
        label = "final (after the check)" if s is bench.final else s.name
        r100 = recall_at_precision(s.curve, 1.0)
        curves[f"{label} (R@100%P {r100:.2f})"] = (s.curve.recall, s.curve.precision)
    return plot_curves(path, curves, "recall (of queries with a revisit)", "precision",
                       f"top-1 loop detection: {Path(bench.name).name}")


def plot_detections(bench: LoopBench, path: Path) -> Path:
    """Reference keyframe positions with the final detections: true, false, missed."""
    import matplotlib.pyplot as plt

    from evaluation.plots import save_figure

    ref = bench.reference
    fig, ax = plt.subplots(figsize=(7.5, 6.5))
    ok = np.isfinite(ref).all(axis=1)
    ax.plot(ref[ok, 0], ref[ok, 1], color="0.7", lw=0.6, label="keyframes (reference)")
    f = bench.final
    q = bench.query_keys
    proposed = np.isfinite(f.score)
    for mask, colour, label in ((proposed & f.correct, "tab:green", "true detection"),
                                (proposed & ~f.correct, "tab:red", "false detection")):
        a, b = ref[q[mask], :2], ref[f.match[mask], :2]
        for p0, p1 in zip(a, b, strict=True):
            ax.plot([p0[0], p1[0]], [p0[1], p1[1]], color=colour, lw=0.8, alpha=0.7)
        ax.scatter(a[:, 0], a[:, 1], s=6, color=colour, label=f"{label} ({int(mask.sum())})")
    missed = bench.has_revisit & ~(proposed & f.correct)
    ax.scatter(ref[q[missed], 0], ref[q[missed], 1], s=5, color="tab:orange",
               label=f"missed revisit ({int(missed.sum())})")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"appearance-only detections after the check: {Path(bench.name).name}")
    ax.legend(loc="best", fontsize=7)
    ax.grid(True, lw=0.3)
    return save_figure(fig, path)


def write_outputs(bench: LoopBench, out: Path) -> dict[str, Path]:
    """Write the output folder (module docstring); returns name -> path."""
    from evaluation.report import image, key_values, table, write_report

    output_dir(out)
    doc = json_document(bench)
    paths = {
        "results": write_json(out / "results.json", doc),
        "queries": write_text_atomic(out / "queries.csv", queries_csv(bench)),
        "pr_curves": plot_pr_curves(bench, out / "pr_curves.png"),
        "detections": plot_detections(bench, out / "detections.png"),
    }
    rk = [[n, *[f"{r[k]:.3f}" for k in RECALL_KS]] for n, r in bench.recall_at_k.items()]
    paths["report"] = write_report(out / "report.md", f"Loop detection: {bench.name}", [
        ("Protocol", "Appearance only, no pose prior: every keyframe's top-1 proposal from "
         "the database of older keyframes, per stage; after the geometric check, the "
         f"first of its {bench.config.loops.global_verify} best distinct places that the "
         "check accepts (accepted places must agree); see `evaluation/loop_bench.py` and "
         "`evaluation/loop_bench_truth.py`."),
        ("Stages", table(TABLE_HEADERS, table_rows(bench))),
        ("Prefilter recall@K", table(["stage", *[f"@{k}" for k in RECALL_KS]], rk)),
        ("Counts", "\n".join(f"- {line}" for line in summary_lines(bench))),
        ("Final operating point", key_values(operating_point(bench))),
        ("Plots", image(paths["pr_curves"], out) + "\n" + image(paths["detections"], out)),
    ])
    return paths
