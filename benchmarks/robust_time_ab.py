"""Benchmark: the default robust back end's time with and without its time savings, on
one corrupted pose graph, in one process (old and new alternately, so the ratio is
measured under the same load).

Run from the repository root::

    python benchmarks/robust_time_ab.py input_M3500_g2o.g2o [--data DIR] [--scale 1]
        [--policy random] [--ratio 50] [--seed 0] [--repeat 1] [--cache DIR]
        [--compare screen|memo]

``--compare screen``: ``old`` is `slam.optimize.optimize` (``gnc``, incremental, from
the odometry chain) with ``screen=False`` (the fast path's check solved in full); ``new``:
``screen=True`` (`slam.fast_path_screen`; off by default).  ``--compare memo``: ``old``
with no solution remembered by the least-squares solvers
(``slam.least_squares.MEMO_ENTRIES = 0``), ``new`` with the default. Prints for each the
CPU seconds of this process, the ATE against the outlier-free optimum [m], false loops
obeyed and true loops rejected (as `benchmarks/robust_modes.py`), then whether both kept
the same loops, the largest position difference between the two results [m] and the CPU
ratio new / old.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import slam.least_squares as least_squares
from benchmarks.robust_cell import cell_parser, read_cell
from evaluation.robustness import aligned_position_error
from slam.optimize import default_outlier_residual, optimize
from slam.pose_graph import whitened_residual

COMPARISONS = {
    "screen": {"old": {"screen": False, "memo": least_squares.MEMO_ENTRIES},
               "new": {"screen": True, "memo": least_squares.MEMO_ENTRIES}},
    "memo": {"old": {"screen": False, "memo": 0},
             "new": {"screen": False, "memo": least_squares.MEMO_ENTRIES}},
}


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--compare", choices=sorted(COMPARISONS), default="screen")
    args = parser.parse_args()
    variants = COMPARISONS[args.compare]
    graph, reference, corrupted, is_false = read_cell(args)
    threshold = default_outlier_residual(graph.dim)
    cpu: dict[str, list[float]] = {name: [] for name in variants}
    results = {}
    for _ in range(args.repeat):
        for name, setting in variants.items():
            least_squares.MEMO_ENTRIES = setting["memo"]
            start = time.process_time()
            result = optimize(corrupted, "none", "gnc", init="odometry",
                              gnc_start="incremental", screen=setting["screen"])
            cpu[name].append(time.process_time() - start)
            results[name] = result
            residuals = np.array([whitened_residual(c, result.poses, graph.dim)
                                  for c in corrupted.loops])
            obeyed = residuals <= threshold
            print(f"{args.graph} x{args.scale:g} {args.policy} {args.ratio:g}% seed "
                  f"{args.seed} {name}: ATE "
                  f"{aligned_position_error(result.poses, reference, graph.dim):.3g} m, "
                  f"{int((obeyed & is_false).sum())} false obeyed, "
                  f"{int((~obeyed & ~is_false).sum())} true rejected, "
                  f"{cpu[name][-1]:.1f} s CPU ({result.solver})", flush=True)
    old, new = results["old"], results["new"]
    same = old.loop_outliers == new.loop_outliers
    diff = max(float(np.linalg.norm(old.poses[k][:2] - new.poses[k][:2])) for k in old.poses)
    ratio = np.median(cpu["new"]) / np.median(cpu["old"])
    print(f"same loops kept: {same}; largest position difference {diff:.3g} m; "
          f"CPU new/old {ratio:.2f} ({np.median(cpu['old']):.1f} -> "
          f"{np.median(cpu['new']):.1f} s)", flush=True)


if __name__ == "__main__":
    main()
