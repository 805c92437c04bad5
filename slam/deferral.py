"""Loops whose innovation test has no power: deferred, then decided by consensus.

The time-ordered admission (`slam.consistency`) admits a loop ``k`` when its
innovation cost against the solved prefix is below the gate ``g`` (gtsam error
units, whitened by the loop's own noise)::

    delta_k = 0.5 b_k^T S_k^-1 b_k < g,    S_k = I + M_k,   M_k = B_k H^-1 B_k^T

When the prefix ties the loop's two poses together only through a long, loosely
stated odometry chain (the first return to the start after thousands of poses),
``S_k`` is so large that the gate admits almost any measurement: the test has no
*power*.  Admitting such a loop decides the prefix's shape by that one loop, and
a false one, if it comes first, bends the map so that the true loops of the same
return are rejected.

Power.  The test is asked whether the loop's later pose ``x_j`` is where the loop
says; the alternative a false loop presents is *another place of the map*.  With
``x_a`` a sample of the prefix's poses (`ALTERNATIVES` of them, evenly spaced in
the sequence), the loop measured to ``x_a`` instead of ``x_j`` shifts its whitened
residual by, to first order, ``d_a = B_j Log(x_j^-1 x_a)`` (``B_j`` the whitened
Jacobian of the loop with respect to ``x_j``; ``Log`` gtsam's tangent map: Pose2
``(v_x, v_y, omega)`` [m, m, rad], Pose3 ``(omega, v)``).  Places that even a test
without prefix uncertainty (``S = I``) cannot tell from ``x_j`` (``0.5 |d_a|^2 < g``:
the same place, revisited) are left out; the power is the share of the others that
the gate rejects::

    power_k = mean_{a: 0.5 |d_a|^2 >= g} [ 0.5 d_a^T S_k^-1 d_a >= g ]

the probability that a loop to a wrong place of the map is told apart from the loop's
own place (a measurement-free property of the gate: the same for a true and a false
loop).  A loop with ``power_k < MIN_POWER`` that the gate would admit is *deferred*:
carried into the next blocks and re-tested against each new prefix.  `MIN_POWER` is
the chi-square probability of the gate itself (0.99): the test must reject a wrong place
as surely as it admits a right one.  With a bounded wait (`slam.admission.AdmissionPass`'s
``wait``, ``defer="bounded"`` of `slam.consistency.incremental_tls`) a loop still deferred
after that many loop-bearing blocks is decided by the plain gate instead.  Otherwise loops
still deferred when the pass ends are rejected by it (the pass's result is then
re-decided on the whole graph by the residual rule, `slam.consistency.refine_tls`, which
re-admits those the final map agrees with).

Consensus.  Deferred loops are admitted together when they agree with one another
with power: for a pair ``(p, q)``, admitting ``p`` (Woodbury update of ``H^-1``, the
Gauss-Newton step it causes) gives ``q`` the conditional residual and covariance::

    b_q|p = b_q - C_qp (I + M_p)^-1 b_p,   M_q|p = M_q - C_qp (I + M_p)^-1 C_qp^T,
    C_qp = B_q H^-1 B_p^T

and the pair *agrees* when ``q`` given ``p`` and ``p`` given ``q`` both pass the gate
with power at least `MIN_POWER`.  The largest set of mutually agreeing deferred loops
(a maximum clique of the agreement graph, `slam.pairwise_consistency.max_clique`, as
pairwise consistency maximisation does: Mangelson et al., ICRA 2018), when it has at
least two loops, is admitted through the usual greedy gate.  The true loops of a
return agree with one another (their poses are close in the sequence at both ends, so
each pins the other's relative pose); a false loop agrees with none of them, and is
decided once the admitted return has given its own test power.
"""

from __future__ import annotations

from typing import Protocol

import gtsam
import numpy as np
from numpy.typing import NDArray

from data import se2
from slam.pairwise_consistency import logmap, max_clique

Array = NDArray[np.float64]
MIN_POWER = 0.99  # the gate must reject wrong places as surely as it admits right ones
ALTERNATIVES = 128  # places of the map a gate's power is measured against


class GainsLike(Protocol):
    """`slam.innovation._Gains`: ``b`` (m, d), ``Bj`` (m, d, d), ``M`` (m, d, d),
    ``Y`` (m, r, d), ``cross(y) -> (m, d, d)``."""

    b: Array
    Bj: Array
    M: Array
    Y: Array

    def cross(self, y: Array) -> Array: ...


def alternative_offsets(
    values: gtsam.Values, ends: list[int], places: list[int], dim: int
) -> Array:
    """``Log(x_j^-1 x_a)`` (m, P, d) of every candidate's later pose `ends` [j] to every
    alternative place `places` [a], at `values` (gtsam tangent order)."""
    if dim == 2:
        xa, xj = _pose2_rows(values, places), _pose2_rows(values, ends)
        rel = se2.compose(se2.inverse(xj)[:, None, :], xa[None, :, :])  # (m, P, 3)
        return logmap(rel.reshape(-1, 3)).reshape(len(ends), len(places), 3)
    poses = [values.atPose3(a) for a in places]
    out = np.empty((len(ends), len(places), 6))
    for n, k in enumerate(ends):
        xj = values.atPose3(k)
        out[n] = [gtsam.Pose3.Logmap(xj.between(xa)) for xa in poses]
    return out


def _pose2_rows(values: gtsam.Values, keys: list[int]) -> Array:
    """(len(keys), 3) poses (x, y, theta) of `keys` in `values`."""
    return np.array([[p.x(), p.y(), p.theta()] for p in (values.atPose2(k) for k in keys)])


def alternative_places(keys: list[int], count: int = ALTERNATIVES) -> list[int]:
    """`count` pose ids evenly spaced along `keys` (the solved prefix in sequence)."""
    n = len(keys)
    picks = np.unique(np.linspace(0, n - 1, min(count, n)).round().astype(int))
    return [keys[p] for p in picks]


def power(covariance: Array, whitened: Array, gate: float) -> Array:
    """Share of the distinguishable places the gate rejects, per candidate (module
    docstring): ``mean_a [0.5 d_a^T S^-1 d_a >= gate]`` over the places ``a`` that a test
    with no prefix uncertainty (``S = I``) rejects, ``0.5 |d_a|^2 >= gate`` (1 when there
    are none).  `covariance` ``S`` (m, d, d), `whitened` ``d`` (m, P, d); (m,)."""
    inv = np.linalg.inv(covariance)
    cost = 0.5 * np.einsum("mpa,mab,mpb->mp", whitened, inv, whitened)
    apart = 0.5 * np.einsum("mpa,mpa->mp", whitened, whitened) >= gate
    told = ((cost >= gate) & apart).sum(axis=1)
    count = apart.sum(axis=1)
    return np.where(count > 0, told / np.maximum(count, 1), 1.0)


def whitened_offsets(gains: GainsLike, offsets: Array) -> Array:
    """``d = B_j Log(x_j^-1 x_a)`` (m, P, d) from the tangent `offsets` (m, P, d)."""
    return np.einsum("mab,mpb->mpa", gains.Bj, offsets)


def agreement(gains: GainsLike, whitened: Array, gate: float,
              min_power: float = MIN_POWER) -> NDArray[np.bool_]:
    """(m, m) symmetric: candidates ``p`` and ``q`` agree (module docstring); diagonal
    True.  `whitened`: `whitened_offsets` of the same candidates."""
    m, d = gains.b.shape
    eye = np.eye(d)
    passes = np.eye(m, dtype=bool)  # passes[p, q]: q given p passes the gate with power
    for p in range(m):
        g = np.linalg.inv(eye + gains.M[p])
        c = gains.cross(gains.Y[p])  # (m, d, d): C_qp
        b = gains.b - np.einsum("mab,bc,c->ma", c, g, gains.b[p])
        s = eye + gains.M - np.einsum("mab,bc,mdc->mad", c, g, c)
        delta = 0.5 * np.einsum("ma,ma->m", b, np.linalg.solve(s, b[..., None])[..., 0])
        ok = (delta < gate) & (power(s, whitened, gate) >= min_power)
        ok[p] = True
        passes[p] = ok
    return passes & passes.T


def consensus(gains: GainsLike, whitened: Array, gate: float,
              min_power: float = MIN_POWER) -> NDArray[np.int64]:
    """Indices of the largest set of mutually agreeing candidates (`agreement`'s maximum
    clique), or none when it has fewer than two."""
    if len(gains.b) < 2:
        return np.zeros(0, np.int64)
    clique = max_clique(agreement(gains, whitened, gate, min_power))
    return clique if len(clique) >= 2 else np.zeros(0, np.int64)
