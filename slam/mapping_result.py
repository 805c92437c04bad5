"""What a run of the mapper produced: `LoopEvent` per loop candidate, `MappingResult`.

`slam.pipeline.Mapper.finish` makes the `MappingResult` (`slam.session_result` completes
it with the sessions and the saved map); `slam.results.write_results` writes it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from loopclosure.loop_candidate import LoopCandidate
from slam.keyframes import Keyframe
from slam.session_file import SavedMap, SessionInfo
from slam.smoothers import IncrementalSmoother

Array = NDArray[np.float64]


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
        timings: seconds per stage (with the front end's worker,
            ``loop_detection_in_worker`` is the part of ``loop_detection`` measured in
            the worker: place descriptions and the matches it made while ahead).
        interrupted: the run was stopped before the end of its input.
        sessions: every session of the map, oldest first (one without ``--map``).
        saved_map: the run as a saved map (``session.npz``; of an interrupted run too:
            what was mapped).
        loop_outliers: indices of the graph's loops the final optimisation rejected.
        worker_peak_rss_mb: peak resident memory of the front end's worker process
            [MB] (`slam.front_end_worker`; 0 without one).
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
    sessions: list[SessionInfo] = field(default_factory=list)
    saved_map: SavedMap | None = None
    loop_outliers: set[int] = field(default_factory=set)
    worker_peak_rss_mb: float = 0.0

    @property
    def accepted_loops(self) -> list[LoopEvent]:
        """Loops added to the graph and kept by the final optimisation."""
        return [e for e in self.loops if e.candidate.accepted and not e.rejected_by_gnc]
