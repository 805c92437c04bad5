"""Multi-session mapping: a saved map continued by a new log with an unknown start pose.

The mapper (`slam.pipeline.Mapper` with ``saved=``) restores the saved keyframes as
keys ``0 .. K-1`` of its graph and place database, and maps the new log as keys
``K ..`` in the frame of its own odometry.  Until the two are joined, the place
database proposes saved keyframes for every new one and the geometric check tests
them with no pose prior (`loopclosure.loop_detector`, "Sessions"); an accepted
inter-session loop does not enter the graph yet but waits (`PendingLoop`).  Each one
implies the transform of the new session's frame in the map frame,

    T = A (+) z (+) B^-1            (A: saved keyframe's pose in the map frame,
                                     B: new keyframe's pose in the session frame,
                                     z: verified pose of B in A's frame)

and the sessions are joined when `SessionsConfig.join_loops` of them, from as many
distinct new keyframes, agree (`consistent_group`): each one's T predicts every
other loop's new keyframe, ``T_p (+) B_q``, within `join_distance` [m] and
`join_angle_deg` of where that loop measured it, ``A_q (+) z_q``: pairwise
consistency as in PCM (Mangelson et al. 2018), a clique that one look-alike place
cannot form.  Then one graph is built from both (the new poses moved by T), the
group's loops are added as loop factors (the others are rejected, "inconsistent with
the session join"), and from there on both sessions are one log to the searches.
The new keyframes from before the join, which met the saved map only in their own
frame, are then checked against it once more by the pose search, nearest to the join
first (`LoopClosureDetector.detect_pose`): the loops a single run would have closed
there with a prior.

This module holds the pieces that do not need the mapper: saved keyframes back as
`Keyframe` objects, the consistency test, and a finished run as a `SavedMap`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from data import se2
from slam.keyframes import Keyframe
from slam.session_file import SavedMap, SessionInfo, pack_ragged

Array = NDArray[np.float64]


@dataclass(slots=True)
class SessionsConfig:
    """When a new session is joined to the saved map (module docstring).

    Attributes:
        join_loops: mutually consistent inter-session loops needed, from that many
            distinct keyframes of the new session.
        join_distance: two loops are consistent when each one's transform predicts the
            other's keyframe within this distance [m] ...
        join_angle_deg: ... and this angle [deg].
    """

    join_loops: int = 3
    join_distance: float = 0.5
    join_angle_deg: float = 5.0


@dataclass(slots=True)
class PendingLoop:
    """An accepted inter-session loop waiting for the join.

    Attributes:
        event: the pipeline's `LoopEvent` of the candidate.
        match: saved keyframe key (map frame).
        query: new keyframe key (session frame).
        relative: ``(3,)`` verified pose of `query` in `match`'s frame.
    """

    event: object
    match: int
    query: int
    relative: Array


def implied_transform(saved_pose: Array, relative: Array, session_pose: Array) -> Array:
    """``T = A (+) z (+) B^-1``: the session frame in the map frame (module docstring)."""
    return se2.compose(se2.compose(saved_pose, relative), se2.inverse(session_pose))


def consistent_group(
    pending: list[PendingLoop], poses: Array, config: SessionsConfig
) -> list[int]:
    """Indices of the largest set of pairwise-consistent pending loops (module
    docstring), or [] when no set of `join_loops` loops from distinct keyframes agrees.

    `poses` are the current estimates of every key: saved keys in the map frame, new
    keys in the session frame.
    """
    n = len(pending)
    if n < config.join_loops:
        return []
    a = np.array([poses[p.match] for p in pending])
    b = np.array([poses[p.query] for p in pending])
    z = np.array([p.relative for p in pending])
    measured = se2.compose(a, z)  # each loop's new keyframe, in the map frame
    t = implied_transform(a, z, b)
    ok = np.zeros((n, n), dtype=bool)
    for i in range(n):  # n is a handful: the loops accepted before a join
        predicted = se2.compose(np.broadcast_to(t[i], (n, 3)), b)
        d = np.hypot(*(predicted[:, :2] - measured[:, :2]).T)
        da = np.abs(se2.wrap_angle(predicted[:, 2] - measured[:, 2]))
        ok[i] = (d <= config.join_distance) & (da <= np.radians(config.join_angle_deg))
    ok &= ok.T
    best: list[int] = []
    for i in np.argsort(-ok.sum(axis=1), kind="stable"):
        group = [int(i)]
        for j in np.flatnonzero(ok[i]):
            if j != i and all(ok[j, g] for g in group):
                group.append(int(j))
        if len(group) > len(best):
            best = group
    queries = {pending[g].query for g in best}
    return sorted(best) if len(queries) >= config.join_loops else []


def saved_keyframes(saved: SavedMap) -> list[Keyframe]:
    """The saved keyframes as `Keyframe` objects (ids = keys; odometry poses in the map
    frame, which keeps every relative pose within a session)."""
    out = []
    for k in range(saved.n_keyframes):
        scan = saved.keyframe_scan(k)
        out.append(Keyframe(
            id=k, stamp=float(saved["kf_stamp"][k]), scan_index=int(saved["kf_scan_index"][k]),
            odom_pose=np.asarray(saved["kf_odom"][k], float), scan=scan, points=scan.points(),
            delta=np.asarray(saved["kf_delta"][k], float),
            covariance=np.asarray(saved["kf_cov"][k], float),
        ))
    return out


def session_spans(sessions: NDArray[np.integer]) -> dict[int, tuple[int, int]]:
    """session -> (first key, last key) of keyframes labelled by `sessions` (in order)."""
    out: dict[int, tuple[int, int]] = {}
    for k, s in enumerate(np.asarray(sessions).tolist()):
        lo, _ = out.get(s, (k, k))
        out[s] = (lo, k)
    return out


def build_saved_map(
    *,
    config: dict,
    sessions: list[SessionInfo],
    keyframes: list[Keyframe],
    keyframe_sessions: NDArray[np.integer],
    keyframe_poses: dict[int, Array],
    place_scans: list,
    odometry: list,
    loops: list,
    scan_stamps: Array,
    scan_sessions: NDArray[np.integer],
    scan_keyframes: NDArray[np.integer],
    scan_poses: Array,
    scan_odometry: Array,
) -> SavedMap:
    """A `SavedMap` of a finished run (keys ``0..K-1`` = positions in `keyframes`).

    `odometry` / `loops` are `slam.pose_graph.Constraint` lists (kept loops only);
    `place_scans` the detector's `place_scan` of every key (None: not described);
    `scan_keyframes` the key each scan hangs from; poses in the map frame.
    """
    pose = np.array([keyframe_poses[k.id] for k in keyframes]).reshape(-1, 3)
    scans = [k.scan for k in keyframes]
    ranges, offsets = pack_ragged([s.ranges for s in scans])
    angles, _ = pack_ragged([s.angles for s in scans])
    places = list(place_scans)
    p_ranges, p_offsets = pack_ragged([np.zeros(0) if p is None else p.ranges for p in places])
    p_angles, _ = pack_ragged([np.zeros(0) if p is None else p.angles for p in places])
    kf_of = np.asarray(scan_keyframes, dtype=np.int64)
    rel = (se2.between(pose[kf_of], np.asarray(scan_poses, float)).reshape(-1, 3)
           if len(kf_of) and len(pose) else np.zeros((len(kf_of), 3)))

    def constraints(cs: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ij = np.array([[c.i, c.j] for c in cs], dtype=np.int64).reshape(-1, 2)
        z = np.array([c.measurement for c in cs], dtype=float).reshape(-1, 3)
        info = np.array([c.information for c in cs], dtype=float).reshape(-1, 3, 3)
        return ij, z, info

    o_ij, o_z, o_info = constraints(odometry)
    l_ij, l_z, l_info = constraints(loops)
    arrays = {
        "kf_session": np.asarray(keyframe_sessions, dtype=np.int64),
        "kf_stamp": np.array([k.stamp for k in keyframes], dtype=float),
        "kf_scan_index": np.array([k.scan_index for k in keyframes], dtype=np.int64),
        "kf_odom": np.array([k.odom_pose for k in keyframes], dtype=float).reshape(-1, 3),
        "kf_pose": pose,
        "kf_delta": np.array([k.delta for k in keyframes], dtype=float).reshape(-1, 3),
        "kf_cov": np.array([k.covariance for k in keyframes], dtype=float).reshape(-1, 3, 3),
        "scan_ranges": ranges, "scan_angles": angles, "scan_offsets": offsets,
        "scan_max_range": np.array([s.max_range for s in scans], dtype=float),
        "scan_min_range": np.array([s.min_range for s in scans], dtype=float),
        "place_ranges": p_ranges, "place_angles": p_angles, "place_offsets": p_offsets,
        "place_max_range": np.array([0.0 if p is None else p.max_range for p in places]),
        "place_min_range": np.array([0.0 if p is None else p.min_range for p in places]),
        "odom_ij": o_ij, "odom_z": o_z, "odom_info": o_info,
        "loop_ij": l_ij, "loop_z": l_z, "loop_info": l_info,
        "sc_stamp": np.asarray(scan_stamps, dtype=float),
        "sc_session": np.asarray(scan_sessions, dtype=np.int64),
        "sc_keyframe": kf_of,
        "sc_relative": rel,
        "sc_odom": np.asarray(scan_odometry, dtype=float).reshape(-1, 3),
    }
    return SavedMap(config=config, sessions=sessions, arrays=arrays)
