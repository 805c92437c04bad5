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

`StickySolver` also remembers its last `MEMO_ENTRIES` solutions (`SolveMemo`): the
robust back end re-solves the same graph from the same start more than once (a pass
resumed from a snapshot repeats its blocks' solves; a hypothesis re-solves the accepted
prefix that the one before it solved), and a repeated solve returns the stored solution
instead of iterating again: the same values the solve would give, since the solver is
deterministic and its path (LM first or dogleg) is part of the key.

Where Cholesky breaks down, it is one stiff factor that breaks it: a factor whose
information matrix is nearly singular (a condition number beyond ``1/sqrt(eps)``) makes
the elimination lose its soft directions when its poses are eliminated after their
neighbours.  `dogleg_stiff_first` eliminates those poses first and factorises by
Cholesky; `StickySolver` uses it for its dogleg solves with ``stiff_cholesky``
(`STIFF_CHOLESKY`, off: its solutions agree with QR's only to the solver's tolerance).
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from collections.abc import Callable

import gtsam
import numpy as np
from scipy.sparse import spmatrix
from scipy.sparse.linalg import SuperLU, splu

LM = "lm"
DOGLEG_QR = "dogleg-qr"
MEMO_ENTRIES = 16  # solutions a `StickySolver` remembers (0: none)
STIFF_CHOLESKY = False  # `StickySolver`'s dogleg by Cholesky, stiff factors first (option)
# Information condition number above which a factor is stiff: the normal equations
# square the Jacobian's condition, so beyond 1/sqrt(eps) they keep under half the digits.
STIFF_CONDITION = 1.0 / float(np.sqrt(np.finfo(float).eps))


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
    factors: gtsam.NonlinearFactorGraph, values: gtsam.Values, max_iterations: int,
    watch: Callable[[gtsam.DoglegOptimizer, int, float, float], None] | None = None,
) -> gtsam.DoglegOptimizer:
    """Powell's dogleg with multifrontal QR from `values` (relative tolerance 1e-6).

    `watch(optimizer, iteration, error_before, error_after)`: called after each
    iteration with the running optimiser (gtsam's ``iterationHook``; it only reads, so
    the iterations are the same with or without it); an exception it raises, other than
    RuntimeError, ends the solve and propagates out of ``optimize``."""
    params = gtsam.DoglegParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-6)
    params.setLinearSolverType("MULTIFRONTAL_QR")
    running: list[gtsam.DoglegOptimizer] = []
    if watch is not None:
        params.iterationHook = lambda i, before, after: watch(running[0], i, before, after)
    optimizer = gtsam.DoglegOptimizer(factors, values, params)
    running.append(optimizer)
    return optimizer


def stiff_keys(factors: gtsam.NonlinearFactorGraph) -> list[int]:
    """The poses of every factor of `factors` with a Gaussian noise model whose
    information ``R^T R`` has a condition number above `STIFF_CONDITION` (sorted)."""
    keys: set[int] = set()
    for n in range(factors.size()):
        factor = factors.at(n)
        try:
            r = factor.noiseModel().R()
        except (AttributeError, RuntimeError, TypeError):  # not a Gaussian noise model
            continue
        s = np.linalg.svd(r, compute_uv=False)
        if s[-1] <= 0.0 or (s[0] / s[-1]) ** 2 > STIFF_CONDITION:
            keys.update(int(k) for k in factor.keys())
    return sorted(keys)


def dogleg_stiff_first(
    factors: gtsam.NonlinearFactorGraph, values: gtsam.Values, max_iterations: int,
    first: list[int],
) -> gtsam.Values:
    """Powell's dogleg by multifrontal Cholesky from `values`, the poses `first`
    eliminated before all others (COLAMD for the rest), else as `dogleg_qr`; QR when
    Cholesky still breaks down.

    Why: sparse Cholesky breaks down (a negative pivot) where a stiff factor's poses are
    eliminated late, after the elimination has mixed its stiff direction with the soft
    ones of the rest of the graph; eliminated first, its stiff block is factorised on its
    own and the Schur complement passed on is no worse conditioned than its neighbours'.
    """
    present = set(int(k) for k in factors.keyVector())
    first = [k for k in first if k in present]
    if not first:
        return dogleg_qr(factors, values, max_iterations).optimize()
    params = gtsam.DoglegParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-6)
    params.setLinearSolverType("MULTIFRONTAL_CHOLESKY")
    params.setOrdering(gtsam.Ordering.ColamdConstrainedFirstNonlinearFactorGraph(factors, first))
    try:
        return gtsam.DoglegOptimizer(factors, values, params).optimize()
    except RuntimeError:  # gtsam IndeterminateLinearSystemException
        return dogleg_qr(factors, values, max_iterations).optimize()


def solve(
    factors: gtsam.NonlinearFactorGraph, values: gtsam.Values, max_iterations: int,
    lm_budget: int | None = None,
    watch: Callable[[gtsam.LevenbergMarquardtOptimizer, int, float, float], None]
    | None = None,
    dogleg_watch: Callable[[gtsam.DoglegOptimizer, int, float, float], None] | None = None,
) -> tuple[gtsam.Values, int, str]:
    """LM, then dogleg with QR if LM fails (module docstring).

    `lm_budget`: LM's iteration cap (default `max_iterations`); LM fails when it
    reaches it.  Returns the solution, the iteration count and the solver used (`LM`
    or `DOGLEG_QR`).  `watch(lm, iteration, error_before, error_after)`: called after
    each LM iteration with the running optimiser (gtsam's ``iterationHook``); an
    exception it raises, other than RuntimeError, ends the solve and propagates.
    `dogleg_watch`: the same after each dogleg iteration (`dogleg_qr`'s `watch`).
    """
    budget = max_iterations if lm_budget is None else min(lm_budget, max_iterations)
    params = lm_params(budget)
    running: list[gtsam.LevenbergMarquardtOptimizer] = []
    if watch is not None:
        params.iterationHook = lambda i, before, after: watch(running[0], i, before, after)
    start_error = factors.error(values)
    best, iterations = values, 0
    try:
        lm = gtsam.LevenbergMarquardtOptimizer(factors, values, params)
        running.append(lm)
        result = lm.optimize()
        iterations = lm.iterations()
        if factors.error(result) < start_error:
            best = result
        if 0 < iterations < budget:
            return result, iterations, LM
    except RuntimeError:  # gtsam IndeterminateLinearSystemException
        pass
    dogleg = dogleg_qr(factors, best, max_iterations, dogleg_watch)
    return dogleg.optimize(), iterations + dogleg.iterations(), DOGLEG_QR


def conditioning(factors: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> str:
    """`LM` if sparse Cholesky can factor the graph at `values`, else `DOGLEG_QR`."""
    try:
        gtsam.LevenbergMarquardtOptimizer(factors, values, lm_params(1)).optimize()
    except RuntimeError:
        return DOGLEG_QR
    return LM


def _values_digest(values: gtsam.Values) -> bytes:
    """A digest of the keys and poses of `values` (Pose2 and Pose3 entries, bit for bit)."""
    h = hashlib.blake2b(digest_size=16)
    h.update(np.asarray(values.keys(), dtype=np.uint64).tobytes())
    h.update(np.ascontiguousarray(gtsam.utilities.extractPose2(values)).tobytes())
    h.update(np.ascontiguousarray(gtsam.utilities.extractPose3(values)).tobytes())
    return h.digest()


def same_factors(a: gtsam.NonlinearFactorGraph, b: gtsam.NonlinearFactorGraph) -> bool:
    """True when `a` and `b` hold equal factors in the same order (gtsam ``equals`` at
    tolerance 0: the same keys, measurement and noise model, bit for bit)."""
    return a.size() == b.size() and all(
        a.at(n).equals(b.at(n), 0.0) for n in range(a.size()))


class SolveMemo:
    """The last `entries` solutions of a solver, looked up by (graph, start, path).

    The lookup key is cheap (the solver path, the graph's size and a digest of the
    start's poses); a hit is confirmed by comparing the stored graph with the new one
    factor by factor (`same_factors`) and the stored start with the new one (gtsam
    ``equals`` at tolerance 0), so a solution is returned only for the same graph from
    the same start.  Each entry carries the solver's state after the solve (whether
    it went on to dogleg for good).  Stored and returned values are copies (callers may
    change theirs).  `hits` and `misses` count lookups.
    """

    def __init__(self, entries: int) -> None:
        self.entries = entries
        self._store: OrderedDict[
            tuple, tuple[gtsam.NonlinearFactorGraph, gtsam.Values, gtsam.Values, bool]
        ] = OrderedDict()
        self.hits = 0
        self.misses = 0

    def key(self, factors: gtsam.NonlinearFactorGraph, values: gtsam.Values,
            path: object) -> tuple:
        """The lookup key of a solve of `factors` from `values` along `path`."""
        return path, factors.size(), _values_digest(values)

    def get(
        self, key: tuple, factors: gtsam.NonlinearFactorGraph, values: gtsam.Values
    ) -> tuple[gtsam.Values, bool] | None:
        """A copy of the stored solution of `factors` from `values` under `key` and the
        state after it, or None."""
        stored = self._store.get(key)
        if (stored is None or not stored[1].equals(values, 0.0)
                or not same_factors(stored[0], factors)):
            self.misses += 1
            return None
        self.hits += 1
        self._store.move_to_end(key)
        return gtsam.Values(stored[2]), stored[3]

    def put(self, key: tuple, factors: gtsam.NonlinearFactorGraph, values: gtsam.Values,
            solution: gtsam.Values, state: bool) -> None:
        """Store `solution` of `factors` from `values` under `key` with the solver's
        `state` after it (the oldest entry goes when full)."""
        if self.entries <= 0:
            return
        self._store[key] = (gtsam.NonlinearFactorGraph(factors), values,
                            gtsam.Values(solution), state)
        self._store.move_to_end(key)
        while len(self._store) > self.entries:
            self._store.popitem(last=False)


class StickySolver:
    """`solve` for a sequence of related graphs; dogleg for good once LM has failed.

    With ``sticky=False`` only an LM that raises (sparse Cholesky breaks down: the graph
    needs QR) switches to dogleg for good; an LM that merely runs out of `lm_budget`
    iterations hands that one solve to dogleg.  Set `dogleg` to start with dogleg.
    `memo`: solutions remembered (`SolveMemo`; default `MEMO_ENTRIES`, 0: none).
    `stiff_cholesky` (default `STIFF_CHOLESKY`): the dogleg solves factorise by Cholesky
    with the poses of stiff factors eliminated first (`dogleg_stiff_first`) where the
    graph has stiff factors; QR otherwise.
    """

    def __init__(
        self, max_iterations: int = 100, lm_budget: int | None = None, sticky: bool = True,
        memo: int | None = None, stiff_cholesky: bool | None = None,
    ) -> None:
        self.max_iterations = max_iterations
        self.lm_budget = lm_budget
        self.sticky = sticky
        self.dogleg = False
        self.memo = SolveMemo(MEMO_ENTRIES if memo is None else memo)
        self.stiff_cholesky = STIFF_CHOLESKY if stiff_cholesky is None else stiff_cholesky
        self._stiff: tuple[int, list[int]] = (-1, [])  # (graph size scanned, stiff keys)

    def _dogleg(self, factors: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
        """Dogleg from `values`: `dogleg_stiff_first` when `stiff_cholesky` and the graph
        has stiff factors (scanned again whenever a larger graph comes), else QR."""
        if not self.stiff_cholesky:
            return dogleg_qr(factors, values, self.max_iterations).optimize()
        if factors.size() > self._stiff[0]:
            self._stiff = (factors.size(), stiff_keys(factors))
        return dogleg_stiff_first(factors, values, self.max_iterations, self._stiff[1])

    def __call__(self, factors: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
        """The solution of `factors` from `values` (a remembered one when this solver has
        solved the same graph from the same start along the same path before)."""
        if self.memo.entries <= 0:
            return self._solve(factors, values)
        key = self.memo.key(factors, values, self.dogleg)
        known = self.memo.get(key, factors, values)
        if known is not None:
            solution, self.dogleg = known
            return solution
        start = gtsam.Values(values)  # the caller may change its values afterwards
        result = self._solve(factors, values)
        self.memo.put(key, factors, start, result, self.dogleg)
        return result

    def _solve(self, factors: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
        if self.dogleg:
            return self._dogleg(factors, values)
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
            return self._dogleg(factors, values)
        if 0 < lm.iterations() < budget:
            return result
        start = result if factors.error(result) < factors.error(values) else values
        return self._dogleg(factors, start)


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
