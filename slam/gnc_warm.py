"""GNC with the TLS loss (Yang et al. 2020), each step warm-started from the last solution.

`slam.optimize.optimize`'s ``method="gnc"`` with ``gnc_start`` ``"given"`` or
``"least-squares"``.
"""

from __future__ import annotations

import gtsam
import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from slam.consistency import tls_threshold
from slam.least_squares import conditioning, lm_params, solve
from slam.pose_graph import Constraint, PoseGraph, RobustKernel

__all__ = ["WARM_STARTS", "gnc_warm"]

Array = NDArray[np.float64]
WARM_STARTS = ("given", "least-squares")


def _gnc_tls_weights(error: Array, barc: Array, mu: float) -> Array:
    """TLS weights of Yang et al. (2020), Eq. (14), in gtsam's error units (0.5 r^2)."""
    lower = mu / (mu + 1.0) * barc
    upper = (mu + 1.0) / mu * barc
    mid = np.sqrt(barc * mu * (mu + 1.0) / np.maximum(error, 1e-300)) - mu
    return np.where(error <= lower, 1.0, np.where(error >= upper, 0.0, np.clip(mid, 0.0, 1.0)))


def gnc_warm(
    graph: PoseGraph,
    values: gtsam.Values,
    *,
    probability: float = 0.99,
    mu_step: float = 1.4,
    max_outer: int = 100,
    inner_iterations: int = 10,
    weights_tol: float = 1e-4,
    start: str = "given",
) -> tuple[gtsam.Values, Array, int]:
    """GNC with the TLS loss whose every step starts from the previous solution.

    The algorithm of gtsam's GncOptimizer (Yang, Antonante, Tzoumas & Carlone 2020:
    mu initialised by their Remark 5, TLS weights by their Eq. (14), mu grown by
    `mu_step` until the weights are binary), with one difference: gtsam restarts
    every weighted least-squares step from the *initial* values, which on a
    corrupted graph costs a full solve per step; here each step continues from
    the last solution with at most `inner_iterations` LM iterations.  Odometry and
    priors are known inliers.  Returns (solution, loop weights, outer iterations).

    `start`: ``"least-squares"`` begins, as the paper does, from the plain
    least-squares solution over every loop; ``"given"`` begins from `values`
    (typically the odometry chain).  With plausible-looking false loops the
    least-squares solution is a crumpled map in which true and false loops are
    equally inconsistent, while from odometry the surrogate's first, nearly
    convex steps (every loop weighted almost 0) stay near odometry and admit the
    loops consistent with it first.  (Graduation from any start can fold M3500
    with half its loops false, because at small ``mu`` the surrogate is close to L1
    and every false loop pulls as hard as a true one: `optimize`'s
    ``gnc_start="incremental"`` uses `slam.consistency.incremental_tls` instead.)
    """
    if start not in WARM_STARTS:
        raise UserError(f"unknown GNC start {start!r}; choose one of {', '.join(WARM_STARTS)}")
    barc = tls_threshold(graph.dim, probability)
    base, _ = graph.factor_graph(RobustKernel("none"))
    n_fixed = base.size() - len(graph.loops)
    loop_factors = [base.at(n_fixed + k) for k in range(len(graph.loops))]

    def weighted_graph(w: Array) -> gtsam.NonlinearFactorGraph:
        g = gtsam.NonlinearFactorGraph()
        for k in range(n_fixed):
            g.add(base.at(k))
        for k, c in enumerate(graph.loops):
            if w[k] > 1e-8:
                g.add(graph.between_factor(
                    Constraint(c.i, c.j, c.measurement, w[k] * c.information)))
        return g

    def loop_errors(v: gtsam.Values) -> Array:
        return np.array([f.error(v) for f in loop_factors])

    weights = np.ones(len(graph.loops))
    if start == "least-squares":
        result, _, used = solve(base, values, 100)
    else:
        result, used = values, conditioning(base, values)
    # Graphs that needed the QR fallback break a Cholesky LM as well.
    linear = "MULTIFRONTAL_QR" if used == "dogleg-qr" else "MULTIFRONTAL_CHOLESKY"

    def refine(w: Array, start: gtsam.Values, iterations: int) -> gtsam.Values:
        g = weighted_graph(w)
        try:
            return gtsam.LevenbergMarquardtOptimizer(
                g, start, lm_params(iterations, linear)).optimize()
        except RuntimeError:  # indeterminate system: retry with QR
            return gtsam.LevenbergMarquardtOptimizer(
                g, start, lm_params(iterations, "MULTIFRONTAL_QR")).optimize()

    errors = loop_errors(result)
    excess = 2.0 * errors - barc
    if len(errors) == 0 or np.all(excess <= 0):
        return result, weights, 0
    mu = max(float(np.min(barc / excess[excess > 0])), 1e-6)
    outer = 0
    for outer in range(1, max_outer + 1):  # noqa: B007 - the count is returned
        new_weights = _gnc_tls_weights(errors, barc, mu)
        result = refine(new_weights, result, inner_iterations)
        errors = loop_errors(result)
        # Binary weights only mean convergence once the surrogate is close to TLS: at
        # small mu every weight of a large residual is ~0 without being decided.
        binary = np.all(np.abs(new_weights - np.round(new_weights)) < weights_tol)
        weights = new_weights
        if binary and mu >= 1.0:
            break
        mu *= mu_step
    weights = np.round(_gnc_tls_weights(errors, barc, mu))
    return refine(weights, result, 100), weights, outer
