"""The stripes benchmark's report: ``report.md``, ``results.json`` and its PNG figures.

`write_stripes_report` writes the paper's Table I and Table II beside this run's
(`evaluation.stripes_benchmark`), the Bull's eye / nearest-neighbour / time table,
where stripes win and lose per class, the timing, and three figures: one object per
class (its stripes above its silhouette, the paper's Fig. 6), the per-class accuracy
bars and one black/white stripe image.  Every file is written atomically.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from data.stripe_scanner import DAILY_CLASSES
from evaluation.stripes_benchmark import (
    PAPER_SECONDS,
    PAPER_TABLE_I,
    PAPER_TABLE_II,
    StripesBenchmarkResult,
)
from evaluation.stripes_objects import silhouette_polygon


def _paper_table_one(result: StripesBenchmarkResult) -> list[list[Any]]:
    rows: list[list[Any]] = [[f"paper {n}", *v] for n, v in PAPER_TABLE_I.items()]
    methods = result.methods()
    for n, r in methods.items():
        rows.append([f"**{n}** (this run)", *r.top_counts.tolist()])
    if result.config.scans_per_object > 1:
        for n, r in methods.items():
            rows.append([f"{n}, other objects only", *r.top_counts_other.tolist()])
    return rows


def _table_two(result: StripesBenchmarkResult) -> tuple[list[str], list[list[Any]]]:
    classes = result.classes
    headers = ["method", *classes, "mean"]
    rows: list[list[Any]] = []
    if set(classes) <= set(DAILY_CLASSES):
        for n, v in PAPER_TABLE_II.items():
            paper = dict(zip(DAILY_CLASSES, v, strict=True))
            vals = [paper[c] for c in classes]
            rows.append([f"paper {n}", *vals, round(float(np.mean(vals)), 1)])
    methods = result.methods()
    for n, r in methods.items():
        vals = [round(100.0 * r.class_accuracy[c], 1) for c in classes]
        rows.append([f"**{n}** (this run)", *vals, round(float(np.mean(vals)), 1)])
    return headers, rows


def _plot_examples(result: StripesBenchmarkResult, path: Path) -> Path:
    """One object per class: its stripes (waterfall, every stripe offset by its frame)
    above its silhouette polygon (Fig. 6 of the paper: stripes and shape)."""
    from evaluation.plots import plt, save_figure

    classes = result.classes[:10]
    first = {c: result.scanned.labels.index(c) for c in classes}
    fig, axes = plt.subplots(2, len(classes), figsize=(2.2 * len(classes), 4.8), squeeze=False)
    for j, c in enumerate(classes):
        scan = result.scanned.scans[first[c]]
        ax = axes[0, j]
        step = max(1, len(scan.stripes) // 40)
        cfg = result.config.scanner
        pitch = cfg.step / (scan.field_of_view / cfg.width)  # one laser step in image columns
        for f, s in zip(scan.frame[::step], scan.stripes[::step], strict=True):
            ax.plot(s[:, 0], -s[:, 1] + pitch * f, lw=0.5, color="tab:red")
        ax.set_title(f"{c}\n{len(scan.stripes)} stripes", fontsize=8)
        ax.set_aspect("equal", adjustable="datalim")
        ax.axis("off")
        ax = axes[1, j]
        poly = silhouette_polygon(scan, result.config.scanner, result.config.silhouette_smooth)
        v = np.vstack([poly.vertices, poly.vertices[:1]])
        ax.fill(v[:, 0], v[:, 1], color="0.2")
        ax.set_aspect("equal", adjustable="datalim")
        ax.axis("off")
    fig.suptitle("stripes (every stripe shifted by its laser position) and silhouettes [mm]",
                 fontsize=9)
    return save_figure(fig, path)


def _plot_class_accuracy(result: StripesBenchmarkResult, path: Path) -> Path:
    """Grouped bars: Table II accuracy per class and method."""
    from evaluation.plots import plt, save_figure

    methods = result.methods()
    classes = result.classes
    x = np.arange(len(classes))
    width = 0.8 / max(len(methods), 1)
    fig, ax = plt.subplots(figsize=(max(6.0, 0.8 * len(classes) + 2), 3.8))
    for i, (n, r) in enumerate(methods.items()):
        ax.bar(x + i * width - 0.4 + width / 2, [100 * r.class_accuracy[c] for c in classes],
               width, label=n)
    ax.set_xticks(x)
    ax.set_xticklabels(classes, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("mean accuracy over the 10 nearest [%]")
    ax.set_ylim(0, 105)
    ax.legend(fontsize=8)
    ax.grid(True, axis="y", lw=0.3)
    return save_figure(fig, path)


def _write_stripe_image(result: StripesBenchmarkResult, path: Path) -> Path:
    """The black/white image of the middle stripe of the first object (paper Section III)."""
    from evaluation.plots import save_image

    scan = result.scanned.scans[0]
    return save_image(path, scan.binary_image(len(scan.stripes) // 2), cmap="gray")


def write_stripes_report(result: StripesBenchmarkResult, out: str | Path) -> dict[str, Path]:
    """``report.md``, ``results.json`` and PNG figures in `out`; returns name -> path."""
    from data.atomic_write import output_dir
    from evaluation.report import image, key_values, table, write_report
    from slam.json_io import write_json

    out_dir = output_dir(out)
    paths = {
        "results": out_dir / "results.json",
        "examples": _plot_examples(result, out_dir / "stripes_examples.png"),
        "class_accuracy": _plot_class_accuracy(result, out_dir / "class_accuracy.png"),
        "stripe_image": _write_stripe_image(
            result, out_dir / f"stripe_image_{result.scanned.scans[0].name}.png"),
    }
    js = result.to_json()
    write_json(paths["results"], js)
    s = result.stripes
    n_q = len(result.scanned.scans)
    k = len(s.top_counts)
    methods = result.methods()
    t1 = table(["method", *[str(i) for i in range(1, k + 1)]], _paper_table_one(result))
    h2, r2 = _table_two(result)
    t2 = table(h2, r2, digits=4)
    summary = table(
        ["method", "Bull's eye [%]", "NN precision", "NN precision (other objects)",
         "different pose: other object", "different pose: instance",
         "representation + matching [s]", "options"],
        [[n, r.bullseye, r.nn_precision, r.nn_precision_other,
          r.different_pose.get("other_object", "-"), r.different_pose.get("instance", "-"),
          r.seconds, ", ".join(f"{a}={b}" for a, b in r.options.items())]
         for n, r in methods.items()],
    )
    timing = key_values({
        "stripes, this run [s]": s.seconds,
        "stripes, paper (Matlab) [s]": PAPER_SECONDS["stripes"],
        "shape context, paper (Matlab) [s]": PAPER_SECONDS["shape-context"],
        **{f"{n}, this run [s]": r.seconds for n, r in methods.items() if n != "stripes"},
        "silhouettes (once for all baselines) [s]": result.silhouette_seconds,
        "scanning (simulator, not counted) [s]": result.scanned.seconds,
    })
    wl_rows = [[f"{method} vs {n}", ", ".join(v["wins"]) or "-",
                ", ".join(v["losses"]) or "-", ", ".join(v["ties"]) or "-"]
               for method in ("stripes", "profile")
               for n, v in result.wins_and_losses(method=method).items()]
    setting = key_values({
        "data set": result.dataset,
        "objects": js["objects"],
        "scans (queries)": n_q,
        "scans per object": result.config.scans_per_object,
        "classes": len(result.classes),
        "seed": result.config.seed,
        "mean stripes per scan": js["mean_stripes_per_object"],
        "laser step [m]": result.config.scanner.step,
        "failed objects": len(js["failed_objects"]),
        "baselines skipped": ", ".join(result.skipped_baselines) or "-",
    })
    sections = [
        ("Setting", setting),
        (f"Table I: same-class objects at positions 1..{k} (this run: of {n_q} queries; "
         "paper: of 100)", t1 + "\n\nPosition 1 is the query itself. \"Other objects only\" "
         "removes each query's other scans of the same object from its ranking."),
        (f"Table II: mean accuracy [%] per class over the {k} nearest", t2),
        ("Bull's eye, nearest neighbour, time", summary + "\n\nNN precision = position 2 / "
         "queries (any scan, which with several scans per object is usually another scan of "
         "the same object); \"other objects\" = the nearest scan of a *different* object. "
         "Different pose (two or more scans per object): first scans as queries against the "
         "second scans, each from its own pose; \"instance\" = the nearest is the query's "
         "own object, \"other object\" = the nearest other object is of its class."),
        ("Where stripes and the stripe profile win and lose (Table II, per class)",
         table(["method vs baseline", "better", "worse", "tie"], wl_rows)
         + "\n\nThe paper: stripes lose on banana and pen against shape."),
        ("Timing: representation + matching of the whole set", timing),
        ("Figures", "\n\n".join([
            image(paths["examples"], out_dir, "stripes and silhouettes"),
            image(paths["class_accuracy"], out_dir, "class accuracy"),
            image(paths["stripe_image"], out_dir, "one black/white stripe image"),
        ])),
    ]
    paths["report"] = write_report(out_dir / "report.md", "Stripes benchmark", sections)
    return paths
