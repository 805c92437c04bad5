"""Laser geometry of CARMEN messages: beam angles, maximum range and laser mounting.

The rules (CARMEN's ``readlog.c`` defaults, the ``PARAM`` names honoured, the
no-return bands of SICK and PLS logs) are in the *Angles* and *Maximum range*
sections of the `data.carmen` docstring.  Angles in radians (PARAM values in
degrees where CARMEN says so), ranges in metres, poses ``(x, y, theta)`` of the
laser in the robot frame.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import numpy as np
from numpy.typing import NDArray

from data.types import Scan

Array = NDArray[np.float64]

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
    """(first bearing, step) [rad] of an ``n``-beam FLASER/RLASER (`data.carmen` docstring)."""
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


def old_laser_max(params: Mapping[str, str], kind: str) -> float | None:
    """``robot_{front,rear}_laser_max`` [m] from PARAM, None when absent or not positive."""
    value = _param_float(params, f"robot_{_side(kind)}_laser_max")
    return value if value is not None and value > 0 else None


def laser_mount(params: Mapping[str, str], kind: str) -> Array:
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


def beyond_bands(ranges: Array) -> bool:
    """A reading above every no-return band: the log is a SICK in cm mode."""
    with np.errstate(invalid="ignore"):
        limit = NO_RETURN_BANDS[-1][0] + _BAND_SLACK
        return bool(np.any((ranges > limit) & np.isfinite(ranges)))


def choose_max_range(ranges: Iterable[Array]) -> float:
    """No-return threshold of a FLASER/RLASER log without PARAM (`data.carmen` docstring).

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


def field_of_view_deg(scan: Scan) -> float:
    """Field of view reported by `CarmenLog.info` [deg].

    The angle from the first to the last beam (CARMEN's and ROS's convention: 180
    for a SICK's 181 beams), except that a scan whose beams close the circle
    (span plus one step reaches 360 degrees) reports 360.
    """
    return math.degrees(scan.fov)
