"""Benchmark: nearest other object of the same class on real meshes, same and different pose.

Run from the repository root::

    python benchmarks/stripes_real.py [--meshes DIR] [--labels CSV] [--seeds 0,1]
                                      [--without-class toy_airplane]

For each seed it runs `evaluation.stripes_benchmark.run_stripes_benchmark` twice on a
labelled mesh folder (default: the YCB multi-instance classes of
``../shared/data/meshes-ycb``), as ``loopclosure bench stripes`` does:

- same pose: one scan per object (object yaw within +-15 degrees, the default), every
  scan a query against all others; figure = the nearest other object is of the
  query's class (``--meshes DIR [--labels CSV] --seed S``);
- different pose: two scans per object from independent poses with any yaw; the
  first scans are the queries, the second scans the database; figure = the nearest
  *other* object's scan is of the query's class (``--scans-per-object 2 --yaw-range
  180``, the "different pose: other" figure).

It prints one row per method (stripes, profile, relief, surface, canonical, fused-stripes,
fused, fused-sc, fused-relief, the silhouette baselines) and the seconds of representation +
matching of the same-pose set.  With
``--without-class C`` it also prints the figures over the queries of every class but
``C`` (the objects of ``C`` stay in the database): for a "class" whose members are not
one shape (YCB's toy-airplane parts), this separates what the matcher misses from what
no shape matcher can find.

Nothing is written; the meshes are read in place.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from data.stripe_scanner import ScannerConfig  # noqa: E402
from evaluation.stripes_benchmark import (  # noqa: E402
    StripesBenchmarkConfig,
    run_stripes_benchmark,
)
from evaluation.stripes_objects import mesh_folder_objects  # noqa: E402

DEFAULT_MESHES = ROOT.parent / "shared" / "data" / "meshes-ycb"


def same_pose(d: np.ndarray, labels: np.ndarray, keep: np.ndarray) -> float:
    """Nearest other scan of the query's class, over the queries in `keep`."""
    dd = np.where(np.isfinite(d), d, np.inf).copy()
    np.fill_diagonal(dd, np.inf)
    return float(np.mean((labels[np.argmin(dd, axis=1)] == labels)[keep]))


def different_pose(d: np.ndarray, labels: np.ndarray, objects: np.ndarray,
                   skip: str | None) -> float:
    """First scans against second scans, nearest other object (`stripes_retrieval`)."""
    ids = list(dict.fromkeys(objects.tolist()))
    first = np.array([np.flatnonzero(objects == o)[0] for o in ids])
    second = np.array([np.flatnonzero(objects == o)[1] for o in ids])
    sub = np.where(np.isfinite(d), d, np.inf)[np.ix_(first, second)]
    np.fill_diagonal(sub, np.inf)
    hit = labels[second][np.argmin(sub, axis=1)] == labels[first]
    keep = labels[first] != skip
    return float(np.mean(hit[keep]))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--meshes", type=Path, default=DEFAULT_MESHES)
    ap.add_argument("--labels", type=Path, default=None)
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--without-class", default=None)
    args = ap.parse_args(argv)
    if not args.meshes.is_dir():
        print(f"skipped: no mesh folder {args.meshes}")
        return
    objs = mesh_folder_objects(args.meshes, args.labels)
    skip = args.without_class
    for seed in (int(s) for s in args.seeds.split(",")):
        same = run_stripes_benchmark(objs, StripesBenchmarkConfig(seed=seed))
        diff = run_stripes_benchmark(objs, StripesBenchmarkConfig(
            seed=seed, scans_per_object=2,
            scanner=replace(ScannerConfig(), yaw_range_deg=180.0)))
        lab_s = np.array(same.scanned.labels)
        lab_d = np.array(diff.scanned.labels)
        head = f"seed {seed}: {len(lab_s)} objects"
        cols = ["same pose", "different pose", "seconds"]
        if skip:
            cols += [f"same, no {skip}", f"different, no {skip}"]
        print(f"\n{head}\n{'method':14s} " + " ".join(f"{c:>22s}" for c in cols))
        for name, r in same.methods().items():
            rd = diff.methods()[name]
            row = [same_pose(r.distances, lab_s, np.ones(len(lab_s), bool)),
                   different_pose(rd.distances, lab_d, diff.scanned.objects, None), r.seconds]
            if skip:
                row += [same_pose(r.distances, lab_s, lab_s != skip),
                        different_pose(rd.distances, lab_d, diff.scanned.objects, skip)]
            print(f"{name:14s} " + " ".join(f"{v:22.3f}" for v in row))


if __name__ == "__main__":
    main()
