"""Reference poses for `loopclosure bench slam`: from relations, a TUM file or the log.

A loop closure is judged against reference poses of its two keyframes, looked up in
scan-index time: every keyframe is stamped with its scan index, so a log whose
clock runs backwards still orders queries correctly.

Reference poses from the relations (`relations_reference`)
----------------------------------------------------------
Relations are between scan stamps, rarely at keyframes, so the reference is a
small pose graph solved with Levenberg-Marquardt (`slam.optimize.optimize`, LAGO
start, Gaussian factors):

* nodes: every scan that is an end of a relation (stamp within
  `RELATION_TOLERANCE`, first scan of a duplicated stamp) and every keyframe of the
  pipeline between the first and the last such scan (in scan order); node key =
  scan index;
* relation edges: the relation's planar delta, standard deviations
  `RELATION_SIGMA` (1 cm, 1 cm, 0.25 deg): tight;
* gap edges between consecutive nodes (scan order): the *gap odometry* increment,
  with the `slam.odometry.MotionNoise` default wheel model applied to the path
  length and the summed turning along the gap (weak: 10 cm after 1 m);
* the first node is held at its gap-odometry pose.

The gap odometry is the pipeline's front-end odometry (``odometry_poses``: scan-to-map
ICP by default, computed before and independently of any loop closure).  A keyframe
has a reference pose when it is a relation node or when the two relation nodes
around it are at most `max_gap_m` (2 m) of gap-odometry path apart; loops touching
any other keyframe are *unverifiable* (counted).

Why not the logged wheel odometry: a robot often turns in place between two
relation nodes, and the wheel odometry's heading over such a turn can be several
degrees off even after the relations pin both ends, enough to call true loops
false.  The relations themselves are not exact either, so the reference is only
as good as they are; a true loop's tolerance (0.2 m, 2 deg) must exceed that.

Independence: nothing of the pipeline's loop closures enters this graph.  Its
only long-range constraints are the hand-verified relations; the gap odometry
fills at most `max_gap_m` of path between two relation nodes and comes from the
front end, which runs before the loop detector and never receives anything from
it or from the back end.  The pipeline's keyframes choose *where* the reference is
read, never its values.  The reference's own fit to the relations is reported
(``fit_trans_mean_m``, ``fit_rot_mean_deg``).

Other references
----------------
`keyframe_reference` reads a reference trajectory (a TUM file, or the poses logged
in the input, `logged_reference`) at the keyframes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data import se2
from data.errors import UserError
from data.types import Relation, Trajectory
from evaluation.relations_metric import lookup, relations_metric
from evaluation.slam_input import SlamInput, evaluation_stamps
from slam.odometry import MotionNoise

Array = NDArray[np.float64]

RELATION_SIGMA: tuple[float, float, float] = (0.01, 0.01, float(np.radians(0.25)))
"""Standard deviations (x [m], y [m], theta [rad]) of a relation edge of the reference."""
RELATION_TOLERANCE = 1e-3
"""Relation stamps match scan stamps within this [s] (as `relations_metric`)."""


def relations_in_range(relations: Sequence[Relation], stamps: Array) -> list[Relation]:
    """The relations whose two stamps are both scan stamps (within `RELATION_TOLERANCE`)."""
    if not relations:
        return []
    t1 = np.array([r.t1 for r in relations])
    t2 = np.array([r.t2 for r in relations])
    ok = (lookup(stamps, t1, RELATION_TOLERANCE) >= 0) & (
        lookup(stamps, t2, RELATION_TOLERANCE) >= 0
    )
    return [r for r, keep in zip(relations, ok, strict=True) if keep]


def _first_of_duplicates(stamps: Array) -> tuple[Array, NDArray[np.intp]]:
    """Sorted unique stamps and the index of the first scan of each."""
    order = np.argsort(stamps, kind="stable")
    uniq, first = np.unique(stamps[order], return_index=True)
    return uniq, order[first]


def trajectory_at_stamps(stamps: Array, poses: Array) -> Trajectory:
    """Per-scan poses as a trajectory sorted by stamp, first scan of a duplicated stamp."""
    uniq, idx = _first_of_duplicates(np.asarray(stamps, float))
    return Trajectory.from_xytheta(uniq, np.asarray(poses, float)[idx])


@dataclass(slots=True)
class RelationsReference:
    """Reference poses of keyframes solved from the relations (module docstring).

    Attributes:
        scan_index: ``(K,)`` scan index of every keyframe that has a reference pose.
        poses: ``(K, 3)`` their reference poses (frame of the gap odometry).
        nodes: poses in the graph; relations: relation edges used.
        keyframes: keyframes asked for; gap_odometry: which odometry filled the gaps.
        fit_trans_mean_m, fit_rot_mean_deg: relations metric of the solved nodes.
        node_index, node_poses: every node (scan index, pose), for plots.
        graph: the graph that was solved (`reference_graph`; None without relations),
            for the reference's own uncertainty (`relative_sigmas`).
    """

    scan_index: NDArray[np.intp]
    poses: Array
    nodes: int
    relations: int
    keyframes: int
    gap_odometry: str
    fit_trans_mean_m: float
    fit_rot_mean_deg: float
    node_index: NDArray[np.intp]
    node_poses: Array
    graph: ReferenceGraph | None = None

    def trajectory(self) -> Trajectory:
        """The keyframe reference in scan-index time (stamp = scan index)."""
        return Trajectory.from_xytheta(self.scan_index.astype(float), self.poses)

    def to_json(self) -> dict[str, Any]:
        """Summary figures."""
        return {
            "nodes": self.nodes,
            "relations": self.relations,
            "keyframes": self.keyframes,
            "keyframes_with_reference": len(self.scan_index),
            "gap_odometry": self.gap_odometry,
            "fit_trans_mean_m": self.fit_trans_mean_m,
            "fit_rot_mean_deg": self.fit_rot_mean_deg,
        }


def _gap_information(odometry: Array, a: NDArray[np.intp], b: NDArray[np.intp]) -> Array:
    """``(M, 3, 3)`` information of the gap edges ``a[m] -> b[m]`` (module docstring)."""
    step = se2.between(odometry[:-1], odometry[1:])
    path = np.concatenate([[0.0], np.cumsum(np.hypot(step[:, 0], step[:, 1]))])
    turn = np.concatenate([[0.0], np.cumsum(np.abs(step[:, 2]))])
    dist, rot = path[b] - path[a], turn[b] - turn[a]
    m = MotionNoise()
    var = np.column_stack([
        m.along_per_m**2 * dist + m.along_per_rad**2 * rot + m.min_sigma_xy**2,
        m.lateral_per_m**2 * dist + m.lateral_per_rad**2 * rot + m.min_sigma_xy**2,
        m.rot_per_m**2 * dist + m.rot_per_rad**2 * rot + m.min_sigma_theta**2,
    ])
    info = np.zeros((len(a), 3, 3))
    info[:, [0, 1, 2], [0, 1, 2]] = 1.0 / var
    return info


@dataclass(slots=True)
class ReferenceGraph:
    """The pose graph of the relations reference (module docstring), before solving.

    Attributes:
        graph: the `slam.pose_graph.PoseGraph`; key = position in `nodes`.
        nodes: ``(M,)`` scan index of every node, increasing.
        rel_nodes: ``(R,)`` scan indices that are an end of a relation.
        relations: the relations used (stamps among the scans, distinct ends).
    """

    graph: Any
    nodes: NDArray[np.intp]
    rel_nodes: NDArray[np.intp]
    relations: list[Relation]


def reference_graph(
    stamps: Array, relations: Sequence[Relation], keyframe_index: Sequence[int],
    odometry: Array,
) -> ReferenceGraph | None:
    """The graph `relations_reference` solves (None: no relation between two scans)."""
    from slam.pose_graph import PoseGraph

    uniq, first = _first_of_duplicates(stamps)
    rels = relations_in_range(relations, stamps)
    if not rels:
        return None
    i1 = first[lookup(uniq, np.array([r.t1 for r in rels]), RELATION_TOLERANCE)]
    i2 = first[lookup(uniq, np.array([r.t2 for r in rels]), RELATION_TOLERANCE)]
    keep = i1 != i2
    i1, i2 = i1[keep], i2[keep]
    rels = [r for r, k in zip(rels, keep, strict=True) if k]
    if len(i1) == 0:
        return None
    kf = np.asarray(keyframe_index, dtype=np.intp)
    rel_nodes = np.unique(np.concatenate([i1, i2]))
    lo, hi = rel_nodes[0], rel_nodes[-1]
    nodes = np.unique(np.concatenate([rel_nodes, kf[(kf >= lo) & (kf <= hi)]]))

    # Graph keys are node positions 0..M-1 (gtsam's LAGO wants consecutive keys).
    graph = PoseGraph(dim=2)
    for key, scan in enumerate(nodes):
        graph.add_pose(key, odometry[scan])
    graph.fixed = {0}
    a, b = nodes[:-1], nodes[1:]
    gap_delta = se2.between(odometry[a], odometry[b])
    for k, (d, info) in enumerate(zip(gap_delta, _gap_information(odometry, a, b), strict=True)):
        graph.add_odometry(k, k + 1, d, info)
    rel_info = np.diag(1.0 / np.square(RELATION_SIGMA))
    for i, j, r in zip(np.searchsorted(nodes, i1), np.searchsorted(nodes, i2), rels,
                       strict=True):
        graph.add_loop(int(i), int(j), se2.from_matrix(r.delta), rel_info)
    return ReferenceGraph(graph, nodes, rel_nodes, rels)


def relations_reference(
    stamps: Array,
    relations: Sequence[Relation],
    keyframe_index: Sequence[int],
    odometry: Array,
    *,
    gap_odometry: str = "front end",
    max_gap_m: float = 2.0,
) -> RelationsReference:
    """Reference poses of the keyframes from `relations` (module docstring).

    Args:
        stamps: ``(N,)`` scan stamps [s] (as logged).
        relations: relations (those with a stamp not among `stamps` are ignored).
        keyframe_index: scan index of every keyframe.
        odometry: ``(N, 3)`` gap odometry, one pose per scan.
        gap_odometry: its name, for the report.
        max_gap_m: longest gap-odometry path between two relation nodes over which a
            keyframe still gets a reference pose [m].
    """
    from slam.optimize import optimize

    stamps = np.asarray(stamps, float)
    odometry = np.asarray(odometry, float).reshape(-1, 3)
    kf = np.asarray(keyframe_index, dtype=np.intp)
    built = reference_graph(stamps, relations, kf, odometry)
    if built is None:
        return RelationsReference(np.zeros(0, np.intp), np.zeros((0, 3)), 0, 0, len(kf),
                                  gap_odometry, float("nan"), float("nan"),
                                  np.zeros(0, np.intp), np.zeros((0, 3)))
    nodes, rel_nodes, rels = built.nodes, built.rel_nodes, built.relations
    solved = optimize(built.graph, kernel="none", method="lm", init="lago").poses
    node_poses = np.array([solved[k] for k in range(len(nodes))])

    at_rel = np.searchsorted(nodes, rel_nodes)
    fit = relations_metric(Trajectory.from_xytheta(stamps[rel_nodes], node_poses[at_rel]), rels,
                           RELATION_TOLERANCE)
    # Keyframes covered: relation nodes, or bracketed by relation nodes close in path.
    step = se2.between(odometry[:-1], odometry[1:])
    path = np.concatenate([[0.0], np.cumsum(np.hypot(step[:, 0], step[:, 1]))])
    lo, hi = rel_nodes[0], rel_nodes[-1]
    inside = kf[(kf >= lo) & (kf <= hi)]
    after = np.searchsorted(rel_nodes, inside, side="left")
    before = np.searchsorted(rel_nodes, inside, side="right") - 1
    on_node = rel_nodes[np.minimum(after, len(rel_nodes) - 1)] == inside
    gap = path[rel_nodes[np.minimum(after, len(rel_nodes) - 1)]] - path[rel_nodes[before]]
    covered = np.unique(inside[on_node | (gap <= max_gap_m)])
    pos = np.searchsorted(nodes, covered)
    return RelationsReference(
        scan_index=covered,
        poses=node_poses[pos],
        nodes=len(nodes),
        relations=len(rels),
        keyframes=len(kf),
        gap_odometry=gap_odometry,
        fit_trans_mean_m=fit.trans_abs_mean,
        fit_rot_mean_deg=fit.rot_abs_mean_deg,
        node_index=nodes,
        node_poses=node_poses,
        graph=built,
    )


def relative_sigmas(built: ReferenceGraph, node_poses: Array, pairs: ArrayLike) -> Array:
    """``(n, 3)`` standard deviations (x, y [m], theta [rad]) of the reference's
    relative pose ``between(pose(a), pose(b))`` for scan-index pairs ``(a, b)`` (both
    nodes of `built`), in a's frame, from the graph's Gaussian marginals at
    `node_poses` (``(M, 3)``, the solved nodes).

    With ``r = a^-1 b`` and right-perturbed poses, ``dr = -Ad(r^-1) da + db`` (Ad the
    SE(2) adjoint ``[[R, (y, -x)^T], [0, 1]]``), so
    ``Sigma_r = J Sigma_ab J^T``, ``J = [-Ad(r^-1), I]`` with ``Sigma_ab`` the 6x6 joint
    marginal covariance of the two poses.  How far the relations pin the relative
    pose of two places that no relation joins directly: a chain of n relations of
    heading sigma s gives about ``s sqrt(n)``.

    Raises:
        UserError: a pair's scan is not a node of the graph.
    """
    import gtsam

    pairs = np.asarray(pairs, dtype=np.intp).reshape(-1, 2)
    pos = np.searchsorted(built.nodes, pairs)
    pos = np.minimum(pos, len(built.nodes) - 1)
    if not np.all(built.nodes[pos] == pairs):
        raise UserError("relative_sigmas: a scan of the pairs is not a reference node")
    graph = built.graph
    factors, _ = graph.factor_graph()
    poses = {k: np.asarray(node_poses[k], float) for k in range(len(built.nodes))}
    marginals = gtsam.Marginals(factors, graph.gtsam_values(poses))
    out = np.zeros((len(pairs), 3))
    for n, (a, b) in enumerate(pos.tolist()):
        if a == b:
            continue
        keys = gtsam.KeyVector([a, b])
        cov = marginals.jointMarginalCovariance(keys).fullMatrix()
        r_inv = se2.between(node_poses[b], node_poses[a])  # r^-1 = b^-1 a
        c, s = np.cos(r_inv[2]), np.sin(r_inv[2])
        ad = np.array([[c, -s, r_inv[1]], [s, c, -r_inv[0]], [0.0, 0.0, 1.0]])
        jac = np.hstack([-ad, np.eye(3)])
        out[n] = np.sqrt(np.maximum(np.diag(jac @ cov @ jac.T), 0.0))
    return out


def keyframe_reference(
    reference: Trajectory, eval_stamps: Array, keyframe_index: Sequence[int],
    max_diff: float = 0.01,
) -> Trajectory:
    """A reference trajectory's poses at the keyframes, re-stamped with their scan index.

    Keyframes whose (evaluation) stamp the reference lacks (within `max_diff` s) are left
    out; their loops become unverifiable.
    """
    kf = np.asarray(keyframe_index, dtype=np.intp)
    hit = lookup(reference.stamps, np.asarray(eval_stamps, float)[kf], max_diff)
    ok = hit >= 0
    return Trajectory(kf[ok].astype(float), reference.poses[hit[ok]])


def logged_reference(data: SlamInput) -> Trajectory:
    """The poses logged in the input (GMapping-corrected logs) as a reference trajectory,
    stamped by `evaluation_stamps` and sorted."""
    if data.logged_poses is None:
        raise UserError(f"{data.name}: --reference-from-log needs odometry poses on every scan")
    if data.odometry_noise is None:
        raise UserError(
            "--reference-from-log needs --odometry-noise SEED: without it the logged poses "
            "are both the odometry every method starts from and the reference"
        )
    stamps, _ = evaluation_stamps(data.stamps)
    return trajectory_at_stamps(stamps, data.logged_poses)

