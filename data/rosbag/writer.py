"""Write scans as a ROS2 bag (sqlite3 or MCAP) that ROS users can play, through `rosbags`.

`write_ros2_bag(scans, out)` streams `Scan` objects into a new ROS2 bag directory
(rosbag2 metadata version 8, CDR, ROS2 Humble message types):

- ``/scan`` ``sensor_msgs/msg/LaserScan`` in frame ``laser``: header stamp from
  ``Scan.stamp`` [s], split exactly into ``sec`` and ``nanosec`` (the float64 stamp is
  converted as an exact rational, rounded once to the nearest nanosecond; never via
  ``stamp * 1e9`` in floating point); ``angle_min`` / ``angle_max`` = first / last
  beam angle [rad], ``angle_increment`` their spacing (the angles must be uniform),
  ``range_min`` / ``range_max`` [m], ``ranges`` float32 [m], no intensities,
  ``time_increment`` and ``scan_time`` 0 (unknown).
- ``/odom`` ``nav_msgs/msg/Odometry`` (``odom`` -> ``base_link``) and ``/tf``
  ``tf2_msgs/msg/TFMessage`` (the same transform) for every scan whose ``odom`` is set:
  ``Scan.odom`` is the planar pose ``(x, y, yaw)`` of the sensor in the odom frame, so
  the pose is written at z = 0 with a yaw-only quaternion.
- ``/tf_static`` ``base_link`` -> ``laser``: identity (``Scan.odom`` already is the
  sensor pose), written once before the first scan with transient-local QoS so late
  subscribers receive it.

Every message is recorded at its header stamp, except where the input's stamps go
backwards (the Intel log's do, while its file order is the order of motion): a
scan and its odometry are then recorded 1 ns after the previous scan, so a player
replays the bag in input order; header stamps stay exact.  The bag is built in a
hidden sibling folder and renamed into place only when complete: an existing
output is never overwritten, and a failed or interrupted conversion leaves nothing
behind.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from collections.abc import Iterable
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from data.errors import DataError, UserError
from data.types import Scan

STORAGES = ("sqlite3", "mcap")
_ANGLE_TOL = 1e-5  # largest deviation from a constant beam increment accepted [rad]
_MAX_SEC = 2**31 - 1  # builtin_interfaces/Time.sec is int32


def split_stamp(stamp: float) -> tuple[int, int]:
    """``(sec, nanosec)`` of a float64 stamp [s], rounded once to the nearest nanosecond.

    The float is taken as the exact rational it represents, so no precision is lost
    to an intermediate ``stamp * 1e9`` product.
    """
    total = round(Fraction(stamp) * 10**9)
    sec, nsec = divmod(total, 10**9)
    return int(sec), int(nsec)


def _uniform_increment(angles: np.ndarray, index: int, out: Path) -> float:
    """Constant beam spacing [rad] of `angles`, or `DataError` when they are not uniform."""
    n = len(angles)
    if n < 2:
        return 0.0
    inc = float(angles[-1] - angles[0]) / (n - 1)
    deviation = float(np.max(np.abs(angles - (angles[0] + inc * np.arange(n)))))
    if not deviation <= _ANGLE_TOL or inc <= 0.0:
        raise DataError(out, f"scan {index} has non-uniform beam angles (deviation "
                             f"{deviation:.3g} rad from a constant step); a LaserScan needs a "
                             "constant angle increment")
    return inc


class _BagWriter:
    """One open rosbags Writer plus the message classes of the Humble typestore."""

    def __init__(self, path: Path, storage: str, topics: dict[str, str],
                 frames: dict[str, str]) -> None:
        from rosbags.interfaces import (
            Qos,
            QosDurability,
            QosHistory,
            QosLiveliness,
            QosReliability,
            QosTime,
        )
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.typesys import Stores, get_typestore

        self.store = get_typestore(Stores.ROS2_HUMBLE)
        self.types = self.store.types
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        self.writer = Writer(path, version=8, storage_plugin=plugin)
        self.topics, self.frames = topics, frames
        self.conns: dict[str, Any] = {}
        zero = QosTime(0, 0)
        self.latched = Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE,
                           QosDurability.TRANSIENT_LOCAL, zero, zero, QosLiveliness.AUTOMATIC,
                           zero, False)  # what ROS2 tf_static publishers offer
        self.count = 0
        self.last_ns = -1  # record time of the previous scan [ns]

    # -- message builders
    def _header(self, sec: int, nsec: int, frame: str) -> Any:
        t = self.types
        return t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=sec,
                                                                                nanosec=nsec),
                                        frame_id=frame)

    def _transform(self, sec: int, nsec: int, parent: str, child: str,
                   xyt: tuple[float, float, float]) -> Any:
        t = self.types
        x, y, yaw = xyt
        return t["geometry_msgs/msg/TransformStamped"](
            header=self._header(sec, nsec, parent),
            child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.0),
                rotation=self._yaw_quaternion(yaw),
            ),
        )

    def _yaw_quaternion(self, yaw: float) -> Any:
        return self.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2),
                                                          w=math.cos(yaw / 2))

    def _write(self, key: str, msgtype: str, msg: Any, ns: int, qos: Any = None) -> None:
        conn = self.conns.get(key)
        if conn is None:
            conn = self.writer.add_connection(self.topics[key], msgtype, typestore=self.store,
                                              offered_qos_profiles=[qos] if qos else ())
            self.conns[key] = conn
        self.writer.write(conn, ns, self.store.serialize_cdr(msg, msgtype))

    # -- one scan
    def add(self, scan: Scan, out: Path) -> None:
        """Write one scan (and its odometry) at its stamp."""
        if not isinstance(scan, Scan):
            raise DataError(out, f"cannot write {type(scan).__name__} as a LaserScan")
        index = scan.index
        stamp = float(scan.stamp)
        if not (math.isfinite(stamp) and 0.0 <= stamp <= _MAX_SEC):
            raise DataError(out, f"scan {index} has stamp {stamp!r}, outside the ROS time "
                                 "range [0, 2^31) s")
        sec, nsec = split_stamp(stamp)
        ns = max(sec * 10**9 + nsec, self.last_ns + 1)  # record time: input order
        self.last_ns = ns
        ranges = np.asarray(scan.ranges, dtype=np.float64).reshape(-1)
        angles = np.asarray(scan.angles, dtype=np.float64).reshape(-1)
        if len(ranges) == 0 or len(ranges) != len(angles) or not np.all(np.isfinite(angles)):
            raise DataError(out, f"scan {index} has {len(ranges)} ranges and {len(angles)} "
                                 "angles (need the same positive number, finite angles)")
        inc = _uniform_increment(angles, index, out)
        frame, base, odom = self.frames["laser"], self.frames["base"], self.frames["odom"]
        t = self.types
        if self.count == 0:
            static = self._transform(sec, nsec, base, frame, (0.0, 0.0, 0.0))
            self._write("tf_static", "tf2_msgs/msg/TFMessage",
                        t["tf2_msgs/msg/TFMessage"](transforms=[static]), ns, self.latched)
        if scan.odom is not None:
            pose = np.asarray(scan.odom, dtype=np.float64).reshape(-1)
            if pose.shape != (3,) or not np.all(np.isfinite(pose)):
                raise DataError(out, f"scan {index} has odometry {pose!r}; expected a finite "
                                     "(x, y, theta)")
            xyt = (float(pose[0]), float(pose[1]), float(pose[2]))
            tf = self._transform(sec, nsec, odom, base, xyt)
            self._write("tf", "tf2_msgs/msg/TFMessage", t["tf2_msgs/msg/TFMessage"](
                transforms=[tf]), ns)
            odometry = t["nav_msgs/msg/Odometry"](
                header=self._header(sec, nsec, odom),
                child_frame_id=base,
                pose=t["geometry_msgs/msg/PoseWithCovariance"](
                    pose=t["geometry_msgs/msg/Pose"](
                        position=t["geometry_msgs/msg/Point"](x=xyt[0], y=xyt[1], z=0.0),
                        orientation=self._yaw_quaternion(xyt[2]),
                    ),
                    covariance=np.zeros(36),
                ),
                twist=t["geometry_msgs/msg/TwistWithCovariance"](
                    twist=t["geometry_msgs/msg/Twist"](
                        linear=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                        angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                    ),
                    covariance=np.zeros(36),
                ),
            )
            self._write("odom", "nav_msgs/msg/Odometry", odometry, ns)
        msg = t["sensor_msgs/msg/LaserScan"](
            header=self._header(sec, nsec, frame),
            angle_min=float(angles[0]),
            angle_max=float(angles[-1]),
            angle_increment=inc,
            time_increment=0.0,
            scan_time=0.0,
            range_min=float(scan.min_range),
            range_max=float(scan.max_range),
            ranges=ranges.astype(np.float32),
            intensities=np.zeros(0, dtype=np.float32),
        )
        self._write("scan", "sensor_msgs/msg/LaserScan", msg, ns)
        self.count += 1


def write_ros2_bag(
    scans: Iterable[Scan],
    out: str | Path,
    *,
    storage: str = "sqlite3",
    scan_topic: str = "/scan",
    odom_topic: str = "/odom",
    frame_id: str = "laser",
    odom_frame: str = "odom",
    base_frame: str = "base_link",
) -> int:
    """Write `scans` as a new ROS2 bag directory `out`; return the number of scans written.

    Args:
        scans: planar scans with uniform beam angles, streamed one by one.
        out: bag directory to create (it must not exist; its parent must).
        storage: ``"sqlite3"`` (``<out>/<name>.db3``) or ``"mcap"`` (``<out>/<name>.mcap``).
        scan_topic, odom_topic: topic names of the LaserScan and Odometry messages.
        frame_id: frame of the scans (the sensor); odom_frame, base_frame: tf frames.

    Raises:
        UserError: unknown storage.
        DataError: output exists, a scan cannot be written as a LaserScan (non-uniform
            angles, bad stamp or odometry), or no scan at all.  Nothing is left behind.
    """
    out = Path(out)
    if storage not in STORAGES:
        raise UserError(f"unknown bag storage {storage!r}; choose one of {', '.join(STORAGES)}")
    if out.exists() or out.is_symlink():
        raise DataError(out, "exists already; not overwriting")
    parent = out.parent
    if not parent.is_dir():
        raise DataError(out, f"parent directory {parent} does not exist")
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial", dir=parent))
    except OSError as exc:
        raise DataError(out, f"cannot create the output: {exc.strerror or exc}") from None
    topics = {"scan": scan_topic, "odom": odom_topic, "tf": "/tf", "tf_static": "/tf_static"}
    frames = {"laser": frame_id, "odom": odom_frame, "base": base_frame}
    staged = tmp / out.name
    try:
        bag = _BagWriter(staged, storage, topics, frames)
        with bag.writer:
            for scan in scans:
                bag.add(scan, out)
            if bag.count == 0:
                raise DataError(out, "no scans to write")
        if out.exists():
            raise DataError(out, "appeared while writing; not overwriting")
        staged.rename(out)
    except OSError as exc:
        raise DataError(out, f"cannot write the bag: {exc.strerror or exc}") from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return bag.count
