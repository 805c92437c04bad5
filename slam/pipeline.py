"""The mapper: scans in, corrected trajectory, loop closures and a pose graph out.

`Mapper.run(scans)` reads as the pipeline of DESIGN.md:

    for each scan:   odometry  ->  keyframe?  ->  graph node + odometry factor
                                                  -> describe the place (database)
                                                  -> detect + verify loop closures
                                                  -> robust loop factors, iSAM2 update
    at the end:      batch GNC over every loop (outliers dropped, reported)
                     -> a pose for every scan (blended between keyframes)
                     -> optionally every scan registered onto the optimised
                        keyframes around it (`refine_scans`)

Frames: the map frame is the odometry frame of the first scan (the first
keyframe's pose is its odometry pose and is held fixed).  All poses are planar
``(x, y, theta)`` of the sensor.

Submaps: a keyframe's local map is the union of the points of keyframes
``k - n .. k + n`` (those that exist), placed by their odometry poses relative to
``k`` (odometry is locally accurate), voxel-downsampled, in k's sensor frame.  A
new keyframe's place is described from its trailing submap (``k - n .. k``).  The
loop detector pulls them through `Mapper.submap`; their version
(`Mapper.submap_version`: the newest keyframe they include) tells it when a cached
registration target is out of date.
"""

from __future__ import annotations

import resource
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from data import se2
from data.errors import UserError
from data.types import PointCloud, Scan
from loopclosure.loop_detector import LoopCandidate, LoopClosureDetector
from loopclosure.registration import voxel_downsample
from slam.config import PipelineConfig
from slam.keyframes import Keyframe, KeyframeSelector, scan_poses_from_keyframes
from slam.odometry import OdometryEstimate, make_odometry
from slam.optimize import IncrementalSmoother, optimize
from slam.refine_scans import refine_scan_poses

Array = NDArray[np.float64]
Progress = Callable[[int, int, int], None]
"""Called after every scan with (scans, keyframes, accepted loops)."""


@dataclass(slots=True)
class LoopEvent:
    """A loop-closure candidate as the pipeline saw it (for loops.csv and metrics)."""

    candidate: LoopCandidate
    stamp_query: float
    stamp_match: float
    factor: int | None = None  # index in the graph's loops when accepted
    rejected_by_gnc: bool = False


@dataclass
class MappingResult:
    """What a run produced (before it is written to files).

    Attributes:
        scan_stamps: ``(N,)`` stamp of every scan, in source order.
        scan_poses: ``(N, 3)`` optimised sensor pose of every scan (map frame).
        odometry_poses: ``(N, 3)`` front-end pose of every scan (before loop closure).
        keyframes: the keyframes (poses in `keyframe_poses`).
        keyframe_poses: id -> optimised pose.
        loops: every candidate tried.
        smoother: the back end (its graph holds every constraint).
        timings: seconds per stage.
        interrupted: the run was stopped before the end of its input.
    """

    scan_stamps: Array
    scan_poses: Array
    odometry_poses: Array
    keyframes: list[Keyframe]
    keyframe_poses: dict[int, Array]
    loops: list[LoopEvent]
    smoother: IncrementalSmoother
    timings: dict[str, float]
    interrupted: bool = False
    odometry_status: dict[str, int] = field(default_factory=dict)

    @property
    def accepted_loops(self) -> list[LoopEvent]:
        """Loops added to the graph and kept by the final optimisation."""
        return [e for e in self.loops if e.candidate.accepted and not e.rejected_by_gnc]


def peak_rss_mb() -> float:
    """Peak resident memory of this process [MB] (Linux: ru_maxrss is in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


class Mapper:
    """The SLAM pipeline (module docstring).  One instance maps one input."""

    def __init__(self, config: PipelineConfig | None = None) -> None:
        self.config = cfg = config or PipelineConfig()
        self.odometry = make_odometry(cfg.odometry, cfg.front_end_config())
        self.keyframes = KeyframeSelector(cfg.keyframes)
        self.smoother = IncrementalSmoother(
            kernel=cfg.backend.kernel,
            relinearize_threshold=cfg.backend.relinearize_threshold,
        )
        if cfg.backend.kernel_scale is not None:
            from slam.pose_graph import RobustKernel

            self.smoother.kernel = RobustKernel(cfg.backend.kernel, cfg.backend.kernel_scale)
        if cfg.uncertainty not in ("since-loop", "marginal"):
            raise UserError(
                f"unknown uncertainty {cfg.uncertainty!r}; choose since-loop or marginal"
            )
        self.detector = LoopClosureDetector(
            cfg.loops, submap=self.submap, submap_version=self.submap_version
        )
        self.loops: list[LoopEvent] = []
        self.odometry_poses: list[Array] = []
        # With `refine_scans`: every scan's points (float32; `refine_scan_poses`
        # voxelises them) and the positions of the keyframes among them.
        self._scan_points: list[NDArray[np.float32]] = []
        self._keyframe_scans: list[int] = []
        self.status: dict[str, int] = {}
        self.timings = {"odometry": 0.0, "keyframes": 0.0, "loop_detection": 0.0,
                        "optimisation": 0.0, "final_optimisation": 0.0}
        self._estimate = np.zeros((0, 3))
        # Covariance of the newest keyframe's pose relative to the last loop closure,
        # in the map frame (see `_propagate_drift`).
        self._drift = np.zeros((3, 3))
        self._submaps: dict[int, tuple[int, Array]] = {}
        self._floor = np.diag(
            np.array([cfg.backend.odometry_floor[0], cfg.backend.odometry_floor[1],
                      np.radians(cfg.backend.odometry_floor[2])]) ** 2
        )

    # -- the run ----------------------------------------------------------------------

    def run(
        self, scans: Iterable[Scan | PointCloud], progress: Progress | None = None
    ) -> MappingResult:
        """Map every scan; Ctrl-C stops early and still returns what was mapped."""
        interrupted = False
        try:
            for n, scan in enumerate(scans, 1):
                self.process(scan)
                if progress is not None:
                    progress(n, len(self.keyframes.keyframes), self._accepted())
        except KeyboardInterrupt:
            interrupted = True
        return self.finish(interrupted=interrupted)

    def process(self, scan: Scan | PointCloud) -> None:
        """One scan through odometry, keyframing and (for keyframes) loop closure."""
        if isinstance(scan, PointCloud) and self.config.odometry != "kiss-icp":
            raise UserError("point clouds need --odometry kiss-icp")
        start = time.perf_counter()
        estimate = self.odometry.process(scan)
        self.timings["odometry"] += time.perf_counter() - start
        self.status[estimate.status] = self.status.get(estimate.status, 0) + 1
        self.odometry_poses.append(np.asarray(estimate.pose, dtype=float))
        if isinstance(scan, PointCloud):
            scan = _planar_scan(scan)
        start = time.perf_counter()
        keyframe = self.keyframes.push(scan, estimate)
        self.timings["keyframes"] += time.perf_counter() - start
        if self.config.refine_scans:
            self._keep_points(scan, keyframe is not None)
        if keyframe is not None:
            self._add_keyframe(keyframe, estimate)

    def _add_keyframe(self, kf: Keyframe, estimate: OdometryEstimate) -> None:
        start = time.perf_counter()
        if kf.id == 0:
            guess = kf.odom_pose
        else:
            guess = se2.compose(self._estimate[kf.id - 1], kf.delta)
        self.smoother.add_pose(kf.id, guess)
        if kf.id > 0:
            cov = kf.covariance + self._floor
            self.smoother.add_odometry(kf.id - 1, kf.id, kf.delta, np.linalg.inv(cov))
            self._drift = _propagate_drift(self._drift, self._estimate[kf.id - 1], kf.delta, cov)
        self.timings["keyframes"] += time.perf_counter() - start
        start = time.perf_counter()
        self.detector.add_keyframe(kf.id, kf.stamp, kf.scan)
        self.timings["loop_detection"] += time.perf_counter() - start
        self._update()
        start = time.perf_counter()
        covariance = (
            self._marginal(kf.id) if self.config.uncertainty == "marginal" else self._drift
        )
        candidates = self.detector.detect(kf.id, self._estimate, covariance)
        self.timings["loop_detection"] += time.perf_counter() - start
        added = False
        for c in candidates:
            event = LoopEvent(c, kf.stamp, self.keyframes.keyframes[c.match].stamp)
            if c.accepted:
                event.factor = self.smoother.add_loop(
                    c.match, c.query, c.relative, np.linalg.inv(c.covariance)
                )
                if not added:  # the pose is now known relative to an older one
                    self._drift = _rotate_covariance(c.covariance, self._estimate[c.match, 2])
                added = True
            self.loops.append(event)
        if added:
            self._update()

    def _keep_points(self, scan: Scan, is_keyframe: bool) -> None:
        self._scan_points.append(scan.points().astype(np.float32))
        if is_keyframe:
            self._keyframe_scans.append(len(self._scan_points) - 1)

    def _update(self) -> None:
        start = time.perf_counter()
        self.smoother.update()
        est = self.smoother.estimate()
        self._estimate = np.array([est[k] for k in range(len(est))])
        self.timings["optimisation"] += time.perf_counter() - start

    def _marginal(self, key: int) -> Array | None:
        try:
            return self.smoother.marginal_covariance(key)
        except RuntimeError:
            return None

    def _accepted(self) -> int:
        return sum(1 for e in self.loops if e.candidate.accepted)

    # -- submaps ----------------------------------------------------------------------

    def submap_version(self, key: int) -> int:
        """Version of `submap(key)`: the newest keyframe it includes (it grows until
        ``key + n`` exists, then never changes)."""
        return min(key + self.config.submap_neighbours(), len(self.keyframes.keyframes) - 1)

    def submap(self, key: int) -> Array:
        """Local map of keyframe `key` in its sensor frame (module docstring), cached."""
        kfs = self.keyframes.keyframes
        n = self.config.submap_neighbours()
        hi = self.submap_version(key)
        cached = self._submaps.get(key)
        if cached is not None and cached[0] == hi:
            return cached[1]
        centre = kfs[key].odom_pose
        parts = []
        for j in range(max(0, key - n), hi + 1):
            rel = se2.between(centre, kfs[j].odom_pose)
            parts.append(se2.transform_points(rel, kfs[j].points))
        pts = np.vstack(parts) if parts else np.zeros((0, 2))
        pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= self.config.submap.max_range]
        pts = voxel_downsample(pts, self.config.submap.voxel)
        self._submaps[key] = (hi, pts)
        # Submaps far behind the newest keyframe are complete and rarely needed again.
        stale = key - 4 * n - self.config.loops.exclude_recent
        for old in [k for k in self._submaps if k < stale and self._submaps[k][0] < k + n]:
            del self._submaps[old]
        return pts

    # -- the end ----------------------------------------------------------------------

    def finish(self, interrupted: bool = False) -> MappingResult:
        """Final batch optimisation (GNC), then a pose for every scan."""
        start = time.perf_counter()
        graph = self.smoother.graph
        poses = dict(enumerate(self._estimate))
        if graph.loops and self.config.backend.final_gnc and not interrupted:
            result = optimize(
                graph, method="gnc", initial=poses,
                gnc_probability=self.config.backend.gnc_probability,
            )
            poses = result.poses
            rejected = set(result.loop_outliers)
            for event in self.loops:
                if event.factor is not None and event.factor in rejected:
                    event.rejected_by_gnc = True
        self.timings["final_optimisation"] += time.perf_counter() - start
        scan_poses = (
            scan_poses_from_keyframes(self.keyframes, poses)
            if self.keyframes.keyframes
            else np.zeros((len(self.keyframes.scan_stamps), 3))
        )
        if self.config.refine_scans and not interrupted and len(self._scan_points) == len(
            scan_poses
        ):
            start = time.perf_counter()
            scan_poses = refine_scan_poses(
                [p.astype(float) for p in self._scan_points], scan_poses,
                self._keyframe_scans, self.config.refine,
            ).poses
            self.timings["refine_scans"] = time.perf_counter() - start
        return MappingResult(
            scan_stamps=np.asarray(self.keyframes.scan_stamps, dtype=float),
            scan_poses=scan_poses,
            odometry_poses=np.asarray(self.odometry_poses).reshape(-1, 3),
            keyframes=self.keyframes.keyframes,
            keyframe_poses=poses,
            loops=self.loops,
            smoother=self.smoother,
            timings=dict(self.timings),
            interrupted=interrupted,
            odometry_status=dict(self.status),
        )


def _rotate_covariance(cov: Array, theta: float) -> Array:
    """A ``(x, y, theta)`` covariance given in a frame at heading `theta`, in the map frame."""
    c, s = np.cos(theta), np.sin(theta)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return rot @ cov @ rot.T


def _propagate_drift(drift: Array, pose: Array, delta: Array, cov: Array) -> Array:
    """First-order covariance of ``pose (+) delta`` in the map frame.

    `drift` is the covariance of `pose` (map frame, x y theta), `cov` that of `delta`
    (body frame of `pose`).  This is the uncertainty a search gate needs: how far the
    pose may have drifted since the last loop closure, without the cost of iSAM2
    marginals (which also measure drift from the *first* pose, and so grow without
    bound on a long run even where the map is locally consistent).
    """
    c, s = np.cos(pose[2]), np.sin(pose[2])
    dx, dy = delta[0], delta[1]
    jac_pose = np.array([[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy],
                         [0.0, 0.0, 1.0]])
    return jac_pose @ drift @ jac_pose.T + _rotate_covariance(cov, pose[2])


def _planar_scan(cloud: PointCloud) -> Scan:
    """A point cloud flattened into a 360-degree planar scan for keyframing and places.

    Points within 0.3 m of the sensor's height, binned by bearing (1 degree), nearest
    per bin; bins without points read as no return.
    """
    pts = cloud.points[np.abs(cloud.points[:, 2]) < 0.3]
    bins = 360
    angles = np.linspace(-np.pi, np.pi, bins, endpoint=False)
    ranges = np.full(bins, 100.0)
    if len(pts):
        r = np.hypot(pts[:, 0], pts[:, 1])
        b = ((np.arctan2(pts[:, 1], pts[:, 0]) + np.pi) / (2 * np.pi) * bins).astype(int) % bins
        np.minimum.at(ranges, b, r)
    return Scan(cloud.stamp, ranges, angles, 100.0, 0.0, None, cloud.index)
