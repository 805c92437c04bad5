"""Variance factors of the odometry segment by segment.

One variance factor for all the odometry (`slam.variance_components`,
`slam.calibrated_choice`) assumes the front end is as good (or as bad) everywhere.  Real
odometry is not: a robot that slips through a doorway or turns on the spot has stretches
whose residuals are several times its average, and a false loop that lands on a quiet
stretch bends it further than that stretch's own residuals support, while the pooled
factor, inflated by the noisy stretches, lets it.  This module estimates one factor per
*segment* of consecutive poses.

Helmert variance-component estimation (Förstner & Wrobel, *Photogrammetric Computer
Vision*, 2016, section 4.2.4; Koch, *Parameter Estimation and Hypothesis Testing in
Linear Models*, 1999) at a least-squares solution of the accepted graph (anchors,
odometry, accepted loops; whitened Jacobian ``A`` with ``m`` rows, ``n`` unknowns,
``N = A^T A``).  Segment ``k`` is the set of odometry factors whose later pose lies in
the ``k``-th run of `SEGMENT` consecutive poses (in id order); with its whitened
residuals ``r_k`` (``r_k^T W_k r_k = 2 E_k``, ``E_k`` its gtsam error) and its rows
``A_k``, its redundancy and variance factor are::

    red_k = n_k - tr(A_k N^-1 A_k^T)            (n_k: the segment's rows)
    s_k   = r_k^T W_k r_k / red_k               (actual / stated variance)

The traces are estimated by Hutchinson's estimator of the hat matrix's diagonal,
``diag(A N^-1 A^T) ~ mean_z z * (A N^-1 A^T z)`` over `PROBES` Rademacher vectors
``z`` (one sparse LU of ``N`` and a solve per few probes; the probes are drawn once per
estimate), summed per group (anchors,
each segment, the loops); the group redundancies are then scaled so that they sum to
the exact total ``m - n``.  The factors are iterated as Helmert's estimate is: the
odometry re-weighted by the last factors, the solution and the redundancies re-computed
(`segment_factors`).  A short or loop-free segment has little
redundancy, so each factor is shrunk toward the pooled odometry factor
``s = sum_k r_k^T W_k r_k / sum_k red_k`` with a prior of `PRIOR_DOF` degrees of
freedom, and capped at 1 (a calibrated segment is never looser than stated)::

    s_k <- min(1, (r_k^T W_k r_k + nu s) / (red_k + nu)),   nu = PRIOR_DOF

Units: variance factors are dimensionless ratios of actual to stated variance; a
calibrated graph divides each odometry information matrix by its segment's factor.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix, csr_matrix, diags
from scipy.sparse.linalg import SuperLU

from slam.innovation import solve_columns
from slam.least_squares import factor_information
from slam.pose_graph import Constraint, PoseGraph, pose_dof

Array = NDArray[np.float64]
SEGMENT = 100  # poses per odometry segment
PROBES = 64  # Rademacher probes of the Hutchinson trace estimate
PRIOR_DOF = 3.0  # degrees of freedom of the pooled factor in each segment's estimate
FLOOR = 1e-4  # smallest factor returned (a noise-free stretch)
ITERATIONS = 5  # at most this many Helmert iterations
TOLERANCE = 0.05  # ... ending once no factor changes by more than this fraction


@dataclass(slots=True)
class SegmentFactors:
    """Odometry variance factors per segment (module docstring).

    Attributes:
        factors: (S,) shrunk and capped factor of every segment (actual / stated variance).
        raw: (S,) ``r_k^T W_k r_k / red_k`` before shrinkage and cap (inf without redundancy).
        redundancy: (S,) scaled redundancy ``red_k`` of every segment.
        pooled: the pooled odometry factor (uncapped).
        segment: (len(graph.odometry),) segment index of every odometry constraint.
    """

    factors: Array
    raw: Array
    redundancy: Array
    pooled: float
    segment: NDArray[np.int64]

    def per_odometry(self) -> Array:
        """The factor of every odometry constraint, in `graph.odometry` order."""
        return self.factors[self.segment]


def odometry_segments(graph: PoseGraph, length: int = SEGMENT) -> NDArray[np.int64]:
    """Segment of every odometry constraint: position of its later pose (ids in increasing
    order) integer-divided by `length`."""
    keys = np.asarray(graph.keys, dtype=np.int64)
    ends = np.array([max(o.i, o.j) for o in graph.odometry], dtype=np.int64)
    return np.searchsorted(keys, ends) // length


def _jacobian(
    factors: gtsam.NonlinearFactorGraph, values: gtsam.Values, n: int
) -> tuple[csr_matrix, Array]:
    """Whitened Jacobian (rows, n) of `factors` at `values` and the whitened right-hand
    side per row (minus the whitened residual)."""
    triplets = factors.linearize(values).sparseJacobian_()
    rows = triplets[0].astype(np.int64) - 1  # 1-based, columns in sorted-key order
    cols = triplets[1].astype(np.int64) - 1
    m = int(rows.max()) + 1
    keep = cols < n  # the last column is the right-hand side
    jac = coo_matrix((triplets[2][keep], (rows[keep], cols[keep])), shape=(m, n)).tocsr()
    rhs = np.bincount(rows[~keep], weights=triplets[2][~keep], minlength=m)
    return jac, rhs


def rademacher(rows: int, probes: int = PROBES, seed: int = 0) -> Array:
    """(rows, probes) Rademacher vectors (entries -1 or 1, equally likely) of `seed`."""
    rng = np.random.default_rng(seed)
    return rng.choice(np.array([-1.0, 1.0]), size=(rows, probes))


def hat_diagonal(
    jac: csr_matrix, probes: int = PROBES, seed: int = 0, lu: SuperLU | None = None,
    z: Array | None = None,
) -> Array:
    """Hutchinson estimate of ``diag(A N^-1 A^T)`` (``N = A^T A``) for a whitened Jacobian
    ``A`` (rows, n): ``mean_z z * (A N^-1 A^T z)`` over `probes` Rademacher vectors.
    `lu`: the factorisation of ``N`` (`slam.least_squares.factor_information`), when
    the caller has it.  `z`: the probes, ``rademacher(rows, probes, seed)``, when the
    caller has them."""
    if z is None:
        z = rademacher(jac.shape[0], probes, seed)
    if lu is None:
        lu = factor_information(jac)
    y = jac @ solve_columns(lu, np.asarray(jac.T @ z))
    return np.mean(z * y, axis=1)


def segment_factors(
    graph: PoseGraph,
    values: gtsam.Values,
    weights: Array,
    *,
    length: int = SEGMENT,
    probes: int = PROBES,
    prior_dof: float = PRIOR_DOF,
    seed: int = 0,
    iterations: int = ITERATIONS,
    tolerance: float = TOLERANCE,
) -> SegmentFactors:
    """Odometry variance factors per segment of `length` poses (module docstring).

    The accepted graph is linearised once at `values` (whitened Jacobian ``A``,
    right-hand side ``b``); an iteration divides the odometry rows of segment ``k`` by
    ``sqrt(s_k)`` (``D A``, ``D b``), solves the Gauss-Newton step
    ``dx = (A^T D^2 A)^-1 A^T D^2 b``, takes the residuals ``D (b - A dx)`` and the
    redundancies of that weighting, and re-estimates every ``s_k`` (``r_k^T W_k r_k``
    in stated units: the calibrated value times the last ``s_k``).  The first iteration
    (``D = I``) is the estimate at the stated covariances.

    Args:
        graph: the pose graph with its stated information.
        values: the linearisation point: a least-squares solution (or close to one) of the
            anchors, the odometry and the loops with ``weights > 0.5`` (stated covariances).
        weights: weight per loop of `graph.loops` (above 0.5: accepted).
        length: poses per segment.
        probes: Rademacher probes of the trace estimate.
        prior_dof: weight, in degrees of freedom, of the pooled factor in each segment's.
        seed: seed of the probes (the estimate is deterministic for a seed).
        iterations: at most this many Helmert iterations (1: the estimate at the stated
            covariances).
        tolerance: the iterations end once no factor changes by more than this fraction.
    """
    d = pose_dof(graph.dim)
    segment = odometry_segments(graph, length)
    n_seg = int(segment.max()) + 1 if len(segment) else 0
    anchors = graph.anchor_keys()
    kept = np.flatnonzero(np.asarray(weights) > 0.5)
    factors = gtsam.NonlinearFactorGraph()
    for k in anchors:
        factors.add(graph.prior_factor(k))
    for o in graph.odometry:
        factors.add(graph.between_factor(o))
    for k in kept:
        factors.add(graph.between_factor(graph.loops[k]))
    n = len(graph.keys) * d
    jac0, rhs0 = _jacobian(factors, values, n)
    # Group of every factor: anchors n_seg + 1, segments 0..n_seg-1, loops n_seg.
    group = np.concatenate([np.full(len(anchors), n_seg + 1), segment,
                            np.full(len(kept), n_seg)]).astype(np.int64)
    rows = np.repeat(group, d)
    odometry_rows = rows < n_seg
    scale = np.ones(n_seg)  # the factors the odometry information is divided by
    z = rademacher(jac0.shape[0], probes, seed)  # the same probes in every iteration
    result = None
    for it in range(iterations):
        row_scale = np.ones(len(rows))
        row_scale[odometry_rows] = 1.0 / np.sqrt(scale[rows[odometry_rows]])
        jac = diags(row_scale) @ jac0
        rhs = row_scale * rhs0
        lu = factor_information(jac)
        residual = rhs - jac @ lu.solve(jac.T @ rhs)
        redundancy_rows = 1.0 - hat_diagonal(jac, probes, seed, lu, z)
        redundancy_rows[rows == n_seg + 1] = 0.0  # anchors fix their poses alone
        red = np.maximum(np.bincount(rows, weights=redundancy_rows, minlength=n_seg + 2), 0.0)
        if red.sum() > 0:
            red *= (jac.shape[0] - n) / red.sum()
        quad = np.bincount(rows, weights=residual**2, minlength=n_seg + 2)  # r^T W r
        red_k, quad_k = red[:n_seg], quad[:n_seg] * scale  # in stated units
        pooled = float(quad_k.sum() / red_k.sum()) if red_k.sum() > 0 else 1.0
        with np.errstate(divide="ignore", invalid="ignore"):
            raw = np.where(red_k > 0, quad_k / red_k, np.inf)
        shrunk = (quad_k + prior_dof * pooled) / (red_k + prior_dof)
        result = SegmentFactors(np.clip(shrunk, FLOOR, 1.0), raw, red_k, pooled, segment)
        change = np.max(np.abs(result.factors / scale - 1.0), initial=0.0)
        scale = result.factors
        if it and change < tolerance:
            break
    assert result is not None
    return result


def calibrated_odometry(graph: PoseGraph, factors: SegmentFactors) -> list[Constraint]:
    """The odometry of `graph` with every information matrix divided by its segment's
    factor (``I_o / s_k``)."""
    per = factors.per_odometry()
    return [Constraint(o.i, o.j, o.measurement, o.information / s)
            for o, s in zip(graph.odometry, per, strict=True)]


def _segment_calibrated(
    graph: PoseGraph, factors: SegmentFactors, unit: Sequence[gtsam.NonlinearFactor],
    weights: Array,
) -> gtsam.NonlinearFactorGraph:
    """Anchors, the odometry calibrated by `factors` and the loops `unit` of
    ``weights > 0.5``: the graph the segment and group re-checks solve."""
    calibrated = gtsam.NonlinearFactorGraph()
    for k in graph.anchor_keys():
        calibrated.add(graph.prior_factor(k))
    for o in calibrated_odometry(graph, factors):
        calibrated.add(graph.between_factor(o))
    for k in np.flatnonzero(np.asarray(weights, dtype=float) > 0.5):
        calibrated.add(unit[k])
    return calibrated
