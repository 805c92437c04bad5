"""One pass over a CARMEN log: message lines in, `Scan` objects out, in file order.

`ScanStream` reads the (decompressed) lines, parses the messages it uses and settles
what a laser line alone does not say: the beam angles of FLASER/RLASER (from
``PARAM``), their maximum range (from ``PARAM``, else the no-return band rule over
the first laser messages, which are held back meanwhile) and the odometry pose of
RAWLASER scans (interpolated between the ``ODOM`` messages before and after them,
which holds them back until the next ``ODOM``).  What the pass saw goes into a
`ReadStats`.  The rules are in the `data.carmen` docstring.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from data import se2
from data.carmen.geometry import (
    DEFAULT_MAX_RANGE,
    beyond_bands,
    choose_max_range,
    laser_mount,
    old_laser_geometry,
    old_laser_max,
)
from data.carmen.parsing import (
    LASER_MESSAGES,
    MESSAGE_NAME,
    OLD_LASERS,
    RAW_LASERS,
    ROBOT_LASERS,
    BadLine,
    LaserLine,
    parse_new_laser,
    parse_odom,
    parse_old_laser,
)
from data.compression import StreamBroken, iter_lines
from data.errors import DataError, warn
from data.progress import ReadProgress
from data.types import Scan

Array = NDArray[np.float64]
Odom = tuple[float, tuple[float, float, float]]  # (stamp [s], robot pose (x, y, theta))

_MAX_RANGE_PREFIX = 500  # laser messages looked at to choose the band
_MAX_ODOM_WAIT = 2000  # RAWLASER scans held back waiting for the next ODOM
_ANGLE_CACHE = 64  # beam-angle arrays kept for reuse
_NONE: tuple[Scan, ...] = ()


@dataclass
class ReadStats:
    """What one pass over the log saw (for `CarmenLog.info` and the warning)."""

    messages: Counter[str] = field(default_factory=Counter)
    laser: str | None = None
    scans: int = 0
    odometry: int = 0
    bad_lines: int = 0
    first_bad: tuple[int, str] | None = None
    broken: str | None = None  # decompression error message
    broken_after: int = 0  # last line read before it
    stamp_min: float = math.inf
    stamp_max: float = -math.inf
    backwards: int = 0
    beams: Counter[int] = field(default_factory=Counter)
    max_ranges: Counter[float] = field(default_factory=Counter)
    first_scan: Scan | None = None
    last_stamp: float = -math.inf

    def count_scan(self, scan: Scan) -> None:
        """Account for one scan handed out."""
        stamp = scan.stamp
        self.scans += 1
        self.beams[len(scan.ranges)] += 1
        self.max_ranges[scan.max_range] += 1
        if stamp < self.last_stamp:
            self.backwards += 1
        self.last_stamp = stamp
        self.stamp_min = min(self.stamp_min, stamp)
        self.stamp_max = max(self.stamp_max, stamp)
        if self.first_scan is None:
            self.first_scan = scan

    def problem(self) -> str | None:
        """The one warning text, or None when the log read cleanly."""
        parts = []
        if self.bad_lines:
            line, reason = self.first_bad or (0, "")
            parts.append(
                f"skipped {self.bad_lines} malformed line(s), first at line {line} ({reason})"
            )
        if self.broken is not None:
            parts.append(
                f"compressed data is corrupt after line {self.broken_after} "
                f"({self.broken}); read the scans before it"
            )
        return "; ".join(parts) if parts else None


class ScanStream:
    """Iterate once over the scans of the log at `path`, filling `stats`.

    Args:
        path: the log (plain, gzip or bzip2).
        stats: filled during the pass; complete when the iteration ends.
        strict: raise `DataError` at the first malformed line instead of counting it.
        laser: ``"auto"`` or the laser message name to read.
        max_range: no-return threshold [m] for every scan, or None (the rules).
        progress: advanced to the bytes of the stored file read (`iter_lines`) and
            the scans read (counted when their line is parsed, not when released).
    """

    def __init__(self, path: Path, stats: ReadStats, *, strict: bool, laser: str,
                 max_range: float | None, progress: ReadProgress | None = None) -> None:
        self.path, self.stats, self.strict = path, stats, strict
        self.progress = progress
        self.laser, self.max_range = laser, max_range
        self.params: dict[str, str] = {}
        self.selected = None if laser == "auto" else laser
        # FLASER/RLASER without max range: held until `choose_max_range` decides.
        self.undecided: list[LaserLine] = []
        self.decided_max: float | None = None
        # RAWLASER: held until the next ODOM; previous ODOM (stamp, pose).
        self.waiting: list[LaserLine] = []
        self.last_odom: Odom | None = None
        self.mount = np.zeros(3)
        self.angle_cache: dict[tuple[int, float, float], Array] = {}
        self.old_geometry: dict[int, tuple[float, float]] = {}  # FLASER beams -> (start, step)
        self.counter = 0

    def __iter__(self) -> Iterator[Scan]:
        """Scans of every line, then the scans still held back; then the final checks."""
        yield from self._read_lines()
        if self.undecided:
            yield from self._flush_undecided()
        if self.waiting:
            yield from self._flush_waiting(None)
        self._finish()

    # ------------------------------------------------------------------ lines

    def _read_lines(self) -> Iterator[Scan]:
        lineno = 0
        try:
            for lineno, raw in enumerate(iter_lines(self.path, self.progress), start=1):
                scans = self._line(lineno, raw)
                if scans:
                    yield from scans
        except StreamBroken as exc:
            if self.strict:
                raise DataError(
                    self.path, f"compressed data is corrupt after line {lineno}: {exc}"
                ) from None
            self.stats.broken = str(exc) or type(exc.cause).__name__
            self.stats.broken_after = lineno
        except OSError as exc:  # the file vanished or became unreadable meanwhile
            raise DataError(self.path, f"cannot read: {exc.strerror or exc}") from None

    def _line(self, lineno: int, raw: bytes) -> Sequence[Scan]:
        """The scans one line releases (often none)."""
        t = raw.split()
        if not t:
            return _NONE
        head = t[0]
        if head[:1] == b"#":
            return _NONE
        if not MESSAGE_NAME.match(head):
            self._bad(lineno, f"not a CARMEN message: {head[:20]!r}")
            return _NONE
        name = head.decode("ascii")
        self.stats.messages[name] += 1
        try:
            if name == "ODOM":
                return self._odom(t)
            if name == "PARAM":
                self._param(t)
            elif name in LASER_MESSAGES:
                return self._laser(name, t, lineno)
        except BadLine as exc:
            self._bad(lineno, f"{name}: {exc}")
        return _NONE

    def _bad(self, line: int, reason: str) -> None:
        if self.strict:
            raise DataError(self.path, f"line {line}: {reason}")
        self.stats.bad_lines += 1
        if self.stats.first_bad is None:
            self.stats.first_bad = (line, reason)

    # ------------------------------------------------------------------ messages

    def _odom(self, t: list[bytes]) -> Sequence[Scan]:
        odom = parse_odom(t)
        self.stats.odometry += 1
        scans = self._flush_waiting(odom) if self.waiting else _NONE
        self.last_odom = odom
        return scans

    def _param(self, t: list[bytes]) -> None:
        if len(t) < 3:
            raise BadLine("PARAM without a value")
        self.params[t[1].decode("latin-1")] = t[2].decode("latin-1")
        self.old_geometry.clear()
        if self.selected in RAW_LASERS:
            self.mount = laser_mount(self.params, self.selected)

    def _laser(self, name: str, t: list[bytes], lineno: int) -> Sequence[Scan]:
        if self.selected is None:
            self.selected = name
            self.mount = laser_mount(self.params, name)
        if name != self.selected:
            return _NONE
        if name in OLD_LASERS:
            scans = self._old_laser(name, t, lineno)
        else:
            scans = self._new_laser(name, t, lineno)
        if self.progress is not None:  # read here, perhaps released later
            self.progress.scan_cell.value += 1
        return scans

    def _old_laser(self, name: str, t: list[bytes], lineno: int) -> Sequence[Scan]:
        """FLASER/RLASER: held back until the maximum range is known."""
        item = parse_old_laser(t, lineno)
        given = self._old_max(name)
        if given is not None or self.decided_max is not None:
            scans = self._flush_undecided() if self.undecided else []
            scans.append(self._make(item, given or self.decided_max, item.pose))
            return scans
        self.undecided.append(item)
        if beyond_bands(item.ranges):
            self.decided_max = DEFAULT_MAX_RANGE
        if self.decided_max is not None or len(self.undecided) >= _MAX_RANGE_PREFIX:
            return self._flush_undecided()
        return _NONE

    def _new_laser(self, name: str, t: list[bytes], lineno: int) -> Sequence[Scan]:
        """ROBOTLASER (pose in the message) or RAWLASER (held back until the next ODOM)."""
        item = parse_new_laser(t, lineno, name in ROBOT_LASERS)
        if math.isnan(item.max_range):
            item.max_range = self._old_max("FLASER") or DEFAULT_MAX_RANGE
        if name in ROBOT_LASERS:
            return (self._make(item, item.max_range, item.pose),)
        self.waiting.append(item)
        if len(self.waiting) >= _MAX_ODOM_WAIT:
            return self._flush_waiting(None)
        return _NONE

    def _old_max(self, kind: str) -> float | None:
        return self.max_range if self.max_range is not None else old_laser_max(self.params, kind)

    # ------------------------------------------------------------------ scans

    def _flush_undecided(self) -> list[Scan]:
        """The FLASER/RLASER scans held back, with the maximum range now decided."""
        if self.decided_max is None:
            self.decided_max = choose_max_range(item.ranges for item in self.undecided)
        scans = [self._make(item, self.decided_max, item.pose) for item in self.undecided]
        self.undecided.clear()
        return scans

    def _flush_waiting(self, new: Odom | None) -> list[Scan]:
        """The RAWLASER scans held back, posed between ODOM `last_odom` and `new`."""
        waiting = self.waiting
        stamps = np.array([item.stamp for item in waiting])
        prev = self.last_odom
        poses: Array | None = None
        if prev is not None or new is not None:
            if prev is None or new is None:
                known = np.asarray((prev or new)[1], dtype=float)  # type: ignore[index]
                robot = np.tile(known, (len(waiting), 1))
            elif prev[0] < new[0]:
                robot = se2.interpolate([prev[0], new[0]], [prev[1], new[1]], stamps)
            else:  # stamps run backwards (or tie): the nearer one in time
                near_new = np.abs(stamps - new[0]) <= np.abs(stamps - prev[0])
                robot = np.where(near_new[:, None], np.asarray(new[1]), np.asarray(prev[1]))
            poses = se2.compose(robot, self.mount)
        scans = [self._make(item, item.max_range, None if poses is None else poses[k].copy())
                 for k, item in enumerate(waiting)]
        waiting.clear()
        return scans

    def _make(self, item: LaserLine, max_range: float, odom: Array | None) -> Scan:
        """The `Scan` of a laser line, numbered and counted."""
        if self.max_range is not None:
            max_range = self.max_range
        scan = Scan(
            stamp=item.stamp,
            ranges=item.ranges,
            angles=self._angles(item),
            max_range=max_range,
            min_range=0.0,
            odom=odom,
            index=self.counter,
        )
        self.counter += 1
        self.stats.count_scan(scan)
        return scan

    def _angles(self, item: LaserLine) -> Array:
        """Beam angles [rad] of a laser line (read-only, shared by scans of one geometry)."""
        n = len(item.ranges)
        if math.isnan(item.start):
            geometry = self.old_geometry.get(n)
            if geometry is None:
                geometry = old_laser_geometry(n, self.params, self.selected or "FLASER")
                self.old_geometry[n] = geometry
            start, step = geometry
        else:
            start, step = item.start, item.step
        key = (n, start, step)
        angles = self.angle_cache.get(key)
        if angles is None:
            angles = start + step * np.arange(n, dtype=float)
            angles.flags.writeable = False
            if len(self.angle_cache) > _ANGLE_CACHE:
                self.angle_cache.clear()
            self.angle_cache[key] = angles
        return angles

    # ------------------------------------------------------------------ end

    def _finish(self) -> None:
        """The selected laser absent from the log is an error; trouble is one warning."""
        stats = self.stats
        stats.laser = self.selected
        if self.laser != "auto" and stats.scans == 0 and stats.bad_lines == 0:
            present = [k for k in LASER_MESSAGES if stats.messages.get(k)]
            raise DataError(
                self.path,
                f"no {self.laser} messages (laser messages present: "
                + (", ".join(present) if present else "none")
                + ")",
            )
        problem = stats.problem()
        if problem is not None:
            warn(f"{self.path}: {problem}")
        elif stats.scans == 0 and self.selected is None:
            warn(f"{self.path}: no laser messages ({', '.join(LASER_MESSAGES)}) in the log")
