"""Robustness of loop-closure kernels to false loop closures.

Protocol (one run per outlier ratio p and kernel):

1. The clean optimum: the graph as given, optimised without a kernel from the
   LAGO initialisation (2D) or the given vertices (3D).  It is the reference.
2. False loops are injected so that they make up a fraction p of all loop edges:
   ``n_false = round(n_true * p / (1 - p))``, by one of the policies of
   `evaluation.outlier_policies` (random, local, grouped, local-grouped); each carries
   the information of a randomly drawn *true* loop edge (as plausible as a real one)
   and none is obeyed by the clean optimum (a copied measurement that happens to be
   right is no false loop).
3. The corrupted graph is optimised with the kernel from the odometry
   initialisation (what a mapper has when the loops arrive).  The M-estimators
   (``huber``, ``cauchy``, ``dcs``, ``gemanmcclure``; ``none`` is plain least squares)
   act on loop factors under Levenberg-Marquardt.  ``gnc`` is the truncated-least-
   squares loss of GNC (Yang et al. 2020) with odometry as known inliers, solved by
   time-ordered admission (`slam.consistency`, ``optimize(..., method="gnc",
   gnc_start="incremental")``): graduated non-convexity itself folds M3500 once half
   its loops are false, from any start.
4. Reported: ATE of the result against the clean optimum (positions of all poses,
   after rigid alignment) [m], the count of false loops the result still *obeys*
   (whitened residual below the chi-square 99% threshold of the loop's dof), the
   count of true loops it rejects, and the wall time.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from evaluation.outlier_policies import POLICIES, inject_false_loops
from evaluation.trajectory_error import umeyama
from slam.optimize import default_outlier_residual, optimize
from slam.pose_graph import PoseGraph, whitened_residual
from slam.variance_components import with_information_scaled

Array = NDArray[np.float64]
ROBUSTNESS_KERNELS = ("none", "huber", "cauchy", "dcs", "gemanmcclure", "gnc")
GNC_START = "incremental"  # `optimize`'s gnc_start for the ``gnc`` kernel
__all__ = ["RobustnessResult", "aligned_position_error", "clean_optimum", "inject_false_loops",
           "run_robustness"]


@dataclass(slots=True)
class RobustnessResult:
    """One (policy, kernel, outlier ratio) run; `odometry_scale` multiplied the odometry
    information of the graph before anything else (1.0: as given)."""

    kernel: str
    outlier_ratio: float
    false_loops: int
    true_loops: int
    ate_vs_clean_m: float
    false_factors_obeyed: int
    true_factors_rejected: int
    seconds: float
    policy: str = "random"
    seed: int = 0
    odometry_scale: float = 1.0

    def to_json(self) -> dict[str, float | int | str]:
        return {
            "policy": self.policy,
            "seed": self.seed,
            "odometry_scale": self.odometry_scale,
            "kernel": self.kernel,
            "outlier_ratio": self.outlier_ratio,
            "false_loops": self.false_loops,
            "true_loops": self.true_loops,
            "ate_vs_clean_m": self.ate_vs_clean_m,
            "false_factors_obeyed": self.false_factors_obeyed,
            "true_factors_rejected": self.true_factors_rejected,
            "seconds": self.seconds,
        }


def aligned_position_error(poses: dict[int, Array], reference: dict[int, Array], dim: int) -> float:
    """RMSE [m] of positions after rigid (Umeyama) alignment of `poses` onto `reference`."""
    keys = sorted(reference)
    if dim == 2:
        p = np.array([poses[k][:2] for k in keys])
        q = np.array([reference[k][:2] for k in keys])
    else:
        p = np.array([poses[k][:3, 3] for k in keys])
        q = np.array([reference[k][:3, 3] for k in keys])
    rot, t, _ = umeyama(p, q)
    return float(np.sqrt(np.mean(np.sum((q - (p @ rot.T + t)) ** 2, axis=1))))


def clean_optimum(graph: PoseGraph) -> dict[int, Array]:
    """The outlier-free reference solution (no kernel; LAGO start in 2D, or the odometry
    chain where LAGO's linear system is indeterminate, as with very loose odometry)."""
    if graph.dim == 2:
        try:
            return optimize(graph, "none", init="lago").poses
        except RuntimeError:  # gtsam IndeterminateLinearSystemException inside LAGO
            return optimize(graph, "none", init="odometry").poses
    return optimize(graph, "none", init="given").poses


def run_robustness(
    graph: PoseGraph,
    ratios: Sequence[float],
    kernels: Sequence[str],
    *,
    seed: int = 0,
    policies: Sequence[str] = ("random",),
    group_size: int = 10,
    odometry_scale: float = 1.0,
    progress: Callable[[str], None] | None = None,
) -> list[RobustnessResult]:
    """The benchmark of the module docstring, every policy x ratio x kernel.

    `policies`: `evaluation.outlier_policies` names; `group_size`: false loops per group
    of the grouped policies; `odometry_scale`: factor on every odometry information
    matrix (looser odometry below 1), applied before the clean optimum is computed.
    """
    for k in kernels:
        if k not in ROBUSTNESS_KERNELS:
            raise UserError(f"unknown kernel {k!r}; choose from {', '.join(ROBUSTNESS_KERNELS)}")
    for p in policies:
        if p not in POLICIES:
            raise UserError(f"policy: unknown {p!r}; choose from {', '.join(POLICIES)}")
    if not odometry_scale > 0:
        raise UserError(f"odometry_scale must be positive, got {odometry_scale}")
    if odometry_scale != 1.0:
        graph = with_information_scaled(graph, odometry_scale)
    reference = clean_optimum(graph)
    threshold = default_outlier_residual(graph.dim)
    results = []
    for policy, ratio in ((p, r) for p in policies for r in ratios):
        corrupted, false_idx = inject_false_loops(
            graph, ratio, np.random.default_rng(seed), policy, group_size=group_size,
            reference=reference,
        )
        false_set = set(false_idx)
        for kernel in kernels:
            if progress:
                progress(f"{kernel}, {policy} at {100 * ratio:.0f}% false loops")
            start = time.perf_counter()
            if kernel == "gnc":
                solution = optimize(corrupted, "none", "gnc", init="odometry", gnc_start=GNC_START)
            else:
                solution = optimize(corrupted, kernel, "lm", init="odometry")
            seconds = time.perf_counter() - start
            residuals = np.array(
                [whitened_residual(c, solution.poses, graph.dim) for c in corrupted.loops]
            )
            obeyed = residuals <= threshold
            is_false = np.array([n in false_set for n in range(len(corrupted.loops))], dtype=bool)
            results.append(
                RobustnessResult(
                    kernel=kernel,
                    outlier_ratio=float(ratio),
                    false_loops=len(false_idx),
                    true_loops=len(graph.loops),
                    ate_vs_clean_m=aligned_position_error(solution.poses, reference, graph.dim),
                    false_factors_obeyed=int((obeyed & is_false).sum()),
                    true_factors_rejected=int((~obeyed & ~is_false).sum()),
                    seconds=seconds,
                    policy=policy,
                    seed=seed,
                    odometry_scale=odometry_scale,
                )
            )
    return results
