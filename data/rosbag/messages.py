"""Turn decoded ROS messages into the project's types: `Scan`, `PointCloud` points, stamps.

Message types are rosbags' ROS2-style names (``sensor_msgs/msg/LaserScan``); the
messages are what ``Typestore.deserialize_ros1`` / ``deserialize_cdr`` return.
Units and frames (stamps [s], ranges [m], angles [rad] in the sensor frame) are in
the `data.rosbag` docstring.  A message that decodes but cannot be converted raises
`BadMessage`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.types import Scan

Array = NDArray[np.float64]

LASERSCAN = "sensor_msgs/msg/LaserScan"
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")

_POINTFIELD_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


class BadMessage(Exception):
    """A message that decodes but cannot be turned into a scan (internal)."""


def stamp_of(header: Any) -> float:
    """Header stamp [s] as float64, one correctly rounded division of integers."""
    return (int(header.stamp.sec) * 10**9 + int(header.stamp.nanosec)) / 10**9


def vector_of(v: Any) -> tuple[float, float, float]:
    """Finite ``(x, y, z)`` of a Point / Vector3 message."""
    out = (float(v.x), float(v.y), float(v.z))
    if not all(math.isfinite(c) for c in out):
        raise BadMessage("non-finite translation")
    return out


def quaternion_of(q: Any) -> tuple[float, float, float, float]:
    """Unit ``(x, y, z, w)`` of a Quaternion message."""
    x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not math.isfinite(n) or n == 0.0:
        raise BadMessage("quaternion of zero or non-finite norm")
    return x / n, y / n, z / n, w / n


def laserscan_to_scan(msg: Any, index: int = 0) -> Scan:
    """`Scan` of a ``sensor_msgs/LaserScan`` message (see the `data.rosbag` docstring)."""
    ranges = np.asarray(msg.ranges, dtype=np.float64)
    n = len(ranges)
    if n == 0:
        raise BadMessage("LaserScan with no ranges")
    a0, inc = float(msg.angle_min), float(msg.angle_increment)
    if not (np.isfinite(a0) and np.isfinite(inc)) or (n > 1 and inc == 0.0):
        raise BadMessage(f"LaserScan with invalid angles (min {a0}, increment {inc})")
    angles = a0 + np.arange(n) * inc
    if inc < 0:
        angles, ranges = angles[::-1].copy(), ranges[::-1].copy()
    rmax, rmin = float(msg.range_max), float(msg.range_min)
    if not np.isfinite(rmax) or rmax <= 0.0:
        rmax = np.inf
    if not np.isfinite(rmin) or rmin < 0.0:
        rmin = 0.0
    return Scan(stamp=stamp_of(msg.header), ranges=ranges, angles=angles, max_range=rmax,
                min_range=rmin, odom=None, index=index)


def pointcloud2_xyz(msg: Any) -> tuple[Array, int]:
    """``(N, 3)`` finite x, y, z [m] of a ``sensor_msgs/PointCloud2`` and the dropped count.

    Decoded in one go with a numpy structured dtype built from the x/y/z field
    offsets, ``point_step`` and the message endianness; rows are gathered with
    ``row_step`` strides when they are padded.  Non-finite points are dropped
    whatever ``is_dense`` claims.
    """
    fields = {f.name: f for f in msg.fields}
    missing = [a for a in "xyz" if a not in fields]
    if missing:
        raise BadMessage(f"PointCloud2 without field(s) {', '.join(missing)}")
    order = ">" if msg.is_bigendian else "<"
    formats, offsets = [], []
    step = int(msg.point_step)
    for axis in "xyz":
        pf = fields[axis]
        if int(pf.datatype) not in (7, 8):
            raise BadMessage(f"PointCloud2 field {axis} is not float32/float64")
        fmt = np.dtype(order + _POINTFIELD_DTYPES[int(pf.datatype)])
        if int(pf.offset) + fmt.itemsize > step:
            raise BadMessage(f"PointCloud2 field {axis} lies outside point_step {step}")
        formats.append(fmt)
        offsets.append(int(pf.offset))
    width, height, row_step = int(msg.width), int(msg.height), int(msg.row_step)
    count = width * height
    if count == 0:
        return np.empty((0, 3)), 0
    data = np.asarray(msg.data, dtype=np.uint8)
    row_bytes = width * step
    if row_step < row_bytes or len(data) < (height - 1) * row_step + row_bytes:
        raise BadMessage(f"PointCloud2 data of {len(data)} bytes is too short for "
                         f"{height}x{width} points")
    if row_step == row_bytes or height == 1:
        buf = data[: count * step]
    else:
        rows = np.lib.stride_tricks.as_strided(data, shape=(height, row_bytes),
                                               strides=(row_step, 1), writeable=False)
        buf = np.ascontiguousarray(rows).reshape(-1)
    dtype = np.dtype({"names": ["x", "y", "z"], "formats": formats, "offsets": offsets,
                      "itemsize": step})
    arr = np.frombuffer(buf.tobytes() if not buf.flags.c_contiguous else buf, dtype=dtype,
                        count=count)
    pts = np.column_stack([arr["x"], arr["y"], arr["z"]]).astype(np.float64)
    finite = np.isfinite(pts).all(axis=1)
    return pts[finite], int(count - np.count_nonzero(finite))
