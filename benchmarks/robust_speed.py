"""Benchmark: CPU time of the default robust back end now against a baseline revision, cell
by cell, with the check that every cell's result is unchanged.

Run from the repository root::

    python benchmarks/robust_speed.py [--baseline REV] [--data DIR]
        [--cells input_INTEL_g2o.g2o:1:random:50:0,...] [--repeat 1]

A cell is ``graph:odometry scale:policy:percent false loops:seed``.  For every cell the
graph is scaled, its clean optimum computed once (`evaluation.robustness.clean_optimum`,
current code) and false loops injected as `eval robustness` does; then the default
robust back end (``optimize(..., "gnc", gnc_start="incremental")``, from odometry) runs
in a fresh process with the baseline revision's code (``git archive REV``) and in one
with the current code, interleaved (`--repeat` times, the order alternating).  Printed
per cell: CPU seconds of the solve (`time.process_time`, so the machine's other load
counts little) of both and their ratio; of each, the cell's verdict quantities as
``benchmarks/robustness.py`` judges them (ATE against the clean optimum [m], false loops
obeyed, true loops rejected); and between the two results the largest position
difference [m] and the number of loops whose decision differs.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CELLS = ("input_INTEL_g2o.g2o:1:random:50:0,input_INTEL_g2o.g2o:1:grouped:50:1,"
         "input_MITb_g2o.g2o:0.01:random:50:0,input_MITb_g2o.g2o:0.1:local-grouped:50:1")


def _cell_graph(data: Path, cell: str, reference_file: Path | None):
    """(graph scaled, corrupted graph, indices of the false loops, clean optimum)."""
    from data.g2o import read_g2o
    from evaluation.robustness import clean_optimum, inject_false_loops
    from slam.pose_graph import PoseGraph
    from slam.variance_components import with_information_scaled

    name, scale, policy, percent, seed = cell.split(":")
    graph = PoseGraph.from_g2o(read_g2o(data / name))
    if float(scale) != 1.0:
        graph = with_information_scaled(graph, float(scale))
    if reference_file is None:
        reference = clean_optimum(graph)
    else:
        saved = np.load(reference_file)
        reference = {int(k): p for k, p in zip(saved["keys"], saved["poses"], strict=True)}
    corrupted, false_idx = inject_false_loops(
        graph, float(percent) / 100, np.random.default_rng(int(seed)), policy,
        group_size=10, reference=reference)
    return graph, corrupted, false_idx, reference


def worker(data: Path, cell: str, reference_file: Path, out: Path) -> None:
    """Solve one cell with the code on ``sys.path`` and save the result to `out`."""
    from evaluation.robustness import aligned_position_error
    from slam.optimize import default_outlier_residual, optimize
    from slam.pose_graph import whitened_residual

    graph, corrupted, false_idx, reference = _cell_graph(data, cell, reference_file)
    start = time.process_time()
    solution = optimize(corrupted, "none", "gnc", init="odometry", gnc_start="incremental")
    seconds = time.process_time() - start
    residuals = np.array([whitened_residual(c, solution.poses, graph.dim)
                          for c in corrupted.loops])
    obeyed = residuals <= default_outlier_residual(graph.dim)
    is_false = np.zeros(len(corrupted.loops), dtype=bool)
    is_false[list(false_idx)] = True
    keys = np.array(sorted(solution.poses))
    np.savez(out, keys=keys, poses=np.array([solution.poses[k] for k in keys]),
             weights=np.asarray(solution.loop_weights), seconds=seconds,
             ate=aligned_position_error(solution.poses, reference, graph.dim),
             obeyed=int((obeyed & is_false).sum()), rejected=int((~obeyed & ~is_false).sum()))


def _positions(poses: np.ndarray) -> np.ndarray:
    return poses[:, :2] if poses.ndim == 2 else poses[:, :3, 3]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", default="HEAD")
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data" / "g2o")
    parser.add_argument("--cells", default=CELLS)
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--worker", nargs=4, metavar=("CODE", "CELL", "REFERENCE", "OUT"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        code, cell, reference, out = args.worker
        sys.path.insert(0, code)
        worker(args.data, cell, Path(reference), Path(out))
        return
    sys.path.insert(0, str(ROOT))
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp) / "baseline"
        base.mkdir()
        archive = subprocess.run(["git", "archive", args.baseline], cwd=ROOT, check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(base)], input=archive, check=True)
        for cell in args.cells.split(","):
            _, _, _, reference = _cell_graph(args.data, cell, None)
            keys = np.array(sorted(reference))
            ref_file = Path(tmp) / "reference.npz"
            np.savez(ref_file, keys=keys, poses=np.array([reference[k] for k in keys]))
            results: dict[str, list] = {"baseline": [], "now": []}
            for r in range(args.repeat):
                order = [("baseline", base), ("now", ROOT)]
                for label, code in order if r % 2 == 0 else order[::-1]:
                    out = Path(tmp) / f"{label}.npz"
                    subprocess.run([sys.executable, __file__, "--data", str(args.data),
                                    "--worker", str(code), cell, str(ref_file), str(out)],
                                   check=True, cwd=code)
                    results[label].append(dict(np.load(out)))
            old, new = results["baseline"], results["now"]
            t_old = float(np.median([x["seconds"] for x in old]))
            t_new = float(np.median([x["seconds"] for x in new]))
            a, b = old[-1], new[-1]
            moved = float(np.max(np.abs(_positions(a["poses"]) - _positions(b["poses"]))))
            decisions = int(np.sum((a["weights"] > 0.5) != (b["weights"] > 0.5)))
            print(json.dumps({
                "cell": cell, "cpu_baseline_s": round(t_old, 2), "cpu_now_s": round(t_new, 2),
                "ratio": round(t_old / t_new, 3),
                "ate_m": [float(a["ate"]), float(b["ate"])],
                "false_obeyed": [int(a["obeyed"]), int(b["obeyed"])],
                "true_rejected": [int(a["rejected"]), int(b["rejected"])],
                "max_position_difference_m": moved, "decisions_differing": decisions,
            }), flush=True)


if __name__ == "__main__":
    main()
