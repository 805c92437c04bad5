"""Parse one line of a CARMEN log: message names, laser and ODOM messages.

A line is given as its whitespace-separated byte tokens; a line that does not
parse raises `BadLine` saying why.  Field layouts, units and the accepted
variants are in the `data.carmen` docstring.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

OLD_LASERS = ("FLASER", "RLASER")
ROBOT_LASERS = ("ROBOTLASER1", "ROBOTLASER2")
RAW_LASERS = ("RAWLASER1", "RAWLASER2", "RAWLASER3", "RAWLASER4")
LASER_MESSAGES: tuple[str, ...] = OLD_LASERS + ROBOT_LASERS + RAW_LASERS

_KNOWN_MESSAGES = frozenset(
    (
        "PARAM SYNC ODOM FLASER RLASER TRUEPOS NEFF LASER NMEAGGA NMEARMC NMEA-GGA NMEA-RMC "
        "SONAR BUMPER ARM IMU SCANMARK POSITIONLASER VELOCITY ROBOTVELOCITY VECTORMOVE "
        "BASEVELOCITY GPSNMEA FLOG ROBOTLASER RAWLASER"
    ).split()
)
_NUMBERED = re.compile(r"^(ROBOTLASER|RAWLASER|LASER)\d$")
MESSAGE_NAME = re.compile(rb"^[A-Z][A-Z0-9_\-]*$")
"""What the first token of a message line must look like."""


def is_known_message(name: str) -> bool:
    """Whether `name` is a message CARMEN writes (read or skipped by the reader)."""
    return name in _KNOWN_MESSAGES or _NUMBERED.match(name) is not None


class BadLine(Exception):
    """A line that does not parse; the message says why."""


@dataclass(slots=True)
class LaserLine:
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
        raise BadLine(f"not a number: {_short(exc)}") from None


def _short(exc: BaseException) -> str:
    text = str(exc)
    return text if len(text) <= 60 else text[:57] + "..."


def _count(token: bytes, what: str, least: int = 0) -> int:
    try:
        n = int(token)
    except ValueError:
        raise BadLine(f"{what} is not an integer: {token[:20]!r}") from None
    if n < least:
        raise BadLine(f"{what} is {n}, below {least}")
    return n


def _check_length(t: list[bytes], expected: int, what: str) -> None:
    """`expected` fields with the logger timestamp; one fewer (none) is accepted."""
    if len(t) not in (expected, expected - 1):
        raise BadLine(f"{what}: expected {expected} fields, found {len(t)}")


def _finite(values: Array, what: str) -> None:
    if not all(map(math.isfinite, values.tolist())):
        raise BadLine(f"non-finite {what}")


def parse_old_laser(t: list[bytes], line: int) -> LaserLine:
    """``FLASER``/``RLASER n ranges x y theta odom_x odom_y odom_theta ipc host logger``."""
    n = _count(t[1], "num_readings", 1) if len(t) > 1 else 0
    _check_length(t, n + 11, f"{n} readings")
    v = _floats(t[2 : n + 9])
    _finite(v[n:], "pose or timestamp")
    return LaserLine(line, float(v[n + 6]), v[:n], math.nan, math.nan, math.nan, v[n : n + 3])


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
        except (BadLine, IndexError) as exc:
            reasons.append(str(exc) if isinstance(exc, BadLine) else "line too short")
    raise BadLine(reasons[0])


def parse_new_laser(t: list[bytes], line: int, with_pose: bool) -> LaserLine:
    """``ROBOTLASERk`` (`with_pose`) or ``RAWLASERk`` (see the `data.carmen` docstring)."""
    cfg, n, m = _layout(t, 14 if with_pose else 3)
    end = 3 + cfg + n + m + (12 if with_pose else 1)  # numeric fields up to ipc
    v = _floats(t[1:end])
    start, fov, step, max_range = (float(x) for x in v[1:5])
    first = cfg + 1  # index of the first range in v
    ranges = v[first : first + n]
    tail = v[first + n + 1 + m :]
    _finite(tail, "pose or timestamp")
    if not (math.isfinite(start) and math.isfinite(fov)):
        raise BadLine("non-finite start angle or field of view")
    if not (math.isfinite(step) and step > 0.0):
        if n < 2 or not fov > 0.0:
            if n >= 2:
                raise BadLine("angular resolution and field of view are not positive")
            step = 0.0
        else:
            step = fov / (n - 1)
    if not max_range > 0.0:  # NaN or not positive: unknown (inf is "no limit")
        max_range = math.nan
    pose = tail[0:3] if with_pose else None
    return LaserLine(line, float(tail[-1]), ranges, start, step, max_range, pose)


def parse_odom(t: list[bytes]) -> tuple[float, tuple[float, float, float]]:
    """``ODOM x y theta tv rv accel ipc host logger`` -> (stamp, (x, y, theta))."""
    _check_length(t, 10, "x y theta tv rv accel")
    try:
        x, y, theta, _tv, _rv, _accel, stamp = map(float, t[1:8])
    except ValueError as exc:
        raise BadLine(f"not a number: {_short(exc)}") from None
    if not all(map(math.isfinite, (x, y, theta, stamp))):
        raise BadLine("non-finite pose or timestamp")
    return stamp, (x, y, theta)
