"""The mapper's last optimisation: one batch GNC over every loop of the finished graph.

`slam.pipeline.Mapper.finish` re-solves the whole graph from the poses its incremental
smoother estimated (`final_gnc`): the loops the GNC rejects are marked on their
`LoopEvent` and reported; ``BackendConfig.final_start`` chooses where the GNC starts
(`final_start`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from slam.config import BackendConfig
from slam.consistency import has_odometry_spine
from slam.mapping_result import LoopEvent
from slam.memory import release_free_memory
from slam.optimize import optimize
from slam.pose_graph import PoseGraph

Array = NDArray[np.float64]


def final_start(graph: PoseGraph, backend: BackendConfig) -> str:
    """`BackendConfig.final_start`, except that a graph without an odometry spine
    (sessions joined by loops alone) is decided by the warm GNC."""
    start = backend.final_start
    return "given" if start == "incremental" and not has_odometry_spine(graph) else start


def final_gnc(
    graph: PoseGraph, poses: dict[int, Array], backend: BackendConfig, loops: list[LoopEvent],
) -> tuple[dict[int, Array], set[int]]:
    """The batch GNC of `graph` from `poses` (key -> ``(3,)`` map-frame pose): its poses
    and the indices of the graph's loops it rejected, each event of `loops` whose
    factor it rejected marked ``rejected_by_gnc``."""
    result = optimize(
        graph, method="gnc", initial=poses,
        gnc_probability=backend.gnc_probability,
        gnc_start=final_start(graph, backend),
        confirm="screen" if backend.admission_check == "screen" else True,
    )
    poses = result.poses
    rejected = set(result.loop_outliers)
    release_free_memory()  # the optimisation's transients, before the outputs
    for event in loops:
        if event.factor is not None and event.factor in rejected:
            event.rejected_by_gnc = True
    return poses, rejected
