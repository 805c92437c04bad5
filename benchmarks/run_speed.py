"""Benchmark: the whole ``loopclosure run`` of a log, old code against new, in one sitting.

Run from the repository root::

    python benchmarks/run_speed.py --baseline REV [--now REV2] [--data DIR]
        [--logs carmen-corrected/intel-corrected.log.gz,...] [--repeat R] [--worker]

For every log the script runs ``loopclosure run LOG --no-map`` with the code of
revision REV (``git archive`` into a temporary folder) and with the working tree
(or revision REV2, archived the same way),
each in a fresh process: first once per code to warm numba's on-disk kernel cache
(a fresh copy compiles every kernel once; that run is not timed, and its outputs
are compared), then R times each, alternately.  It prints per log and code the
median CPU seconds of the run's process (user + system, from
``resource.getrusage(RUSAGE_CHILDREN)``) and the median ``loop_detection`` seconds
of its ``summary.json``, their ratios (baseline / now: above 1 is faster now), and
whether ``loops.csv``, ``trajectory.tum`` and ``graph.g2o`` are byte-identical between the two
codes.  By default the front end runs in this process too (``--set
front_end_worker=false``), so the CPU time is the whole pipeline's and does not
depend on how the two processes overlap; ``--worker`` keeps the forked worker
(its CPU time is counted as well: a child of the child).
"""

from __future__ import annotations

import argparse
import filecmp
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LOGS = "carmen/intel.clf.bz2,carmen-corrected/intel-corrected.log.gz"


def run_once(code: Path, log: Path, out: Path, worker: bool) -> tuple[float, float]:
    """CPU seconds of one ``loopclosure run`` with `code` on `log` into `out`, and
    the ``loop_detection`` seconds of its summary."""
    env = dict(os.environ, PYTHONPATH=str(code))
    cmd = [sys.executable, "-c", "from slam.cli.main import main; main()", "run", str(log),
           "--out", str(out), "--no-map"]
    if not worker:
        cmd += ["--set", "front_end_worker=false"]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(cmd, env=env, cwd=code, check=True, capture_output=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    summary = json.loads((out / "summary.json").read_text())
    return cpu, float(summary["timings_s"]["loop_detection"])


def checkout(rev: str, folder: Path) -> Path:
    """The code of revision `rev` (``git archive``) in `folder`."""
    folder.mkdir()
    archive = subprocess.run(["git", "archive", rev], cwd=ROOT, check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    return folder


def identical(a: Path, b: Path) -> str:
    """Which of the two runs' loop, trajectory and graph files agree byte for byte
    (``graph.g2o`` when both runs wrote one)."""
    names = ["loops.csv", "trajectory.tum"]
    if (a / "graph.g2o").exists() and (b / "graph.g2o").exists():
        names.append("graph.g2o")
    return ", ".join(f"{n} {'identical' if filecmp.cmp(a / n, b / n, shallow=False) else 'DIFFER'}"
                     for n in names)


def revision_parser(description: str, logs: str) -> argparse.ArgumentParser:
    """An argument parser for old-against-new timings: ``--baseline``, ``--now``,
    ``--data``, ``--logs`` (default `logs`) and ``--repeat``."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--baseline", required=True, help="a revision (git archive)")
    parser.add_argument("--now", help="a revision to measure instead of the working tree")
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--logs", default=logs, help="comma-separated, under --data")
    parser.add_argument("--repeat", type=int, default=2, help="timed runs per code")
    return parser


def main() -> None:
    parser = revision_parser(__doc__.split("\n")[0], LOGS)
    parser.add_argument("--worker", action="store_true",
                        help="keep the front end's forked worker")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        base = checkout(args.baseline, Path(tmp) / "baseline")
        now = ROOT if args.now is None else checkout(args.now, Path(tmp) / "now")
        codes = [("baseline", base), ("now", now)]
        for name in args.logs.split(","):
            log = args.data / name
            if not log.exists():
                sys.exit(f"{log} not found: pass --data with the shared data folder")
            outs = {label: Path(tmp) / f"{label}-warm" for label, _ in codes}
            for label, code in codes:  # warm the kernel caches; compare the outputs
                run_once(code, log, outs[label], args.worker)
            cpu: dict[str, list[float]] = {"baseline": [], "now": []}
            loops: dict[str, list[float]] = {"baseline": [], "now": []}
            for r in range(args.repeat):
                for label, code in codes if r % 2 == 0 else codes[::-1]:
                    c, d = run_once(code, log, Path(tmp) / f"{label}-{r}", args.worker)
                    cpu[label].append(c)
                    loops[label].append(d)
            old_c, new_c = (statistics.median(cpu[k]) for k in ("baseline", "now"))
            old_d, new_d = (statistics.median(loops[k]) for k in ("baseline", "now"))
            print(f"{name}: CPU {old_c:.1f} s ({args.baseline}) -> {new_c:.1f} s "
                  f"({args.now or 'now'}), "
                  f"ratio {old_c / new_c:.2f}; loop_detection {old_d:.1f} s -> {new_d:.1f} s, "
                  f"ratio {old_d / new_d:.2f}; {identical(outs['baseline'], outs['now'])}",
                  flush=True)


if __name__ == "__main__":
    main()
