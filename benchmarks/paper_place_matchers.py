"""Benchmark: Bull's eye of matcher variants on the place data sets of ``bench places``.

Run from the repository root::

    python benchmarks/paper_place_matchers.py --dataset box --dataset robot:DIR
        [--range-cap M] [--variant NAME:METHOD[:KEY=VALUE,KEY=VALUE ...] ...]
        [--query-step S] [--per-log]

Each data set is loaded as ``loopclosure bench places`` loads it
(`evaluation.place_datasets.load_dataset`, seed 0; ``--range-cap`` for the robot
places), and each variant is the matcher METHOD with its config fields set as given
(values parsed as Python literals: ``norm='l1'``, ``n_rings=64``,
``sampling='arc'``), plus ``scale_invariant=True`` on MPEG-7 as the benchmark does
(`evaluation.places_methods.method_overrides`).  ``bench places`` runs the defaults
only; this runs options against them on the same polygons.

Printed per variant and data set: the Bull's eye score [%] (`evaluation.retrieval`:
the 2n nearest of every query).  With ``--query-step S`` only every S-th shape is a
query (its distances to all shapes; the score is over those queries), for screening
a slow matcher; the default 1 is the full score of ``bench places``.  With
``--per-log`` the score of each log's queries (robot labels ``<log>/place<k>``; the
part of a label before ``/``) is printed too, against all shapes.
"""

from __future__ import annotations

import argparse
import ast
import time

import numpy as np

from evaluation.place_datasets import RobotPlacesConfig, load_dataset
from evaluation.places_methods import build_matcher, method_overrides


def parse_variant(text: str) -> tuple[str, str, dict[str, object]]:
    """``NAME:METHOD[:K=V,K=V]`` -> (name, method, overrides)."""
    parts = text.split(":", 2)
    if len(parts) < 2:
        raise SystemExit(f"variant {text!r}: expected NAME:METHOD[:KEY=VALUE,...]")
    options: dict[str, object] = {}
    if len(parts) == 3 and parts[2]:
        for item in parts[2].split(","):
            key, value = item.split("=", 1)
            options[key.strip()] = ast.literal_eval(value.strip())
    return parts[0], parts[1], options


def bullseye_rows(d: np.ndarray, labels: np.ndarray, rows: np.ndarray) -> float:
    """Bull's eye [%] of the query `rows` (row i of `d` is shape rows[i] against all)."""
    _, inverse, counts = np.unique(labels, return_inverse=True, return_counts=True)
    n = counts[inverse][rows]
    d = d.copy()
    d[np.arange(len(rows)), rows] = -np.inf  # the query first among equal distances
    order = np.argsort(d, axis=1, kind="stable")
    same = labels[order] == labels[rows][:, None]
    hits = (same & (np.arange(d.shape[1])[None, :] < 2 * n[:, None])).sum(axis=1)
    return float(100.0 * hits.sum() / n.sum())


def bullseye_by_group(
    d: np.ndarray, labels: np.ndarray, rows: np.ndarray
) -> dict[str, float]:
    """Bull's eye [%] of the queries of each group (label part before ``/``)."""
    groups = np.array([str(label).split("/", 1)[0] for label in labels[rows]])
    return {
        g: bullseye_rows(d[groups == g], labels, rows[groups == g]) for g in np.unique(groups)
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", action="append", required=True)
    ap.add_argument("--range-cap", type=float, default=None)
    ap.add_argument("--variant", action="append", default=[])
    ap.add_argument("--query-step", type=int, default=1)
    ap.add_argument("--per-log", action="store_true")
    args = ap.parse_args()
    variants = [parse_variant(v) for v in args.variant] or [
        ("default", m, {}) for m in ("fft", "ring", "mrm")]
    robot = RobotPlacesConfig(range_cap=args.range_cap)
    for spec in args.dataset:
        polygons, labels, description = load_dataset(spec, robot=robot)
        scale_invariant = bool(description.get("scale_invariant", False))
        rows = np.arange(0, len(polygons), args.query_step)
        for name, method, options in variants:
            base, _ = method_overrides(method, scale_invariant)
            matcher = build_matcher(method, {**base, **options})
            start = time.process_time()
            descriptors = [matcher.describe(p) for p in polygons]
            stacked = matcher.stack(descriptors)
            d = np.stack([matcher.distances(descriptors[i], stacked) for i in rows])
            score = bullseye_rows(d, np.asarray(labels), rows)
            print(f"{spec} cap={args.range_cap} {name} ({method} {options}): "
                  f"Bull's eye {score:.2f} % over {len(rows)} queries "
                  f"[{time.process_time() - start:.0f} s CPU]", flush=True)
            if args.per_log:
                parts = bullseye_by_group(d, np.asarray(labels), rows)
                print("    " + "  ".join(f"{g} {v:.1f}" for g, v in parts.items()), flush=True)


if __name__ == "__main__":
    main()
