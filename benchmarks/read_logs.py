"""Benchmark: how fast the readers turn real logs into scans.

Run from the repository root::

    python benchmarks/read_logs.py [--data DIR] [--repeat N]

Each case is one function ``case(data_dir) -> (scans, label)`` timed end to end;
the script prints wall-clock seconds, CPU seconds of the process (all threads),
scans per second, and each case's ratio to the decompression floor measured in
the same run (reading a compressed log can never beat decompressing it).  The
goal: the whole Intel log in under 3 s.

Cases: ``decompress`` (bzip2 of intel.clf.bz2 alone, the floor), ``carmen``
(`data.carmen.CarmenLog` over intel.clf.bz2), ``ros2-mcap`` and ``ros2-sqlite3``
(`data.rosbag` over the Intel log converted to a ROS2 bag with
`data.rosbag.write_ros2_bag`; the conversion is made once, in a temporary
folder deleted at exit, and is not timed).  Add a case by writing a function and
listing it in `CASES`.
"""

from __future__ import annotations

import argparse
import atexit
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from data.carmen import CarmenLog  # noqa: E402
from data.compression import open_binary  # noqa: E402
from data.sources import open_source  # noqa: E402

INTEL = Path("carmen") / "intel.clf.bz2"


def case_decompress(data: Path) -> tuple[int, str]:
    """Decompress intel.clf.bz2 in 64 KiB pieces, nothing else (the floor)."""
    size = 0
    with open_binary(data / INTEL) as f:
        while piece := f.read(1 << 16):
            size += len(piece)
    return 0, f"{size / 1e6:.1f} MB decompressed"


def case_carmen(data: Path) -> tuple[int, str]:
    """Iterate every scan of intel.clf.bz2 with `CarmenLog`."""
    beams = 0
    scans = 0
    for scan in CarmenLog(data / INTEL):
        scans += 1
        beams += len(scan.ranges)
    return scans, f"{beams:,} beams"


_BAGS: dict[str, Path] = {}


def _intel_bag(data: Path, storage: str) -> Path:
    """The Intel log as a ROS2 bag (made once per run, outside the timing)."""
    if storage not in _BAGS:
        from data.rosbag import write_ros2_bag

        folder = Path(tempfile.mkdtemp(prefix="read_logs_"))
        atexit.register(shutil.rmtree, folder, True)
        _BAGS[storage] = folder / f"intel-{storage}"
        write_ros2_bag(CarmenLog(data / INTEL), _BAGS[storage], storage=storage)
    return _BAGS[storage]


def _read_bag(bag: Path) -> tuple[int, str]:
    beams = 0
    scans = 0
    for scan in open_source(bag):
        scans += 1
        beams += len(scan.ranges)
    return scans, f"{beams:,} beams"


CASES: dict[str, Callable[[Path], tuple[int, str]]] = {
    "decompress": case_decompress,
    "carmen": case_carmen,
    "ros2-mcap": lambda data: _read_bag(_intel_bag(data, "mcap")),
    "ros2-sqlite3": lambda data: _read_bag(_intel_bag(data, "sqlite3")),
}


def run(name: str, data: Path, repeat: int) -> tuple[float, float, int, str]:
    """Best wall time of `repeat` runs, its CPU time, scans and label."""
    best = (float("inf"), 0.0, 0, "")
    for _ in range(repeat):
        wall, cpu = time.perf_counter(), time.process_time()
        scans, label = CASES[name](data)
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        if wall < best[0]:
            best = (wall, cpu, scans, label)
    return best


def main(argv: list[str] | None = None) -> int:
    default = Path(os.environ.get("LOOPCLOSURE_SHARED_DATA", ROOT.parent / "shared" / "data"))
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=default, help="shared data folder")
    parser.add_argument("--repeat", type=int, default=1, help="runs per case (best is kept)")
    parser.add_argument("cases", nargs="*", default=list(CASES), help="cases to run")
    args = parser.parse_args(argv)
    if not (args.data / INTEL).exists():
        print(f"error: {args.data / INTEL} not found (pass --data)", file=sys.stderr)
        return 2
    unknown = [c for c in args.cases if c not in CASES]
    if unknown:
        print(f"error: unknown case(s) {unknown}; known: {list(CASES)}", file=sys.stderr)
        return 2
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print(f"{'case':<12}{'wall s':>8}{'cpu s':>8}{'scans':>8}{'scans/s':>10}{'x floor':>9}  note")
    floor = None
    for name in args.cases:
        if name.startswith("ros2-"):
            _intel_bag(args.data, name.removeprefix("ros2-"))  # convert before timing
        wall, cpu, scans, label = run(name, args.data, args.repeat)
        if name == "decompress":
            floor = wall
        rate = f"{scans / wall:,.0f}" if scans else "-"
        ratio = f"{wall / floor:.2f}" if floor else "-"
        print(f"{name:<12}{wall:>8.2f}{cpu:>8.2f}{scans:>8}{rate:>10}{ratio:>9}  {label}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
