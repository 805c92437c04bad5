"""A few iterations that tell when the plain least-squares optimum cannot be the TLS one.

`slam.optimize`'s fast path solves the graph with every loop in at each rung of the
odometry ladder and keeps that optimum when every loop's error there is at most ``c``
(gtsam error units, ``e = 0.5 r^T I r``; ``c`` = `slam.innovation.tls_threshold`).  With
many false loops between far-apart poses that solve is the dearest of the whole robust
back end: the false loops fill the elimination of the normal equations in (every
iteration factorises a nearly dense matrix) and the solve needs tens of iterations,
only for the fast path to be discarded.

`majority_fails` runs at most `SCREEN_ITERATIONS` iterations of the same solver from the
same start (Levenberg-Marquardt; Powell's dogleg with multifrontal QR where Cholesky
breaks down) and stops as soon as every loop is at most ``c``.  When after them more than
half of the loops still exceed ``c`` (the median loop error is above ``c``), the loops
are mostly inconsistent with one another: the fast path's premise, a graph whose loops
agree, fails, and the caller goes straight to the time-ordered admission.  Otherwise the
fast path's own check runs unchanged from the same start, so a graph that passes the
screen is decided exactly as without it.  On a consistent graph the first iterations
take up the odometry's drift and the loops fall below ``c`` within a few of them; the
false loops of a corrupted one stay far above it, since no map satisfies them together.

Limitation (why `slam.optimize.optimize` has it off by default): a consistent graph whose
solve from the odometry chain converges slowly (near-singular odometry information, as
Intel's, with its odometry stated loosely) keeps most loops above ``c`` for many more
iterations than the screen runs although the converged optimum holds every loop; the
screen then skips a fast path that the full check accepts, and the result is the
admission's instead of the plain optimum.  The total error's decrease over the screen's
iterations does not tell the two apart either.

`stalled_solve` is the other way to spend less on that solve: it is
`slam.least_squares.solve` itself (the same Levenberg-Marquardt run, iteration for
iteration, and dogleg with QR where LM fails), watched after every LM iteration, and
given up (None) as soon as LM has stalled with most loops still above ``c``: the last
iteration took a step that lowered the total error, but by less than `STALL_DECREASE` of
it (relative), while more than half of the loops exceed ``c``.  An iteration without a
step (LM giving up before its first, as on near-singular information where Cholesky
fails at every damping) is not a stall: `solve` then goes on with dogleg; nor is a small
step under heavy damping (LM's lambda above `STALL_LAMBDA`: LM crawling, e.g. Intel with
its odometry information x0.01, whose LM runs to its cap at relative decreases of 1e-2
and whose dogleg then reaches an optimum that holds every loop).  When it is not
given up it returns what `solve` returns, bit for bit (the watch only reads the
optimizer's state).  It is not a proof that the converged solve fails: LM's relative
decrease is not monotone (it dips when the damping rises and recovers after), and LM could
crawl on to its iteration cap, after which `solve` goes on with dogleg; a graph whose
loops all fall below ``c`` only after such a dip or by that dogleg would be given up.
Measured per cell by `benchmarks/fast_path_stall.py` (the full solve's trajectory and
where the rule fires).

Where LM fails and `solve` goes on with dogleg (Intel, MIT: sparse Cholesky breaks down
on their near-singular information), the dogleg's iterations are watched too, by another
rule: dogleg's trust region keeps each step's relative decrease of the total error near
a few percent whether the loops agree or not, so a small decrease tells nothing there.
What does is the number of loops above ``c``: the solve is given up once that number has
not fallen below its least so far for `STALL_WINDOW` dogleg iterations while more than
half of the loops are above ``c``.  On a graph whose loops agree, the count falls as soon
as the odometry chain's drift is taken up (nearly every loop is above ``c`` there), and
it goes on falling every few iterations; with many false loops it stays near the number
of loops from the first iteration to the last.  Again a measured rule, not a proof; it
too returns `solve`'s result bit for bit whenever it does not give up.
"""

from __future__ import annotations

import gtsam
import numpy as np

from slam.least_squares import dogleg_qr, lm_params, solve

SCREEN_ITERATIONS = 5  # solver iterations of the screen at most
STALL_DECREASE = 1e-2  # `stalled_solve`: relative decrease of one LM iteration that is a stall
# `stalled_solve`: LM's damping (gtsam's lambda, added to the normal equations' diagonal)
# above which a small decrease is the damping's, not a stall (LM crawling, as on
# near-singular information: it may run to its cap, after which `solve` goes on with dogleg).
STALL_LAMBDA = 1.0
# `stalled_solve`'s dogleg rule: dogleg iterations without a new least number of loops
# above ``c`` (with more than half above) after which the solve is given up (0: off).
STALL_WINDOW = 10


class _Stalled(Exception):
    """Raised from LM's iteration hook to end a stalled solve (`stalled_solve`)."""


def is_stall(iteration: int, before: float, after: float, decrease: float) -> bool:
    """True when LM's `iteration` (its count after the iteration) took a step that lowered
    the total error from `before` to `after` (gtsam units) by less than `decrease` of
    `before`.  An iteration that found no step (no decrease, iteration count 0) is LM
    giving up, after which `slam.least_squares.solve` goes on with dogleg: not a stall."""
    return iteration >= 1 and 0.0 < before - after < decrease * before


class CountStall:
    """The dogleg rule of `stalled_solve`, fed one iteration at a time: `seen(iteration,
    above)` with the dogleg's iteration count (1 after its first iteration) and the
    number of loops above ``c`` after it, of `loops` loops; True once that number has not
    fallen below its least so far for `window` iterations while more than half of the
    loops are above ``c``."""

    def __init__(self, loops: int, window: int = STALL_WINDOW) -> None:
        self.loops, self.window = loops, window
        self.least: int | None = None  # the least number above ``c`` seen so far
        self.since = 0  # the iteration that first reached it

    def seen(self, iteration: int, above: int) -> bool:
        if self.least is None or above < self.least:
            self.least, self.since = above, iteration
            return False
        return iteration - self.since >= self.window and 2 * above > self.loops


def stalled_solve(
    factors: gtsam.NonlinearFactorGraph, values: gtsam.Values, max_iterations: int,
    loop_index: list[int], c: float, decrease: float = STALL_DECREASE,
    window: int | None = None,
) -> tuple[gtsam.Values, int, str] | None:
    """`slam.least_squares.solve(factors, values, max_iterations)`, or None when an LM
    step lowers the total error by less than `decrease` (relative) while more than
    half of the loop factors ``factors.at(k)``, k in `loop_index`, have an error above `c`
    (gtsam units; module docstring), or when its dogleg iterations (where LM fails) go
    `window` iterations without lowering the number of loops above `c` while more than
    half are above (`CountStall`; None: `STALL_WINDOW`; 0: dogleg not watched).  Returns
    ``(solution, iterations, solver)`` as `solve` does, bit for bit, whenever it does not
    give up."""
    loops = [factors.at(k) for k in loop_index]

    def above(now: gtsam.Values) -> int:
        return sum(f.error(now) > c for f in loops)

    def watch(lm: gtsam.LevenbergMarquardtOptimizer, iteration: int, before: float,
              after: float) -> None:
        if not is_stall(iteration, before, after, decrease):
            return
        if lm.lambda_() > STALL_LAMBDA:
            return
        if 2 * above(lm.values()) > len(loop_index):
            raise _Stalled

    window = STALL_WINDOW if window is None else window
    counts = CountStall(len(loop_index), window) if window > 0 else None

    def dogleg_watch(dogleg: gtsam.DoglegOptimizer, iteration: int, before: float,
                     after: float) -> None:
        if counts is not None and counts.seen(iteration, above(dogleg.values())):
            raise _Stalled

    try:
        return solve(factors, values, max_iterations, watch=watch,
                     dogleg_watch=dogleg_watch if counts is not None else None)
    except _Stalled:
        return None


def majority_fails(
    factors: gtsam.NonlinearFactorGraph, loop_index: list[int], values: gtsam.Values,
    c: float, iterations: int = SCREEN_ITERATIONS,
) -> bool:
    """True when, after at most `iterations` solver iterations on `factors` from `values`,
    more than half of the loop factors ``factors.at(k)``, k in `loop_index`, have an
    error above `c` (module docstring); False as soon as none has."""
    if not loop_index:
        return False
    try:
        optimizer = gtsam.LevenbergMarquardtOptimizer(factors, values, lm_params(iterations))
        return _fails(optimizer, factors, loop_index, c, iterations)
    except RuntimeError:  # gtsam IndeterminateLinearSystemException: QR as `solve` does
        return _fails(dogleg_qr(factors, values, iterations), factors, loop_index, c,
                      iterations)


def _fails(
    optimizer: gtsam.NonlinearOptimizer, factors: gtsam.NonlinearFactorGraph,
    loop_index: list[int], c: float, iterations: int,
) -> bool:
    errors = np.zeros(len(loop_index))
    for _ in range(iterations):
        optimizer.iterate()
        values = optimizer.values()
        errors = np.array([factors.at(k).error(values) for k in loop_index])
        if not (errors > c).any():
            return False
    return 2 * int((errors > c).sum()) > len(loop_index)
