"""Pairwise consistency of 2D loop closures through the odometry chain (PCM).

Pairwise consistency maximisation (Mangelson, Dominic, Eustice & Vasudevan, "Pairwise
Consistent Measurement Set Maximization for Robust Multi-robot Map Merging", ICRA
2018): two loops are *consistent* when the cycle they close with the odometry has a
Mahalanobis distance under a chi-square gate, and the accepted set is the maximum
clique of the consistency graph.

Frames and units.  Poses are (x, y, theta) [m, m, rad]; tangent vectors are gtsam
``Pose2``'s (v_x, v_y, omega).  A measurement ``z`` of pose ``j`` in ``i``'s frame
with covariance ``Sigma`` (the inverse of its stated information) is perturbed on the
right, ``z Exp(eta)``, ``eta ~ N(0, Sigma)``, as gtsam's between factor has it.

The odometry chain.  The poses in id order must be joined by odometry ``p - 1 -> p``
(the spine of a g2o file or a mapper); other odometry edges are ignored (the chain's
covariance is then an upper bound).  Dead reckoning gives ``P_p = P_{p-1} o_p``
(``P_0``: the first pose's given pose).  The truth is ``T_p = Exp(-E_p) P_p`` with the
world-frame drift ``E_p = E_{p-1} + Ad(P_p) eta_p`` (first order), so
``Cov(E_p, E_q) = S_min(p, q)`` with the cumulative world covariances::

    S_p = sum_{k <= p} Ad(P_k) Sigma_k Ad(P_k)^T,    S_0 = 0.

A loop ``k`` between chain positions ``a < b`` (reversed loops are inverted first)
gives the world-frame discrepancy ``G_k = P_a z_k P_b^-1``; to first order
``G_k = Exp(d_k)`` with ``d_k = E_a - E_b + Ad(P_b) zeta_k``, so a true loop has
``G_k`` near the identity up to the drift of its own interval.  Two loops close the
cycle ``z_i (P_b_i^-1 P_b_j) z_j^-1 (P_a_j^-1 P_a_i)``, which is ``G_i G_j^-1``
conjugated by ``P_a_i``; its residual and covariance (first order) are::

    r_ij = Log(G_i G_j^-1)
    C_ij = Q_i + Q_j - 2 O_ij,   Q_k = (S_b - S_a) + Ad(P_b) Sigma_k Ad(P_b)^T,
    O_ij = S_min(b_i, b_j) - S_max(a_i, a_j)  if max(a) < min(b), else 0

(only the odometry in the symmetric difference of the two intervals enters; the
shared part cancels).  The pair is consistent when ``r^T C^-1 r <= chi2_3^-1(p)``.

The maximum clique is found by the greedy heuristic of Pattabiraman et al. ("Fast
algorithms for the maximum clique problem on massive graphs", 2015): from each of the
highest-degree vertices, repeatedly add the candidate with most neighbours among the
remaining candidates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from data import se2
from data.errors import UserError
from slam.pose_graph import PoseGraph, chi2_quantile

Array = NDArray[np.float64]
CHUNK = 200_000  # pairs per vectorised block of `consistency_matrix`
CLIQUE_STARTS = 32  # start vertices of the greedy maximum clique


def adjoint(poses: Array) -> Array:
    """gtsam ``Pose2.AdjointMap`` of (m, 3) poses: (m, 3, 3), ``T Exp(xi) = Exp(Ad xi) T``."""
    poses = np.atleast_2d(poses)
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    ad = np.zeros((len(poses), 3, 3))
    ad[:, 0, 0], ad[:, 0, 1], ad[:, 0, 2] = c, -s, poses[:, 1]
    ad[:, 1, 0], ad[:, 1, 1], ad[:, 1, 2] = s, c, -poses[:, 0]
    ad[:, 2, 2] = 1.0
    return ad


def logmap(poses: Array) -> Array:
    """gtsam ``Pose2.Logmap`` of (m, 3) poses: (m, 3) tangent vectors (v_x, v_y, omega).

    ``v = V(theta)^-1 t`` with ``V^-1 = (theta / 2) [[cot(theta/2), 1], [-1, cot(theta/2)]]``.
    """
    poses = np.atleast_2d(poses)
    theta = poses[:, 2]
    half = 0.5 * theta
    small = np.abs(theta) < 1e-6
    safe = np.where(small, 1.0, half)
    a = np.where(small, 1.0 - theta**2 / 12.0, safe / np.tan(safe))  # (theta/2) cot(theta/2)
    x, y = poses[:, 0], poses[:, 1]
    return np.stack([a * x + half * y, -half * x + a * y, theta], axis=1)


@dataclass(slots=True)
class LoopCycles:
    """Per-loop terms of the pairwise test (module docstring).

    Attributes:
        g: (m, 3) discrepancies ``G_k`` as poses.
        q: (m, 3, 3) covariances ``Q_k``.
        a, b: (m,) chain positions of each loop's earlier and later pose.
        s: (n, 3, 3) cumulative world covariances ``S_p`` of the chain.
    """

    g: Array
    q: Array
    a: NDArray[np.int64]
    b: NDArray[np.int64]
    s: Array

    def distances(self, i: NDArray[np.int64], j: NDArray[np.int64]) -> Array:
        """Squared Mahalanobis distances ``r^T C^-1 r`` of the cycles of loop pairs (i, j)."""
        r = logmap(se2.compose(self.g[i], se2.inverse(self.g[j])))
        lo = np.maximum(self.a[i], self.a[j])
        hi = np.minimum(self.b[i], self.b[j])
        overlap = (self.s[hi] - self.s[lo]) * (hi > lo)[:, None, None]
        cov = self.q[i] + self.q[j] - 2.0 * overlap
        return np.einsum("ma,ma->m", r, np.linalg.solve(cov, r[..., None])[..., 0])


def loop_cycles(graph: PoseGraph) -> LoopCycles:
    """The odometry chain's dead reckoning and drift covariances, and every loop's terms."""
    if graph.dim != 2:
        raise UserError("pairwise consistency is implemented for 2D pose graphs")
    keys = graph.keys
    position = {k: n for n, k in enumerate(keys)}
    n = len(keys)
    step = np.zeros((n, 3))
    sigma = np.zeros((n, 3, 3))
    seen = np.zeros(n, dtype=bool)
    for o in graph.odometry:
        p, q = position[o.i], position[o.j]
        if abs(p - q) != 1 or seen[max(p, q)]:
            continue
        cov = np.linalg.inv(o.information)
        if q < p:  # stored backwards: o = z^-1, covariance moved by Ad(z^-1)
            z = se2.inverse(o.measurement)
            ad = adjoint(z)[0]
            step[p], sigma[p] = z, ad @ cov @ ad.T
        else:
            step[q], sigma[q] = o.measurement, cov
        seen[max(p, q)] = True
    if not seen[1:].all():
        raise UserError(f"pairwise consistency needs odometry between consecutive poses; "
                        f"{int((~seen[1:]).sum())} poses have none")
    chain = np.empty((n, 3))
    chain[0] = graph.initial[keys[0]]
    for p in range(1, n):
        chain[p] = se2.compose(chain[p - 1], step[p])
    ad = adjoint(chain)
    s = np.cumsum(np.einsum("nab,nbc,ndc->nad", ad, sigma, ad), axis=0)
    m = len(graph.loops)
    g, q = np.empty((m, 3)), np.empty((m, 3, 3))
    a, b = np.empty(m, np.int64), np.empty(m, np.int64)
    for k, lp in enumerate(graph.loops):
        pi, pj = position[lp.i], position[lp.j]
        z, cov = lp.measurement, np.linalg.inv(lp.information)
        if pj < pi:
            pi, pj, z = pj, pi, se2.inverse(z)
            adz = adjoint(z)[0]
            cov = adz @ cov @ adz.T
        a[k], b[k] = pi, pj
        g[k] = se2.compose(se2.compose(chain[pi], z), se2.inverse(chain[pj]))
        adb = ad[pj]
        q[k] = s[pj] - s[pi] + adb @ cov @ adb.T
    return LoopCycles(g, q, a, b, s)


def consistency_matrix(graph: PoseGraph, probability: float = 0.99) -> NDArray[np.bool_]:
    """(m, m) symmetric: loops i and j pass the pairwise chi-square test (diagonal True)."""
    cycles = loop_cycles(graph)
    m = len(graph.loops)
    gate = chi2_quantile(probability, 3)
    adj = np.eye(m, dtype=bool)
    iu, ju = np.triu_indices(m, k=1)
    for start in range(0, len(iu), CHUNK):
        i, j = iu[start : start + CHUNK], ju[start : start + CHUNK]
        ok = cycles.distances(i, j) <= gate
        adj[i[ok], j[ok]] = True
        adj[j[ok], i[ok]] = True
    return adj


def max_clique(adj: NDArray[np.bool_], starts: int = CLIQUE_STARTS) -> NDArray[np.int64]:
    """A large clique of the symmetric boolean adjacency `adj` (greedy; module docstring).

    Returns the sorted vertex indices.  Exact on graphs whose maximum clique is found
    from one of its highest-degree members; a heuristic in general.
    """
    m = len(adj)
    if m == 0:
        return np.zeros(0, np.int64)
    degree = adj.sum(axis=1) - 1  # the diagonal is not an edge
    best: list[int] = []
    for v in np.argsort(-degree, kind="stable")[:starts]:
        if degree[v] + 1 <= len(best):
            break
        cand = np.flatnonzero(adj[v] & (degree + 1 > len(best)))
        cand = cand[cand != v]
        clique = [int(v)]
        count = adj[np.ix_(cand, cand)].sum(axis=1) - 1  # neighbours among the candidates
        while len(cand):
            u = int(np.argmax(count))
            clique.append(int(cand[u]))
            keep = adj[cand[u], cand]
            keep[u] = False
            gone = cand[~keep]
            cand, count = cand[keep], count[keep]
            if len(gone) and len(cand):
                count = count - adj[np.ix_(cand, gone)].sum(axis=1)
        if len(clique) > len(best):
            best = clique
    return np.array(sorted(best), dtype=np.int64)
