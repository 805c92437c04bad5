"""One-by-one re-decision of a TLS solution's loops under calibrated odometry.

The time-ordered admission (`slam.consistency`) decides loops against the graph's
*stated* covariances; `slam.calibrated_choice` picks among its candidates under odometry
calibrated by one variance factor ``s`` (`slam.calibrated_choice.own_factor`).

`recheck_loops` (``optimize(..., recheck=True)``) then re-decides the chosen loops one by
one.  At the calibrated solution ``x*`` (whitened Jacobian ``A``, information
``H = A^T A`` *including* every accepted loop), removing an accepted loop ``k``
(whitened residual ``b``, Jacobian ``B``, ``M = B H^-1 B^T``) lowers the least-squares
cost, to first order, by the leave-one-out innovation::

    rho_k = 0.5 b^T (I - M)^-1 b          (gtsam error units)

(the innovation of ``k`` against the graph without it, written with the quantities of
the graph with it).  Keeping ``k`` is worth it under TLS iff ``rho_k < c``; since all
``n`` accepted loops are tested at once, a loop is removed only above the family-wise
gate `removal_gate` (``c`` at the per-loop level ``p^(1/n)``, Sidak), so that a graph of
true loops loses none with probability ``p``.  Loops are removed greedily, largest
``rho`` first while ``rho`` exceeds the gate; after each removal the others' ``b``,
``M`` and ``H^-1 B^T`` are updated exactly for it by the rank-``dof`` Woodbury downdate
``H'^-1 = H^-1 + Y (I - M)^-1 Y^T`` (``Y = H^-1 B^T``) and the Gauss-Newton step it
causes, ``dx = -Y (I - M)^-1 b``, so a false loop that props up another is judged after
it is gone.  Then the loops rejected earlier (and not removed here) whose innovation
alone is below ``c`` are offered back (`slam.consistency.greedy_admission` at ``c``),
``s`` is re-estimated with the new decisions, and the rounds repeat until no decision
changes (at most `MAX_ROUNDS`).  A loop removed by the re-check is never re-admitted by
it, so the rounds end.  The caller solves the *stated* graph with the decisions.

Cost: every round runs `own_factor` (a calibrated solve, one sparse LU and the marginal
covariance blocks of every accepted loop's two poses), even when nothing changes, which
on large graphs costs many times the admission (off by default for that reason); the
Woodbury updates' ``H^-1 B^T`` rows (`InnovationTest.gains`, memory of loops x touched
rows x dof) are built only when some ``rho`` exceeds the gate, and for the rejected loops
admissible alone.
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from slam.calibrated_choice import _accepted, own_factor
from slam.innovation import InnovationTest, _Gains, greedy_admission, tls_threshold
from slam.least_squares import StickySolver
from slam.pose_graph import PoseGraph, chi2_quantile, pose_dof

Array = NDArray[np.float64]
MAX_ROUNDS = 20  # re-check rounds (each: a calibrated solve, a factor step, maybe decisions)


def removal_costs(gains: _Gains) -> Array:
    """``rho_q = 0.5 b^T (I - M)^-1 b`` of every accepted loop (gtsam error units), with
    `gains` linearised at the solution of the graph that includes them."""
    return _quadratic(gains.b, -gains.M)


def _quadratic(b: Array, m: Array) -> Array:
    """``0.5 b^T (I + m)^-1 b`` per row: the admission cost for ``m = M``, the removal cost
    for ``m = -M``."""
    s = np.eye(b.shape[1]) + m
    return 0.5 * np.einsum("ma,ma->m", b, np.linalg.solve(s, b[..., None])[..., 0])


def greedy_removal(gains: _Gains, gate: float) -> tuple[list[int], Array]:
    """Remove accepted loops largest ``rho`` first while ``rho > gate`` (module docstring).

    Returns the removed indices in order and the final ``rho`` of every loop (of the
    removed ones meaningless).  `gains` is consumed."""
    m = len(gains.b)
    open_ = np.ones(m, dtype=bool)
    removed: list[int] = []
    eye = np.eye(gains.b.shape[1])
    while open_.any():
        rho = removal_costs(gains)
        rho[~open_] = -np.inf
        k = int(np.argmax(rho))
        if not rho[k] > gate:
            break
        removed.append(k)
        open_[k] = False
        gain = np.linalg.inv(eye - gains.M[k])
        c = gains.cross(gains.Y[k])  # B_q H^-1 B_k^T
        gains.b = gains.b + np.einsum("mab,bc,c->ma", c, gain, gains.b[k])
        gains.M = gains.M + np.einsum("mab,bc,mdc->mad", c, gain, c)
        gains.Y = gains.Y + np.einsum("nb,bc,mdc->mnd", gains.Y[k], gain, c)
        # The removed loop's own rows are meaningless from here on; keep M_k off I.
        gains.M[k] = 0.0
    return removed, removal_costs(gains)


def removal_gate(n: int, dof: int, probability: float = 0.99) -> float:
    """Error level above which one of `n` accepted loops is removed: ``0.5 chi2_dof^-1(p^(1/n))``.

    The re-check tests all `n` accepted loops at once against "every one is an inlier";
    at this per-loop level (Sidak) the chance of removing any true loop of a Gaussian
    graph is ``1 - p``, as for one loop at the TLS threshold ``c`` (``n = 1``).
    """
    return 0.5 * chi2_quantile(probability ** (1.0 / max(n, 1)), dof)


def recheck_loops(
    graph: PoseGraph,
    values: gtsam.Values,
    weights: Array,
    *,
    probability: float = 0.99,
    solver: StickySolver | None = None,
    unit: Sequence[gtsam.NonlinearFactor] | None = None,
    max_rounds: int = MAX_ROUNDS,
    start: float = 1.0,
) -> tuple[Array, float]:
    """Re-checked loop weights of a TLS solution (`values`, `weights`) and the last
    odometry variance factor used (module docstring); `weights` unchanged (factor 1) when
    a calibrated solve fails (as in `calibrated_choice`).

    `unit`: the loops' Gaussian factors (computed when None); `solver`: the least-squares
    solver for the calibrated solves; `start`: a first guess of the odometry factor.
    """
    try:
        return _recheck(graph, values, weights, probability, solver or StickySolver(),
                        unit, max_rounds, start)
    except RuntimeError:  # gtsam IndeterminateLinearSystemException
        return (np.asarray(weights) > 0.5).astype(float), 1.0


def _recheck(
    graph: PoseGraph, values: gtsam.Values, weights: Array, probability: float,
    solve: StickySolver, unit: Sequence[gtsam.NonlinearFactor] | None, max_rounds: int,
    start: float,
) -> tuple[Array, float]:
    """`recheck_loops`' rounds."""
    if unit is None:
        unit = [graph.between_factor(lp) for lp in graph.loops]
    c = tls_threshold(graph.dim, probability)
    d = pose_dof(graph.dim)
    keys = graph.keys
    w = (np.asarray(weights) > 0.5).astype(float)
    removed = np.zeros(len(w), dtype=bool)
    current, s = values, start
    for _ in range(max_rounds):
        if not (w > 0.5).any():
            break
        cal = own_factor(graph, current, w, unit=unit, solver=solve, start=s,
                         with_gains=False)
        s, current, fixed, kept = cal.s, cal.values, cal.fixed, cal.kept
        assert cal.test is not None
        gate = removal_gate(len(kept), d, probability)
        b, gram = cal.test.blocks([unit[k] for k in kept])
        drop: list[int] = []
        if (_quadratic(b, -gram) > gate).any():  # only then the (m, r, d) gains
            drop, _ = greedy_removal(cal.test.gains([unit[k] for k in kept]), gate)
        changed = bool(drop)
        test = cal.test
        if drop:
            w[kept[drop]] = 0.0
            removed[kept[drop]] = True
            current = solve(_accepted(fixed, unit, w), current)
            test = InnovationTest(_accepted(fixed, unit, w), current, keys, d)
        offer = np.flatnonzero((w < 0.5) & ~removed)
        if len(offer):
            b, gram = test.blocks([unit[k] for k in offer])
            offer = offer[_quadratic(b, gram) < c]  # admissible alone, before any other
        if len(offer):
            admitted, _ = greedy_admission(test.gains([unit[k] for k in offer]), c)
            if admitted:
                w[offer[admitted]] = 1.0
                changed = True
        if not changed:
            break
    return w, s


