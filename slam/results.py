"""Writing a `MappingResult` into the output folder (see `slam.outputs` for the formats)."""

from __future__ import annotations

import gc
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from data.atomic_write import output_dir
from data.g2o import write_g2o
from data.trajectory_io import write_tum
from data.types import Trajectory
from slam.json_io import write_json
from slam.map_io import render_png
from slam.map_io import write_map as write_map_files
from slam.memory import peak_rss_mb, release_free_memory
from slam.occupancy_map import MapConfig, build_occupancy_grid
from slam.outputs import LoopRecord, output_stamps, write_loops_csv, write_trajectories
from slam.pipeline import MappingResult
from slam.session_file import FILE_NAME as SESSION_FILE
from slam.session_file import write_saved_map


def loop_records(result: MappingResult) -> list[LoopRecord]:
    """One `LoopRecord` per candidate the run tried."""
    records = []
    for e in result.loops:
        c = e.candidate
        v = c.verification
        records.append(
            LoopRecord(
                keyframe_a=c.match,
                keyframe_b=c.query,
                stamp_a=e.stamp_match,
                stamp_b=e.stamp_query,
                search=c.source,
                prior=c.prior,
                accepted=c.accepted and not e.rejected_by_gnc,
                reason="rejected by GNC" if e.rejected_by_gnc else c.reason,
                prefilter_distance=c.prefilter_distance,
                prefilter_rank=c.prefilter_rank,
                verifier_distance=min(c.verifier_distances.values(), default=float("nan")),
                score=c.fused_score,
                fitness=v.fitness if v else float("nan"),
                rms=v.rms if v else float("nan"),
                inlier_ratio=v.inlier_ratio if v else float("nan"),
                consistency=v.consistency if v else float("nan"),
                relative=c.relative,
                rejected_by_gnc=e.rejected_by_gnc,
            )
        )
    return records


def _loop_segments(result: MappingResult, poses: dict[int, Any], search: str) -> np.ndarray:
    """``(L, 4)`` map-frame positions of the two keyframes of each accepted loop that
    `search` proposed, under `poses` (keyframe id -> pose)."""
    return np.array([
        np.r_[poses[e.candidate.match][:2], poses[e.candidate.query][:2]]
        for e in result.accepted_loops if e.candidate.source == search
    ]).reshape(-1, 4)


def _write_maps(out: Path, result: MappingResult, map_config: MapConfig | None) -> dict[str, str]:
    """``map.pgm/.yaml/.png`` at the optimised poses, and ``map_before.png``: the map the
    front end alone made (keyframes at their odometry poses), with the loops that were
    then found drawn between the odometry poses: the drift loop closure removed."""
    files: dict[str, str] = {}
    keyframes = result.keyframes
    scans = [k.scan for k in keyframes]
    for stem, poses, trajectory in (
        ("map", result.keyframe_poses, result.scan_poses),
        ("map_before", {k.id: np.asarray(k.odom_pose) for k in keyframes},
         result.odometry_poses),
    ):
        grid = build_occupancy_grid(
            scans, np.array([poses[k.id] for k in keyframes]), config=map_config
        )
        overlays = {
            "trajectory_xy": trajectory[:, :2],
            "loops": _loop_segments(result, poses, "pose"),
            "appearance_loops": _loop_segments(result, poses, "appearance"),
        }
        if stem == "map":
            paths = write_map_files(grid, out, **overlays)
            files.update({f"map_{k}": str(v) for k, v in paths.items()})
        else:
            files["map_before_png"] = str(render_png(grid, out / f"{stem}.png", **overlays))
        del grid
        release_free_memory()
    return files


def write_results(
    out: str | Path,
    result: MappingResult,
    source: str,
    *,
    wall_s: float,
    write_map: bool = True,
    map_config: MapConfig | None = None,
) -> dict[str, Any]:
    """Write every output file of a run; returns the summary (also in summary.json)."""
    start = time.perf_counter()
    # A finished Mapper's state (place database, registration targets, submaps) sits in
    # reference cycles that only a full collection frees: free it before the maps are
    # drawn on top of it.
    gc.collect()
    release_free_memory()
    out = output_dir(out)
    stamps, stamp_rule = output_stamps(result.scan_stamps, source)
    files: dict[str, str] = {}
    if len(stamps):
        files.update({k: str(v) for k, v in write_trajectories(
            out, stamps, result.scan_poses).items()})
        write_trajectories_odometry = out / "odometry.tum"
        order = np.argsort(stamps, kind="stable")
        write_tum(write_trajectories_odometry,
                  Trajectory.from_xytheta(stamps[order], result.odometry_poses[order]))
        files["odometry_tum"] = str(write_trajectories_odometry)
    graph = result.smoother.graph
    if graph.initial:
        kept = [i for i in range(len(graph.loops)) if i not in result.loop_outliers]
        g = graph.to_g2o(result.keyframe_poses)
        kept_pairs = {(graph.loops[i].i, graph.loops[i].j) for i in kept}
        g.edges = [
            edge for edge in g.edges
            if edge.j == edge.i + 1 or (edge.i, edge.j) in kept_pairs
        ]
        write_g2o(out / "graph.g2o", g)
        files["g2o"] = str(out / "graph.g2o")
    write_loops_csv(out / "loops.csv", loop_records(result))
    files["loops"] = str(out / "loops.csv")
    if result.saved_map is not None:
        files["session"] = str(write_saved_map(out / SESSION_FILE, result.saved_map))
    write_json(out / "sessions.json", {"sessions": [asdict(s) for s in result.sessions]})
    files["sessions"] = str(out / "sessions.json")
    if write_map and result.keyframes:
        files.update(_write_maps(out, result, map_config))
    accepted = [e for e in result.loops if e.candidate.accepted]
    timings = dict(result.timings)
    timings["output"] = time.perf_counter() - start
    summary: dict[str, Any] = {
        "source": source,
        "scans": len(result.scan_stamps),
        "keyframes": len(result.keyframes),
        "loops_proposed": len(result.loops),
        "loops_accepted": len(accepted) - sum(e.rejected_by_gnc for e in accepted),
        "loops_rejected_by_check": len(result.loops) - len(accepted),
        "loops_rejected_by_gnc": sum(e.rejected_by_gnc for e in accepted),
        "loops_by_stage": {
            s: sum(1 for e in accepted if e.candidate.source == s and not e.rejected_by_gnc)
            for s in ("pose", "appearance")
        },
        "wall_s": wall_s + timings["output"],
        "peak_rss_mb": peak_rss_mb(),
        "peak_rss_mb_worker": result.worker_peak_rss_mb,
        "timings_s": timings,
        "odometry_status": result.odometry_status,
        "trajectory_stamps": stamp_rule,
        "interrupted": result.interrupted,
        "sessions": [asdict(s) for s in result.sessions],
        "files": files,
    }
    write_json(out / "summary.json", summary)
    return summary
