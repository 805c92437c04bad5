"""Every parameter of `loopclosure run`, in one tree with defaults that work.

The tree is plain dataclasses: YAML files (``--config FILE``) and ``--set
section.key=value`` overrides go through `slam.config_io`, and every run writes
the tree it used to ``config.yaml`` beside its results.

The defaults were chosen on the embedded demo and several real logs together (not
tuned to one of them); each section's class documents its fields and units.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from data.errors import UserError
from loopclosure.loop_config import LoopClosureConfig
from slam.keyframes import KeyframeConfig
from slam.occupancy_map import MapConfig
from slam.odometry.icp2d import Icp2dConfig
from slam.odometry.kiss import KissConfig
from slam.odometry.wheel import WheelConfig
from slam.refine_scans import RefineConfig
from slam.sessions import SessionsConfig

FINAL_STARTS = ("given", "incremental")
ADMISSION_CHECKS = ("exact", "screen")  # `slam.admission.CONFIRM_MODES`
"""Values of `BackendConfig.final_start`."""


@dataclass(slots=True)
class SubmapConfig:
    """Local maps around keyframes (place description and loop verification).

    Attributes:
        neighbours: keyframes on each side of a keyframe that form its submap (None:
            10 after a scan-matching front end, whose poses are locally accurate; 2
            after wheel odometry, whose drift blurs a submap a few metres long
            beyond what the geometric check accepts).
        voxel: voxel size of submap points [m].
        max_range: submap points farther than this from the keyframe are dropped [m].
        stop_at_kidnap: a keyframe after a kidnapped odometry increment (the front end's
            ``extra["kidnap"]``, an increment it could not register) starts a new
            segment of submaps, as a session start does: no submap (registration
            target, free-space origins) reaches across an increment whose odometry
            is not scan-matched.  Trailing maps (place descriptions, the longer
            re-check) still span the session.
    """

    neighbours: int | None = None
    voxel: float = 0.05
    max_range: float = 20.0
    stop_at_kidnap: bool = False


@dataclass(slots=True)
class BackendConfig:
    """The pose graph and its optimisation.

    Attributes:
        kernel: robust kernel of loop factors while mapping (see `slam.pose_graph`).
        kernel_scale: its scale in whitened units (None: the kernel's default).
        final_gnc: after the last scan, re-solve the whole graph with GNC-TLS and drop
            the loops it classifies as outliers (reported, marked in loops.csv).
        gnc_probability: chi-square quantile of the GNC inlier threshold.
        final_start: how that final GNC-TLS decides the loops: ``"incremental"``
            (time-ordered TLS admission from the odometry chain,
            `slam.consistency.incremental_tls`, its candidates compared under
            calibrated odometry by `slam.calibrated_choice`: the back end
            `eval robustness` measures as ``gnc``, which holds where most loops are
            false; seconds on thousands of keyframes) or ``"given"`` (warm GNC from
            the mapper's iSAM2 estimate: fast, and right when the accepted loops are
            nearly all true).
        odometry_floor: standard deviations added to each keyframe-to-keyframe odometry
            constraint (x [m], y [m], theta [deg]): scan-matching covariances ignore
            correlated errors, this keeps them honest.
        relinearize_threshold: iSAM2 relinearisation threshold.
        admission_check: how the incremental final pass confirms an admitted loop's
            actual cost: ``"exact"`` (a leave-one-out re-solve of each loop of a round
            whose joint cost is above the threshold) or ``"screen"`` (first clear the
            loops whose linearised leave-one-out cost is at most half the threshold,
            `slam.innovation.removal_costs`; not exact).
    """

    kernel: str = "cauchy"
    kernel_scale: float | None = None
    final_gnc: bool = True
    gnc_probability: float = 0.99
    final_start: str = "incremental"
    odometry_floor: tuple[float, float, float] = (0.002, 0.002, 0.05)
    relinearize_threshold: float = 0.01
    admission_check: str = "exact"

    def __post_init__(self) -> None:
        if self.final_start not in FINAL_STARTS:
            raise UserError(f"backend.final_start must be one of {', '.join(FINAL_STARTS)}, "
                            f"got {self.final_start!r}")
        if self.admission_check not in ADMISSION_CHECKS:
            raise UserError("backend.admission_check must be one of "
                            f"{', '.join(ADMISSION_CHECKS)}, got {self.admission_check!r}")


@dataclass(slots=True)
class PipelineConfig:
    """`loopclosure run`: front end, keyframes, loop closure, back end, map.

    Attributes:
        odometry: front end, ``icp2d``, ``kiss-icp`` or ``wheel``.
        icp2d, kiss_icp, wheel: the front ends' parameters.
        keyframes: keyframe selection.
        submap: local maps of keyframes.
        loops: the loop-closure plugin (place database, geometric check, search).
        backend: pose graph and optimisation.
        map: occupancy grid written at the end.
        refine_scans: after the final optimisation, register every scan onto the
            optimised keyframes around it (`slam.refine_scans`; keeps each scan's
            points until the end of the run).
        refine: its parameters.
        uncertainty: what gates the loop search: ``since-loop`` (odometry covariance
            accumulated since the last accepted loop closure; cheap) or ``marginal``
            (iSAM2's marginal covariance of the newest keyframe; grows with the
            distance from the first pose and costs a marginal per keyframe).
        sessions: when a new log continuing a saved map (``run --map``) is joined to it.
        front_end_worker: run the laser front end (``icp2d``, ``wheel``) in a forked
            worker process, a few scans ahead of the rest of the mapper
            (`slam.front_end_worker`; same results, the front end's time hidden on a
            second core).
    """

    odometry: str = "icp2d"
    icp2d: Icp2dConfig = field(default_factory=Icp2dConfig)
    kiss_icp: KissConfig = field(default_factory=KissConfig)
    wheel: WheelConfig = field(default_factory=WheelConfig)
    keyframes: KeyframeConfig = field(default_factory=KeyframeConfig)
    submap: SubmapConfig = field(default_factory=SubmapConfig)
    loops: LoopClosureConfig = field(default_factory=LoopClosureConfig)
    backend: BackendConfig = field(default_factory=BackendConfig)
    map: MapConfig = field(default_factory=MapConfig)
    refine_scans: bool = False
    refine: RefineConfig = field(default_factory=RefineConfig)
    uncertainty: str = "since-loop"
    sessions: SessionsConfig = field(default_factory=SessionsConfig)
    front_end_worker: bool = True

    def submap_neighbours(self) -> int:
        """Keyframes on each side of a keyframe in its submap (`SubmapConfig.neighbours`)."""
        if self.submap.neighbours is not None:
            return self.submap.neighbours
        return 2 if self.odometry == "wheel" else 10

    def front_end_config(self) -> Icp2dConfig | KissConfig | WheelConfig:
        """The parameters of the selected front end."""
        return {"icp2d": self.icp2d, "kiss-icp": self.kiss_icp, "wheel": self.wheel}.get(
            self.odometry, self.icp2d
        )
