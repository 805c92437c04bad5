"""`write_log`: write scans and odometry as a CARMEN log that `CarmenLog` reads back.

The lines written (``PARAM``, ``ODOM``, ``ROBOTLASER1`` or ``RAWLASER1``), their
order and their precision are in the `write_log` docstring; the message formats are
those of the `data.carmen` docstring.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import IO

import numpy as np
from numpy.typing import NDArray

from data.atomic_write import atomic_output
from data.compression import compressing_text_writer
from data.errors import DataError, UserError
from data.types import Scan

Array = NDArray[np.float64]

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

    A ``.gz`` / ``.bz2`` suffix compresses (`data.compression.compressing_text_writer`).
    The file is written atomically (`data.atomic_write.atomic_output`), so an error
    leaves any previous file as it was and nothing else behind.

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
    with atomic_output(path, "wb") as raw, compressing_text_writer(raw, path) as out:
        written = _write_body(out, path, scans, odometry, param_lines, hostname)
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
