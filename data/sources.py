"""One entry point for every scan source: `open_source(path)` picks the reader.

A scan source is anything with a `path`, a `format` name, an `info()` that
describes it and an iterator that yields `Scan` (or `PointCloud`) objects one at
a time, in the order of motion.  Readers stream: a 1 GB log is never loaded at once.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Protocol, runtime_checkable

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
