"""Benchmark: the place database's describe and query stages, old code against new, in one run.

Run from the repository root::

    python benchmarks/place_stage_speed.py --baseline REV [--now REV2] [--data DIR]
        [--scans N] [--stride S] [--gap G] [--repeat R]

Places: every S-th of the first N scans of the Intel log (``carmen/intel.clf.bz2``),
each the polygon of the sensor origin and its valid end points (sensor frame [m],
`benchmarks.pair_histogram_speed.intel_polygons`).  For each code (REV by ``git
archive``; the working tree, or REV2) a fresh worker process with that code on
``PYTHONPATH`` (this file with ``--worker``) does what a mapping run asks of the place
database, with the default `PlaceDatabaseConfig`:

- ``describe``: every polygon described (`PlaceDatabase.describe`: the surface-pair
  histogram, FLIRT, the heading FFT, the polar grid) and stored under key i;
- ``query``: every key i >= G asked with its own descriptors over the keys at most
  i - G (`PlaceDatabase.query`, no headings);
- ``query_stored``: the same over a growing window, as keyframes sharing a wide view ask
  (`PlaceDatabase.query_stored` of key i - i mod 3 over the keys at most i - G).

Each stage and the parts inside it (FLIRT's describe and distances, the pair
histogram's describe, the polar grid, the grid similarity, the screen) are timed in
CPU seconds (``time.process_time``; a part's time is inside its stage's).  A worker
also prints a SHA-256 digest of every descriptor and every answer (keys, scores,
distances, prefilter distances): equal digests mean the two codes give the same bits.
Each code runs once untimed (numba compiles or loads its kernels; the digests are
compared), then R times each, alternately; prints per stage the median CPU seconds of
both and their ratio old / new (above 1: faster now).
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import importlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: (module, class or None, attribute, label) of the timed stages and parts.
STAGES = [
    ("loopclosure.place_database", "PlaceDatabase", "describe", "database describe"),
    ("loopclosure.matchers.flirt", "FlirtMatcher", "describe", "flirt_describe"),
    ("loopclosure.matchers.pair_histogram", "PairHistogramMatcher", "describe",
     "pairs_describe"),
    ("loopclosure.place_database", None, "polar_grid", "polar grid"),
    ("loopclosure.place_database", "PlaceDatabase", "query", "query"),
    ("loopclosure.place_database", "PlaceDatabase", "query_stored", "query_stored"),
    ("loopclosure.matchers.flirt", "FlirtMatcher", "distances", "flirt_distances"),
    ("loopclosure.place_database", "PlaceDatabase", "_grid_similarity", "grid similarity"),
    ("loopclosure.place_database", "PlaceDatabase", "_screen", "screen"),
]


def _install(total: defaultdict[str, float]) -> None:
    """Wrap every stage of `STAGES` with a CPU timer adding to `total`."""
    for module, owner, name, label in STAGES:
        mod = importlib.import_module(module)
        where = getattr(mod, owner) if owner else mod
        function = getattr(where, name)

        def timed(*args, _f=function, _label=label, **kwargs):
            start = time.process_time()
            try:
                return _f(*args, **kwargs)
            finally:
                total[_label] += time.process_time() - start

        setattr(where, name, functools.wraps(function)(timed))


def _digest_descriptors(h: hashlib._Hash, descriptors: dict) -> None:
    """Feed every array of a keyframe's descriptors (any nesting) into `h`."""
    import numpy as np

    for key in sorted(descriptors):
        value = descriptors[key]
        h.update(key.encode())
        fields = getattr(value, "__slots__", None) or getattr(value, "__dataclass_fields__", None)
        parts = [getattr(value, f) for f in fields] if fields else [value]
        for part in parts:
            a = np.asarray(part)
            h.update(str(a.dtype).encode() + str(a.shape).encode())
            h.update(np.ascontiguousarray(a).tobytes())


def worker(data: Path, scans: int, stride: int, gap: int) -> None:
    """Time the stages with the code on ``PYTHONPATH``; print a JSON line (docstring)."""
    import numpy as np

    from benchmarks.pair_histogram_speed import intel_polygons
    from loopclosure.place_database import PlaceDatabase

    polygons = intel_polygons(data, scans)[::stride]
    total: defaultdict[str, float] = defaultdict(float)
    _install(total)
    h = hashlib.sha256()
    db = PlaceDatabase()
    for i, polygon in enumerate(polygons):
        descriptors = db.describe(polygon)
        _digest_descriptors(h, descriptors)
        db.add_descriptors(i, descriptors)
    keys = np.arange(len(polygons))
    for i in range(gap, len(polygons)):
        for match in db.query(db.descriptors(i), allowed=keys[: i - gap + 1], headings=False):
            h.update(repr((match.key, match.score, match.prefilter_distance,
                           sorted(match.distances.items()))).encode())
        for match in db.query_stored(i - i % 3, allowed=keys[: i - gap + 1]):
            h.update(repr((match.key, match.score, match.prefilter_distance,
                           sorted(match.distances.items()))).encode())
    print(json.dumps({"cpu": dict(total), "digest": h.hexdigest(), "places": len(polygons)}))


def _run_worker(code: Path, args: argparse.Namespace) -> dict:
    env = dict(os.environ, PYTHONPATH=str(code))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--data", str(args.data),
           "--scans", str(args.scans), "--stride", str(args.stride), "--gap", str(args.gap)]
    out = subprocess.run(cmd, env=env, cwd=code, check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", help="a revision (git archive)")
    parser.add_argument("--now", help="a revision to measure instead of the working tree")
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--scans", type=int, default=3000)
    parser.add_argument("--stride", type=int, default=5)
    parser.add_argument("--gap", type=int, default=20, help="keys a query skips")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per code")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.data, args.scans, args.stride, args.gap)
        return
    if not args.baseline:
        parser.error("--baseline is required")
    sys.path.insert(0, str(ROOT))
    from benchmarks.run_speed import checkout

    with tempfile.TemporaryDirectory() as tmp:
        base = checkout(args.baseline, Path(tmp) / "baseline")
        now = ROOT if args.now is None else checkout(args.now, Path(tmp) / "now")
        codes = [("baseline", base), ("now", now)]
        warm = {label: _run_worker(code, args) for label, code in codes}
        cpu: dict[str, list[dict]] = {"baseline": [], "now": []}
        for r in range(args.repeat):
            for label, code in codes if r % 2 == 0 else codes[::-1]:
                cpu[label].append(_run_worker(code, args)["cpu"])
    same = warm["baseline"]["digest"] == warm["now"]["digest"]
    print(f"{warm['now']['places']} Intel places; descriptors and answers "
          f"{'identical' if same else 'DIFFER'} ({args.baseline} vs {args.now or 'now'})")
    print(f"{'stage':20s} {'old s':>8s} {'new s':>8s} {'old/new':>8s}")
    for _, _, _, label in STAGES:
        old = statistics.median(c.get(label, 0.0) for c in cpu["baseline"])
        new = statistics.median(c.get(label, 0.0) for c in cpu["now"])
        ratio = old / new if new > 0 else float("nan")
        print(f"{label:20s} {old:8.2f} {new:8.2f} {ratio:8.2f}")


if __name__ == "__main__":
    main()
