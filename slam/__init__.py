"""The host: odometry front ends, the gtsam pose graph, the mapper pipeline, maps and the CLI.

A library user maps a log in three lines::

    from data import open_source
    from slam import Mapper, write_results

    result = Mapper().run(open_source("intel.clf.bz2"))

`Mapper` runs the pipeline (odometry -> keyframes -> pose graph -> loop closures
from `loopclosure` -> iSAM2 -> final GNC) under one `PipelineConfig`; the
`MappingResult` it returns holds every pose, loop candidate and timing, and
`write_results` writes it as the CLI does (TUM/KITTI trajectories, g2o, loops.csv,
a ROS map_server map, summary.json, the saved map ``session.npz``);
``Mapper(saved=read_saved_map(folder))`` continues a saved map with a new log
(`slam.sessions`).  `PoseGraph` with `slam.optimize.optimize` is
the back end on its own (batch LM with a robust kernel, or GNC).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from data.lazy_exports import lazy_exports

if TYPE_CHECKING:
    from slam.config import BackendConfig, PipelineConfig, SubmapConfig
    from slam.mapping_result import LoopEvent, MappingResult
    from slam.occupancy_map import MapConfig, OccupancyGrid, build_occupancy_grid
    from slam.optimization_result import OptimizationResult
    from slam.pipeline import Mapper
    from slam.pose_graph import PoseGraph, RobustKernel
    from slam.results import write_results
    from slam.session_file import SavedMap, SessionInfo, read_saved_map, write_saved_map
    from slam.sessions import SessionsConfig
    from slam.smoothers import IncrementalSmoother

# Where each exported name lives.  Loaded on first use, so the CLI (which lives in
# `slam.cli` and so imports this package first) starts without gtsam and scipy.
_HOMES = {
    "BackendConfig": "slam.config",
    "PipelineConfig": "slam.config",
    "SubmapConfig": "slam.config",
    "MapConfig": "slam.occupancy_map",
    "OccupancyGrid": "slam.occupancy_map",
    "build_occupancy_grid": "slam.occupancy_map",
    "IncrementalSmoother": "slam.smoothers",
    "OptimizationResult": "slam.optimization_result",
    "LoopEvent": "slam.mapping_result",
    "Mapper": "slam.pipeline",
    "MappingResult": "slam.mapping_result",
    "PoseGraph": "slam.pose_graph",
    "RobustKernel": "slam.pose_graph",
    "write_results": "slam.results",
    "SavedMap": "slam.session_file",
    "SessionInfo": "slam.session_file",
    "read_saved_map": "slam.session_file",
    "write_saved_map": "slam.session_file",
    "SessionsConfig": "slam.sessions",
}


__getattr__, __dir__ = lazy_exports(__name__, globals(), _HOMES)

__all__ = [
    "BackendConfig",
    "IncrementalSmoother",
    "LoopEvent",
    "MapConfig",
    "Mapper",
    "MappingResult",
    "OccupancyGrid",
    "OptimizationResult",
    "PipelineConfig",
    "PoseGraph",
    "RobustKernel",
    "SavedMap",
    "SessionInfo",
    "SessionsConfig",
    "SubmapConfig",
    "build_occupancy_grid",
    "read_saved_map",
    "write_results",
    "write_saved_map",
]
