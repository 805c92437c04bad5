"""Where the mapper's geometric checks spend their time: cProfile per check, by verdict.

Run from the repository root (the working tree's code on ``PYTHONPATH``)::

    python benchmarks/check_profile.py LOG [LOG ...] [--top N]

Each log is mapped as ``loopclosure run LOG`` maps it (the default pipeline, the
front end in the mapper's process, the log's own odometry).  Every check from a
prior (`loopclosure.candidate_checks.CandidateChecks._check_prior`) and every
query's checks with no prior (`CandidateChecks._verify_free`, a query's places
together) runs under its own ``cProfile.Profile``, merged by verdict: a check from a
prior accepted, stopped by the pre-ICP screens, or rejected after ICP; a query's
checks with no prior with a place accepted or none.  Per log and group it prints
the calls, their CPU seconds (``time.process_time``, profiling included: cProfile
slows Python-level code several times more than compiled kernels, so the shares
below overstate Python overhead), and each part's share of the group's profiled
time: the compiled ICP, the pre-ICP screens, the correlative lattices, the
free-space tests, the likelihood grids and the targets' normals (once per target),
the heading hypotheses of the places, the submaps the host builds; then, with
``--top``, the group's N functions of largest own time.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: Part -> (file, function, own time (True) or cumulative time (False)).
PARTS = {
    "ICP kernel": ("icp_kernel.py", "_register_kernel", True),
    "screens": ("loopclosure/", "_screen_kernel", True),
    "screens (stopped)": ("prior_screen.py", "_screen_until_kernel", True),
    "lattices": ("correlative.py", "search", False),
    "free space": ("free_space.py", "consistency", False),
    "likelihood grids": ("correlative.py", "widths", False),
    "target normals": ("grid_target.py", "estimate_normals_fast", False),
    "headings": ("place_database.py", "with_headings", False),
    "host submaps": ("pipeline.py", "submap", False),
}


def _prior_kind(c) -> str:
    if c.accepted:
        return "accepted"
    return "screened" if c.reason.startswith(("no overlap", "no fit within")) else "rejected"


def profile(log: Path, top: int) -> None:
    from evaluation.slam_input import load_input
    from loopclosure.candidate_checks import CandidateChecks
    from loopclosure.warm_up import warm_up
    from slam.config import PipelineConfig
    from slam.pipeline import Mapper

    warm_up()
    stats: dict[str, pstats.Stats] = {}
    cpu: dict[str, list[float]] = {}

    def wrap(name, real, verdict):
        def run(self, *args, **kwargs):
            prof = cProfile.Profile()
            t0 = time.process_time()
            prof.enable()
            out = real(self, *args, **kwargs)
            prof.disable()
            label = f"{name} {verdict(out)}"
            row = cpu.setdefault(label, [0, 0.0])
            row[0] += 1
            row[1] += time.process_time() - t0
            if label in stats:
                stats[label].add(prof)
            else:
                stats[label] = pstats.Stats(prof)
            return out
        return run

    real_prior, real_free = CandidateChecks._check_prior, CandidateChecks._verify_free
    CandidateChecks._check_prior = wrap("prior", real_prior, _prior_kind)
    CandidateChecks._verify_free = wrap(
        "no prior", real_free,
        lambda out: "place accepted" if any(c.accepted for c in out) else "none accepted")
    try:
        t0 = time.process_time()
        Mapper(PipelineConfig(front_end_worker=False)).run(load_input(log).scans)
        total = time.process_time() - t0
    finally:
        CandidateChecks._check_prior, CandidateChecks._verify_free = real_prior, real_free
    print(f"\n{log.name}: run {total:.1f} s CPU (profiled checks included)")
    for label in sorted(stats):
        st = stats[label]
        profiled = sum(v[2] for v in st.stats.values())  # own times add up to the total
        shares = []
        for part, (file, func, own) in PARTS.items():
            t = sum(v[2] if own else v[3] for (f, _, fn), v in st.stats.items()
                    if fn == func and file in f)
            if t > 0:
                shares.append(f"{part} {100 * t / profiled:.0f}%")
        calls, seconds = cpu[label]
        print(f"  {label}: {calls} calls, {seconds:.2f} s CPU; " + ", ".join(shares))
        if top > 0:
            buf = io.StringIO()
            st.stream = buf
            st.sort_stats("tottime").print_stats(top)
            print(buf.getvalue())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("logs", nargs="+", type=Path)
    parser.add_argument("--top", type=int, default=0, help="functions listed per group")
    args = parser.parse_args()
    for log in args.logs:
        profile(log, args.top)


if __name__ == "__main__":
    main()
