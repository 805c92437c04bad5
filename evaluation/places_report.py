"""What `loopclosure bench places` prints and writes: summary lines, tables, plots, report.

`summary_lines` is the terminal table of one data set (ours / the paper's figure
per method), `json_document` the ``--json`` document, `paper_tables` the paper's
Tables I-III in its layout (per data-set column our figure, then the paper's),
`timing_table` every CPU time, `plot_result` the ROC and precision-recall curves,
and `write_places_report` the output folder (``report.md``, ``roc_<set>.png``,
``pr_<set>.png``, ``results.json``), every file written atomically.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from evaluation.places_benchmark import PlacesResult
from evaluation.places_paper import (
    COLUMN_TITLES,
    PAPER_AUC,
    PAPER_BULLSEYE,
    PAPER_COLUMNS,
    PAPER_FSCORE,
    PAPER_ROW_NAMES,
    PAPER_TIME_MS,
    paper_figure,
)
from evaluation.retrieval import curves

Array = NDArray[np.float64]


def json_document(results: Sequence[PlacesResult]) -> dict[str, Any]:
    """One data set: its ``to_json()``; several: ``{"datasets": [...]}``."""
    if len(results) == 1:
        return results[0].to_json()
    return {"datasets": [r.to_json() for r in results]}


def _fmt(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def summary_lines(result: PlacesResult) -> list[str]:
    """Plain-text table of one data set: ours vs the paper for every method."""
    k = result.kind
    head = (f"{result.dataset}: {result.shapes} shapes, {result.classes} classes, "
            f"workers {result.workers}")
    lines = [head, f"{'method':<14}{'bullseye':>18}{'AUC':>14}{'F-score':>14}"
                   f"{'ms/pair':>18}{'describe':>10}{'compare':>10}",
             f"{'':<14}{'ours / paper':>18}{'ours / paper':>14}{'ours / paper':>14}"
             f"{'ours / paper':>18}{'ms':>10}{'ms':>10}"]
    for name, r in result.methods.items():
        lines.append(
            f"{name:<14}"
            f"{r.bullseye:>9.2f} / {_fmt(paper_figure(PAPER_BULLSEYE, name, k), 2):>6}"
            f"{r.auc:>7.3f} / {_fmt(paper_figure(PAPER_AUC, name, k), 2):>4}"
            f"{r.fscore:>7.3f} / {_fmt(paper_figure(PAPER_FSCORE, name, k), 2):>4}"
            f"{r.ms_per_pair:>9.4f} / {_fmt(PAPER_TIME_MS.get(name), 2):>6}"
            f"{r.ms_describe:>10.4f}{r.ms_compare:>10.4f}"
        )
    for name, why in result.unavailable.items():
        lines.append(f"{name:<14}unavailable ({why})")
    for name, why in result.failed.items():
        lines.append(f"{name:<14}failed ({why})")
    return lines


def _row_order(results: Sequence[PlacesResult]) -> list[str]:
    names: list[str] = []
    for r in results:
        names += [*r.methods, *r.unavailable, *r.failed]
    return list(dict.fromkeys(names))


def _cell(result: PlacesResult, name: str, attr: str, digits: int) -> str:
    if name in result.methods:
        return f"{getattr(result.methods[name], attr):.{digits}f}"
    if name in result.unavailable:
        return "n/a"
    if name in result.failed:
        return "failed"
    return "-"


def _column_title(result: PlacesResult, results: Sequence[PlacesResult]) -> str:
    title = COLUMN_TITLES.get(result.kind, result.kind)
    if sum(r.kind == result.kind for r in results) > 1:
        title += f" ({result.dataset})"
    return title


def paper_tables(results: Sequence[PlacesResult]) -> dict[str, str]:
    """Markdown Tables I, II, III: per data set, our figure then the paper's."""
    from evaluation.report import table

    names = _row_order(results)
    timing = next((r for r in results if r.kind == "robot"), results[-1])
    out: dict[str, str] = {}
    specs = [("I", "bullseye", PAPER_BULLSEYE, 2), ("II", "auc", PAPER_AUC, 3),
             ("III", "fscore", PAPER_FSCORE, 3)]
    for number, attr, paper, digits in specs:
        headers = ["Method"]
        for r in results:
            title = _column_title(r, results)
            headers += [f"{title} ours", f"{title} paper"]
        if number == "I":
            headers += [f"Time [ms] ours ({_column_title(timing, results)})", "Time [ms] paper"]
        rows = []
        for name in names:
            row = [PAPER_ROW_NAMES.get(name, name)]
            for r in results:
                row += [_cell(r, name, attr, digits),
                        _fmt(paper_figure(paper, name, r.kind), 2)]
            if number == "I":
                row += [_cell(timing, name, "ms_per_pair", 4), _fmt(PAPER_TIME_MS.get(name), 2)]
            rows.append(row)
        out[number] = table(headers, rows)
    return out


def timing_table(results: Sequence[PlacesResult]) -> str:
    """Markdown table of every CPU time [ms] per data set, with the paper's Table I time."""
    from evaluation.report import table

    headers = ["Method", "data set", "ms/pair (batched)", "ms/pair (one pair)",
               "describe", "compare (batched)", "compare (one pair)", "paper ms/pair",
               "paper / ours (one pair)"]
    rows = []
    for r in results:
        for name, m in r.methods.items():
            paper = PAPER_TIME_MS.get(name)
            ratio = None if paper is None else paper / max(m.ms_per_pair_single, 1e-12)
            rows.append([name, _column_title(r, results), f"{m.ms_per_pair:.4f}",
                         f"{m.ms_per_pair_single:.4f}", f"{m.ms_describe:.4f}",
                         f"{m.ms_compare:.5f}", f"{m.ms_compare_single:.4f}",
                         _fmt(paper, 2), _fmt(ratio, 1)])
    return table(headers, rows)


def _thin(x: Array, y: Array, n: int = 2000) -> tuple[Array, Array]:
    """At most `n` points of a curve, first and last kept (plots stay light)."""
    if len(x) <= n:
        return x, y
    idx = np.unique(np.linspace(0, len(x) - 1, n).round().astype(int))
    return x[idx], y[idx]


def plot_result(result: PlacesResult, out: Path, stem: str) -> tuple[Path, Path]:
    """``roc_<stem>.png`` and ``pr_<stem>.png`` of every method of `result`."""
    from evaluation.plots import plot_curves

    roc: dict[str, tuple[Array, Array]] = {}
    pr: dict[str, tuple[Array, Array]] = {}
    for name, m in result.methods.items():
        c = curves(m.distances, result.labels)
        roc[f"{name} (AUC {m.auc:.3f})"] = _thin(np.r_[0.0, c.fpr], np.r_[0.0, c.tpr])
        pr[f"{name} (F {m.fscore:.3f})"] = _thin(c.recall, c.precision)
    title = f"{COLUMN_TITLES.get(result.kind, result.kind)}: {result.shapes} shapes"
    p1 = plot_curves(out / f"roc_{stem}.png", roc, "false positive rate",
                     "true positive rate", f"ROC, {title}", diagonal=True)
    p2 = plot_curves(out / f"pr_{stem}.png", pr, "recall", "precision",
                     f"precision-recall, {title}")
    return p1, p2


def _dataset_section(result: PlacesResult) -> str:
    d = result.description
    lines = [f"- `{result.dataset}`: {result.shapes} shapes in {result.classes} classes "
             f"(sizes {min(d['class_sizes'].values())}-{max(d['class_sizes'].values())}), "
             f"scale invariant: {d.get('scale_invariant')}, seed {result.seed}, "
             f"workers {result.workers}."]
    if d.get("rule"):
        lines.append(f"  Rule: {d['rule']}.")
    for log, f in d.get("logs", {}).items():
        lines.append(
            f"  - {log}: {f['scans']} scans ({f['beams']} beams over {f['fov_deg']} deg, "
            f"{f['virtual_scans']} virtual 360-degree scans), {f['places']} places, scans per "
            f"place {f['scans_per_place']}, passes {f['passes_per_place']}, heading spread "
            f"{f['heading_spread_deg']} deg"
        )
    for name, why in result.unavailable.items():
        lines.append(f"  - {name}: unavailable ({why})")
    for name, why in result.failed.items():
        lines.append(f"  - {name}: failed ({why})")
    lines += [f"  - note: {n}" for n in result.notes]
    return "\n".join(lines)


def write_places_report(out: Path, results: Sequence[PlacesResult]) -> dict[str, Path]:
    """``report.md``, ROC and P-R PNGs per data set, ``results.json`` in `out`."""
    from data.atomic_write import output_dir
    from evaluation.report import image, write_report
    from slam.json_io import write_json

    output_dir(out)
    files: dict[str, Path] = {}
    plots: list[str] = []
    seen: dict[str, int] = {}
    for r in results:
        seen[r.kind] = seen.get(r.kind, 0) + 1
        stem = r.kind if seen[r.kind] == 1 else f"{r.kind}{seen[r.kind]}"
        if r.methods:
            roc, pr = plot_result(r, out, stem)
            files[f"roc_{stem}"], files[f"pr_{stem}"] = roc, pr
            plots.append(f"{_column_title(r, results)}:\n\n" + image(roc, out, "ROC") + " "
                         + image(pr, out, "precision-recall"))
    tables = paper_tables(results)
    mpeg7_note = ("The paper's MPEG-7 column is on all 1,400 shapes; ours is on the folder "
                  "given (e.g. the 200-shape subset). ")
    protocol = (
        "Every shape is compared with every shape (`evaluation/places_benchmark.py`). "
        "Bull's eye counts same-class shapes among the 2n nearest (n = class size, query "
        "included); AUC and F-score over all unordered pairs of the symmetrised matrix. "
        "Times are CPU time (`time.process_time`) per comparison: batched = "
        "2 x describe + (stack + all-pairs `distances`) / M^2; one pair = 2 x describe + "
        "one `distance(a, b)`. The paper's time is on its robot set, one core of a "
        "3.1 GHz Xeon. " + (mpeg7_note if any(r.kind == "mpeg7" for r in results) else "")
    )
    sections = [
        ("Data sets", "\n".join(_dataset_section(r) for r in results)),
        ("Protocol", protocol),
        ("Table I: Bull's eye [%] and time per comparison [ms]", tables["I"]),
        ("Table II: area under ROC", tables["II"]),
        ("Table III: best F-score", tables["III"]),
        ("CPU times [ms]", timing_table(results)),
        ("ROC and precision-recall", "\n\n".join(plots) or "no method ran"),
    ]
    doc = json_document(results)
    doc["paper"] = {"columns": list(PAPER_COLUMNS), "bullseye": PAPER_BULLSEYE,
                    "auc": PAPER_AUC, "fscore": PAPER_FSCORE, "time_ms": PAPER_TIME_MS}
    write_json(out / "results.json", doc)
    files["results"] = out / "results.json"
    files["report"] = write_report(out / "report.md", "Place recognition: the paper's "
                                   "Tables I-III reproduced", sections)
    return files
