"""One entry point for every scan source: `open_source(path)` picks the reader.

A scan source is anything with a `path`, a `format` name, an `info()` that
describes it, a `progress()` that says how far an iteration has got, and an
iterator that yields `Scan` (or `PointCloud`) objects one at a time, in the order
of motion.  Readers stream: a 1 GB log is never loaded at once.  `info()` may need
a whole pass; a progress display uses `progress()`, whose total is known without
reading (file size, or a bag index's message count).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Protocol, runtime_checkable

from data.errors import DataError
from data.progress import ReadProgress
from data.types import PointCloud, Scan, SourceInfo


@runtime_checkable
class ScanSource(Protocol):
    """What every reader offers (CARMEN log, ROS1/ROS2/MCAP bag, simulator output)."""

    path: Path
    format: str

    def __iter__(self) -> Iterator[Scan | PointCloud]:
        """Scans in the order of motion, odometry (if any) attached to each."""
        ...

    def info(self) -> SourceInfo:
        """Counts and sensor description (may read the whole file once)."""
        ...

    def progress(self) -> ReadProgress:
        """How far the latest iteration has read, against a total known up front."""
        ...


def open_source(
    path: str | Path,
    *,
    topic: str | None = None,
    odom_topic: str | None = None,
    strict: bool = False,
) -> ScanSource:
    """The reader for `path`, chosen by content: ROS bag (file or folder) or CARMEN log.

    Raises `DataError` naming the file when it is missing or of no known scan format
    (a g2o graph or a trajectory is recognised and refused with a hint).
    """
    from data.carmen import CarmenLog, is_carmen
    from data.g2o import is_g2o
    from data.rosbag import RosBag, is_rosbag

    path = Path(path)
    if not path.exists():
        raise DataError(path, "no such file or directory")
    if is_rosbag(path):
        return RosBag(path, topic=topic, odom_topic=odom_topic, strict=strict)
    if path.is_dir():
        raise DataError(path, "is a directory but not a ROS2 bag (no metadata.yaml)")
    if topic is not None:
        raise DataError(path, f"--topic {topic} given, but this is not a ROS bag")
    if is_carmen(path):
        return CarmenLog(path, strict=strict)
    if is_g2o(path):
        raise DataError(path, "is a g2o pose graph, not a scan log (try `loopclosure optimize`)")
    raise DataError(
        path,
        "unknown format: expected a CARMEN log (.clf/.log, plain, .gz or .bz2) "
        "or a ROS bag (ROS1 .bag, ROS2 folder, .db3 or .mcap)",
    )


def describe(path: str | Path, *, topic: str | None = None, strict: bool = False) -> SourceInfo:
    """What `loopclosure info` reports: any scan source, or a g2o pose graph."""
    from data.g2o import graph_info, is_g2o, read_g2o

    path = Path(path)
    if path.is_file() and is_g2o(path):
        graph = read_g2o(path)
        meta = graph_info(graph)
        return SourceInfo(format=f"g2o-se{graph.dim}", path=str(path), extra=meta)
    return open_source(path, topic=topic, strict=strict).info()
