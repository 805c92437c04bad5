"""The outcome of a batch solve (`slam.optimize.optimize`) and its loop classification.

A loop constraint is reported as an outlier when GNC gives it a weight below 0.5, or
(other methods) when its whitened residual under the solution exceeds
`default_outlier_residual` (sqrt of the chi-square 99% quantile: 3.37 for 3 degrees of
freedom, 4.20 for 6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slam.pose_graph import chi2_quantile, pose_dof

__all__ = ["OptimizationResult", "default_outlier_residual"]

Array = NDArray[np.float64]


def default_outlier_residual(dim: int, probability: float = 0.99) -> float:
    """Whitened-residual threshold of a loop factor: sqrt(chi2 quantile) for its dof."""
    return float(np.sqrt(chi2_quantile(probability, pose_dof(dim))))


@dataclass(slots=True)
class OptimizationResult:
    """Outcome of a batch solve.

    Attributes:
        poses: id -> optimised pose ((3,) planar or 4x4).
        initial_error, final_error: gtsam graph error (0.5 * sum of squared whitened
            residuals, robust-weighted) before and after.
        iterations: optimiser iterations (GNC: those of its least-squares warm start).
        seconds: wall time of the solve.
        loop_residuals: whitened residual of every loop constraint under `poses`.
        loop_outliers: indices into `graph.loops` classified as outliers.
        loop_weights: GNC weights per loop (1 inlier, 0 outlier); None for LM.
        solver: "lm", "dogleg-qr" (LM fallback, see `slam.least_squares`), "gnc-tls-warm",
            "tls-incremental-<gate>" (``gnc_start="incremental"``; "...-segments" when
            the segment re-check removed loops), "least-squares-clean" (the incremental
            admission's fast path: the plain optimum was its decision) or "gnc-tls" (gtsam).
    """

    poses: dict[int, Array]
    initial_error: float
    final_error: float
    iterations: int
    seconds: float
    loop_residuals: Array
    loop_outliers: list[int]
    loop_weights: Array | None = None
    solver: str = "lm"
