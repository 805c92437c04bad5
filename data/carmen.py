"""CARMEN log files: a streaming reader (`CarmenLog`) and a writer (`write_log`).

A CARMEN log ("carmen log file", ``.clf`` / ``.log``; plain, gzip or bzip2, told
apart by magic bytes) holds one message per line::

    message_name [message contents] ipc_timestamp ipc_hostname logger_timestamp

Units: metres, radians, seconds.  ``ipc_timestamp`` is the time the message was
made (used as `Scan.stamp`); ``logger_timestamp`` is the time the logger received
it (ignored).  Lines starting with ``#`` are comments.  The formats below were
checked against CARMEN's ``readlog.c`` / ``writelog.c`` (``src/logtools``) and the
SICK driver (``src/laser``).

Messages read
-------------
``PARAM name value [ipc_timestamp] hostname logger_timestamp``
    A parameter of CARMEN's ``.ini``.  Only the name and the first value token
    are used.  Honoured names (all optional):

    - ``robot_front_laser_max`` / ``robot_rear_laser_max`` [m]: no-return value
      of ``FLASER`` / ``RLASER`` (readings ``>=`` it are invalid).
    - ``laser_front_laser_fov`` / ``laser_rear_laser_fov`` [deg] and
      ``laser_front_laser_resolution`` / ``laser_rear_laser_resolution`` [deg]:
      beam geometry of ``FLASER`` / ``RLASER`` (see *Angles*).
    - ``robot_frontlaser_offset`` (x, forward) [m], ``robot_frontlaser_side_offset``
      (y, left) [m], ``robot_frontlaser_angular_offset`` [rad]: mounting of
      laser 1 on the robot, used to turn interpolated ``ODOM`` poses into laser
      poses for ``RAWLASER1``.  ``robot_rearlaser_offset`` [m]: the rear laser
      (``RAWLASER2``) sits that far *behind* the robot centre looking backwards,
      pose ``(-offset, 0, pi)`` in the robot frame, as CARMEN's localizer does.

    A ``PARAM`` applies to the laser messages after it (CARMEN writes them first).

``ODOM x y theta tv rv accel ipc_timestamp hostname logger_timestamp``
    Wheel odometry pose of the robot centre (m, m, rad) and velocities.

``FLASER`` / ``RLASER`` (front / rear laser, old format)::

    num_readings range[num_readings] x y theta odom_x odom_y odom_theta
    ipc_timestamp hostname logger_timestamp

    ``x y theta`` is the pose of the laser (`Scan.odom`); in the GMapping-corrected
    logs it is the corrected pose.  ``odom_*`` is the robot's odometry (unused).

``ROBOTLASER1`` / ``ROBOTLASER2``::

    laser_type start_angle field_of_view angular_resolution maximum_range
    accuracy remission_mode num_readings range[num_readings] num_remissions
    remission[num_remissions] laser_pose_x laser_pose_y laser_pose_theta
    robot_pose_x robot_pose_y robot_pose_theta laser_tv laser_rv
    forward_safety_dist side_safety_dist turn_axis ipc_timestamp hostname
    logger_timestamp

    `Scan.odom` is the laser pose.  Logs of old CARMEN versions lack
    ``remission_mode``; both layouts are accepted (the one whose counts match the
    line wins).

``RAWLASER1`` .. ``RAWLASER4`` (the laser driver's own message, no pose)::

    laser_type start_angle field_of_view angular_resolution maximum_range
    accuracy remission_mode num_readings range[num_readings] num_remissions
    remission[num_remissions] ipc_timestamp hostname logger_timestamp

    `Scan.odom` is the robot's ``ODOM`` pose interpolated to the scan stamp
    (`data.se2.interpolate` between the ODOM messages just before and just after
    the scan in file order; the nearer one in time when their stamps run
    backwards; the nearest one at the ends of the log), composed with the laser
    mounting from ``PARAM`` (above; identity for ``RAWLASER3``/``4``).  The reader
    holds the scans that wait for the next ``ODOM`` (at most 2,000; beyond that
    they take the last ODOM pose).  With no ``ODOM`` in the log, `Scan.odom` is
    None.

Every other message (``NEFF``, ``SYNC``, ``TRUEPOS``, ``NMEA...``, ...) is
skipped silently, and so are laser messages of a kind other than the selected one.

Which laser
-----------
``laser="auto"`` takes the kind of the first laser message in the file (file
order: whichever of ``FLASER``, ``RLASER``, ``ROBOTLASER1/2``, ``RAWLASER1..4``
comes first); ``laser="RLASER"`` (any listed name) selects that one.  A selected
kind absent from the whole file is a `DataError` at the end of the iteration.

Angles
------
Beam ``i`` has bearing ``start_angle + i * angular_resolution`` (CARMEN's
convention: angles of beam *centres*, the first at ``start_angle``; CARMEN's
``field_of_view`` is first-to-last, ``(n - 1) * angular_resolution``).
``ROBOTLASER``/``RAWLASER`` carry these fields; when ``angular_resolution`` is
not positive, ``field_of_view / (n - 1)`` is used.

``FLASER``/``RLASER`` carry none.  With ``laser_*_laser_resolution`` (deg) in the
log's PARAMs: that step, the first beam at ``-fov / 2`` (``fov`` from
``laser_*_laser_fov`` [deg], default 180), used when ``n`` beams fit the fov
(``(n - 1) * step`` within one step below ``fov``: e.g. 360 beams at 0.5 deg span
-90..+89.5 deg as CARMEN's SICK driver says), otherwise ignored.  With
``laser_*_laser_fov`` alone: ``n`` beams evenly from ``-fov/2`` to ``+fov/2``.
Otherwise CARMEN's own default (``readlog.c`` and its SICK driver): a 180-degree
fov and a step of ``fov / n`` for an even ``n`` or ``fov / (n - 1)`` for an odd
``n``, the first beam at -90 degrees; so 180 beams span -90..+89 degrees in 1
degree steps (the SICK's last beam dropped), 181 beams -90..+90, 360 beams
-90..+89.5.  This departs from ``../shared/data/SOURCES.md`` (which says pi/179
for Intel) on the evidence of the data: with 1-degree steps consecutive Intel
scans fit better (mean ICP overlap 0.800 against 0.780 over the first 2,500
scans) and scan-matching odometry agrees with the Intel relations far better
(0.16 m against 0.43 m mean translational error); the relations were made with
CARMEN's tools.  `old_laser_geometry` is the one place to change.

Maximum range
-------------
`Scan.max_range` is the no-return threshold: readings ``>=`` it, NaN, inf and
``<= 0`` are invalid (`Scan.valid`); they are kept raw in `Scan.ranges`.

- ``ROBOTLASER``/``RAWLASER``: ``maximum_range`` of the message (when it is not
  positive: as for ``FLASER``).
- ``FLASER``/``RLASER``: ``robot_front_laser_max`` / ``robot_rear_laser_max``
  from PARAM when present.  Otherwise 80.0 m, CARMEN's own default for these
  messages (SICK LMS in cm mode logs a missing return as 81.83-81.91 m: Intel,
  Freiburg, Seattle), *unless* the log is a SICK in mm mode or a clipped log:
  the reader looks at the first 500 laser messages (holding them back, bounded)
  and, when no reading in them exceeds one of the no-return values
  8.191, 16.383, 32.767 m (SICK 8/16/32 m modes, codes 2^k - 1 mm) or 50.0 m
  (PLS and clipped Radish logs) by more than 5 mm and at least 0.5 % of their
  beams lie in the band just below the smallest such value that is not
  exceeded (12.5 mm wide for the SICK modes, 5 mm for 50.0), the band's lower
  edge becomes the maximum range (32.7545 m for Orebro's 32.76/32.77 m
  no-returns).
- ``max_range=`` given to `CarmenLog` overrides all of this.

Bad input
---------
A missing file, a directory, an empty file or one whose first lines are not
CARMEN messages raise `DataError` ("not a CARMEN log: ...").  A malformed line
of a message the reader uses (wrong count of fields, no range reading, a number
that does not parse, a non-finite pose or stamp, a line cut short, a first token
that is no message name) is skipped; at the end of the iteration one warning
gives the count and the first bad line number.  A compressed stream that breaks
off (bzip2/gzip error) ends the iteration after the last good line, with the
same single warning.  ``strict=True`` raises `DataError` with the line number
instead.  A line may omit the final logger timestamp.  The reader never sorts:
file order is the order of motion (Intel's ipc timestamps run backwards 631
times).
"""

from __future__ import annotations

import bz2
import contextlib
import functools
import gzip
import io
import math
import os
import queue
import re
import secrets
import threading
import zlib
from collections import Counter
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray

from data import se2
from data.compression import compression_of, read_magic
from data.errors import DataError, UserError, warn
from data.types import Scan, SourceInfo

Array = NDArray[np.float64]

OLD_LASERS = ("FLASER", "RLASER")
ROBOT_LASERS = ("ROBOTLASER1", "ROBOTLASER2")
RAW_LASERS = ("RAWLASER1", "RAWLASER2", "RAWLASER3", "RAWLASER4")
LASER_MESSAGES: tuple[str, ...] = OLD_LASERS + ROBOT_LASERS + RAW_LASERS

#: CARMEN's default maximum range of FLASER/RLASER [m] (``readlog.c``).
DEFAULT_MAX_RANGE = 80.0
#: (no-return value, lower edge of its band) [m]: SICK mm modes and 50 m logs.
NO_RETURN_BANDS: tuple[tuple[float, float], ...] = (
    (8.191, 8.1785),
    (16.383, 16.3705),
    (32.767, 32.7545),
    (50.0, 49.995),
)
_BAND_SLACK = 0.005  # a reading may exceed the no-return value by this [m]
_BAND_MIN_FRACTION = 0.005  # share of prefix beams that must be in the band
_MAX_RANGE_PREFIX = 500  # laser messages looked at to choose the band
_MAX_ODOM_WAIT = 2000  # RAWLASER scans held back waiting for the next ODOM

_KNOWN_MESSAGES = frozenset(
    (
        "PARAM SYNC ODOM FLASER RLASER TRUEPOS NEFF LASER NMEAGGA NMEARMC NMEA-GGA NMEA-RMC "
        "SONAR BUMPER ARM IMU SCANMARK POSITIONLASER VELOCITY ROBOTVELOCITY VECTORMOVE "
        "BASEVELOCITY GPSNMEA FLOG ROBOTLASER RAWLASER"
    ).split()
)
_NUMBERED = re.compile(r"^(ROBOTLASER|RAWLASER|LASER)\d$")
_MESSAGE_NAME = re.compile(rb"^[A-Z][A-Z0-9_\-]*$")
_READ = 1 << 15  # bytes read from the file at a time
_FEED = 1 << 10  # compressed bytes per decompressor call: a failing call loses its output
_QUEUE = 16  # pieces the decompressing thread may run ahead (bzip2: up to 900 kB each)
_SNIFF_BYTES = 1 << 18
_SNIFF_LINES = 50

_STREAM_ERRORS = (OSError, EOFError, zlib.error)


def _is_known_message(name: str) -> bool:
    return name in _KNOWN_MESSAGES or _NUMBERED.match(name) is not None


# --------------------------------------------------------------------------- decompression


class _StreamBroken(Exception):
    """The decompressor failed after some data; carries the original error."""

    def __init__(self, cause: BaseException) -> None:
        super().__init__(_short(cause) or type(cause).__name__)
        self.cause = cause


def _decompressed(path: Path) -> Iterator[bytes]:
    """The file's bytes, decompressed (gzip or bzip2 by magic bytes), piece by piece.

    Feeds the decompressor 1 KiB at a time and yields each output at once, so a
    damaged stream gives (nearly) every byte before the damage (bzip2: every block
    before the damaged one) before `_StreamBroken`.  Concatenated streams are read on.
    Raises `DataError` when the file cannot be opened.
    """
    kind = compression_of(path)
    try:
        f = open(path, "rb")  # closed in the finally below
    except OSError as exc:
        raise DataError(path, f"cannot open: {exc.strerror or exc}") from None
    try:
        if kind == "none":
            while piece := f.read(_READ):
                yield piece
            return
        make = bz2.BZ2Decompressor if kind == "bzip2" else lambda: zlib.decompressobj(31)
        decompressor = make()
        fresh = True  # nothing fed to the current decompressor yet
        while True:
            data = f.read(_READ)
            if not data:
                if not (decompressor.eof or fresh):
                    raise _StreamBroken(EOFError("compressed data ends before its end marker"))
                return
            for at in range(0, len(data), _FEED):
                data_left = data[at : at + _FEED]
                while data_left:
                    try:
                        out = decompressor.decompress(data_left)
                    except _STREAM_ERRORS as exc:
                        raise _StreamBroken(exc) from exc
                    fresh = False
                    if out:
                        yield out
                    if not decompressor.eof:
                        break
                    data_left = decompressor.unused_data  # a concatenated stream follows
                    decompressor, fresh = make(), True
    finally:
        f.close()


def _in_thread(pieces: Iterator[bytes]) -> Iterator[bytes]:
    """`pieces` produced by a background thread (zlib and bzip2 release the GIL).

    At most `_QUEUE` pieces wait in memory; closing the generator stops the thread.
    Exceptions of the producer are raised in the consumer.
    """
    pipe: queue.Queue[bytes | BaseException | None] = queue.Queue(maxsize=_QUEUE)
    stop = threading.Event()

    def put(item: bytes | BaseException | None) -> None:
        while not stop.is_set():
            try:
                pipe.put(item, timeout=0.05)
                return
            except queue.Full:
                continue

    def produce() -> None:
        try:
            for piece in pieces:
                if stop.is_set():
                    return
                put(piece)
        except BaseException as exc:  # handed to the consumer, raised there
            put(exc)
            return
        finally:
            pieces.close()  # type: ignore[attr-defined]
        put(None)

    worker = threading.Thread(target=produce, name="carmen-decompress", daemon=True)
    worker.start()
    try:
        while True:
            item = pipe.get()
            if item is None:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        worker.join(timeout=5.0)


def _lines(path: Path) -> Iterator[bytes]:
    """Lines of the (decompressed) file without their ``\\n``, in file order.

    Compressed files are decompressed by a background thread.  Raises
    `_StreamBroken` when decompression fails; the partial line before the failure
    is dropped.
    """
    pieces = _decompressed(path)
    if compression_of(path) != "none":
        pieces = _in_thread(pieces)
    tail = b""
    for piece in pieces:
        parts = (tail + piece).split(b"\n")
        tail = parts.pop()
        yield from parts
    if tail:
        yield tail


# --------------------------------------------------------------------------- sniffing


def _sniff(path: Path) -> str | None:
    """None when `path` looks like a CARMEN log, else the reason it does not."""
    read_magic(path)  # DataError for missing files, directories, unreadable files
    pieces: list[bytes] = []
    size = 0
    complete = False
    stream = _decompressed(path)
    try:
        for piece in stream:
            pieces.append(piece)
            size += len(piece)
            if size >= _SNIFF_BYTES:
                break
        else:
            complete = True
    except _StreamBroken as exc:
        if not pieces:
            return f"cannot decompress: {exc}"
    finally:
        stream.close()
    head = b"".join(pieces)
    if not head.strip():
        return "file is empty"
    lines = head.split(b"\n")
    if not complete and len(lines) > 1:
        lines.pop()  # the last line may be cut by the read limit or the damage
    considered = known = 0
    for raw in lines:
        tokens = raw.split(None, 1)
        if not tokens or tokens[0].startswith(b"#"):
            continue
        considered += 1
        if _is_known_message(tokens[0].decode("latin-1")):
            known += 1
        if considered >= _SNIFF_LINES:
            break
    if considered == 0:
        return "no message lines, only comments"
    if known == 0 or 2 * known < considered:
        return f"{considered - known} of the first {considered} lines are not CARMEN messages"
    return None


def is_carmen(path: str | Path) -> bool:
    """Cheap sniff: do the first non-comment lines look like CARMEN messages?

    Reads at most about 256 KiB (decompressed).  False for missing files,
    directories, garbage and empty files; never raises.
    """
    try:
        return _sniff(Path(path)) is None
    except DataError:
        return False


# --------------------------------------------------------------------------- parsing


class _BadLine(Exception):
    """A line that does not parse; the message says why."""


@dataclass(slots=True)
class _Laser:
    """One parsed laser message (before max range and odometry are settled)."""

    line: int
    stamp: float
    ranges: Array
    start: float  # first bearing [rad]; NaN = FLASER/RLASER geometry from PARAM
    step: float  # angular resolution [rad]
    max_range: float  # NaN = FLASER/RLASER: decided by PARAM or the band rule
    pose: Array | None  # laser pose from the message; None for RAWLASER


def _floats(tokens: list[bytes]) -> Array:
    try:
        return np.array(tokens, dtype=float)
    except ValueError as exc:
        raise _BadLine(f"not a number: {_short(exc)}") from None


def _short(exc: BaseException) -> str:
    text = str(exc)
    return text if len(text) <= 60 else text[:57] + "..."


def _count(token: bytes, what: str, least: int = 0) -> int:
    try:
        n = int(token)
    except ValueError:
        raise _BadLine(f"{what} is not an integer: {token[:20]!r}") from None
    if n < least:
        raise _BadLine(f"{what} is {n}, below {least}")
    return n


def _check_length(t: list[bytes], expected: int, what: str) -> None:
    """`expected` fields with the logger timestamp; one fewer (none) is accepted."""
    if len(t) not in (expected, expected - 1):
        raise _BadLine(f"{what}: expected {expected} fields, found {len(t)}")


def _finite(values: Array, what: str) -> None:
    if not all(map(math.isfinite, values.tolist())):
        raise _BadLine(f"non-finite {what}")


def _parse_old_laser(t: list[bytes], line: int) -> _Laser:
    """``FLASER``/``RLASER n ranges x y theta odom_x odom_y odom_theta ipc host logger``."""
    n = _count(t[1], "num_readings", 1) if len(t) > 1 else 0
    _check_length(t, n + 11, f"{n} readings")
    v = _floats(t[2 : n + 9])
    _finite(v[n:], "pose or timestamp")
    return _Laser(line, float(v[n + 6]), v[:n], math.nan, math.nan, math.nan, v[n : n + 3])


def _layout(t: list[bytes], tail: int) -> tuple[int, int, int]:
    """(config fields, num_readings, num_remissions) of a ROBOTLASER/RAWLASER line.

    `tail` counts the fields after the remissions, logger timestamp included.  The
    current layout has 7 config fields (with ``remission_mode``), old logs 6.
    """
    reasons = []
    for cfg in (7, 6):
        try:
            n = _count(t[1 + cfg], "num_readings", 1)
            m = _count(t[2 + cfg + n], "num_remissions")
            _check_length(t, 3 + cfg + n + m + tail, f"{n} readings, {m} remissions")
            return cfg, n, m
        except (_BadLine, IndexError) as exc:
            reasons.append(str(exc) if isinstance(exc, _BadLine) else "line too short")
    raise _BadLine(reasons[0])


def _parse_new_laser(t: list[bytes], line: int, with_pose: bool) -> _Laser:
    """``ROBOTLASERk`` (`with_pose`) or ``RAWLASERk`` (see the module docstring)."""
    cfg, n, m = _layout(t, 14 if with_pose else 3)
    end = 3 + cfg + n + m + (12 if with_pose else 1)  # numeric fields up to ipc
    v = _floats(t[1:end])
    start, fov, step, max_range = (float(x) for x in v[1:5])
    first = cfg + 1  # index of the first range in v
    ranges = v[first : first + n]
    tail = v[first + n + 1 + m :]
    _finite(tail, "pose or timestamp")
    if not (math.isfinite(start) and math.isfinite(fov)):
        raise _BadLine("non-finite start angle or field of view")
    if not (math.isfinite(step) and step > 0.0):
        if n < 2 or not fov > 0.0:
            if n >= 2:
                raise _BadLine("angular resolution and field of view are not positive")
            step = 0.0
        else:
            step = fov / (n - 1)
    if not max_range > 0.0:  # NaN or not positive: unknown (inf is "no limit")
        max_range = math.nan
    pose = tail[0:3] if with_pose else None
    return _Laser(line, float(tail[-1]), ranges, start, step, max_range, pose)


def _parse_odom(t: list[bytes]) -> tuple[float, tuple[float, float, float]]:
    """``ODOM x y theta tv rv accel ipc host logger`` -> (stamp, (x, y, theta))."""
    _check_length(t, 10, "x y theta tv rv accel")
    try:
        x, y, theta, _tv, _rv, _accel, stamp = map(float, t[1:8])
    except ValueError as exc:
        raise _BadLine(f"not a number: {_short(exc)}") from None
    if not all(map(math.isfinite, (x, y, theta, stamp))):
        raise _BadLine("non-finite pose or timestamp")
    return stamp, (x, y, theta)


# --------------------------------------------------------------------------- configuration


def _param_float(params: Mapping[str, str], name: str) -> float | None:
    value = params.get(name)
    if value is None:
        return None
    try:
        x = float(value)
    except ValueError:
        return None
    return x if math.isfinite(x) else None


def _side(kind: str) -> str:
    return "rear" if kind == "RLASER" else "front"


def old_laser_geometry(
    n: int, params: Mapping[str, str], kind: str = "FLASER"
) -> tuple[float, float]:
    """(first bearing, step) [rad] of an ``n``-beam FLASER/RLASER (module docstring)."""
    side = _side(kind)
    fov_deg = _param_float(params, f"laser_{side}_laser_fov")
    res_deg = _param_float(params, f"laser_{side}_laser_resolution")
    fov = math.radians(fov_deg) if fov_deg is not None and fov_deg > 0 else math.pi
    if res_deg is not None and res_deg > 0 and n >= 2:
        step = math.radians(res_deg)
        span = (n - 1) * step
        if fov - step - 1e-9 <= span <= fov + 1e-9:
            return -fov / 2.0, step
    if n < 2:
        return 0.0, 0.0
    return -fov / 2.0, fov / (n if n % 2 == 0 else n - 1)


def _old_laser_max(params: Mapping[str, str], kind: str) -> float | None:
    value = _param_float(params, f"robot_{_side(kind)}_laser_max")
    return value if value is not None and value > 0 else None


def _mount(params: Mapping[str, str], kind: str) -> Array:
    """Pose of the laser in the robot frame (x, y, theta) for RAWLASER messages."""
    if kind == "RAWLASER1":
        return np.array(
            [
                _param_float(params, "robot_frontlaser_offset") or 0.0,
                _param_float(params, "robot_frontlaser_side_offset") or 0.0,
                _param_float(params, "robot_frontlaser_angular_offset") or 0.0,
            ]
        )
    if kind == "RAWLASER2":
        return np.array([-(_param_float(params, "robot_rearlaser_offset") or 0.0), 0.0, math.pi])
    return np.zeros(3)


def _beyond_bands(ranges: Array) -> bool:
    """A reading above every no-return band: the log is a SICK in cm mode."""
    with np.errstate(invalid="ignore"):
        limit = NO_RETURN_BANDS[-1][0] + _BAND_SLACK
        return bool(np.any((ranges > limit) & np.isfinite(ranges)))


def choose_max_range(ranges: Iterable[Array]) -> float:
    """No-return threshold of a FLASER/RLASER log without PARAM (module docstring).

    `ranges` are the readings of the first laser messages (up to 500).
    """
    finite = [r[np.isfinite(r)] for r in ranges]
    values = np.concatenate(finite) if finite else np.zeros(0)
    if values.size == 0:
        return DEFAULT_MAX_RANGE
    top = float(values.max())
    for value, low in NO_RETURN_BANDS:
        if top <= value + _BAND_SLACK:
            in_band = int(np.count_nonzero(values >= low))
            if in_band >= max(1.0, _BAND_MIN_FRACTION * values.size):
                return low
            break
    return DEFAULT_MAX_RANGE


# --------------------------------------------------------------------------- the reader


def field_of_view_deg(scan: Scan) -> float:
    """Field of view reported by `CarmenLog.info` [deg].

    The angle from the first to the last beam (CARMEN's and ROS's convention: 180
    for a SICK's 181 beams), except that a scan whose beams close the circle
    (span plus one step reaches 360 degrees) reports 360.
    """
    return math.degrees(scan.fov)


@dataclass
class _Stats:
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


class CarmenLog:
    """Streaming reader of a CARMEN log: ``for scan in CarmenLog(path): ...``.

    Yields `data.types.Scan` one at a time in file order (``index`` from 0); see
    the module docstring for the messages, angles, maximum range, odometry and
    error rules.  Satisfies `data.sources.ScanSource`.

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
        reason = _sniff(self.path)
        if reason is not None:
            raise DataError(self.path, f"not a CARMEN log: {reason}")
        self._info: SourceInfo | None = None

    def __iter__(self) -> Iterator[Scan]:
        """Scans in file order, odometry attached (module docstring)."""
        return self._scans(_Stats())

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
            stats = _Stats()
            for _ in self._scans(stats):
                pass
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
            self._info = SourceInfo(
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
        return self._info

    # ------------------------------------------------------------------ internals

    def _bad(self, stats: _Stats, line: int, reason: str) -> None:
        if self.strict:
            raise DataError(self.path, f"line {line}: {reason}")
        stats.bad_lines += 1
        if stats.first_bad is None:
            stats.first_bad = (line, reason)

    def _scans(self, stats: _Stats) -> Iterator[Scan]:
        """The iteration proper: parse, settle max range and odometry, yield."""
        params: dict[str, str] = {}
        selected = None if self.laser == "auto" else self.laser
        # FLASER/RLASER without max range: held until `choose_max_range` decides.
        undecided: list[_Laser] = []
        decided_max: float | None = None
        # RAWLASER: held until the next ODOM; previous ODOM (stamp, pose).
        waiting: list[_Laser] = []
        last_odom: tuple[float, tuple[float, float, float]] | None = None
        mount = np.zeros(3)
        angle_cache: dict[tuple[int, float, float], Array] = {}
        old_geometry: dict[int, tuple[float, float]] = {}  # FLASER beams -> (start, step)
        counter = 0
        last_stamp = -math.inf

        def make(item: _Laser, max_range: float, odom: Array | None) -> Scan:
            nonlocal counter, last_stamp
            n = len(item.ranges)
            if math.isnan(item.start):
                geometry = old_geometry.get(n)
                if geometry is None:
                    geometry = old_laser_geometry(n, params, selected or "FLASER")
                    old_geometry[n] = geometry
                start, step = geometry
            else:
                start, step = item.start, item.step
            key = (n, start, step)
            angles = angle_cache.get(key)
            if angles is None:
                angles = start + step * np.arange(n, dtype=float)
                angles.flags.writeable = False
                if len(angle_cache) > 64:
                    angle_cache.clear()
                angle_cache[key] = angles
            if self.max_range is not None:
                max_range = self.max_range
            scan = Scan(
                stamp=item.stamp,
                ranges=item.ranges,
                angles=angles,
                max_range=max_range,
                min_range=0.0,
                odom=odom,
                index=counter,
            )
            counter += 1
            stats.scans += 1
            stats.beams[n] += 1
            stats.max_ranges[max_range] += 1
            if item.stamp < last_stamp:
                stats.backwards += 1
            last_stamp = item.stamp
            stats.stamp_min = min(stats.stamp_min, item.stamp)
            stats.stamp_max = max(stats.stamp_max, item.stamp)
            if stats.first_scan is None:
                stats.first_scan = scan
            return scan

        def flush_undecided() -> Iterator[Scan]:
            nonlocal decided_max
            if decided_max is None:
                decided_max = choose_max_range(item.ranges for item in undecided)
            for item in undecided:
                yield make(item, decided_max, item.pose)
            undecided.clear()

        def flush_waiting(new: tuple[float, tuple[float, float, float]] | None) -> Iterator[Scan]:
            """Yield the RAWLASER scans held back, between ODOM `last_odom` and `new`."""
            stamps = np.array([item.stamp for item in waiting])
            prev = last_odom
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
                poses = se2.compose(robot, mount)
            for k, item in enumerate(waiting):
                yield make(item, item.max_range, None if poses is None else poses[k].copy())
            waiting.clear()

        def old_max(kind: str) -> float | None:
            return self.max_range if self.max_range is not None else _old_laser_max(params, kind)

        lineno = 0
        try:
            for lineno, raw in enumerate(_lines(self.path), start=1):
                t = raw.split()
                if not t:
                    continue
                head = t[0]
                if head[:1] == b"#":
                    continue
                if not _MESSAGE_NAME.match(head):
                    self._bad(stats, lineno, f"not a CARMEN message: {head[:20]!r}")
                    continue
                name = head.decode("ascii")
                stats.messages[name] += 1
                try:
                    if name == "ODOM":
                        odom = _parse_odom(t)
                        stats.odometry += 1
                        if waiting:
                            yield from flush_waiting(odom)
                        last_odom = odom
                    elif name == "PARAM":
                        if len(t) < 3:
                            raise _BadLine("PARAM without a value")
                        params[t[1].decode("latin-1")] = t[2].decode("latin-1")
                        old_geometry.clear()
                        if selected in RAW_LASERS:
                            mount = _mount(params, selected)
                    elif name in LASER_MESSAGES:
                        if selected is None:
                            selected = name
                            mount = _mount(params, name)
                        if name != selected:
                            continue
                        if name in OLD_LASERS:
                            item = _parse_old_laser(t, lineno)
                            given = old_max(name)
                            if given is not None or decided_max is not None:
                                if undecided:
                                    yield from flush_undecided()
                                yield make(item, given or decided_max, item.pose)
                                continue
                            undecided.append(item)
                            if _beyond_bands(item.ranges):
                                decided_max = DEFAULT_MAX_RANGE
                            if decided_max is not None or len(undecided) >= _MAX_RANGE_PREFIX:
                                yield from flush_undecided()
                        else:
                            item = _parse_new_laser(t, lineno, name in ROBOT_LASERS)
                            if math.isnan(item.max_range):
                                item.max_range = old_max("FLASER") or DEFAULT_MAX_RANGE
                            if name in ROBOT_LASERS:
                                yield make(item, item.max_range, item.pose)
                            else:
                                waiting.append(item)
                                if len(waiting) >= _MAX_ODOM_WAIT:
                                    yield from flush_waiting(None)
                except _BadLine as exc:
                    self._bad(stats, lineno, f"{name}: {exc}")
        except _StreamBroken as exc:
            if self.strict:
                raise DataError(
                    self.path, f"compressed data is corrupt after line {lineno}: {exc}"
                ) from None
            stats.broken = str(exc) or type(exc.cause).__name__
            stats.broken_after = lineno
        except OSError as exc:  # the file vanished or became unreadable meanwhile
            raise DataError(self.path, f"cannot read: {exc.strerror or exc}") from None

        if undecided:
            yield from flush_undecided()
        if waiting:
            yield from flush_waiting(None)
        stats.laser = selected
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
        elif stats.scans == 0 and selected is None:
            warn(f"{self.path}: no laser messages ({', '.join(LASER_MESSAGES)}) in the log")


# --------------------------------------------------------------------------- the writer


_HEADER = (
    "# CARMEN Logfile written by loopclosure (data.carmen.write_log)",
    "# file format is one message per line",
    "# message_name [message contents] ipc_timestamp ipc_hostname logger_timestamp",
    "# message formats defined: PARAM ODOM ROBOTLASER1 RAWLASER1",
    "# PARAM param_name param_value",
    "# ODOM x y theta tv rv accel",
    "# ROBOTLASER1 laser_type start_angle field_of_view angular_resolution maximum_range "
    "accuracy remission_mode num_readings [range_readings] num_remissions [remissions] "
    "laser_pose_x laser_pose_y laser_pose_theta robot_pose_x robot_pose_y robot_pose_theta "
    "laser_tv laser_rv forward_safety_dist side_safty_dist turn_axis",
    "# RAWLASER1 laser_type start_angle field_of_view angular_resolution maximum_range "
    "accuracy remission_mode num_readings [range_readings] num_remissions [remissions]",
)
#: CARMEN's ``UNKNOWN_PROXIMITY_SENSOR`` laser type: the writer does not know the sensor.
WRITER_LASER_TYPE = 99
_ANGLE_TOLERANCE = 1e-6  # [rad] largest deviation from even spacing the writer accepts


@functools.lru_cache(maxsize=16)
def _ranges_format(n: int) -> str:
    """``"%.4f %.4f ..."`` for `n` readings (``%`` prints NaN and inf as nan, inf)."""
    return " ".join(["%.4f"] * n)


def _fmt(x: float, digits: str) -> str:
    if math.isfinite(x):
        return format(x, digits)
    return "nan" if math.isnan(x) else ("inf" if x > 0 else "-inf")


def _laser_line(scan: Scan, number: int, with_pose: bool, host: str, t0: float, where: Path) -> str:
    ranges = np.asarray(scan.ranges, dtype=float).reshape(-1)
    angles = np.asarray(scan.angles, dtype=float).reshape(-1)
    n = len(ranges)
    if n == 0:
        raise DataError(where, f"scan {number} has no beams")
    if len(angles) != n:
        raise DataError(where, f"scan {number}: {n} ranges but {len(angles)} angles")
    if not math.isfinite(scan.stamp):
        raise DataError(where, f"scan {number}: non-finite stamp {scan.stamp}")
    start = float(angles[0]) if n else 0.0
    step = float(angles[-1] - angles[0]) / (n - 1) if n >= 2 else 0.0
    if n >= 2:
        deviation = np.abs(angles - (start + step * np.arange(n))).max()
        if not (step > 0 and deviation <= _ANGLE_TOLERANCE):
            raise DataError(
                where,
                f"scan {number}: beam angles are not evenly spaced and increasing; "
                "CARMEN stores only a start angle and a resolution",
            )
    fov = step * (n - 1) if n >= 2 else 0.0
    body = _ranges_format(n) % tuple(ranges.tolist())
    head = (
        f"{'ROBOTLASER1' if with_pose else 'RAWLASER1'} {WRITER_LASER_TYPE} "
        f"{start:.10f} {fov:.10f} {step:.12f} {_fmt(float(scan.max_range), '.10g')} 0.0100 0 {n}"
    )
    tail = f"{scan.stamp:.6f} {host} {scan.stamp - t0:.6f}"
    if with_pose:
        pose = np.asarray(scan.odom, dtype=float).reshape(3)
        if not np.isfinite(pose).all():
            raise DataError(where, f"scan {number}: non-finite odometry pose {pose}")
        p = " ".join(f"{x:.6f}" for x in pose)
        return f"{head} {body} 0 {p} {p} 0 0 0 0 0 {tail}\n"
    return f"{head} {body} 0 {tail}\n"


def _odom_line(stamp: float, pose: Array, host: str, t0: float) -> str:
    x, y, theta = (float(v) for v in pose)
    return f"ODOM {x:.6f} {y:.6f} {theta:.6f} 0 0 0 {stamp:.6f} {host} {stamp - t0:.6f}\n"


@contextlib.contextmanager
def _open_output(tmp: Path, final: Path) -> Iterator[IO[str]]:
    """Text stream writing `tmp` (created, never overwritten), compressed by `final`'s suffix."""
    suffix = final.suffix.lower()
    with contextlib.ExitStack() as stack:
        raw: IO[bytes] = stack.enter_context(open(tmp, "xb"))
        if suffix == ".gz":
            raw = stack.enter_context(
                gzip.GzipFile(filename=final.stem, mode="wb", compresslevel=6, fileobj=raw)
            )
        elif suffix == ".bz2":
            raw = stack.enter_context(bz2.BZ2File(raw, "wb"))
        text = stack.enter_context(io.TextIOWrapper(raw, encoding="ascii", newline="\n"))
        yield text


def write_log(
    path: str | Path,
    scans: Iterable[Scan],
    odometry: Iterable[tuple[float, Array]] | None = None,
    params: Mapping[str, object] | None = None,
    hostname: str = "loopclosure",
) -> int:
    """Write scans (and odometry) as a CARMEN log that `CarmenLog` reads back.

    Layout: header comments, one ``PARAM`` line per entry of `params` (values must
    not contain white space), then ``ODOM`` and laser lines merged by stamp (a
    message is written before the next one of the other stream when its stamp is
    not later; each stream keeps its own order).  Each scan becomes a
    ``ROBOTLASER1`` line (start angle, field of view, resolution and maximum range
    included, so e.g. a 360-degree scan round-trips; laser pose and robot pose
    both `Scan.odom`), or a ``RAWLASER1`` line when the first scan has no
    odometry (then none may have it).  Precision: ranges 0.1 mm (``%.4f``; NaN and
    inf as ``nan``/``inf``), stamps and poses 1e-6, angles 1e-10 rad, maximum
    range 10 significant digits (``inf`` allowed).  `Scan.min_range` has no CARMEN
    field and is not stored (it reads back as 0).

    A ``.gz`` / ``.bz2`` suffix compresses.  The file is written to a temporary
    file beside `path` and renamed at the end, so an error leaves nothing behind.

    Args:
        path: output file.
        scans: scans in order; angles evenly spaced and increasing.
        odometry: ``(stamp [s], (x, y, theta))`` robot poses, or None.
        params: CARMEN parameters, e.g. ``{"robot_frontlaser_offset": 0.0}``.
        hostname: the host field of every line (no white space).

    Returns:
        The number of scans written.

    Raises:
        DataError: a scan or pose the format cannot hold (named by its index),
            nothing at all to write, or the file cannot be written.
        UserError: a bad hostname or parameter.
    """
    path = Path(path)
    if not _one_word(hostname):
        raise UserError(f"hostname must be one ASCII word, got {hostname!r}")
    param_lines = []
    for name, value in (params or {}).items():
        text = _param_text(value)
        if not (_one_word(str(name)) and _one_word(text)):
            raise UserError(
                f"CARMEN PARAM {name!r} = {value!r}: name and value must be one ASCII word"
            )
        param_lines.append(f"PARAM {name} {text} 0.000000 {hostname} 0.000000\n")

    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise DataError(path, "output folder does not exist")
    tmp = directory / f".{path.name}.{secrets.token_hex(6)}.tmp"  # same file system
    try:
        with _open_output(tmp, path) as out:
            written = _write_body(out, path, scans, odometry, param_lines, hostname)
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise DataError(path, f"cannot write: {exc.strerror or exc}") from exc
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return written


def _one_word(text: str) -> bool:
    return bool(text) and text.isascii() and not any(c.isspace() for c in text)


def _param_text(value: object) -> str:
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _write_body(
    out: IO[str],
    path: Path,
    scans: Iterable[Scan],
    odometry: Iterable[tuple[float, Array]] | None,
    param_lines: list[str],
    host: str,
) -> int:
    """Header, PARAMs, then ODOM and laser lines merged by stamp; returns scans written."""
    out.write("\n".join(_HEADER) + "\n")
    out.writelines(param_lines)
    scan_iter = iter(scans)
    odom_iter = iter(odometry) if odometry is not None else iter(())

    def next_odom() -> tuple[float, Array] | None:
        item = next(odom_iter, None)
        if item is None:
            return None
        stamp, pose = float(item[0]), np.asarray(item[1], dtype=float).reshape(-1)
        if pose.shape != (3,) or not (math.isfinite(stamp) and np.isfinite(pose).all()):
            raise DataError(path, f"odometry entry at stamp {stamp}: need a finite (x, y, theta)")
        return stamp, pose

    scan = next(scan_iter, None)
    odom = next_odom()
    starts = [scan.stamp] if scan is not None else []
    starts += [odom[0]] if odom is not None else []
    t0 = min((s for s in starts if math.isfinite(s)), default=0.0)
    with_pose = scan is not None and scan.odom is not None
    if scan is None and odom is None and not param_lines:
        raise DataError(path, "nothing to write: no scans, odometry or parameters")
    written = 0
    while scan is not None or odom is not None:
        if odom is not None and (scan is None or odom[0] <= scan.stamp):
            out.write(_odom_line(odom[0], odom[1], host, t0))
            odom = next_odom()
            continue
        assert scan is not None
        if (scan.odom is not None) != with_pose:
            raise DataError(
                path,
                f"scan {written} {'has' if scan.odom is not None else 'lacks'} an odometry "
                "pose unlike the first scan: a CARMEN log needs all or none",
            )
        out.write(_laser_line(scan, written, with_pose, host, t0, path))
        written += 1
        scan = next(scan_iter, None)
    return written
