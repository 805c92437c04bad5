"""Nonlinear least squares on a gtsam factor graph, for every optimiser of `slam`.

`solve` is Levenberg-Marquardt with sparse Cholesky, falling back to Powell's
dogleg with QR when LM fails.  Some published graphs (Intel, MIT) carry
information entries of 1e12 next to near-zero ones; sparse Cholesky breaks down on
them and LM's damping cannot find a descent direction from a poor start, while
dogleg with QR converges.  LM is the first choice because it is about twice as fast
on well-conditioned graphs.

`StickySolver` solves a sequence of related graphs: once LM has failed on one of
them, every later call goes straight to dogleg instead of first spending LM's
iterations.  Its `lm_budget` caps LM's iterations (the rest go to dogleg): on
near-singular graphs LM does not raise but runs out all its iterations (far longer
than the dogleg solve), and a sequence of warm-started solves that converge in a few LM
iterations loses nothing by the cap.  Error units are gtsam's (``0.5 r^T I r``).
"""

from __future__ import annotations

import gtsam
from scipy.sparse import spmatrix
from scipy.sparse.linalg import SuperLU, splu

LM = "lm"
DOGLEG_QR = "dogleg-qr"


def lm_params(
    max_iterations: int, solver: str = "MULTIFRONTAL_CHOLESKY"
) -> gtsam.LevenbergMarquardtParams:
    """The project's LM settings (relative tolerance 1e-6, absolute 1e-9)."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-6)
    params.setAbsoluteErrorTol(1e-9)
    params.setlambdaInitial(1e-4)
    params.setlambdaFactor(3.0)
    params.setLinearSolverType(solver)
    return params


def dogleg_qr(
    factors: gtsam.NonlinearFactorGraph, values: gtsam.Values, max_iterations: int
) -> gtsam.DoglegOptimizer:
    """Powell's dogleg with multifrontal QR from `values` (relative tolerance 1e-6)."""
    params = gtsam.DoglegParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-6)
    params.setLinearSolverType("MULTIFRONTAL_QR")
    return gtsam.DoglegOptimizer(factors, values, params)


def solve(
    factors: gtsam.NonlinearFactorGraph, values: gtsam.Values, max_iterations: int,
    lm_budget: int | None = None,
) -> tuple[gtsam.Values, int, str]:
    """LM, then dogleg with QR if LM fails (module docstring).

    `lm_budget`: LM's iteration cap (default `max_iterations`); LM fails when it
    reaches it.  Returns the solution, the iteration count and the solver used (`LM`
    or `DOGLEG_QR`).
    """
    budget = max_iterations if lm_budget is None else min(lm_budget, max_iterations)
    start_error = factors.error(values)
    best, iterations = values, 0
    try:
        lm = gtsam.LevenbergMarquardtOptimizer(factors, values, lm_params(budget))
        result = lm.optimize()
        iterations = lm.iterations()
        if factors.error(result) < start_error:
            best = result
        if 0 < iterations < budget:
            return result, iterations, LM
    except RuntimeError:  # gtsam IndeterminateLinearSystemException
        pass
    dogleg = dogleg_qr(factors, best, max_iterations)
    return dogleg.optimize(), iterations + dogleg.iterations(), DOGLEG_QR


def conditioning(factors: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> str:
    """`LM` if sparse Cholesky can factor the graph at `values`, else `DOGLEG_QR`."""
    try:
        gtsam.LevenbergMarquardtOptimizer(factors, values, lm_params(1)).optimize()
    except RuntimeError:
        return DOGLEG_QR
    return LM


class StickySolver:
    """`solve` for a sequence of related graphs; dogleg for good once LM has failed.

    With ``sticky=False`` only an LM that raises (sparse Cholesky breaks down: the graph
    needs QR) switches to dogleg for good; an LM that merely runs out of `lm_budget`
    iterations hands that one solve to dogleg.  Set `dogleg` to start with dogleg.
    """

    def __init__(
        self, max_iterations: int = 100, lm_budget: int | None = None, sticky: bool = True
    ) -> None:
        self.max_iterations = max_iterations
        self.lm_budget = lm_budget
        self.sticky = sticky
        self.dogleg = False

    def __call__(self, factors: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
        """The solution of `factors` from `values`."""
        if self.dogleg:
            return dogleg_qr(factors, values, self.max_iterations).optimize()
        if self.sticky:
            result, _, used = solve(factors, values, self.max_iterations, self.lm_budget)
            self.dogleg = used == DOGLEG_QR
            return result
        budget = self.max_iterations if self.lm_budget is None else self.lm_budget
        try:
            lm = gtsam.LevenbergMarquardtOptimizer(factors, values, lm_params(budget))
            result = lm.optimize()
        except RuntimeError:  # gtsam IndeterminateLinearSystemException
            self.dogleg = True
            return dogleg_qr(factors, values, self.max_iterations).optimize()
        if 0 < lm.iterations() < budget:
            return result
        start = result if factors.error(result) < factors.error(values) else values
        return dogleg_qr(factors, start, self.max_iterations).optimize()


def factor_information(jacobian: spmatrix) -> SuperLU:
    """Sparse LU of the information matrix ``H = J^T J`` of a whitened Jacobian ``J``.

    ``H`` is symmetric positive definite (a graph whose gauge is fixed), so the LU
    needs no pivoting (Gaussian elimination is stable on such matrices) and keeps
    the symmetric minimum-degree ordering of ``H``: SuperLU's symmetric mode with
    ``diag_pivot_thresh = 0``.  On pose graphs that leaves far less fill than the
    default partial pivoting, so factorisations and solves are several times faster,
    with the same solution to rounding.
    """
    h = (jacobian.T @ jacobian).tocsc()
    return splu(h, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                options={"SymmetricMode": True})
