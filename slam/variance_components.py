"""Variance-component estimation: how pessimistic a pose graph's stated covariances are.

A pose graph states an information matrix for every constraint, but front ends state
them loosely: a graph's odometry may claim ten or a hundred times the variance its
measurements show.  Robust back ends decide false loops against those covariances
(an innovation test, a TLS threshold), so the same data with looser stated odometry
lets a false loop bend the trajectory onto itself at a cost below the threshold.
This module estimates, from the graph's own residuals, one variance factor per
group of constraints (odometry, loops), so a back end can judge loops against
covariances the data supports.

Helmert / Förstner variance-component estimation (Förstner & Wrobel,
*Photogrammetric Computer Vision*, 2016, section 4.2.4; Koch, *Parameter
Estimation and Hypothesis Testing in Linear Models*, 1999).  With the whitened
Jacobian ``A`` of the graph at its least-squares solution, ``H = A^T A`` and
``A_g`` the rows of group ``g``, the redundancy of the group is::

    r_g = m_g - tr(H^-1 A_g^T A_g)          (sum of the group's redundancy numbers)

and its variance factor ``s_g^2 = v_g^T P_g v_g / r_g = 2 E_g / r_g`` (``E_g``: the
group's gtsam error, ``0.5 r^T I r``).  Every group's information is divided by its
``s_g^2`` and the solve repeated until the factors settle (for the odometry, secant
steps on ``log s^2`` against the log of its factor); the fixed point does not
depend on how each group was scaled to begin with, so a graph whose odometry
information is scaled by any constant yields the same calibrated graph.  The trace
of the loop rows is computed exactly (one sparse LU of ``H`` per iteration and one
solve per loop row), the odometry's as the rest of the total redundancy ``m - n``.

Units: variance factors are dimensionless (ratios of actual to stated variance).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix

from slam.least_squares import StickySolver, factor_information
from slam.pose_graph import Constraint, PoseGraph, pose_dof

Array = NDArray[np.float64]
MIN_REDUNDANCY = 6.0  # a group needs this much redundancy (two 2D loops) for its factor
BOUNDS = (1e-4, 1e4)  # the estimated factors are clipped to this range
CHUNK = 600  # loop rows per solve of the trace


@dataclass(slots=True)
class VarianceFactors:
    """Estimated variance factors (actual / stated variance) of odometry and loops.

    ``odometry`` or ``loops`` is 1.0 when its group has less than `MIN_REDUNDANCY`.
    ``redundancy``: (odometry, loops) redundancies of the last iteration.
    """

    odometry: float
    loops: float
    redundancy: tuple[float, float]
    iterations: int


def with_information_scaled(graph: PoseGraph, odometry: float, loops: float = 1.0) -> PoseGraph:
    """A copy of `graph` whose odometry and loop information are multiplied by the factors."""

    def scaled(cs: list[Constraint], s: float) -> list[Constraint]:
        return [Constraint(c.i, c.j, c.measurement, c.information * s) for c in cs]

    return PoseGraph(
        graph.dim,
        dict(graph.initial),
        scaled(graph.odometry, odometry),
        scaled(graph.loops, loops),
        set(graph.fixed),
    )


def _redundancies(
    factors: gtsam.NonlinearFactorGraph, values: gtsam.Values, groups: Array, dof: int
) -> Array:
    """Redundancy of the odometry (label 1) and loop (label 2) groups of `groups`.

    Exact: ``r_loops = m_loops - tr(A_l H^-1 A_l^T)`` from one multi-right-hand-side
    solve per chunk of loop rows, and ``r_odometry = (m - n) - r_loops`` (the total
    redundancy, less the anchor priors' which is zero: they fix their poses alone).
    """
    triplets = factors.linearize(values).sparseJacobian_()
    rows = triplets[0].astype(np.int64) - 1
    cols = triplets[1].astype(np.int64) - 1
    n = int(values.size()) * dof
    keep = cols < n  # the last column is the right-hand side
    jac = coo_matrix(
        (triplets[2][keep], (rows[keep], cols[keep])), shape=(len(groups) * dof, n)
    ).tocsr()
    lu = factor_information(jac)
    loop_rows = np.flatnonzero(np.repeat(groups, dof) == 2)
    trace = 0.0
    for start in range(0, len(loop_rows), CHUNK):
        a_l = jac[loop_rows[start : start + CHUNK]]
        x = lu.solve(a_l.T.toarray())  # H^-1 A_l^T
        trace += float(np.einsum("rn,nr->", a_l.toarray(), x))
    r_loops = len(loop_rows) - trace
    r_total = len(groups) * dof - n
    return np.array([0.0, r_total - r_loops, r_loops])


def estimate_variance_factors(
    graph: PoseGraph,
    inliers: Array,
    values: gtsam.Values,
    *,
    iterations: int = 50,
    tolerance: float = 1e-3,
    loops_free: bool = False,
    min_redundancy: float = MIN_REDUNDANCY,
) -> VarianceFactors:
    """Variance factors of odometry and of the loops with ``inliers > 0.5`` (module docstring).

    Args:
        graph: the pose graph with its stated information.
        inliers: weight per loop of `graph.loops` (those above 0.5 take part).
        values: start of the least-squares solves (e.g. the robust solution).
        iterations: at most this many re-weighted solves.
        tolerance: stop when no factor changes by more than this fraction.
        loops_free: estimate the loops' factor too; by default the loops keep their
            stated information (factor 1) and only the odometry is estimated, since
            two free groups can trade all the redundancy between them.
        min_redundancy: a group with less redundancy keeps the factor 1.
    """
    keep = [c for c, w in zip(graph.loops, inliers, strict=True) if w > 0.5]
    dof = pose_dof(graph.dim)
    solve = StickySolver()
    f_odo, f_loop = 1.0, 1.0
    redundancy = np.zeros(3)
    n_prior = len(graph.anchor_keys())
    groups = np.array([0] * n_prior + [1] * len(graph.odometry) + [2] * len(keep))
    done = 0
    last: tuple[float, float] | None = None  # (log f, log s^2) of the previous odometry step
    for done in range(1, iterations + 1):  # noqa: B007 - the count is returned
        cal = with_information_scaled(PoseGraph(
            graph.dim, graph.initial, graph.odometry, keep, graph.fixed), f_odo, f_loop)
        factors, _ = cal.factor_graph()
        values = solve(factors, values)
        redundancy = _redundancies(factors, values, groups, dof)
        errors = np.array([factors.at(k).error(values) for k in range(factors.size())])
        step = np.ones(2)
        for g in (1, 2) if loops_free else (1,):
            if redundancy[g] >= min_redundancy:
                step[g - 1] = 2.0 * errors[groups == g].sum() / redundancy[g]
        # Odometry: secant steps on log s^2(log f) = 0 (plain re-weighting, f / s^2, first
        # and when the secant is flat; re-weighting alone converges slowly when one
        # group holds most of the redundancy).
        x, y = np.log(f_odo), np.log(step[0])
        slope = (y - last[1]) / (x - last[0]) if last is not None and x != last[0] else 1.0
        last = (x, y)
        if not 0.05 < slope < 20.0:
            slope = 1.0
        f_odo = float(np.clip(np.exp(x - y / slope), *BOUNDS))
        f_loop = float(np.clip(f_loop / step[1], *BOUNDS))
        if np.all(np.abs(step - 1.0) < tolerance):
            break
    return VarianceFactors(1.0 / f_odo, 1.0 / f_loop, (redundancy[1], redundancy[2]), done)
