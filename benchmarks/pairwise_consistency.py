"""Benchmark: what pairwise consistency (PCM) can decide about false loops on the shared graphs.

Run from the repository root::

    python benchmarks/pairwise_consistency.py [--data DIR] [--graphs a.g2o,b.g2o]
        [--scales 1,0.1,0.01] [--policies random,local,grouped,local-grouped]
        [--ratios 0,10,50] [--seeds 2] [--probability 0.99]

For every graph, odometry information scaling, policy, ratio and seed, false loops are
injected as `eval robustness` does (`evaluation.outlier_policies.inject_false_loops`
against the clean optimum), the pairwise consistency matrix of all loops is computed
(`slam.pairwise_consistency.consistency_matrix`, cycle Mahalanobis distance through the
odometry chain under the chi-square gate of `--probability`, 3 dof) and its maximum
clique taken (`max_clique`).  Printed per case: the fraction of true-true and
false-true loop pairs that pass the gate, how many false loops the clique keeps and how
many true loops it leaves out, and the CPU seconds of the matrix and of the clique.

Used as a gate of the robust back end (loops outside the clique not admitted), a case
needs ``false in`` 0 and ``true out`` small; a true-true rate below the gate's
probability means the first-order cycle covariances do not describe the graph.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from data.g2o import read_g2o
from evaluation.outlier_policies import POLICIES, inject_false_loops
from evaluation.robustness import clean_optimum
from slam.pairwise_consistency import consistency_matrix, max_clique
from slam.pose_graph import PoseGraph
from slam.variance_components import with_information_scaled

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data" / "g2o")
    parser.add_argument("--graphs", default="input_INTEL_g2o.g2o,input_MITb_g2o.g2o")
    parser.add_argument("--scales", default="1,0.1,0.01")
    parser.add_argument("--policies", default=",".join(POLICIES))
    parser.add_argument("--ratios", default="0,10,50", help="percent")
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--probability", type=float, default=0.99)
    args = parser.parse_args()
    ratios = [float(r) / 100 for r in args.ratios.split(",")]
    for name in args.graphs.split(","):
        given = PoseGraph.from_g2o(read_g2o(args.data / name))
        for scale in (float(s) for s in args.scales.split(",")):
            graph = given if scale == 1.0 else with_information_scaled(given, scale)
            reference = clean_optimum(graph)
            for policy in args.policies.split(","):
                for ratio in ratios:
                    for seed in range(args.seeds if ratio > 0 else 1):
                        corrupted, false_idx = inject_false_loops(
                            graph, ratio, np.random.default_rng(seed), policy,
                            group_size=10, reference=reference)
                        is_false = np.zeros(len(corrupted.loops), dtype=bool)
                        is_false[false_idx] = True
                        start = time.process_time()
                        adj = consistency_matrix(corrupted, args.probability)
                        t_matrix = time.process_time() - start
                        clique = max_clique(adj)
                        t_clique = time.process_time() - start - t_matrix
                        kept = np.zeros(len(is_false), dtype=bool)
                        kept[clique] = True
                        true_pairs = adj[np.ix_(~is_false, ~is_false)]
                        off = ~np.eye(len(true_pairs), dtype=bool)
                        tt = true_pairs[off].mean() if off.any() else float("nan")
                        ft = (adj[np.ix_(is_false, ~is_false)].mean() if is_false.any()
                              else float("nan"))
                        print(f"{name:22} x{scale:<5g} {policy:14} {100 * ratio:3.0f}% seed {seed}"
                              f"  pairs consistent: true-true {tt:.3f} false-true {ft:.3f}"
                              f"  clique {len(clique)}: false in {int((kept & is_false).sum())}"
                              f"/{int(is_false.sum())}, true out {int((~kept & ~is_false).sum())}"
                              f"/{int((~is_false).sum())}  cpu {t_matrix:.2f} + {t_clique:.2f} s",
                              flush=True)


if __name__ == "__main__":
    main()
