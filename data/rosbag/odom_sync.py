"""Attach odometry to scans: the sensor pose in the odometry frame at each scan stamp.

`OdomSync` collects ``odom -> base`` samples (from ``nav_msgs/Odometry`` or
``/tf``) and the ``base -> sensor`` chain (``/tf_static``, else ``/tf``), and hands
scans back in stream order once odometry at or after their stamp is known:
``T_odom_base(stamp) * T_base_sensor``, interpolated linearly in translation and by
shortest arc (planar) or slerp (3D) in rotation, clamped to the nearest end pose
outside the odometry span.  Poses are ``(x, y, yaw)`` [m, m, rad] for scans and
``4x4`` matrices for clouds.  The rules are in the `data.rosbag` docstring.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data import se2
from data.rosbag.messages import BadMessage, quaternion_of, stamp_of, vector_of
from data.types import PointCloud, Scan

Array = NDArray[np.float64]

BASE_FRAMES = ("base_link", "base_footprint")

_KEEP_ODOM_S = 1.0  # odometry history kept behind the last scan handed out [s]
_MAX_PENDING = 2000  # scans buffered at most while waiting for odometry
_BATCH = 64  # scans given their odometry pose together


def _frame(name: str) -> str:
    """tf frame name without the ROS1 leading slash."""
    return name.lstrip("/")


def _yaw(q: tuple[float, float, float, float]) -> float:
    """Rotation about z [rad] of a unit quaternion (the planar part of its rotation)."""
    x, y, z, w = q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _matrix(t: tuple[float, float, float], q: tuple[float, float, float, float]) -> Array:
    """``4x4`` pose of translation `t` [m] and unit quaternion `q` (x, y, z, w)."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w), t[0]],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w), t[1]],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y), t[2]],
        [0.0, 0.0, 0.0, 1.0],
    ])


def _interpolate_se3(stamps: Array, mats: Array, query: Array) -> Array:
    """``(B, 4, 4)`` poses at `query`: linear translation, slerp rotation, clamped ends."""
    from scipy.spatial.transform import Rotation, Slerp

    query = np.clip(query, stamps[0], stamps[-1])
    if len(stamps) == 1 or stamps[-1] == stamps[0]:
        return np.repeat(mats[-1:], len(query), axis=0)
    # Slerp needs strictly increasing times: keep the last sample of equal stamps.
    keep = np.append(np.diff(stamps) > 0, True)
    stamps, mats = stamps[keep], mats[keep]
    out = np.repeat(np.eye(4)[None], len(query), axis=0)
    out[:, :3, :3] = Slerp(stamps, Rotation.from_matrix(mats[:, :3, :3]))(query).as_matrix()
    for k in range(3):
        out[:, k, 3] = np.interp(query, stamps, mats[:, k, 3])
    return out


_Link = tuple[str, tuple[float, float, float], tuple[float, float, float, float]]


@dataclass
class OdomSync:
    """Attach the sensor pose in the odom frame to scans, in stream order.

    Odometry samples are the base pose in the odom frame at header stamps, kept as
    ``(x, y, yaw)`` when `planar` (scans) and as ``4x4`` matrices otherwise (clouds).
    A scan waits in `pending` until a sample at or after its stamp exists (or the
    stream ends, or more than `_MAX_PENDING` scans wait).
    """

    mode: str | None  # None, "odom" (nav_msgs/Odometry) or "tf"
    planar: bool = True
    odom_frame: str = "odom"
    base_frame: str | None = None
    stamps: list[float] = field(default_factory=list)
    samples: list[Any] = field(default_factory=list)
    statics: dict[str, _Link] = field(default_factory=dict)
    links: dict[str, _Link] = field(default_factory=dict)
    pending: deque[tuple[Scan | PointCloud, str]] = field(default_factory=deque)
    outside: int = 0  # scans outside the odometry time span (nearest pose used)
    no_odom: int = 0  # scans handed out without any odometry sample
    missing_chain: set[str] = field(default_factory=set)
    _offsets: dict[str, Array] = field(default_factory=dict)  # sensor frame -> T_base_sensor
    _chain: set[str] = field(default_factory=set)  # frames the cached offsets depend on

    # -- inputs
    def add_odometry(self, msg: Any) -> None:
        """A ``nav_msgs/Odometry`` message: pose of child_frame_id in frame_id."""
        child = _frame(msg.child_frame_id)
        if self.base_frame is None:
            self.base_frame = child
            self.odom_frame = _frame(msg.header.frame_id)
        if child == self.base_frame:
            pose = msg.pose.pose
            self._add_sample(stamp_of(msg.header), vector_of(pose.position),
                             quaternion_of(pose.orientation))

    def add_tf(self, msg: Any, static: bool) -> int:
        """A tf message; returns how many odom -> base samples it held."""
        added = 0
        for tr in msg.transforms:
            parent, child = _frame(tr.header.frame_id), _frame(tr.child_frame_id)
            try:
                t, q = vector_of(tr.transform.translation), quaternion_of(tr.transform.rotation)
            except BadMessage:
                continue
            if not static and self.mode == "tf" and parent == self.odom_frame \
                    and self._is_base(child):
                self.base_frame = child
                self._add_sample(stamp_of(tr.header), t, q)
                added += 1
                continue
            table = self.statics if static else self.links
            if child in self._chain and table.get(child) != (parent, t, q):
                self._offsets.clear()
                self._chain.clear()
            table[child] = (parent, t, q)
        return added

    def _is_base(self, child: str) -> bool:
        if self.base_frame is not None:
            return child == self.base_frame
        return child in BASE_FRAMES or child.endswith(tuple("/" + b for b in BASE_FRAMES))

    def _add_sample(self, stamp: float, t: tuple[float, float, float],
                    q: tuple[float, float, float, float]) -> None:
        sample = (t[0], t[1], _yaw(q)) if self.planar else _matrix(t, q)
        if not self.stamps or stamp >= self.stamps[-1]:
            i = len(self.stamps)
        else:
            i = bisect.bisect_right(self.stamps, stamp)
        self.stamps.insert(i, stamp)
        self.samples.insert(i, sample)

    # -- outputs
    def push(self, item: Scan | PointCloud, frame: str) -> list[Scan | PointCloud]:
        """Queue a scan; return the scans (in order) whose odometry is now known."""
        if self.mode is None:
            return [item]
        self.pending.append((item, _frame(frame)))
        return self.ready()

    def ready(self) -> list[Scan | PointCloud]:
        """Scans at the front of the queue covered by odometry, `_BATCH` at a time.

        Releasing in batches keeps the per-scan cost of the (vectorised) interpolation
        small; scans beyond `_MAX_PENDING` are forced out with the nearest pose.
        """
        n = 0
        if self.stamps:
            last = self.stamps[-1]
            while n < len(self.pending) and self.pending[n][0].stamp <= last:
                n += 1
        if n < _BATCH:
            n = 0
        return self._release(max(n, len(self.pending) - _MAX_PENDING))

    def finish(self) -> list[Scan | PointCloud]:
        """Everything still queued, with the nearest odometry pose (end of stream)."""
        return self._release(len(self.pending))

    def _release(self, n: int) -> list[Scan | PointCloud]:
        if n <= 0:
            return []
        batch = [self.pending.popleft() for _ in range(n)]
        items = [it for it, _ in batch]
        if not self.stamps:
            self.no_odom += n
            return items
        query = np.array([it.stamp for it in items])
        first, last = self.stamps[0], self.stamps[-1]
        self.outside += int(np.count_nonzero((query < first) | (query > last)))
        # Only the samples bracketing the batch take part in the interpolation.
        lo = max(0, bisect.bisect_right(self.stamps, float(query.min())) - 1)
        hi = max(bisect.bisect_left(self.stamps, float(query.max())) + 1, lo + 1)
        stamps = np.asarray(self.stamps[lo:hi])
        samples = np.asarray(self.samples[lo:hi])
        offsets = np.stack([self._offset(frame) for _, frame in batch])
        if self.planar:
            sensor = se2.compose(se2.interpolate(stamps, samples, query), offsets)
        else:
            sensor = _interpolate_se3(stamps, samples, query) @ offsets
        for it, pose in zip(items, sensor, strict=True):
            it.odom = pose
        self._prune(float(query.max()))
        return items

    def _offset(self, sensor: str) -> Array:
        """``T_base_sensor`` ((x, y, yaw) if planar) from the tf chain; identity if none.

        The chain follows /tf_static first, else the latest /tf transform of a frame.
        """
        cached = self._offsets.get(sensor)
        if cached is not None:
            return cached
        mat, frame, seen = np.eye(4), sensor, set()
        while frame and frame != self.base_frame:
            link = self.statics.get(frame) or self.links.get(frame)
            if link is None or frame in seen:
                self.missing_chain.add(sensor)
                mat = np.eye(4)
                break
            seen.add(frame)
            mat = _matrix(link[1], link[2]) @ mat
            frame = link[0]
        out = se2.from_matrix(mat) if self.planar else mat
        self._offsets[sensor] = out
        self._chain.update(seen)
        self._chain.add(sensor)
        return out

    def _prune(self, done: float) -> None:
        keep = max(0, bisect.bisect_right(self.stamps, done - _KEEP_ODOM_S) - 1)
        if keep > 0:
            del self.stamps[:keep], self.samples[:keep]
