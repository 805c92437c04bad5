"""Which score ranks the final detections of bench loops best: fused score or check figures?

Run from the repository root, on the output folders of ``loopclosure bench loops ...
--stages fused --out DIR`` (one per log)::

    python benchmarks/final_ranking.py DIR [DIR ...]

The final row's precision-recall curve ranks each query's accepted detection by
the fused score of its place (`evaluation.loop_bench`).  Here the same detections
(``queries.csv``: the final match, its truth and the check's figures of it) are
ranked by other scores, and recall at 100% and 99% precision and the average
precision printed per log:

* ``fused``: the benchmark's own ranking;
* each check figure alone: ``consistency``, ``fitness``, ``matched_length`` (log),
  ``margin``, ``degeneracy``;
* ``logistic``: a logistic regression of the detection's truth on the fused score
  and the check figures (standardised), **fitted leave-one-log-out**: the log it
  ranks is never among the logs it was fitted on.

Detections the reference cannot judge within its own uncertainty (relations
reference, the ``unverifiable`` column) count as wrong, as the benchmark counts them.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evaluation.loop_bench_truth import (  # noqa: E402
    average_precision,
    pr_curve,
    recall_at_precision,
)

FEATURES = ("fused_score", "check_consistency", "check_fitness", "check_matched_length",
            "check_margin", "check_degeneracy")


def load(folder: Path) -> dict:
    """The accepted final detections of one run: features ``(n, F)``, truth ``(n,)``,
    and the run's revisit count."""
    rows = [r for r in csv.DictReader(open(folder / "queries.csv")) if r["final_match"] != ""]
    x = np.array([[float(r[f]) if r[f] != "" else np.nan for f in FEATURES] for r in rows],
                 float).reshape(-1, len(FEATURES))
    fused = np.array([float(r["final_score"]) for r in rows], float)
    x[:, 0] = fused
    x[:, FEATURES.index("check_matched_length")] = np.log(
        np.maximum(x[:, FEATURES.index("check_matched_length")], 1e-3))
    y = np.array([r["final_correct"] == "1" for r in rows], bool)
    revisits = json.load(open(folder / "results.json"))["revisits"]
    return dict(name=folder.name, x=x, y=y, revisits=int(revisits))


def figures(score: np.ndarray, y: np.ndarray, revisits: int) -> tuple[float, float, float]:
    """Recall at 100% / 99% precision and average precision of one ranking."""
    curve = pr_curve(np.nan_to_num(score, nan=-np.inf), y, revisits)
    return (recall_at_precision(curve, 1.0), recall_at_precision(curve, 0.99),
            average_precision(curve))


def fit_logistic(x: np.ndarray, y: np.ndarray, l2: float = 1.0, iterations: int = 50
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Logistic regression by Newton's method with an L2 penalty on the weights
    (features standardised by the fitting set's mean and deviation): ``(mean, std,
    w)``, ``w[0]`` the intercept."""
    mean, std = np.nanmean(x, axis=0), np.nanstd(x, axis=0) + 1e-9
    z = np.nan_to_num((x - mean) / std)
    a = np.column_stack([np.ones(len(z)), z])
    w = np.zeros(a.shape[1])
    pen = l2 * np.eye(a.shape[1])
    pen[0, 0] = 0.0
    for _ in range(iterations):
        p = 1.0 / (1.0 + np.exp(-a @ w))
        g = a.T @ (p - y) + pen @ w
        h = (a * (p * (1 - p))[:, None]).T @ a + pen
        w -= np.linalg.solve(h, g)
    return mean, std, w


def logistic_score(model: tuple, x: np.ndarray) -> np.ndarray:
    mean, std, w = model
    z = np.nan_to_num((x - mean) / std)
    return np.column_stack([np.ones(len(z)), z]) @ w


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("folders", nargs="+", type=Path)
    ap.add_argument("--features", default=",".join(FEATURES),
                    help="features of the logistic (comma-separated)")
    args = ap.parse_args()
    runs = [load(f) for f in args.folders]
    use = [FEATURES.index(f) for f in args.features.split(",")]
    names = ["fused", "consistency", "fitness", "matched_length", "margin", "degeneracy",
             "logistic (leave-one-log-out)"]
    print("log".ljust(22) + "".join(n.rjust(30) for n in names))
    for i, run in enumerate(runs):
        cells = [figures(run["x"][:, j], run["y"], run["revisits"]) for j in range(len(FEATURES))]
        others = [r for j, r in enumerate(runs) if j != i]
        model = fit_logistic(np.vstack([r["x"][:, use] for r in others]),
                             np.concatenate([r["y"] for r in others]))
        cells.append(figures(logistic_score(model, run["x"][:, use]), run["y"],
                             run["revisits"]))
        print(run["name"].ljust(22) + "".join(
            f"{a:.3f} / {b:.3f} / {c:.3f}".rjust(30) for a, b, c in cells))
    model = fit_logistic(np.vstack([r["x"][:, use] for r in runs]),
                         np.concatenate([r["y"] for r in runs]))
    print("\n(cells: recall at 100% precision / at 99% / average precision)")
    print("logistic fitted on every log: mean", np.round(model[0], 4), "std",
          np.round(model[1], 4), "weights (intercept first)", np.round(model[2], 3))


if __name__ == "__main__":
    main()
