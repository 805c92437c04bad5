"""Benchmark: the default robust back end's time with and without its time savings, on
one corrupted pose graph, in one process (old and new alternately, so the ratio is
measured under the same load).

Run from the repository root::

    python benchmarks/robust_time_ab.py input_M3500_g2o.g2o [--data DIR] [--scale 1]
        [--policy random] [--ratio 50] [--seed 0] [--repeat 1] [--cache DIR]
        [--compare screen|memo|stiff|undo-isam]

``--compare screen``: ``old`` is `slam.optimize.optimize` (``gnc``, incremental, from
the odometry chain) with ``screen=False`` (the fast path's check solved in full); ``new``:
``screen=True`` (`slam.fast_path_screen`; off by default).  ``--compare memo``: ``old``
with no solution remembered by the least-squares solvers
(``slam.least_squares.MEMO_ENTRIES = 0``), ``new`` with the default. ``--compare stiff``:
``old`` the default, ``new`` with ``slam.least_squares.STIFF_CHOLESKY = True`` (dogleg by
Cholesky, stiff factors' poses first). ``--compare undo-isam``: ``old`` with the undo
hypotheses batch-solved, ``new`` with ``slam.admission_undo.BY_ISAM = True`` (solved on a
copy of the pass's iSAM2 prefix; the default). Prints for each the
CPU seconds of this process, the memo's hits among the solvers' calls, the ATE against the
outlier-free optimum [m], false loops obeyed and true loops rejected (as
`benchmarks/robust_modes.py`), then whether both kept the same loops, the largest position
difference between the two results [m], the ATEs' difference [m] and the CPU ratio new /
old.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import slam.admission_undo as admission_undo
import slam.least_squares as least_squares
from benchmarks.robust_cell import cell_parser, read_cell
from evaluation.robustness import aligned_position_error
from slam.optimize import default_outlier_residual, optimize
from slam.pose_graph import whitened_residual

MEMO = least_squares.MEMO_ENTRIES
COMPARISONS = {
    "screen": {"old": {"screen": False, "memo": MEMO, "stiff": False},
               "new": {"screen": True, "memo": MEMO, "stiff": False}},
    "memo": {"old": {"screen": False, "memo": 0, "stiff": False},
             "new": {"screen": False, "memo": MEMO, "stiff": False}},
    "stiff": {"old": {"screen": False, "memo": MEMO, "stiff": False},
              "new": {"screen": False, "memo": MEMO, "stiff": True}},
    "undo-isam": {"old": {"screen": False, "memo": MEMO, "stiff": False, "undo_isam": False},
                  "new": {"screen": False, "memo": MEMO, "stiff": False, "undo_isam": True}},
}


LOOKUPS = {"hits": 0, "lookups": 0}  # of every solver's memo in the run under way
_get = least_squares.SolveMemo.get


def _counted_get(self, key, factors, values):  # type: ignore[no-untyped-def]
    found = _get(self, key, factors, values)
    LOOKUPS["lookups"] += 1
    LOOKUPS["hits"] += found is not None
    return found


least_squares.SolveMemo.get = _counted_get  # type: ignore[method-assign]


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--compare", choices=sorted(COMPARISONS), default="screen")
    args = parser.parse_args()
    variants = COMPARISONS[args.compare]
    graph, reference, corrupted, is_false = read_cell(args)
    threshold = default_outlier_residual(graph.dim)
    cpu: dict[str, list[float]] = {name: [] for name in variants}
    results, ates = {}, {}
    for _ in range(args.repeat):
        for name, setting in variants.items():
            least_squares.MEMO_ENTRIES = setting["memo"]
            least_squares.STIFF_CHOLESKY = setting["stiff"]
            admission_undo.BY_ISAM = setting.get("undo_isam", admission_undo.BY_ISAM)
            LOOKUPS.update(hits=0, lookups=0)
            start = time.process_time()
            result = optimize(corrupted, "none", "gnc", init="odometry",
                              gnc_start="incremental", screen=setting["screen"])
            cpu[name].append(time.process_time() - start)
            results[name] = result
            residuals = np.array([whitened_residual(c, result.poses, graph.dim)
                                  for c in corrupted.loops])
            obeyed = residuals <= threshold
            ates[name] = aligned_position_error(result.poses, reference, graph.dim)
            print(f"{args.graph} x{args.scale:g} {args.policy} {args.ratio:g}% seed "
                  f"{args.seed} {name}: ATE {ates[name]:.3g} m, "
                  f"{int((obeyed & is_false).sum())} false obeyed, "
                  f"{int((~obeyed & ~is_false).sum())} true rejected, "
                  f"{cpu[name][-1]:.1f} s CPU ({result.solver}; memo hits "
                  f"{LOOKUPS['hits']} of {LOOKUPS['lookups']} solves)", flush=True)
    old, new = results["old"], results["new"]
    same = old.loop_outliers == new.loop_outliers
    diff = max(float(np.linalg.norm(old.poses[k][:2] - new.poses[k][:2])) for k in old.poses)
    ratio = np.median(cpu["new"]) / np.median(cpu["old"])
    print(f"same loops kept: {same}; largest position difference {diff:.3g} m; ATE "
          f"difference {abs(ates['new'] - ates['old']):.3g} m; "
          f"CPU new/old {ratio:.2f} ({np.median(cpu['old']):.1f} -> "
          f"{np.median(cpu['new']):.1f} s)", flush=True)


if __name__ == "__main__":
    main()
