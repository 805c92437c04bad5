"""The mapper: scans in, corrected trajectory, loop closures and a pose graph out.

`Mapper.run(scans)` reads as the pipeline of DESIGN.md:

    for each scan:   odometry  ->  keyframe?  ->  graph node + odometry factor
                                                  -> describe the place (database)
                                                  -> detect + verify loop closures
                                                  -> robust loop factors, iSAM2 update
                                                     (only when a loop was added: until
                                                     then a new pose is its odometry guess,
                                                     where iSAM2 would put it)
    at the end:      batch GNC over every loop (outliers dropped, reported)
                     -> a pose for every scan (blended between keyframes)
                     -> optionally every scan registered onto the optimised
                        keyframes around it (`refine_scans`)

Two processes (`Mapper.run`, `PipelineConfig.front_end_worker`): the first column
(odometry, keyframe choice, describing the place, and the place database's query
while the worker is ahead) needs only the scans and the odometry, so a forked worker
runs it a batch of scans ahead (`slam.front_end_worker`); this process does what
needs the pose estimates.  `Mapper.process(scan)` does all of it here, one scan at a
time.

A new session of a saved map (``Mapper(saved=...)``) restores the saved keyframes
first and joins the new log to them by place recognition (`slam.sessions`).

Frames: the map frame is the odometry frame of the first scan (the first
keyframe's pose is its odometry pose and is held fixed).  All poses are planar
``(x, y, theta)`` of the sensor.

Submaps: a keyframe's local map is the union of the points of keyframes
``k - n .. k + n`` placed by their odometry poses relative to ``k``, in k's sensor
frame; a new keyframe's place is described from its trailing submap (``k - n .. k``).
The loop detector pulls them through `Mapper.submap`, `Mapper.submap_version` and
`Mapper.trailing_map` (`slam.submap_cache`).

This module is the mapper's front door and its table of contents (`Mapper`, whose
methods read as the stages above); the stages' own jobs are modules of their own
(`LoopEvent` and `MappingResult` are re-exported here):

* `slam.mapping_result`: `LoopEvent` and `MappingResult`, what a run produced.
* `slam.submap_cache`: the keyframes' submaps (cached, versioned) and trailing maps.
* `slam.drift`: the drift covariance since the last loop closure (the search gate).
* `slam.session_join`: the joint graph of a saved map and the session joined to it.
* `slam.final_pass`: the final batch GNC.
* `slam.planar_scan`: a point cloud as a planar scan.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable

import numpy as np
from numpy.typing import NDArray

from data import se2
from data.errors import UserError
from data.types import PointCloud, Scan
from loopclosure.keyframe_store import KeyframePlace
from loopclosure.loop_detector import LoopClosureDetector
from loopclosure.place_match import PlaceMatch
from slam.config import PipelineConfig
from slam.drift import _propagate_drift, _rotate_covariance
from slam.final_pass import final_gnc
from slam.front_end_worker import LEAD, map_in_worker, worker_available
from slam.kernel_warm_up import warm_up_isolated
from slam.keyframes import GrowingRows, Keyframe, KeyframeSelector, scan_poses_from_keyframes
from slam.mapping_result import LoopEvent, MappingResult
from slam.memory import release_free_memory
from slam.odometry import OdometryEstimate, make_odometry
from slam.planar_scan import _planar_scan
from slam.refine_scans import refine_scan_poses
from slam.session_file import SavedMap
from slam.session_join import fill_joint_graph
from slam.session_result import complete_sessions
from slam.sessions import (
    PendingLoop,
    consistent_group,
    implied_transform,
    saved_keyframes,
    session_spans,
)
from slam.smoothers import IncrementalSmoother
from slam.submap_cache import SubmapCache, segment_span

__all__ = ["LoopEvent", "Mapper", "MappingResult", "Progress"]

Array = NDArray[np.float64]
Progress = Callable[[int, int, int], None]
"""Called after every scan with (scans, keyframes, accepted loops)."""


class Mapper:
    """The SLAM pipeline (module docstring).  One instance maps one input.

    With `saved` (a `SavedMap`, from `slam.session_file.read_saved_map`) the input is a
    new session of that map: its keyframes are restored first and the new log is
    joined to it by place recognition (`slam.sessions`); `name` names the session.
    """

    def __init__(
        self, config: PipelineConfig | None = None, saved: SavedMap | None = None,
        name: str = "",
    ) -> None:
        self.config = cfg = config or PipelineConfig()
        self.odometry = make_odometry(cfg.odometry, cfg.front_end_config())
        self.keyframes = KeyframeSelector(cfg.keyframes)
        self.smoother = self._new_smoother()
        if cfg.uncertainty not in ("since-loop", "marginal"):
            raise UserError(
                f"unknown uncertainty {cfg.uncertainty!r}; choose since-loop or marginal"
            )
        self.detector = LoopClosureDetector(
            cfg.loops, submap=self.submap, submap_version=self.submap_version,
            trailing_map=self.trailing_map,
        )
        self.detector.set_submap_origins(self.submap_origins)
        self.loops: list[LoopEvent] = []
        self._accepted_tally = (0, 0, False)  # `_accepted`: events counted, count, joined
        self._odometry_rows = GrowingRows(3)  # the front end's pose of every scan
        self._worker_stats: dict[str, float] = {}
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
        self._submap_cache = SubmapCache(cfg, self._keyframe, self._span, self._session_span)
        self._floor = np.diag(
            np.array([cfg.backend.odometry_floor[0], cfg.backend.odometry_floor[1],
                      np.radians(cfg.backend.odometry_floor[2])]) ** 2
        )
        # Sessions: the saved keyframes are keys 0 .. base-1, the new log's base ..
        self.name = name
        self._saved = saved
        self._base = 0 if saved is None else saved.n_keyframes
        self._old: list[Keyframe] = [] if saved is None else saved_keyframes(saved)
        self._old_spans = {} if saved is None else session_spans(saved["kf_session"])
        # First keys of the new session's submap segments (`_span`): its first key and,
        # with `SubmapConfig.stop_at_kidnap`, every keyframe after a kidnapped increment.
        self._segment_starts = [self._base]
        self._kidnapped = False  # a kidnapped increment since the newest keyframe
        self._joined = saved is None
        self._pending: list[PendingLoop] = []
        self._joined_at: int | None = 0 if saved is None else None
        self._joined_after: float | None = 0.0 if saved is None else None
        self._path = 0.0  # odometry path length of the new session [m]
        if saved is not None:
            self._restore(saved)

    def _new_smoother(self) -> IncrementalSmoother:
        backend = self.config.backend
        smoother = IncrementalSmoother(
            kernel=backend.kernel, relinearize_threshold=backend.relinearize_threshold
        )
        if backend.kernel_scale is not None:
            from slam.pose_graph import RobustKernel

            smoother.kernel = RobustKernel(backend.kernel, backend.kernel_scale)
        return smoother

    def _restore(self, saved: SavedMap) -> None:
        """The saved keyframes into the place database (session 0, the map frame)."""
        start = time.perf_counter()
        empty = Scan(0.0, np.zeros(0), np.zeros(0), 1.0)
        for k, kf in enumerate(self._old):
            self.detector.add_keyframe(
                k, kf.stamp, kf.scan, session=0, place_scan=saved.place_scan(k) or empty
            )
        self._estimate = np.asarray(saved["kf_pose"], dtype=float).reshape(-1, 3).copy()
        self.timings["restore"] = time.perf_counter() - start

    # -- the run ----------------------------------------------------------------------

    def run(
        self, scans: Iterable[Scan | PointCloud], progress: Progress | None = None
    ) -> MappingResult:
        """Map every scan (the front end in a worker process where it can: module
        docstring); Ctrl-C stops early and still returns what was mapped."""
        interrupted = False
        worker = self._front_end_in_worker()
        if worker:
            warm_up_isolated()  # load the kernels here: the forked worker inherits them
            steps = map_in_worker(self._worker_step, scans, self._worker_stats)
        else:
            steps = ((scan, (*self._odometry_step(scan), None, None, 0.0, None, None))
                     for scan in scans)
        try:
            for n, (scan, step) in enumerate(steps, 1):
                self._after_odometry(scan, *step, from_worker=worker)
                if progress is not None:
                    progress(n, len(self.keyframes.keyframes), self._accepted())
        except KeyboardInterrupt:
            interrupted = True
        except SystemError as exc:  # Ctrl-C during a numba kernel surfaces as this
            if not isinstance(exc.__cause__, KeyboardInterrupt):
                raise
            interrupted = True
        finally:
            steps.close()  # stops the worker of an interrupted run
        return self.finish(interrupted=interrupted)

    def process(self, scan: Scan | PointCloud) -> None:
        """One scan through odometry, keyframing and (for keyframes) loop closure."""
        self._after_odometry(scan, *self._odometry_step(scan))

    def _front_end_in_worker(self) -> bool:
        """`PipelineConfig.front_end_worker`, for the laser front ends, where a process
        can fork (`slam.front_end_worker`)."""
        return (self.config.front_end_worker and self.config.odometry != "kiss-icp"
                and worker_available())

    def _odometry_step(self, scan: Scan | PointCloud) -> tuple[OdometryEstimate, float]:
        """The front end's estimate of `scan` and the seconds it took."""
        if isinstance(scan, PointCloud) and self.config.odometry != "kiss-icp":
            raise UserError("point clouds need --odometry kiss-icp")
        start = time.perf_counter()
        estimate = self.odometry.process(scan)
        return estimate, time.perf_counter() - start

    def _worker_step(self, scan: Scan, ahead: int) -> tuple[
        OdometryEstimate, float, KeyframePlace | None, list[PlaceMatch] | None, float,
        tuple[int, Array] | None, tuple[tuple[float, ...], Keyframe | None],
    ]:
        """In the front end's worker (`slam.front_end_worker`), a fork of this mapper:
        the odometry of `scan` and, when it makes a keyframe, that keyframe's place
        description, with the seconds taken.  Keyframes and places depend only on the
        odometry, so the worker's copies of the keyframe selector and the detector stay
        in step with the mapper's.  While the worker is `ahead` of the mapper by
        `LEAD` results it also asks the place database (the same matches, which the
        mapper otherwise asks for itself): the work goes to whichever process waits.
        The keyframe's submap, when its description made it (a sensor narrower than a
        full circle), goes along with its version: the mapper's `detect` of the
        keyframe asks for that very submap (no newer keyframe exists there yet).  The
        keyframe selector's row of the scan and the keyframe it made go along too: the
        mapper adopts them instead of selecting again (`KeyframeSelector.adopt`)."""
        estimate, seconds = self._odometry_step(scan)
        keyframe = self.keyframes.push(scan, estimate)
        self._note_kidnap(estimate, keyframe)
        selected = (self.keyframes.last_row, keyframe)
        if keyframe is None:
            return estimate, seconds, None, None, 0.0, None, selected
        start = time.perf_counter()
        key, session = self._base + keyframe.id, int(self._saved is not None)
        place = self.detector.describe_keyframe(key, keyframe.stamp, keyframe.scan,
                                                session=session)
        self.detector.add_keyframe(key, keyframe.stamp, keyframe.scan, session=session,
                                   place=place)
        matches = self.detector.appearance_matches(key) if ahead >= LEAD else None
        return (estimate, seconds, place, matches, time.perf_counter() - start,
                self._submaps.get(key), selected)

    def _after_odometry(
        self, scan: Scan | PointCloud, estimate: OdometryEstimate, seconds: float,
        place: KeyframePlace | None = None, matches: list[PlaceMatch] | None = None,
        place_seconds: float = 0.0, submap: tuple[int, Array] | None = None,
        selected: tuple[tuple[float, ...], Keyframe | None] | None = None, *,
        from_worker: bool = False,
    ) -> None:
        """Keyframing and (for keyframes) loop closure of a scan the front end placed;
        `place`, `matches` and `submap` are the keyframe's place description, the place
        database's matches of it and its submap ``(version, points)`` when the worker
        made them (`from_worker`), `selected` the worker's keyframe selection of the
        scan (its selector's row and keyframe, adopted here; None: selected here)."""
        self.timings["odometry"] += seconds
        self.timings["loop_detection"] += place_seconds
        if from_worker:  # of loop_detection, the seconds the worker spent [s]
            self.timings["loop_detection_in_worker"] = (
                self.timings.get("loop_detection_in_worker", 0.0) + place_seconds)
        self.status[estimate.status] = self.status.get(estimate.status, 0) + 1
        self._odometry_rows.append(estimate.pose)
        if isinstance(scan, PointCloud):
            scan = _planar_scan(scan)
        start = time.perf_counter()
        keyframe = (self.keyframes.push(scan, estimate) if selected is None
                    else self.keyframes.adopt(*selected))
        self._note_kidnap(estimate, keyframe)
        self.timings["keyframes"] += time.perf_counter() - start
        if self.config.refine_scans:
            self._keep_points(scan, keyframe is not None)
        if from_worker and (keyframe is None) != (place is None):
            raise RuntimeError("the front end worker's keyframes differ from the mapper's")
        if keyframe is not None:
            if submap is not None:
                self._adopt_submap(self._base + keyframe.id, *submap)
            self._add_keyframe(keyframe, estimate, place, matches)

    @property
    def saved(self) -> SavedMap | None:
        """The saved map this run continues (None: a run of its own)."""
        return self._saved

    @property
    def joined(self) -> bool:
        """The new session is in the saved map's frame (always true without one)."""
        return self._joined

    def _add_keyframe(
        self, kf: Keyframe, estimate: OdometryEstimate, place: KeyframePlace | None = None,
        matches: list[PlaceMatch] | None = None,
    ) -> None:
        start = time.perf_counter()
        key = self._base + kf.id
        if kf.id == 0:
            guess = kf.odom_pose
        else:
            guess = se2.compose(self._estimate[key - 1], kf.delta)
        self.smoother.add_pose(key, guess)
        # iSAM2 would put the new pose at its guess: its update waits for a loop.
        self._estimate = np.vstack([self._estimate[:key], guess])
        if kf.id > 0:
            cov = kf.covariance + self._floor
            self.smoother.add_odometry(key - 1, key, kf.delta, np.linalg.inv(cov))
            self._drift = _propagate_drift(self._drift, self._estimate[key - 1], kf.delta, cov)
            self._path += float(np.hypot(kf.delta[0], kf.delta[1]))
        self.timings["keyframes"] += time.perf_counter() - start
        start = time.perf_counter()
        self.detector.add_keyframe(key, kf.stamp, kf.scan, session=int(self._saved is not None),
                                   place=place)
        self.timings["loop_detection"] += time.perf_counter() - start
        if self.config.uncertainty == "marginal":
            self._update()  # iSAM2's marginal of the new pose gates the search
        start = time.perf_counter()
        covariance = (
            self._marginal(key) if self.config.uncertainty == "marginal" else self._drift
        )
        candidates = self.detector.detect(key, self._estimate, covariance, matches)
        self.timings["loop_detection"] += time.perf_counter() - start
        added = False
        for c in candidates:
            event = LoopEvent(c, kf.stamp, self._keyframe(c.match).stamp)
            if c.accepted and not self._joined and c.match < self._base:
                self._pending.append(PendingLoop(event, c.match, c.query, c.relative))
            elif c.accepted:
                event.factor = self.smoother.add_loop(
                    c.match, c.query, c.relative, np.linalg.inv(c.covariance)
                )
                if not added:  # the pose is now known relative to an older one
                    self._drift = _rotate_covariance(c.covariance, self._estimate[c.match, 2])
                added = True
            self.loops.append(event)
        if added:
            self._update()
        if self._pending and not self._joined:
            self._try_join(kf)

    @property
    def odometry_poses(self) -> Array:
        """``(N, 3)`` front-end pose of every scan so far (odometry frame; a view)."""
        return self._odometry_rows.data

    def _keep_points(self, scan: Scan, is_keyframe: bool) -> None:
        self._scan_points.append(scan.points().astype(np.float32))
        if is_keyframe:
            self._keyframe_scans.append(len(self._scan_points) - 1)

    def _update(self) -> None:
        start = time.perf_counter()
        self.smoother.update()
        keys, poses = self.smoother.estimate_rows()
        first = 0 if self._joined else self._base
        if len(keys) and not np.array_equal(keys, np.arange(first, first + len(keys))):
            raise RuntimeError("pose keys are not consecutive")  # a mapper bug, not input
        if self._joined:
            self._estimate = poses.reshape(-1, 3)
        else:  # the saved poses, then the new session's in its own frame
            self._estimate = np.vstack([self._estimate[: self._base], poses.reshape(-1, 3)])
        self.timings["optimisation"] += time.perf_counter() - start

    def _marginal(self, key: int) -> Array | None:
        try:
            return self.smoother.marginal_covariance(key)
        except RuntimeError:
            return None

    def _accepted(self) -> int:
        """Loops accepted so far (the progress display asks at every scan): the events
        added since the last call are counted onto the last count, and all of them once
        more after a session join, the one place an event's verdict changes later."""
        counted, count, joined = self._accepted_tally
        if joined != self._joined:
            counted, count = 0, 0
        count += sum(1 for e in self.loops[counted:] if e.candidate.accepted)
        self._accepted_tally = (len(self.loops), count, self._joined)
        return count

    # -- sessions (`slam.sessions`, `slam.session_join`) ------------------------------

    def _try_join(self, kf: Keyframe) -> None:
        """Join the new session when enough pending loops agree (`slam.sessions`): one
        graph of both, the new poses moved into the map frame."""
        group = consistent_group(self._pending, self._estimate, self.config.sessions)
        if not group:
            return
        start = time.perf_counter()
        saved, base = self._saved, self._base
        assert saved is not None
        first = self._pending[group[0]]
        t = implied_transform(
            self._estimate[first.match], first.relative, self._estimate[first.query]
        )
        joint = self._new_smoother()
        offset = fill_joint_graph(joint, saved, base, self.smoother.graph, self._estimate, t)
        for e in self.loops:
            if e.factor is not None:
                e.factor += offset
        for n, p in enumerate(self._pending):
            c = p.event.candidate
            if n in group:
                p.event.factor = joint.add_loop(
                    p.match, p.query, p.relative, np.linalg.inv(c.covariance))
            else:
                c.accepted, c.reason = False, "inconsistent with the session join"
        self._pending = []
        self.smoother = joint
        self._joined = True
        self._joined_at = kf.id
        self._joined_after = self._path
        self.detector.join(1, 0)
        self._drift = _rotate_covariance(first.event.candidate.covariance,
                                         saved["kf_pose"][first.match][2])
        self.timings["optimisation"] += time.perf_counter() - start
        self._update()
        self._catch_up(kf.id)

    def _catch_up(self, joined_at: int) -> None:
        """The new session's keyframes from before the join, nearest to it first, each
        checked against the saved map by the pose search (they met it in their own
        frame, where only a check with no prior could see it)."""
        start, optimisation = time.perf_counter(), self.timings["optimisation"]
        kfs = self.keyframes.keyframes
        drift = self._drift  # of the join keyframe; grows with every step back
        for kf in reversed(kfs[:joined_at]):
            key = self._base + kf.id
            later = kfs[kf.id + 1]
            drift = _propagate_drift(drift, self._estimate[key + 1], se2.inverse(later.delta),
                                     later.covariance + self._floor)
            added = False
            for c in self.detector.detect_pose(key, self._estimate, drift, below=self._base):
                event = LoopEvent(c, kf.stamp, self._keyframe(c.match).stamp)
                if c.accepted:
                    event.factor = self.smoother.add_loop(
                        c.match, c.query, c.relative, np.linalg.inv(c.covariance))
                    added = True
                self.loops.append(event)
            if added:
                self._update()
        self.timings["loop_detection"] += (time.perf_counter() - start) - (
            self.timings["optimisation"] - optimisation)  # _update times its own part

    def _keyframe(self, key: int) -> Keyframe:
        """Keyframe `key` of any session (saved ones first)."""
        return self._old[key] if key < self._base else self.keyframes.keyframes[key - self._base]

    def _span(self, key: int) -> tuple[int, int]:
        """First and last key so far of `key`'s submap segment: its session, or in the
        new session with `SubmapConfig.stop_at_kidnap` the stretch between kidnapped
        increments (`_note_kidnap`).  Trailing maps span the session (`_session_span`)."""
        if key < self._base:
            return self._old_spans[int(self._saved["kf_session"][key])]
        return segment_span(self._segment_starts, key,
                            self._base + len(self.keyframes.keyframes) - 1)

    def _session_span(self, key: int) -> tuple[int, int]:
        """First and last key so far of `key`'s session (the span of trailing maps)."""
        if key < self._base:
            return self._old_spans[int(self._saved["kf_session"][key])]
        return self._base, self._base + len(self.keyframes.keyframes) - 1

    def _note_kidnap(self, estimate: OdometryEstimate, keyframe: Keyframe | None) -> None:
        """With `SubmapConfig.stop_at_kidnap`: a keyframe after a kidnapped increment
        (the front end's ``extra["kidnap"]``, between it and the keyframe before) starts
        a submap segment.  Called for every scan, in the mapper and in the front end's
        worker alike, so both build the same submaps."""
        if not self.config.submap.stop_at_kidnap:
            return
        self._kidnapped = self._kidnapped or bool(estimate.extra.get("kidnap", False))
        if keyframe is not None:
            if self._kidnapped and keyframe.id > 0:
                self._segment_starts.append(self._base + keyframe.id)
            self._kidnapped = False

    # -- submaps (`slam.submap_cache`) ------------------------------------------------

    def submap_version(self, key: int) -> int:
        """Version of `submap(key)`: the newest keyframe it includes."""
        return self._submap_cache.version(key)

    def submap(self, key: int) -> Array:
        """Local map of keyframe `key` in its sensor frame [m] (module docstring), cached."""
        return self._submap_cache.submap(key)

    def submap_origins(self, key: int) -> tuple[Array, Array]:
        """The keys `submap(key)` merges and their front-end sensor poses in `key`'s
        sensor frame (``(k,)``, ``(k, 3)`` [m, rad])."""
        return self._submap_cache.origins(key)

    def trailing_map(self, key: int, n: int) -> Array:
        """Keyframes ``key - n .. key`` of `key`'s session, in `key`'s sensor frame [m],
        cropped and voxelised as a submap (the loop detector's wide view)."""
        return self._submap_cache.trailing_map(key, n)

    def _local_points(self, key: int, first: int, last: int) -> Array:
        """Keyframes ``first .. last`` in `key`'s sensor frame [m], cropped and voxelised."""
        return self._submap_cache.local_points(key, first, last)

    def _adopt_submap(self, key: int, version: int, points: Array) -> None:
        """`submap(key)` as the front end's worker built it, cached when current."""
        self._submap_cache.adopt(key, version, points)

    @property
    def _submaps(self) -> dict[int, tuple[int, Array]]:
        """The cached submaps: key -> (version, points)."""
        return self._submap_cache.submaps

    # -- the end (`slam.final_pass`, `slam.mapping_result`) ---------------------------

    def _release_incremental_solver(self) -> None:
        """Before the final batch GNC, which re-solves the whole graph from the poses
        estimated so far: iSAM2's factorisation (its Bayes tree and linearisation
        points, tens of MB on thousands of keyframes) is not needed any more, so a
        fresh smoother holding the same `PoseGraph` replaces it and it is freed, not
        resident under the GNC's own transients."""
        fresh = self._new_smoother()
        fresh.graph = self.smoother.graph
        self.smoother = fresh
        release_free_memory()

    def finish(self, interrupted: bool = False) -> MappingResult:
        """Final batch optimisation (GNC), then a pose for every scan."""
        start = time.perf_counter()
        # The submaps and their registration targets are caches (rebuilt on demand):
        # not resident under the final optimisation's transients.
        self._submap_cache.clear()
        self.detector.release_caches()
        graph = self.smoother.graph
        known = len(self._estimate)  # a run stopped by Ctrl-C may hold a newer pose
        poses = {k: self._estimate[k] if k < known else graph.initial[k] for k in graph.initial}
        rejected: set[int] = set()
        if graph.loops and self.config.backend.final_gnc and not interrupted:
            self._release_incremental_solver()
            poses, rejected = final_gnc(graph, poses, self.config.backend, self.loops)
        for p in self._pending:  # the sessions were never joined
            p.event.candidate.accepted = False
            p.event.candidate.reason = "session not joined (too few consistent loops)"
        self.timings["final_optimisation"] += time.perf_counter() - start
        local = {k.id: poses[self._base + k.id] for k in self.keyframes.keyframes}
        scan_poses = (
            scan_poses_from_keyframes(self.keyframes, local)
            if self.keyframes.keyframes
            else np.zeros((len(self.keyframes.scan_stamps), 3))
        )
        if self.config.refine_scans and not interrupted and len(self._scan_points) == len(
            scan_poses
        ):
            start = time.perf_counter()
            scan_poses = refine_scan_poses(
                self._scan_points, scan_poses,
                self._keyframe_scans, self.config.refine,
            ).poses
            self.timings["refine_scans"] = time.perf_counter() - start
        result = MappingResult(
            scan_stamps=self.keyframes.scan_stamps.copy(),
            scan_poses=scan_poses,
            odometry_poses=self.odometry_poses.copy(),
            keyframes=self.keyframes.keyframes,
            keyframe_poses=local,
            loops=self.loops,
            smoother=self.smoother,
            timings=dict(self.timings),
            interrupted=interrupted,
            odometry_status=dict(self.status),
            loop_outliers=rejected,
            worker_peak_rss_mb=self._worker_stats.get("peak_rss_mb", 0.0),
        )
        return complete_sessions(self, result, poses)

