"""Benchmark: where the time of one robustness cell goes, stage by stage.

Run from the repository root::

    python benchmarks/robust_cell_time.py [--graph input_INTEL_g2o.g2o] [--scale 1]
        [--policy random] [--ratio 0.5] [--seed 0] [--repeat 1] [--cap 0] [--dump FILE]
        [--plain on|off]

Builds the cell as `benchmarks/robustness.py` does (`evaluation.robustness`: the graph
with its odometry information scaled, false loops injected by the policy), solves it
with the default robust back end (``optimize(..., "gnc", gnc_start=GNC_START)``) under
cProfile and prints the wall time and the cumulative seconds of each stage: the
fast path's check (the plain least-squares optimum over every loop at each odometry
rung, solved before any admission and discarded when a loop fails there), the
time-ordered admission passes, the calibrated choice (its own-factor estimates and
judgements), the offer back, the bar search, the segment re-check, and every
least-squares solve; then what the stages are made of: gtsam's iSAM2 updates (the
admission's prefix, `slam.isam_prefix`) and batch optimisations (LM or dogleg, wherever
called), the undo hypotheses, the nonlinear check of admissions, the innovation tests and
their sparse LU factorisations.  Stages nest (the bar search runs admission passes), so
the seconds do not add up.  Under cProfile a run is slower than the sweep's.  ``--plain
off`` skips the unprofiled run before the profiled one; ``--cap S`` stops the profiled
run after S seconds of process CPU (`benchmarks.robust_cell.cpu_cap`; the profile up to
there is printed); ``--dump FILE`` writes the cProfile statistics for ``pstats``.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.robust_cell import CpuCapped, cpu_cap
from data.g2o import read_g2o
from evaluation.robustness import GNC_START, _prepared, inject_false_loops
from slam.optimize import optimize
from slam.pose_graph import PoseGraph

STAGES = {
    "fast-path check": ("optimize.py", "_clean_optimum"),
    "admission passes": ("admission.py", "advance"),
    "calibrated choice": ("calibrated_choice.py", "calibrated_choices"),
    "  own factors": ("calibrated_choice.py", "own_factor"),
    "  judgements": ("calibrated_choice.py", "winner_at"),
    "offer back": ("offer_back.py", "offer_back"),
    "bar search": ("consistency.py", "bar_search"),
    "refine_tls": ("consistency.py", "refine_tls"),
    "segment re-check": ("segment_recheck.py", "segment_recheck"),
    "least-squares solves": ("least_squares.py", "__call__"),
    "polish": ("consistency.py", "polish"),
    "gtsam iSAM2 updates": ("~", "<built-in method gtsam.gtsam.update>"),
    "gtsam batch optimize": ("~", "<built-in method gtsam.gtsam.optimize>"),
    "undo hypotheses": ("admission_undo.py", "test_hypotheses"),
    "nonlinear check": ("admission.py", "_unconfirmed"),
    "innovation tests": ("innovation.py", "__init__"),
    "  sparse LU": ("linsolve.py", "splu"),
}


def stage_seconds(stats: pstats.Stats) -> dict[str, tuple[int, float]]:
    """(calls, cumulative seconds) of every stage of `STAGES` in `stats`."""
    out = {}
    for name, (file, func) in STAGES.items():
        calls, cum = 0, 0.0
        for (path, _, f), (_, nc, _, ct, _) in stats.stats.items():  # type: ignore[attr-defined]
            if path.endswith(file) and f == func:
                calls, cum = calls + nc, cum + ct
        out[name] = (calls, cum)
    return out


def main() -> None:
    root = Path(__file__).resolve().parents[1]
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=root.parent / "shared" / "data" / "g2o")
    parser.add_argument("--graph", default="input_INTEL_g2o.g2o")
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--policy", default="random")
    parser.add_argument("--ratio", type=float, default=0.5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--cap", type=float, default=0.0)
    parser.add_argument("--dump", type=Path, default=None)
    parser.add_argument("--plain", default="on", choices=("on", "off"))
    args = parser.parse_args()
    graph = PoseGraph.from_g2o(read_g2o(args.data / args.graph))
    graph, reference = _prepared(graph, ["gnc"], [args.policy], args.scale, None)
    corrupted, _ = inject_false_loops(graph, args.ratio, np.random.default_rng(args.seed),
                                      args.policy, group_size=10, reference=reference)
    for _ in range(args.repeat):
        head = (f"{args.graph} x{args.scale:g} {args.policy} {100 * args.ratio:.0f}% seed "
                f"{args.seed}")
        if args.plain == "on":
            start, cpu = time.perf_counter(), time.process_time()
            solution = optimize(corrupted, "none", "gnc", init="odometry",
                                gnc_start=GNC_START)
            print(f"{head}: {time.perf_counter() - start:.2f} s "
                  f"({time.process_time() - cpu:.2f} s CPU, {solution.solver})")
        profile = cProfile.Profile()
        cpu = time.process_time()
        try:
            with cpu_cap(args.cap):
                profile.enable()
                optimize(corrupted, "none", "gnc", init="odometry", gnc_start=GNC_START)
        except CpuCapped:
            print(f"{head}: profiled run capped at {args.cap:g} s CPU")
        finally:
            profile.disable()
        print(f"{head}: profiled run {time.process_time() - cpu:.2f} s CPU")
        stats = pstats.Stats(profile)
        if args.dump is not None:
            stats.dump_stats(args.dump)
        for name, (calls, seconds) in stage_seconds(stats).items():
            print(f"  {name:22s} {calls:5d} calls {seconds:7.2f} s (profiled)")


if __name__ == "__main__":
    main()
