"""Benchmark: the place database's keyframe description, old code against new, in one
process, stage by stage, on the polygons a default run describes.

Two steps::

    python benchmarks/describe_stage_speed.py collect LOG [LOG ...] --out DIR
    python benchmarks/describe_stage_speed.py compare DIR --baseline REV [--repeat R]
        [--limit N]

``collect`` maps each log as ``loopclosure run`` does (the default pipeline in one
process; a corrected log with the odometry of seed 0, as `benchmarks/prior_free_phases.py`
maps it) and records the vertices of every polygon `PlaceDatabase.describe` is given
(the keyframes' 360-degree virtual scans and the wide views, sensor frame [m]) in
``DIR/<log>.npz``, outside the repository (data is never copied in).

``compare`` loads revision REV's versions of the description's files (`FILES`, by
``git show``; their imports of one another rewritten so that the old code calls only
old code) beside the working tree's and times, on the first N polygons of every
recorded log, R alternate passes of each code (CPU seconds, ``time.process_time``,
best pass):

* ``pairs``: the surface-pair histogram's describe (`PairHistogramMatcher.describe`);
* ``flirt``: FLIRT's interest points and beta-grids (`flirt_features.describe_polygon`);
* ``polar grid``: the bit-packed polar occupancy grid (`place_grids.polar_grid`);
* ``database describe``: `PlaceDatabase.describe` with the default configuration
  (the three above and the heading FFT, in the order the database calls them).

Per log and stage it prints the best CPU microseconds a keyframe of either code,
their ratio (old / new: above 1 is faster now) and whether every descriptor is
bit-identical (every array's bytes).
"""

from __future__ import annotations

import argparse
import importlib.util
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: Module -> file of the code the description runs (loaded from REV as ``<stem>_old``).
FILES = {
    "loopclosure.matchers.pair_histogram": "loopclosure/matchers/pair_histogram.py",
    "loopclosure.matchers.pair_kernel": "loopclosure/matchers/pair_kernel.py",
    "loopclosure.matchers.flirt_features": "loopclosure/matchers/flirt_features.py",
    "loopclosure.matchers.flirt_grid_kernel": "loopclosure/matchers/flirt_grid_kernel.py",
    "loopclosure.matchers.flirt_peak_kernel": "loopclosure/matchers/flirt_peak_kernel.py",
    "loopclosure.matchers.flirt_curve_kernel": "loopclosure/matchers/flirt_curve_kernel.py",
    "loopclosure.place_grids": "loopclosure/place_grids.py",
}


def collect(logs: list[Path], out: Path) -> None:
    from evaluation.slam_input import load_input
    from loopclosure.place_database import PlaceDatabase
    from loopclosure.warm_up import warm_up
    from slam.config import PipelineConfig
    from slam.pipeline import Mapper

    warm_up()
    real = PlaceDatabase.describe
    seen: list[np.ndarray] = []

    def recording(self, polygon):
        seen.append(np.array(polygon.vertices))
        return real(self, polygon)

    PlaceDatabase.describe = recording
    out.mkdir(parents=True, exist_ok=True)
    for log in logs:
        seen.clear()
        data = load_input(log, odometry_noise=0 if "corrected" in log.name else None)
        Mapper(PipelineConfig(front_end_worker=False)).run(data.scans)
        name = log.name.split(".")[0]
        np.savez(out / f"{name}.npz", *seen)
        print(f"{name}: {len(seen)} polygons", flush=True)


def load_old(rev: str, folder: Path) -> dict[str, object]:
    """Revision `rev`'s modules of `FILES` (those it has), each importing the others'
    old versions: module name -> module."""
    texts = {}
    for module, path in FILES.items():
        done = subprocess.run(["git", "show", f"{rev}:{path}"], cwd=ROOT,
                              capture_output=True, text=True)
        if done.returncode == 0:
            texts[module] = done.stdout
    names = {m: Path(FILES[m]).stem + "_old" for m in texts}
    loaded = {}
    sys.path.insert(0, str(folder))
    for module, text in texts.items():
        for other, alias in names.items():
            text = re.sub(rf"\b{re.escape(other)}\b", alias, text)
        (folder / f"{names[module]}.py").write_text(text)
    for module in texts:
        spec = importlib.util.spec_from_file_location(names[module],
                                                      folder / f"{names[module]}.py")
        assert spec is not None and spec.loader is not None
        mod = importlib.util.module_from_spec(spec)
        sys.modules[names[module]] = mod
        spec.loader.exec_module(mod)
        loaded[module] = mod
    return loaded


def same(a: object, b: object) -> bool:
    """Bit-identical descriptors (arrays by bytes, dataclasses field by field)."""
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    if hasattr(a, "__dataclass_fields__"):
        return all(same(getattr(a, f), getattr(b, f)) for f in a.__dataclass_fields__)
    if isinstance(a, float):
        return np.float64(a).tobytes() == np.float64(b).tobytes()
    return a == b


def stages(old: dict[str, object]) -> dict[str, tuple[Callable, Callable]]:
    """Stage -> (old describe, new describe) of one polygon."""
    import loopclosure.place_database as pdb
    from loopclosure.matchers import flirt_features, pair_histogram
    from loopclosure.matchers.flirt import FlirtMatcher
    from loopclosure.place_database import PlaceDatabase
    from loopclosure.place_grids import polar_grid

    new_db = PlaceDatabase()
    cfg = new_db.config
    features = new_db.matchers["flirt"]._features
    old_pairs = old["loopclosure.matchers.pair_histogram"].PairHistogramMatcher()
    old_ff = old["loopclosure.matchers.flirt_features"]
    old_grid = old["loopclosure.place_grids"].polar_grid

    class OldFlirt(FlirtMatcher):
        def describe(self, polygon):
            return old_ff.describe_polygon(polygon, self._features)

    old_db = PlaceDatabase(matchers={"pairs": old_pairs, "flirt": OldFlirt()})

    def old_describe(polygon):
        pdb.polar_grid = old_grid
        try:
            return old_db.describe(polygon)
        finally:
            pdb.polar_grid = polar_grid

    new_pairs = pair_histogram.PairHistogramMatcher()
    return {
        "pairs": (old_pairs.describe, new_pairs.describe),
        "flirt": (lambda p: old_ff.describe_polygon(p, features),
                  lambda p: flirt_features.describe_polygon(p, features)),
        "polar grid": (lambda p: old_grid(p, cfg), lambda p: polar_grid(p, cfg)),
        "database describe": (old_describe, new_db.describe),
    }


def compare(folder: Path, rev: str, repeat: int, limit: int) -> None:
    from loopclosure.polygon import Polygon

    with tempfile.TemporaryDirectory() as tmp:
        work = stages(load_old(rev, Path(tmp)))
        totals = {label: [0.0, 0.0] for label in work}
        for file in sorted(folder.glob("*.npz")):
            with np.load(file) as z:
                polygons = [Polygon(z[k]) for k in z.files][:limit]
            print(f"\n{file.stem}: {len(polygons)} polygons "
                  f"({np.mean([len(p) for p in polygons]):.0f} vertices)", flush=True)
            for label, (f_old, f_new) in work.items():
                f_old(polygons[0])
                f_new(polygons[0])  # numba compiles or loads its kernels
                identical = all(same(f_old(p), f_new(p)) for p in polygons)
                best = [np.inf, np.inf]
                for r in range(repeat):
                    for i in ((0, 1) if r % 2 == 0 else (1, 0)):
                        fn = (f_old, f_new)[i]
                        t0 = time.process_time()
                        for p in polygons:
                            fn(p)
                        best[i] = min(best[i], time.process_time() - t0)
                totals[label][0] += best[0]
                totals[label][1] += best[1]
                n = len(polygons)
                print(f"  {label:18s} old {1e6 * best[0] / n:8.1f} us  new "
                      f"{1e6 * best[1] / n:8.1f} us  old/new {best[0] / best[1]:5.2f}  "
                      f"bit-identical {identical}", flush=True)
        print("\nall logs (sum of best passes):")
        for label, (a, b) in totals.items():
            print(f"  {label:18s} old/new {a / b:5.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="step", required=True)
    c = sub.add_parser("collect")
    c.add_argument("logs", type=Path, nargs="+")
    c.add_argument("--out", type=Path, required=True)
    m = sub.add_parser("compare")
    m.add_argument("folder", type=Path)
    m.add_argument("--baseline", required=True)
    m.add_argument("--repeat", type=int, default=5)
    m.add_argument("--limit", type=int, default=400)
    args = parser.parse_args()
    if args.step == "collect":
        collect(args.logs, args.out)
    else:
        compare(args.folder, args.baseline, args.repeat, args.limit)


if __name__ == "__main__":
    main()
