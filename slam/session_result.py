"""A finished run's sessions: the `MappingResult` of every session and its saved map.

`complete_sessions` is the last step of `slam.pipeline.Mapper.finish`:

- a run without a saved map is one session, the first of its own saved map;
- a new session that was joined (`slam.sessions`) makes a result of *all* sessions in
  the map frame: the saved keyframes and scans (each scan moved with the keyframe it
  hangs from), then the new ones, keys as in the joint graph;
- a new session that was never joined is written in its own frame, alone (keys from
  0, its inter-session candidates left out): its saved map is a map of its own, and
  the saved map it was given is not touched (a warning says so).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from data import se2
from data.errors import warn
from slam.config_io import to_dict
from slam.pose_graph import Constraint, PoseGraph
from slam.session_file import SessionInfo
from slam.sessions import build_saved_map


def _shifted(graph: PoseGraph, offset: int) -> PoseGraph:
    """`graph` with every key moved by `offset`."""
    def move(c: Constraint) -> Constraint:
        return dataclasses.replace(c, i=c.i + offset, j=c.j + offset)

    return PoseGraph(
        dim=graph.dim, initial={k + offset: v for k, v in graph.initial.items()},
        odometry=[move(c) for c in graph.odometry], loops=[move(c) for c in graph.loops],
        fixed={k + offset for k in graph.fixed},
    )


def complete_sessions(mapper: Any, result: Any, poses: dict[int, Any]) -> Any:
    """`result` (the `slam.pipeline.MappingResult` of `mapper`'s new session: its scans,
    its keyframes with their own ids; `poses` of every key of the graph) completed as
    the module docstring says, with `sessions` and `saved_map` set.  (Typed loosely:
    `slam.pipeline` imports this module.)"""
    saved, base = mapper._saved, mapper._base
    detector = mapper.detector
    new_kfs = result.keyframes
    n_scans = len(result.scan_stamps)
    scan_kf = np.maximum(np.asarray(mapper.keyframes.scan_keyframe, dtype=np.int64), 0)
    graph = result.smoother.graph
    name = mapper.name
    if saved is not None and mapper.joined:
        transform = se2.compose(poses[base], se2.inverse(new_kfs[0].odom_pose))
        keyframes = mapper._old + [
            dataclasses.replace(k, id=base + k.id, odom_pose=se2.compose(transform, k.odom_pose))
            for k in new_kfs
        ]
        key_pose = np.array([poses[k] for k in range(len(keyframes))])
        old_scans = se2.compose(key_pose[saved["sc_keyframe"]], saved["sc_relative"])
        inter = sum(1 for e in result.accepted_loops if e.candidate.match < base)
        session = len(saved.sessions)
        sessions = [dataclasses.replace(s) for s in saved.sessions] + [SessionInfo(
            name=name, scans=n_scans, keyframes=len(new_kfs), joined=True,
            joined_at_keyframe=mapper._joined_at, joined_after_m=mapper._joined_after,
            loops=inter, transform=[float(v) for v in transform])]
        result = dataclasses.replace(
            result,
            keyframes=keyframes,
            keyframe_poses={k: np.asarray(poses[k], float) for k in range(len(keyframes))},
            scan_stamps=np.concatenate([saved["sc_stamp"], result.scan_stamps]),
            scan_poses=np.vstack([old_scans, result.scan_poses]),
            odometry_poses=np.vstack([
                saved["sc_odom"], se2.compose(transform, result.odometry_poses)
                if n_scans else np.zeros((0, 3))]),
            sessions=sessions,
        )
        kf_sessions = np.concatenate([saved["kf_session"], np.full(len(new_kfs), session)])
        scan_sessions = np.concatenate([saved["sc_session"], np.full(n_scans, session)])
        scan_keyframes = np.concatenate([saved["sc_keyframe"], scan_kf + base])
        file_sessions = sessions
    else:
        own = SessionInfo(name=name, scans=n_scans, keyframes=len(new_kfs), joined=True)
        sessions = [own]
        if saved is not None:
            warn(f"{name or 'new session'}: it never revisited the saved map: it is written "
                 "in its own frame, alone, and the saved map is left as it was")
            result.loops = [e for e in result.loops if e.candidate.match >= base]
            for e in result.loops:
                e.candidate.match -= base
                e.candidate.query -= base
            result.smoother.graph = _shifted(graph, -base)
            sessions = [dataclasses.replace(s) for s in saved.sessions] + [dataclasses.replace(
                own, joined=False, joined_at_keyframe=None, joined_after_m=None,
                transform=None)]
        result.sessions = sessions
        keyframes = new_kfs
        kf_sessions = np.zeros(len(new_kfs), dtype=np.int64)
        scan_sessions = np.zeros(n_scans, dtype=np.int64)
        scan_keyframes = scan_kf
        file_sessions = [own]
    graph = result.smoother.graph
    kept = [c for n, c in enumerate(graph.loops) if n not in result.loop_outliers]
    first_key = 0 if mapper.joined else base
    result.saved_map = build_saved_map(
        config=to_dict(mapper.config),
        sessions=file_sessions,
        keyframes=keyframes,
        keyframe_sessions=kf_sessions,
        keyframe_poses=result.keyframe_poses,
        place_scans=[detector.place_scan(first_key + n) for n in range(len(keyframes))],
        odometry=graph.odometry,
        loops=kept,
        scan_stamps=result.scan_stamps,
        scan_sessions=scan_sessions,
        scan_keyframes=scan_keyframes,
        scan_poses=result.scan_poses,
        scan_odometry=result.odometry_poses,
    )
    return result
