"""Keyframe selection: which scans become nodes of the pose graph.

A scan becomes a keyframe when the odometry has moved at least `distance` metres
or turned at least `rotation_deg` degrees since the last keyframe, or when
`max_interval` seconds have passed (so a robot standing still still gets a node
now and then); the first usable scan is always one.  Between two keyframes the
per-scan increments are chained (`slam.odometry.accumulate`) into the odometry
constraint of the graph, covariance included.

Every scan remembers the keyframe before it and its pose relative to that
keyframe, so after optimisation each scan gets a pose (see
`scan_poses_from_keyframes`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data import se2
from data.types import Scan
from slam.odometry import OdometryEstimate, accumulate

Array = NDArray[np.float64]


@dataclass(slots=True)
class KeyframeConfig:
    """When a scan becomes a keyframe.

    Attributes:
        distance: travelled distance since the last keyframe [m].
        rotation_deg: rotation since the last keyframe [deg].
        max_interval: time since the last keyframe [s] (<= 0: never by time).
        min_valid_beams: scans with fewer valid beams never become keyframes.
    """

    distance: float = 0.3
    rotation_deg: float = 15.0
    max_interval: float = 10.0
    min_valid_beams: int = 20


@dataclass(slots=True)
class Keyframe:
    """A node of the graph.

    Attributes:
        id: consecutive from 0.
        stamp: the scan's stamp [s].
        scan_index: the scan's index in the source.
        odom_pose: ``(3,)`` front-end pose of the sensor (odometry frame).
        scan: the scan itself (its points describe the place and build the map).
        points: ``(M, 2)`` valid end points in the sensor frame [m].
        delta: odometry increment from the previous keyframe (``(3,)``, zero for the first).
        covariance: its ``3x3`` covariance (right perturbation, x, y, theta).
    """

    id: int
    stamp: float
    scan_index: int
    odom_pose: Array
    scan: Scan
    points: Array
    delta: Array = field(default_factory=lambda: np.zeros(3))
    covariance: Array = field(default_factory=lambda: np.eye(3) * 1e-6)


class KeyframeSelector:
    """Turns the stream of (scan, odometry estimate) into keyframes (module docstring)."""

    def __init__(self, config: KeyframeConfig | None = None) -> None:
        self.config = config or KeyframeConfig()
        self.keyframes: list[Keyframe] = []
        # Per scan, in source order: stamp, keyframe before it and the pose relative to
        # it, one row each (`GrowingRows`: no Python object per scan).
        self._scans = GrowingRows(5)
        self._delta = np.zeros(3)
        self._cov = np.zeros((3, 3))

    def push(self, scan: Scan, estimate: OdometryEstimate) -> Keyframe | None:
        """Account for one scan; returns the new keyframe if this scan became one."""
        cfg = self.config
        if self.keyframes:
            self._delta, self._cov = accumulate(
                self._delta, self._cov, estimate.delta, estimate.covariance
            )
        last = self.keyframes[-1] if self.keyframes else None
        new = None
        # Due first: most scans are not, and then their valid beams need no count.
        if ((last is None or self._due(last, estimate))
                and np.count_nonzero(scan.valid) >= cfg.min_valid_beams):
            scan = _share_angles(scan, last)
            new = Keyframe(
                id=len(self.keyframes),
                stamp=float(scan.stamp),
                scan_index=int(scan.index),
                odom_pose=np.asarray(estimate.pose, dtype=float).copy(),
                scan=scan,
                points=scan.points(),
                delta=self._delta.copy() if last is not None else np.zeros(3),
                covariance=self._cov.copy() if last is not None else np.eye(3) * 1e-6,
            )
            self.keyframes.append(new)
            self._delta, self._cov = np.zeros(3), np.zeros((3, 3))
        if self.keyframes:
            kf_id = self.keyframes[-1].id
            offset = se2.between(self.keyframes[-1].odom_pose, estimate.pose)
        else:  # scans before the first usable one hang off keyframe 0 once it exists
            kf_id, offset = -1, np.asarray(estimate.pose, dtype=float)
        self._scans.append((float(scan.stamp), kf_id, offset[0], offset[1], offset[2]))
        return new

    @property
    def last_row(self) -> tuple[float, float, float, float, float]:
        """The newest scan's row: its stamp [s], the id of the keyframe before it (-1
        before the first) and its pose relative to that keyframe ``(x, y, theta)`` [m,
        m, rad] (`scan_offset`)."""
        return tuple(float(v) for v in self._scans.data[-1])  # type: ignore[return-value]

    def adopt(self, row: ArrayLike, keyframe: Keyframe | None) -> Keyframe | None:
        """Account for one scan as another selector of the same input did (`push` in
        another process): its `last_row` and the keyframe it made of the scan (None: no
        keyframe), with no odometry work here.  The keyframe shares the previous
        keyframe's bearings array when equal, as `push` would.  A selector is fed by
        `push` or by `adopt`, not both: the odometry chained since the last keyframe is
        not kept here.  Returns the keyframe.

        Raises:
            ValueError: `keyframe` is not the next one (its id is not the count so far).
        """
        if keyframe is not None:
            if keyframe.id != len(self.keyframes):
                raise ValueError(f"keyframe {keyframe.id} adopted after "
                                 f"{len(self.keyframes)} keyframes")
            last = self.keyframes[-1] if self.keyframes else None
            scan = _share_angles(keyframe.scan, last)
            if scan is not keyframe.scan:  # a copy: the given keyframe is left as it is
                keyframe = dataclasses.replace(keyframe, scan=scan)
            self.keyframes.append(keyframe)
        self._scans.append(row)
        return keyframe

    @property
    def scan_stamps(self) -> Array:
        """``(N,)`` stamp of every scan pushed so far [s], in source order (a view)."""
        return self._scans.data[:, 0]

    @property
    def scan_keyframe(self) -> NDArray[np.int64]:
        """``(N,)`` id of the keyframe before every scan (-1 before the first keyframe)."""
        return self._scans.data[:, 1].astype(np.int64)

    @property
    def scan_offset(self) -> Array:
        """``(N, 3)`` pose of every scan relative to `scan_keyframe` (before the first
        keyframe: its odometry pose), ``(x, y, theta)`` [m, m, rad] (a view)."""
        return self._scans.data[:, 2:]

    def _due(self, last: Keyframe, estimate: OdometryEstimate) -> bool:
        cfg = self.config
        moved = se2.between(last.odom_pose, estimate.pose)
        if np.hypot(moved[0], moved[1]) >= cfg.distance:
            return True
        if abs(np.degrees(moved[2])) >= cfg.rotation_deg:
            return True
        return cfg.max_interval > 0 and abs(estimate.stamp - last.stamp) >= cfg.max_interval


def _share_angles(scan: Scan, last: Keyframe | None) -> Scan:
    """`scan`, with the bearings array of the `last` keyframe's scan when they are equal
    (a laser's bearings rarely change: one array for all keyframes, not a copy each)."""
    if last is None or last.scan.angles is scan.angles:
        return scan
    if last.scan.angles.shape == scan.angles.shape and np.array_equal(last.scan.angles,
                                                                     scan.angles):
        return dataclasses.replace(scan, angles=last.scan.angles)
    return scan


class GrowingRows:
    """A float64 ``(N, D)`` array grown by amortised doubling: appending a row never
    re-stacks the stored ones, and a row costs ``8 D`` bytes (a list of per-row arrays
    costs about 120 bytes more per row)."""

    def __init__(self, dim: int, capacity: int = 1024) -> None:
        self._data = np.zeros((capacity, dim))
        self._size = 0

    def __len__(self) -> int:
        return self._size

    def append(self, row: ArrayLike) -> None:
        """Store one ``(D,)`` row."""
        if self._size == len(self._data):
            grown = np.zeros((2 * len(self._data), self._data.shape[1]))
            grown[: self._size] = self._data[: self._size]
            self._data = grown
        self._data[self._size] = row
        self._size += 1

    @property
    def data(self) -> Array:
        """``(N, D)`` view of the stored rows."""
        return self._data[: self._size]


def scan_poses_from_keyframes(
    selector: KeyframeSelector, keyframe_poses: dict[int, Array]
) -> Array:
    """``(N, 3)`` pose of every scan pushed so far, in the map frame.

    A scan between keyframes k and k+1 is placed from both ends: ``p_a = K_k ⊕ o_k``
    (its odometry offset from k) and ``p_b = K_{k+1} ⊕ (odometry from k+1 to the scan)``,
    blended linearly by the fraction of the k -> k+1 odometry travelled, so the
    correction a loop closure makes is spread smoothly instead of jumping at keyframes.
    Scans before the first keyframe are placed from keyframe 0 by their odometry.
    """
    kfs = selector.keyframes
    n = len(selector.scan_stamps)
    if not kfs:
        return np.zeros((n, 3))
    kf_of = selector.scan_keyframe
    offsets = selector.scan_offset
    opt = np.array([keyframe_poses[k.id] for k in kfs])
    odom = np.array([k.odom_pose for k in kfs])
    out = np.zeros((n, 3))
    before = kf_of < 0
    if before.any():
        rel = se2.between(odom[0], offsets[before])
        out[before] = se2.compose(opt[0], rel)
    idx = np.flatnonzero(~before)
    k = kf_of[idx]
    p_a = se2.compose(opt[k], offsets[idx])
    nxt = np.minimum(k + 1, len(kfs) - 1)
    has_next = nxt > k
    scan_odom = se2.compose(odom[k], offsets[idx])
    p_b = se2.compose(opt[nxt], se2.between(odom[nxt], scan_odom))
    step = se2.between(odom[k], odom[nxt])
    travel = np.hypot(step[:, 0], step[:, 1]) + np.abs(step[:, 2])
    done = np.hypot(offsets[idx, 0], offsets[idx, 1]) + np.abs(offsets[idx, 2])
    w = np.where(has_next & (travel > 1e-9), np.clip(done / np.maximum(travel, 1e-9), 0, 1), 0.0)
    dtheta = se2.wrap_angle(p_b[:, 2] - p_a[:, 2])
    out[idx, :2] = (1 - w)[:, None] * p_a[:, :2] + w[:, None] * p_b[:, :2]
    out[idx, 2] = se2.wrap_angle(p_a[:, 2] + w * dtheta)
    return out
