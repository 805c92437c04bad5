"""Benchmark: CPU time of the default ``icp2d`` front end, old code against new, in ONE
process, runs interleaved.

Run from the repository root::

    python benchmarks/front_end_ab.py --baseline REV [--now REV2] [--data DIR]
        [--logs carmen-corrected/orebro-corrected.log.gz,...] [--repeat R] [--limit N]

The code of revision REV (``git archive`` into a temporary folder) is imported first,
under the package names ``data``, ``loopclosure`` and ``slam``; its front end's
class and config are kept, those modules are dropped from ``sys.modules``, and the
working tree (or REV2, archived the same way) is imported under the same names.
Both front ends then live in this one process, each calling its own compiled
kernels (numba caches them per source file); before each code runs, its modules are
put back under the project's names in ``sys.modules`` (what it imports at call
time is then its own).  Every log is read once by either
code's reader (a front end checks scans against its own ``Scan`` class).  Per log:
one untimed run of each code (kernels loaded or compiled), then R timed runs of
each, alternating which goes first; a run is the front end of the default pipeline
configuration (``PipelineConfig().odometry`` with ``front_end_config()``) over
every scan in file order, timed by ``time.process_time``.  The script prints the
best and median CPU seconds of either code, the ratio of their medians (old / new:
above 1 is faster now), microseconds per scan, and whether every estimate (pose,
increment, covariance as float64 bytes, status, fitness) is bit-identical.  With
``--whole-runs`` it then runs ``loopclosure run LOG --no-map`` (defaults, the front
end in its worker) once with either code, each in its own process, and says whether
their ``loops.csv`` and ``trajectory.tum`` are byte-identical.
"""

from __future__ import annotations

import hashlib
import importlib
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.run_speed import ROOT, checkout, identical, revision_parser, run_once

LOGS = ("carmen-corrected/orebro-corrected.log.gz,carmen-corrected/freiburg-101-corrected.log.gz,"
        "carmen-corrected/belgioioso-corrected.log.gz")
PACKAGES = ("data", "loopclosure", "slam", "evaluation")


def _drop_project_modules() -> dict[str, Any]:
    """Remove the project's modules from ``sys.modules``; return them."""
    names = [m for m in sys.modules if m.split(".")[0] in PACKAGES]
    return {name: sys.modules.pop(name) for name in names}


def activate(code: dict[str, Any]) -> None:
    """Put `code`'s modules under the project's names in ``sys.modules``, so that what
    it imports at call time (readers, the front end's compiled module) is its own."""
    _drop_project_modules()
    sys.modules.update(code["modules"])


def load_code(folder: Path) -> dict[str, Any]:
    """The front end class, its default config and the log reader of the code in
    `folder`, imported under the project's package names, with those modules."""
    _drop_project_modules()
    sys.path.insert(0, str(folder))
    try:
        importlib.invalidate_caches()
        cfg = importlib.import_module("slam.config").PipelineConfig()
        if cfg.odometry != "icp2d":
            sys.exit(f"{folder}: the default front end is {cfg.odometry}, not icp2d")
        icp2d = importlib.import_module("slam.odometry.icp2d")
        icp2d._fast()  # its compiled module, imported now from this folder
        code = {
            "front_end": icp2d.Icp2dOdometry,
            "config": cfg.front_end_config(),
            "open": importlib.import_module("data.sources").open_source,
        }
    finally:
        sys.path.remove(str(folder))
    code["modules"] = _drop_project_modules()
    return code


def read(code: dict[str, Any], log: Path, limit: int) -> list[Any]:
    """The scans of `log` read by `code`'s reader (its own ``Scan`` class)."""
    activate(code)
    scans = list(code["open"](str(log)))
    return scans[:limit] if limit > 0 else scans


def run(code: dict[str, Any], scans: list[Any]) -> tuple[float, str]:
    """CPU seconds of `code`'s default front end over `scans`, and a digest of its
    estimates."""
    activate(code)
    odometry = code["front_end"](code["config"])
    start = time.process_time()
    estimates = [odometry.process(scan) for scan in scans]
    cpu = time.process_time() - start
    digest = hashlib.sha256()
    for e in estimates:
        digest.update(e.pose.tobytes() + e.delta.tobytes() + e.covariance.tobytes()
                      + e.status.encode() + repr(e.fitness).encode())
    return cpu, digest.hexdigest()


def main() -> None:
    parser = revision_parser(__doc__.split("\n")[0], LOGS)
    parser.add_argument("--limit", type=int, default=0, help="first N scans (0: all)")
    parser.add_argument("--whole-runs", action="store_true",
                        help="also compare loopclosure run's loops.csv and trajectory.tum")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        base = checkout(args.baseline, Path(tmp) / "baseline")
        now = ROOT if args.now is None else checkout(args.now, Path(tmp) / "now")
        codes = {"old": load_code(base), "new": load_code(now)}
        print(f"{'log':<46} {'scans':>6} {'old best':>8} {'new best':>8} {'old med':>8} "
              f"{'new med':>8} {'ratio':>6} {'old us':>7} {'new us':>7}  estimates", flush=True)
        for name in args.logs.split(","):
            log = args.data / name
            if not log.exists():
                sys.exit(f"{log} not found: pass --data with the shared data folder")
            scans = {label: read(code, log, args.limit) for label, code in codes.items()}
            digests = {label: run(code, scans[label])[1] for label, code in codes.items()}
            cpu: dict[str, list[float]] = {"old": [], "new": []}
            order = ["old", "new"]
            for r in range(args.repeat):
                for label in order if r % 2 == 0 else order[::-1]:
                    seconds, digest = run(codes[label], scans[label])
                    cpu[label].append(seconds)
                    if digest != digests[label]:
                        digests[label] = "unstable"
            n = len(scans["new"])
            old_m, new_m = statistics.median(cpu["old"]), statistics.median(cpu["new"])
            same = "identical" if digests["old"] == digests["new"] else "DIFFER"
            print(f"{name:<46} {n:>6} {min(cpu['old']):8.3f} {min(cpu['new']):8.3f} "
                  f"{old_m:8.3f} {new_m:8.3f} {old_m / new_m:6.3f} {1e6 * old_m / n:7.1f} "
                  f"{1e6 * new_m / n:7.1f}  {same}", flush=True)
            if args.whole_runs:
                del scans
                outs = {label: Path(tmp) / f"{label}-{log.name}" for label in codes}
                for label, code in (("old", base), ("new", now)):
                    run_once(code, log, outs[label], worker=True)
                print(f"    loopclosure run: {identical(outs['old'], outs['new'])}", flush=True)


if __name__ == "__main__":
    main()
