"""Every file format and every data-set generator: the one place that parses bytes.

`open_source(path)` opens any scan source (a CARMEN log, a ROS1 bag, a ROS2 bag in
sqlite3 or MCAP) by its content and yields `Scan` (or `PointCloud`) objects in the
order of motion; `simulate_run` (in `data.sim`) makes the embedded simulated world.
Readers and writers of each format live in their own module (`data.carmen`,
`data.rosbag`, `data.g2o`, `data.trajectory_io`, `data.relations`), writers all go
through `data.atomic_write`.

Nothing in `data` imports `loopclosure`, `slam` or `evaluation`.
"""

from __future__ import annotations

from data.errors import DataError, DataWarning, LoopClosureError, UserError
from data.sources import ScanSource, describe, open_source
from data.types import (
    GraphEdge,
    PointCloud,
    PoseGraphData,
    Relation,
    Scan,
    SourceInfo,
    Trajectory,
)

__all__ = [
    "DataError",
    "DataWarning",
    "GraphEdge",
    "LoopClosureError",
    "PointCloud",
    "PoseGraphData",
    "Relation",
    "Scan",
    "ScanSource",
    "SourceInfo",
    "Trajectory",
    "UserError",
    "describe",
    "open_source",
]
