"""Benchmark: the fused object matcher's speed against an earlier commit, same decisions.

Run from the repository root::

    python benchmarks/stripes_speed.py [--meshes DIR] [--seeds 0,1] [--baseline REV]
                                       [--repeats 5] [--cache DIR]
                                       [--decisions-may-change]

"Old" is the code of the packages ``loopclosure`` and ``evaluation`` at git revision
``--baseline`` (default `BASELINE`, the commit before the fused matcher's speed work),
extracted with ``git archive`` into a temporary folder and imported beside the
working tree under the names ``_old_loopclosure`` and ``_old_evaluation`` (their
imports of each other renamed); "new" is the working tree.  Both run in this one
process on the same scans, so their time ratios hold on a noisy machine.

1. Same distances: the YCB multi-instance classes and the second labelled set
   (``benchmarks/stripes_ycb_other_labels.csv``) scanned at every seed, same pose (one
   scan per object, the default scanner) and different pose (two scans per object, any
   yaw), as ``benchmarks/stripes_variants.py``; on every such scan set the old and the
   new code make the silhouettes and every part's full distance matrix (profile,
   relief, surface context, canonical profile, shape context on 50 points) and the
   two fused matrices (``fused``: profile + relief + surface + ``shape-context-50``;
   ``fused-stripes``: profile + relief + surface + canonical; locally scaled, the
   arithmetic mean, `fuse`'s default in both revisions), and
   the benchmark judges the *decisions*: per matrix and query, the nearest other
   object (the query itself excluded) must be the same in old and new; it prints,
   per scan set, the outputs equal to the bit and, for the others, the largest
   relative change of a distance ``|new - old| / |old|`` (an intended rounding
   change, e.g. another summation order, moves the last bits of some distances and
   no decision).  A changed decision stops it with an error (a near tie broken the
   other way too: the change is then no longer only rounding for this benchmark).
   The silhouettes (vertices) must be equal to the bit.  With
   ``--decisions-may-change`` changed decisions are counted and printed and the run
   goes on to the timing (a matcher changed on purpose).
2. Time: representation + matching of 100 objects (the first 100 scans made, as
   ``stripes_variants``): per part, the old and the new function called alternately
   ``--repeats`` times, the fastest of each kept, and their ratio; then the two fused
   matchers (sum of their parts and the fusion step), with and without the
   silhouettes.  Time it with one BLAS thread (``OPENBLAS_NUM_THREADS=1``).

``--cache DIR`` keeps the scans (pickles) in DIR, e.g. ``/tmp/stripes-speed``, never in
the repository.  Nothing else is written; the meshes are read in place.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import io
import pickle
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from types import ModuleType
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from benchmarks.stripes_real import DEFAULT_MESHES  # noqa: E402
from data.stripe_scanner import ScannerConfig  # noqa: E402

#: The commit before the speed work (the "old" code by default).
BASELINE = "276411eb05e4aed3fd459a8f613d9c2aa64f4949"
OTHER_LABELS = ROOT / "benchmarks" / "stripes_ycb_other_labels.csv"
#: Objects of the timing set.
TIMING_OBJECTS = 100
#: Packages taken from the baseline revision.
PACKAGES = ("loopclosure", "evaluation")
#: Parts of each fused matcher (as `evaluation.stripes_benchmark`).
FUSED: dict[str, tuple[str, ...]] = {
    "fused": ("profile", "relief", "surface", "sc50"),
    "fused-stripes": ("profile", "relief", "surface", "canonical"),
}


def old_packages(rev: str, folder: Path) -> dict[str, ModuleType]:
    """The modules the benchmark calls, from `PACKAGES` at git revision `rev`, imported
    as ``_old_<package>`` from `folder` (module docstring)."""
    tar = subprocess.run(["git", "-C", str(ROOT), "archive", rev, *PACKAGES],
                         capture_output=True, check=True).stdout
    with tarfile.open(fileobj=io.BytesIO(tar)) as t:
        t.extractall(folder, filter="data")
    names = "|".join(PACKAGES)
    pattern = re.compile(rf"(?<=from )({names})\b|(?<=import )({names})\b"
                         rf"|(?<=[\"'])({names})(?=\.)")
    for pkg in PACKAGES:
        (folder / pkg).rename(folder / f"_old_{pkg}")
    for path in folder.rglob("*.py"):
        text = path.read_text()
        path.write_text(pattern.sub(lambda m: "_old_" + m.group(0), text))
    sys.path.insert(0, str(folder))
    return {"benchmark": importlib.import_module("_old_evaluation.stripes_benchmark"),
            "objects": importlib.import_module("_old_evaluation.stripes_objects"),
            "stripes": importlib.import_module("_old_loopclosure.stripes")}


def new_packages() -> dict[str, ModuleType]:
    """The same modules from the working tree."""
    return {"benchmark": importlib.import_module("evaluation.stripes_benchmark"),
            "objects": importlib.import_module("evaluation.stripes_objects"),
            "stripes": importlib.import_module("loopclosure.stripes")}


def part_runs(code: dict[str, ModuleType], scans: list, cfg: ScannerConfig,
              polys: list | None = None) -> dict[str, Callable[[], Any]]:
    """Part -> call making its output from `scans` with `code` (module docstring);
    ``sc50`` on `polys` (the silhouettes made beforehand), or on its own when None."""
    b, o = code["benchmark"], code["objects"]

    def sc50() -> np.ndarray:
        p = polys if polys is not None else [o.silhouette_polygon(s, cfg, 1.0) for s in scans]
        return b.baseline_distances("shape-context-50", p)[0]

    return {
        "silhouettes": lambda: [o.silhouette_polygon(s, cfg, 1.0) for s in scans],
        "profile": lambda: b.profile_distances(scans)[0],
        "relief": lambda: b.relief_distances(scans, cfg)[0],
        "surface": lambda: b.surface_distances(scans, cfg)[0],
        "canonical": lambda: b.canonical_distances(scans, cfg)[0],
        "sc50": sc50,
    }


def outputs(code: dict[str, ModuleType], scans: list, cfg: ScannerConfig) -> dict[str, Any]:
    """Every part's output and the fused matrices on `scans` with `code`."""
    polys = part_runs(code, scans, cfg)["silhouettes"]()
    out: dict[str, Any] = {"silhouettes": [p.vertices for p in polys]}
    for name, run in part_runs(code, scans, cfg, polys).items():
        if name != "silhouettes":
            out[name] = run()
    for name, parts in FUSED.items():
        out[name] = code["stripes"].fuse([out[p] for p in parts], scaling="local")
    return out


def identical(a: Any, b: Any) -> bool:
    """Equal to the bit: arrays (NaN where NaN) or lists of arrays."""
    if isinstance(a, list):
        return len(a) == len(b) and all(identical(x, y) for x, y in zip(a, b, strict=True))
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and bool(np.array_equal(a, b, equal_nan=True))


def scan_sets(meshes: Path, seeds: list[int], cache: Path | None) -> list[tuple[str, list,
                                                                              ScannerConfig]]:
    """``(column name, scans, scanner)`` per (set, seed, pose), as `stripes_variants`."""
    from evaluation.stripes_objects import mesh_folder_objects, scan_objects

    out = []
    for name, labels in (("ycb", None), ("other", OTHER_LABELS)):
        objs = None
        for seed in seeds:
            for pose in ("same", "diff"):
                cfg = (ScannerConfig() if pose == "same"
                       else replace(ScannerConfig(), yaw_range_deg=180.0))
                per = 1 if pose == "same" else 2
                key = hashlib.sha1(repr((str(meshes.resolve()), str(labels), cfg, seed, per))
                                   .encode()).hexdigest()[:12]
                path = None if cache is None else cache / f"scans-{key}.pkl"
                if path is not None and path.is_file():
                    with path.open("rb") as fh:
                        scans = pickle.load(fh)
                else:
                    objs = objs or mesh_folder_objects(meshes, labels)
                    scans = scan_objects(objs, cfg, seed, per).scans
                    if path is not None:
                        cache.mkdir(parents=True, exist_ok=True)  # type: ignore[union-attr]
                        with path.open("wb") as fh:
                            pickle.dump(scans, fh)
                out.append((f"{name}{seed}{pose[0]}", scans, cfg))
    return out


def relative_change(a: Any, b: Any) -> float:
    """Largest ``|b - a| / |a|`` over the entries finite in both (0 where both are 0)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    ok = np.isfinite(a) & np.isfinite(b)
    diff = np.abs(b[ok] - a[ok])
    scale = np.abs(a[ok])
    rel = np.where(diff == 0, 0.0, diff / np.where(scale > 0, scale, np.inf))
    rel = np.where((diff > 0) & (scale == 0), np.inf, rel)
    return float(rel.max()) if rel.size else 0.0


def nearest_other(d: np.ndarray) -> np.ndarray:
    """Per row of a square distance matrix, the column of the smallest distance, the
    diagonal (the query itself) excluded."""
    d = np.where(np.isfinite(d), d, np.inf)
    np.fill_diagonal(d, np.inf)
    return np.argmin(d, axis=1)


def decision_changes(a: np.ndarray, b: np.ndarray) -> int:
    """Queries whose nearest other object differs between the square matrices `a` (old)
    and `b` (new)."""
    return int(np.sum(nearest_other(a) != nearest_other(b)))


def check_same(old: dict, new: dict, sets: list, stop: bool = True) -> None:
    """Step 1 of the module docstring: the same silhouettes and the same nearest-other
    decisions of every matrix, or exit (with `stop` False, changed decisions are
    counted and the run goes on: a matcher changed on purpose); the largest relative
    change of each matrix."""
    print("same decisions (old vs new: nearest other object of every query; max relative "
          "change of the distances that are not equal to the bit):")
    for col, scans, cfg in sets:
        a, b = outputs(old, scans, cfg), outputs(new, scans, cfg)
        if not identical(a["silhouettes"], b["silhouettes"]):
            raise SystemExit(f"{col}: the new code changes the silhouettes")
        notes, broken = [], []
        mats = [k for k in a if k != "silhouettes"]
        for k in mats:
            if identical(a[k], b[k]):
                continue
            notes.append(f"{k} {relative_change(a[k], b[k]):.1e}")
            changed = decision_changes(np.asarray(a[k]), np.asarray(b[k]))
            if changed:
                broken.append(f"{k}: {changed} decisions")
        same = len(mats) - len(notes)
        print(f"  {col:8s} {len(scans):4d} scans: {same} of {len(mats)} matrices equal to the "
              "bit" + (f"; decisions unchanged, max relative change {', '.join(notes)}"
                       if notes and not broken else "")
              + (f"; CHANGED {', '.join(broken)}" if broken else ""))
        if broken and stop:
            raise SystemExit(f"{col}: the new code changes {', '.join(broken)}")


def fastest(runs: dict[str, tuple[Callable, Callable]], repeats: int) -> dict[str, list[float]]:
    """Part -> [old, new] fastest wall seconds of `repeats` alternating calls."""
    secs: dict[str, list[float]] = {}
    for name, (old, new) in runs.items():
        old(), new()  # warm: compiled kernels, caches
        best = [np.inf, np.inf]
        for _ in range(repeats):
            for k, f in enumerate((old, new)):
                t0 = time.perf_counter()
                f()
                best[k] = min(best[k], time.perf_counter() - t0)
        secs[name] = best
    return secs


def timing(old: dict, new: dict, scans: list, cfg: ScannerConfig, repeats: int) -> None:
    """Step 2 of the module docstring."""
    polys_old = part_runs(old, scans, cfg)["silhouettes"]()
    polys_new = part_runs(new, scans, cfg)["silhouettes"]()
    ro, rn = part_runs(old, scans, cfg, polys_old), part_runs(new, scans, cfg, polys_new)
    secs = fastest({k: (ro[k], rn[k]) for k in ro}, repeats)
    d = {k: rn[k]() for k in rn if k != "silhouettes"}
    for name, parts in FUSED.items():
        secs[f"fuse ({name})"] = list(fastest({name: (
            lambda p=parts: old["stripes"].fuse([d[m] for m in p], scaling="local"),
            lambda p=parts: new["stripes"].fuse([d[m] for m in p], scaling="local"))},
            repeats)[name])
    print(f"\ntime: representation + matching of {len(scans)} objects [s], fastest of "
          f"{repeats}, old and new alternating in this run")
    print(f"{'part':28s} {'old':>7s} {'new':>7s} {'old/new':>8s}")
    for name, (o, n) in secs.items():
        print(f"{name:28s} {o:7.3f} {n:7.3f} {o / n:8.2f}")
    for name, parts in FUSED.items():
        rows = [(name, [*parts, f"fuse ({name})"])]
        if "sc50" in parts:  # a matcher with a silhouette verifier needs the silhouettes
            rows.append((f"{name} + silhouettes", [*parts, f"fuse ({name})", "silhouettes"]))
        for label, keys in rows:
            o, n = sum(secs[k][0] for k in keys), sum(secs[k][1] for k in keys)
            print(f"{label:28s} {o:7.3f} {n:7.3f} {o / n:8.2f}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--meshes", type=Path, default=DEFAULT_MESHES)
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--baseline", default=BASELINE)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--cache", type=Path, default=None)
    ap.add_argument("--decisions-may-change", action="store_true",
                    help="count changed nearest-other decisions and go on to the timing "
                         "(the matcher changed on purpose) instead of stopping")
    args = ap.parse_args(argv)
    if not args.meshes.is_dir():
        print(f"skipped: no mesh folder {args.meshes}")
        return
    folder = Path(tempfile.mkdtemp(prefix="stripes-speed-"))
    try:
        old, new = old_packages(args.baseline, folder), new_packages()
        sets = scan_sets(args.meshes, [int(s) for s in args.seeds.split(",")], args.cache)
        print(f"old: {args.baseline[:12]} ({', '.join(PACKAGES)}); new: the working tree")
        check_same(old, new, sets, stop=not args.decisions_may_change)
        pool = [s for _, scans, _ in sets for s in scans]
        k = min(TIMING_OBJECTS, len(pool))
        timing(old, new, pool[:k], ScannerConfig(), args.repeats)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
