"""Read ROS bags as scans: ROS1 (v2.0 and the older V1.2) and ROS2 (sqlite3, MCAP).

Modules: `backends` (the storage backends and how a bag is opened),
`ros1_records` (the sequential ROS1 record reader), `messages` (message ->
`Scan` / points), `odom_sync` (odometry attached to scans), `reader` (`RosBag`),
`writer` (`write_ros2_bag`, see its docstring).  Import from `data.rosbag`.

`RosBag(path)` is a `data.sources.ScanSource`.  It yields one `Scan` per
``sensor_msgs/LaserScan`` message, or one `PointCloud` per ``sensor_msgs/PointCloud2``
message, of a single topic, streaming (one message decoded at a time), in bag order.

Units and frames:

- ``Scan.stamp`` / ``PointCloud.stamp`` [s] come from the message header,
  ``(sec * 10**9 + nanosec) / 10**9`` (one correctly rounded float64 division, no
  intermediate float product).
- ``Scan.ranges`` [m] are the raw float32 readings as float64; ``Scan.angles`` [rad]
  are ``angle_min + i * angle_increment`` in the sensor frame (``header.frame_id``),
  reversed together with the ranges when the increment is negative so that angles
  increase.  ``max_range = range_max``, ``min_range = range_min`` [m].
- ``PointCloud.points`` [m] are the finite x, y, z of the cloud in its header frame.
- ``odom`` is the pose of the *sensor* in the odometry frame at the scan stamp:
  ``(x, y, yaw)`` [m, m, rad] for scans, a ``4x4`` matrix for clouds, or None when
  the bag has no odometry.  It is ``T_odom_base(stamp) * T_base_sensor``, where
  ``T_odom_base`` comes from a ``nav_msgs/Odometry`` topic or from the ``odom ->
  base_link`` (or ``base_footprint``) transforms on ``/tf``, interpolated at the scan
  stamp (linear in translation, shortest arc / slerp in rotation; stamps outside the
  odometry span take the nearest end pose), and ``T_base_sensor`` is the chain of
  ``/tf_static`` (or other ``/tf``) transforms from the base frame to the sensor
  frame (identity when absent; with an Odometry topic, /tf is only consulted for
  this chain when the bag has no /tf_static).  Scans are buffered until an odometry
  sample at or after their stamp arrives (or the bag ends) and handed out in batches
  of up to 64, so the stream stays in bag order with bounded memory.

Reading paths: ROS2 bags go through ``rosbags.highlevel.AnyReader`` (a directory with
``metadata.yaml``, or a single ``.db3`` / ``.mcap`` file; a file with ``metadata.yaml``
beside it is read through its directory).  ROS1 v2.0 bags go through
``rosbags.rosbag1.Reader`` (the index); when the index cannot be used (inconsistent
index records, unindexed or truncated bag) the bag is read sequentially, record by
record (format spec: wiki.ros.org/Bags/Format/2.0), with one warning.  ROS bag V1.2
files (wiki.ros.org/Bags/Format/1.2), which rosbags refuses, are read sequentially
the same way.  ROS1 messages are decoded with ``Typestore.deserialize_ros1`` (types
from the bag's own message definitions, falling back to the ROS1 Noetic types), ROS2
messages with ``deserialize_cdr``.

Bad input (missing path, not a bag, truncated or empty bag, wrong topic) raises
`DataError` naming the file; no rosbags exception escapes.  Recoverable trouble
(index fallback, undecodable messages) warns once with counts; ``strict=True``
turns it into `DataError`.
"""

from data.rosbag.backends import is_rosbag
from data.rosbag.messages import (
    LASERSCAN,
    ODOMETRY,
    POINTCLOUD2,
    TF_TYPES,
    laserscan_to_scan,
    pointcloud2_xyz,
)
from data.rosbag.odom_sync import BASE_FRAMES
from data.rosbag.reader import RosBag
from data.rosbag.writer import STORAGES, split_stamp, write_ros2_bag

__all__ = [
    "BASE_FRAMES",
    "LASERSCAN",
    "ODOMETRY",
    "POINTCLOUD2",
    "STORAGES",
    "TF_TYPES",
    "RosBag",
    "is_rosbag",
    "laserscan_to_scan",
    "pointcloud2_xyz",
    "split_stamp",
    "write_ros2_bag",
]
