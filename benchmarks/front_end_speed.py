"""Benchmark: CPU time of the default ``icp2d`` front end alone, old code against new,
in one sitting.

Run from the repository root::

    python benchmarks/front_end_speed.py --baseline REV [--now REV2] [--data DIR]
        [--logs carmen/intel.clf.bz2,...] [--repeat R] [--limit N]

For every log, the front end of the default pipeline configuration
(``PipelineConfig().odometry`` with ``front_end_config()``) processes every scan in
file order, with the code of revision REV (``git archive`` into a temporary folder)
and with the working tree (or revision REV2, archived the same way), each in a fresh
process: first once per code to warm numba's on-disk kernel cache (not timed), then R
times each, alternately.  A child reads the log before its clock starts and reports
the CPU seconds (``time.process_time``) of the scan loop, the number of map
rebuilds, and a digest of every estimate's pose, increment and covariance (their
float64 bytes).  The script prints per log the median CPU seconds of either code,
their ratio (baseline / now: above 1 is faster now), milliseconds per scan, and
whether the two codes' estimates are bit-identical.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.run_speed import ROOT, checkout, revision_parser

LOGS = ("carmen/intel.clf.bz2,carmen-corrected/freiburg-campus-corrected.log.gz,"
        "carmen-corrected/freiburg-101-corrected.log.gz")

# The child: run by `python -c` with PYTHONPATH set to one code's folder.
CHILD = """
import hashlib, json, sys, time
from data.sources import open_source
from slam.config import PipelineConfig
from slam.odometry import make_odometry
log, limit = sys.argv[1], int(sys.argv[2])
scans = list(open_source(log))
if limit > 0:
    scans = scans[:limit]
cfg = PipelineConfig()
odo = make_odometry(cfg.odometry, cfg.front_end_config())
digest = hashlib.sha256()
t0 = time.process_time()
estimates = [odo.process(s) for s in scans]
cpu = time.process_time() - t0
for e in estimates:
    digest.update(e.pose.tobytes() + e.delta.tobytes() + e.covariance.tobytes())
print(json.dumps({"cpu": cpu, "scans": len(scans), "digest": digest.hexdigest(),
                  "rebuilds": getattr(odo, "map_rebuilds", -1)}))
"""


def run_once(code: Path, log: Path, limit: int) -> dict:
    """The child's report for `code` on `log`."""
    out = subprocess.run([sys.executable, "-c", CHILD, str(log), str(limit)],
                         env=dict(os.environ, PYTHONPATH=str(code)),
                         cwd=code, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> None:
    parser = revision_parser(__doc__.split("\n")[0], LOGS)
    parser.add_argument("--limit", type=int, default=0, help="first N scans (0: all)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        base = checkout(args.baseline, Path(tmp) / "baseline")
        now = ROOT if args.now is None else checkout(args.now, Path(tmp) / "now")
        codes = [("baseline", base), ("now", now)]
        print(f"{'log':<48} {'scans':>6} {'rebuilds':>8} {'old s':>7} {'new s':>7} "
              f"{'ratio':>6} {'old ms':>7} {'new ms':>7}  estimates")
        for name in args.logs.split(","):
            log = args.data / name
            if not log.exists():
                sys.exit(f"{log} not found: pass --data with the shared data folder")
            warm = {label: run_once(code, log, args.limit) for label, code in codes}
            cpu: dict[str, list[float]] = {"baseline": [], "now": []}
            for r in range(args.repeat):
                for label, code in codes if r % 2 == 0 else codes[::-1]:
                    cpu[label].append(run_once(code, log, args.limit)["cpu"])
            old, new = (statistics.median(cpu[k]) for k in ("baseline", "now"))
            n = warm["now"]["scans"]
            same = ("identical" if warm["baseline"]["digest"] == warm["now"]["digest"]
                    else "DIFFER")
            print(f"{name:<48} {n:>6} {warm['now']['rebuilds']:>8} {old:7.2f} {new:7.2f} "
                  f"{old / new:6.2f} {1000 * old / n:7.2f} {1000 * new / n:7.2f}  {same}",
                  flush=True)


if __name__ == "__main__":
    main()
