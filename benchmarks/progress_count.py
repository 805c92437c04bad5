"""Benchmark: the progress display's count of accepted loops, per scan, in one run.

Run from the repository root::

    python benchmarks/progress_count.py [--scans 13631] [--loops 3004]

The mapper reports its accepted loops to the progress display after every scan.
Counted over every loop event each time, the cost grows with scans x loops (on
Intel's 13,631 scans and 3,004 loop events, seconds of the mapper's own process);
`slam.pipeline.Mapper._accepted` counts only the events added since its last call.
Both are timed here on the same synthetic run (loop events arriving evenly over the
scans, two in three accepted) and must agree on every count; prints both times and
their ratio.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from types import SimpleNamespace

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from slam.pipeline import Mapper  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scans", type=int, default=13631)
    ap.add_argument("--loops", type=int, default=3004)
    args = ap.parse_args()
    events = [SimpleNamespace(candidate=SimpleNamespace(accepted=i % 3 != 0))
              for i in range(args.loops)]
    arrive = [round((s + 1) * args.loops / args.scans) for s in range(args.scans)]
    mapper = Mapper.__new__(Mapper)  # only the attributes `_accepted` reads
    mapper.loops, mapper._joined, mapper._accepted_tally = [], True, (0, 0, False)

    t = time.perf_counter()
    every, loops = [], []
    for n in arrive:
        loops.extend(events[len(loops):n])
        every.append(sum(1 for e in loops if e.candidate.accepted))
    t_every = time.perf_counter() - t

    t = time.perf_counter()
    tally = []
    for n in arrive:
        mapper.loops.extend(events[len(mapper.loops):n])
        tally.append(mapper._accepted())
    t_tally = time.perf_counter() - t

    assert every == tally, "the two counts disagree"
    print(f"{args.scans} scans, {args.loops} loop events: every event each scan "
          f"{t_every:.3f} s, events since the last call {t_tally:.3f} s, "
          f"ratio {t_tally / t_every:.3f}")


if __name__ == "__main__":
    main()
