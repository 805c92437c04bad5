"""`CarmenLog`: the streaming reader of a CARMEN log and its `info()` summary.

The messages read, the beam geometry, maximum range, odometry and error rules are
in the `data.carmen` docstring; one pass over the file is a `ScanStream`.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from data.carmen.geometry import field_of_view_deg
from data.carmen.parsing import LASER_MESSAGES
from data.carmen.sniff import sniff
from data.carmen.stream import ReadStats, ScanStream
from data.errors import DataError, UserError
from data.progress import ReadProgress
from data.types import Scan, SourceInfo


class CarmenLog:
    """Streaming reader of a CARMEN log: ``for scan in CarmenLog(path): ...``.

    Yields `data.types.Scan` one at a time in file order (``index`` from 0); see
    the `data.carmen` docstring for the messages, angles, maximum range, odometry
    and error rules.  Satisfies `data.sources.ScanSource`.

    Args:
        path: plain, ``.gz`` or ``.bz2`` log (compression told by magic bytes).
        strict: raise `DataError` at the first malformed line instead of skipping it.
        laser: ``"auto"`` (first laser message kind in the file) or one of
            `LASER_MESSAGES`.
        max_range: no-return threshold [m] for every scan, overriding messages,
            PARAMs and the default rule.

    Raises:
        DataError: the file is missing, a directory, empty or not a CARMEN log.
        UserError: `laser` is not a CARMEN laser message name.
    """

    format = "carmen"

    def __init__(
        self,
        path: str | Path,
        *,
        strict: bool = False,
        laser: str = "auto",
        max_range: float | None = None,
    ) -> None:
        self.path = Path(path)
        self.strict = strict
        wanted = laser.strip().upper()
        if wanted != "AUTO" and wanted not in LASER_MESSAGES:
            raise UserError(
                f"unknown CARMEN laser message {laser!r}: choose auto or one of "
                + ", ".join(LASER_MESSAGES)
            )
        self.laser = "auto" if wanted == "AUTO" else wanted
        if max_range is not None and not (math.isfinite(max_range) and max_range > 0):
            raise UserError(f"max_range must be a positive number of metres, got {max_range}")
        self.max_range = max_range
        reason = sniff(self.path)
        if reason is not None:
            raise DataError(self.path, f"not a CARMEN log: {reason}")
        self._info: SourceInfo | None = None
        self._progress = ReadProgress(self.path.stat().st_size, "bytes")

    def __iter__(self) -> Iterator[Scan]:
        """Scans in file order, odometry attached (`data.carmen` docstring)."""
        self._progress.start()
        return self._counted(self._scans(ReadStats(), self._progress))

    def progress(self) -> ReadProgress:
        """How far the latest iteration has read: bytes of the stored (possibly
        compressed) file, of its size, and the scans read; nothing is read to know
        the total."""
        return self._progress

    def _counted(self, scans: Iterator[Scan]) -> Iterator[Scan]:
        """`scans`; at their end the progress gets the exact count yielded."""
        count = 0
        for scan in scans:
            count += 1
            yield scan
        self._progress.scans = count
        self._progress.finish()

    def info(self) -> SourceInfo:
        """Counts and sensor description; reads the whole file once (then cached).

        ``scans``/``beams``/``max_range``: of the selected laser (beams and max range
        of the first scan; ``extra`` lists other beam counts or max ranges when the
        log mixes them); ``fov_deg``: `field_of_view_deg` of the first scan;
        ``duration_s``: largest minus smallest scan stamp; ``odometry``: number of
        ODOM messages.  ``extra``: ``messages`` (count per message name), ``laser``
        (the kind read), ``bad_lines``, ``first_bad_line``, ``stamps_backwards``
        (times a scan stamp is smaller than the previous one), the first and last
        beam angle [deg].  Emits the same warning as an iteration.
        """
        if self._info is None:
            stats = ReadStats()
            for _ in self._scans(stats):
                pass
            self._info = self._summary(stats)
        return self._info

    def _scans(self, stats: ReadStats, progress: ReadProgress | None = None) -> Iterator[Scan]:
        stream = ScanStream(self.path, stats, strict=self.strict, laser=self.laser,
                            max_range=self.max_range, progress=progress)
        return iter(stream)

    def _summary(self, stats: ReadStats) -> SourceInfo:
        """`SourceInfo` of a complete pass (see `info`)."""
        first = stats.first_scan
        duration = stats.stamp_max - stats.stamp_min if stats.scans else None
        extra: dict[str, Any] = {
            "messages": dict(sorted(stats.messages.items())),
            "laser": stats.laser,
            "bad_lines": stats.bad_lines,
            "first_bad_line": stats.first_bad[0] if stats.first_bad else None,
            "stamps_backwards": stats.backwards,
        }
        if first is not None and len(first.angles):
            extra["first_angle_deg"] = math.degrees(float(first.angles[0]))
            extra["last_angle_deg"] = math.degrees(float(first.angles[-1]))
        if len(stats.beams) > 1:
            extra["beam_counts"] = {str(k): v for k, v in sorted(stats.beams.items())}
        if len(stats.max_ranges) > 1:
            extra["max_range_counts"] = {str(k): v for k, v in sorted(stats.max_ranges.items())}
        if stats.broken is not None:
            extra["corrupt_after_line"] = stats.broken_after
        return SourceInfo(
            format=self.format,
            path=str(self.path),
            scans=stats.scans,
            beams=len(first.ranges) if first is not None else None,
            fov_deg=field_of_view_deg(first) if first is not None else None,
            max_range=first.max_range if first is not None else None,
            duration_s=duration,
            odometry=stats.odometry,
            extra=extra,
        )
