"""The with/without comparison: a simulated run mapped with and without object landmarks.

`run_landmarks(seed, config)` reads as its steps:

1. `_library`: the known objects (one Daily-like instance of each `library_classes`,
   drawn from `library_seed`) scanned into an `ObjectLibrary`.
2. `_world`: a Box world with every library object and one instance of each
   `distractor_classes` (unknown objects) beside the route, driven `laps` times
   (`world.simulate_landmark_run`).
3. `_clusters`: the mapper's segmentation of the push-broom scans with the odometry.
4. `_recognise`: each object cluster against the library; accepted recognitions
   become observations: the cluster's centroid corrected by the matched entry's
   centre offset (`library`), as range and bearing from the keyframe nearest in time.
5. `_solve`: the keyframe pose graph without landmarks (the odometry) and with them
   (`graph.solve`).

Ground truth is used only to score: a cluster's true object is the object most of its
points hit (the simulator's `hits`); a recognition is correct when the recognised
library object is that object (its identity, hence also its class).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data import se2
from data.sim import MotionConfig, OdometryNoise
from data.stripe_scanner import daily_set
from data.stripe_scanner.daily import make_object
from data.stripe_scanner.meshes import Mesh
from slam.landmarks.graph import (
    GraphConfig,
    LandmarkObservation,
    LandmarkSolution,
    keyframe_indices,
    solve,
)
from slam.landmarks.library import (
    LibraryConfig,
    ObjectLibrary,
    Recognition,
    RecognitionConfig,
    cluster_height,
)
from slam.landmarks.segmentation import ObjectCluster, SegmentationConfig, segment
from slam.landmarks.sensor import PushBroomLaser
from slam.landmarks.world import LandmarkRun, WorldConfig, simulate_landmark_run

Array = NDArray[np.float64]
Progress = Callable[[str, int, int], None]


@dataclass(frozen=True, slots=True)
class LandmarkRunConfig:
    """Every parameter of the landmark experiment (defaults: the reported benchmark).

    Attributes:
        library_classes: Daily classes of the known objects (one instance each).
        distractor_classes: Daily classes of unknown objects also placed in the world.
        library_seed: seed of the known objects' shapes (fixed: the robot's library).
        laps: laps of the figure-eight route.
        speed: robot speed [m/s].
        laser, world, segmentation, library, recognition, graph: the parts' configs.
        odometry_noise: wheel-odometry error model.
    """

    library_classes: tuple[str, ...] = ("apple", "banana", "chips", "egg", "orange", "pear")
    distractor_classes: tuple[str, ...] = ("book", "bottle_cap", "pen")
    library_seed: int = 2024
    laps: float = 2.0
    speed: float = 0.5
    laser: PushBroomLaser = field(default_factory=PushBroomLaser)
    world: WorldConfig = field(default_factory=WorldConfig)
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    library: LibraryConfig = field(default_factory=LibraryConfig)
    recognition: RecognitionConfig = field(default_factory=RecognitionConfig)
    graph: GraphConfig = field(default_factory=GraphConfig)
    odometry_noise: OdometryNoise = field(default_factory=OdometryNoise)

    def to_json(self) -> dict[str, Any]:
        """Plain dict of every parameter."""
        return asdict(self)


@dataclass(slots=True)
class ClusterRecord:
    """One object cluster: what it was, what the library said, and how it is used.

    Attributes:
        cluster: the cluster.
        truth: index into the run's objects of the object most of its points hit (-1: none).
        truth_identity: that object's library identity (-1: unknown object or none).
        recognition: the library's answer (stripes distance and ratio tests, size verification).
        recognition_stripes_only: the stripes alone, without size verification (ablation).
        observation: the landmark observation made of it (accepted recognitions only).
        centre: estimated object centre in the odometry frame [m].
    """

    cluster: ObjectCluster
    truth: int
    truth_identity: int
    recognition: Recognition
    recognition_stripes_only: Recognition
    observation: LandmarkObservation | None
    centre: Array

    @property
    def correct(self) -> bool:
        """Accepted and the recognised object is the true one."""
        return self.recognition.accepted and self.recognition.identity == self.truth_identity


@dataclass(slots=True)
class LandmarkResult:
    """Everything the experiment produced (the benchmark scores it)."""

    config: LandmarkRunConfig
    library: ObjectLibrary
    run: LandmarkRun
    records: list[ClusterRecord]
    rejected_tracks: list[ObjectCluster]
    keyframes: NDArray[np.intp]
    without: Array
    with_landmarks: LandmarkSolution

    @property
    def observations(self) -> list[LandmarkObservation]:
        """The landmark observations in the graph."""
        return [r.observation for r in self.records if r.observation is not None]


def _known_objects(cfg: LandmarkRunConfig) -> tuple[list[Mesh], list[str]]:
    """The library's objects: one Daily-like instance per library class."""
    return daily_set(seed=cfg.library_seed, per_class=1, classes=cfg.library_classes)


def _library(cfg: LandmarkRunConfig, progress: Progress | None) -> ObjectLibrary:
    meshes, labels = _known_objects(cfg)
    lib_cfg = LibraryConfig(cfg.library.yaws_deg, cfg.library.offsets, cfg.speed)
    return ObjectLibrary.build(meshes, labels, cfg.laser, lib_cfg, cfg.segmentation,
                               cfg.recognition, seed=cfg.library_seed, progress=progress)


def _world(cfg: LandmarkRunConfig, seed: int) -> LandmarkRun:
    meshes, labels = _known_objects(cfg)
    rng = np.random.default_rng([seed, 7])
    distractors = [make_object(c, rng, f"unknown_{c}") for c in cfg.distractor_classes]
    all_meshes = [*meshes, *distractors]
    all_labels = [*labels, *cfg.distractor_classes]
    identities = [*range(len(meshes)), *[-1] * len(distractors)]
    order = np.random.default_rng([seed, 8]).permutation(len(all_meshes))
    motion = MotionConfig(speed=cfg.speed, laps=cfg.laps, lateral_offset=0.05)
    return simulate_landmark_run(
        [all_meshes[i] for i in order], [all_labels[i] for i in order],
        [identities[i] for i in order], seed=seed, laser=cfg.laser, world=cfg.world,
        motion=motion, odometry_noise=cfg.odometry_noise)


def _truth(run: LandmarkRun, cluster: ObjectCluster) -> int:
    """Index of the object most of the cluster's points hit (-1 when none)."""
    scans = np.repeat(cluster.scans, [len(b) for b in cluster.stripe_beams])
    ids = run.hits[scans, np.concatenate(cluster.stripe_beams)]
    ids = ids[ids >= 0]
    return int(np.bincount(ids).argmax()) if len(ids) else -1


def _recognise(
    run: LandmarkRun, library: ObjectLibrary, clusters: list[ObjectCluster],
    keyframes: NDArray[np.intp],
) -> list[ClusterRecord]:
    records = []
    odom_at = run.odom[run.scan_ids]
    for c in clusters:
        desc = library.describe(c)
        rec = library.recognise_descriptor(desc, cluster_height(c), len(c.scans))
        rec_ng = library.recognise_descriptor(desc)
        truth = _truth(run, c)
        identity = run.objects[truth].identity if truth >= 0 else -1
        heading = float(odom_at[c.middle_scan, 2])
        rot = np.array([[np.cos(heading), -np.sin(heading)], [np.sin(heading), np.cos(heading)]])
        centre = c.centroid + (rot @ rec.centre_offset if rec.accepted else 0.0)
        obs = None
        if rec.accepted:
            scan = int(run.scan_ids[c.middle_scan])
            k = int(np.argmin(np.abs(keyframes - scan)))
            local = se2.transform_points(se2.inverse(run.odom[keyframes[k]]), centre[None])[0]
            obs = LandmarkObservation(k, rec.identity, float(np.arctan2(local[1], local[0])),
                                      float(np.hypot(*local)))
        records.append(ClusterRecord(c, truth, identity, rec, rec_ng, obs, centre))
    return records


def run_landmarks(
    seed: int = 0,
    config: LandmarkRunConfig | None = None,
    progress: Progress | None = None,
) -> LandmarkResult:
    """Steps 1-5 of the module docstring for one seed."""
    cfg = config or LandmarkRunConfig()
    library = _library(cfg, progress)
    if progress is not None:
        progress("simulating the run", 0, 1)
    run = _world(cfg, seed)
    if progress is not None:
        progress("simulating the run", 1, 1)
    tracks = segment(run.laser, run.scan_ids, run.ranges, run.odom[run.scan_ids],
                     cfg.segmentation)
    clusters = [t for t in tracks if not t.rejected]
    keyframes = keyframe_indices(run.odom, cfg.graph.keyframe_spacing)
    records = _recognise(run, library, clusters, keyframes)
    kf_odom = run.odom[keyframes]
    observations = [r.observation for r in records if r.observation is not None]
    solution = solve(kf_odom, observations, cfg.odometry_noise, cfg.graph)
    return LandmarkResult(cfg, library, run, records, [t for t in tracks if t.rejected],
                          keyframes, kf_odom, solution)
