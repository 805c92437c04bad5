"""The methods `loopclosure bench slam` compares, each run over the same scans in memory.

* ``pipeline``: `slam.pipeline.Mapper` with the given `PipelineConfig` (front end,
  keyframes, loop closure, iSAM2, final GNC); its per-scan poses are
  `MappingResult.scan_poses`.
* ``wheel``: the logged odometry alone (``make_odometry("wheel", config.wheel)``):
  one pose per scan, no loop closure.
* ``kiss-icp``: KISS-ICP alone on the scans lifted to z = 0
  (``make_odometry("kiss-icp", config.kiss_icp)``, seeded with the wheel increment
  when the scans carry odometry), no loop closure.

All three report poses of the sensor in the odometry frame of the first scan
(``(x, y, theta)`` [m, m, rad]), one per scan, so they are directly comparable, and
the wall seconds of the run (the scans are already in memory).  `run_method` reports
a method that raises (a bug, e.g. a solver failure; not bad input) as failed, with a
warning and its error, so the other methods still run.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError, warn
from data.types import PointCloud, Scan
from evaluation.slam_input import Progress, SlamInput, no_progress
from slam.config import PipelineConfig
from slam.odometry import make_odometry
from slam.pipeline import Mapper, MappingResult

Array = NDArray[np.float64]

METHODS: tuple[str, ...] = ("pipeline", "wheel", "kiss-icp")


def parse_methods(text: str) -> list[str]:
    """Comma-separated method names (`METHODS`, or ``all``), in the given order, unique."""
    names = [n.strip().lower() for n in text.split(",") if n.strip()]
    names = ["kiss-icp" if n in ("kiss", "kissicp", "kiss_icp") else n for n in names]
    if names == ["all"]:
        return list(METHODS)
    if not names:
        raise UserError(f"--methods needs at least one of {', '.join(METHODS)}")
    unknown = [n for n in names if n not in METHODS]
    if unknown:
        raise UserError(
            f"unknown method(s) {', '.join(unknown)}; choose from {', '.join(METHODS)} or all"
        )
    return list(dict.fromkeys(names))


@dataclass(slots=True)
class MethodRun:
    """One method's per-scan trajectory and cost.

    Attributes:
        method: a name of `METHODS`.
        poses: ``(N, 3)`` sensor pose of every scan (x [m], y [m], theta [rad]); None
            when the method failed.
        wall_s: wall seconds of the run (scans already in memory; until the failure).
        statuses: front-end status counts.
        result: the pipeline's full result (``pipeline`` only).
        error: ``"ExceptionType: first line of its message"`` when the method failed.
    """

    method: str
    poses: Array | None
    wall_s: float
    statuses: dict[str, int] = field(default_factory=dict)
    result: MappingResult | None = None
    error: str | None = None


def run_pipeline(
    scans: Sequence[Scan | PointCloud], config: PipelineConfig, progress: Progress = no_progress
) -> MethodRun:
    """Map `scans` with `Mapper(config)`; Ctrl-C propagates (a partial run is no result)."""
    total = len(scans)
    start = time.perf_counter()
    mapper = Mapper(config)

    def step(n: int, keyframes: int, loops: int) -> None:
        if n % 10 == 0 or n == total:
            progress("pipeline", n, total)

    result = mapper.run(scans, progress=step)
    wall = time.perf_counter() - start
    if result.interrupted:
        raise KeyboardInterrupt
    return MethodRun("pipeline", result.scan_poses, wall, dict(result.odometry_status), result)


def run_odometry(
    name: str,
    scans: Sequence[Scan | PointCloud],
    config: PipelineConfig,
    progress: Progress = no_progress,
) -> MethodRun:
    """One front end alone over `scans` (``wheel`` or ``kiss-icp``, config from `config`)."""
    sections = {"wheel": config.wheel, "kiss-icp": config.kiss_icp}
    if name not in sections:
        raise UserError(f"run_odometry: name must be one of {', '.join(sections)}, got {name!r}")
    section = sections[name]
    total = len(scans)
    poses = np.zeros((total, 3))
    statuses: dict[str, int] = {}
    start = time.perf_counter()
    odometry = make_odometry(name, section)
    for n, scan in enumerate(scans):
        estimate = odometry.process(scan)
        poses[n] = estimate.pose
        statuses[estimate.status] = statuses.get(estimate.status, 0) + 1
        if (n + 1) % 10 == 0 or n + 1 == total:
            progress(name, n + 1, total)
    return MethodRun(name, poses, time.perf_counter() - start, statuses)


def run_method(
    name: str, data: SlamInput, config: PipelineConfig, progress: Progress = no_progress
) -> MethodRun:
    """One method; a method that raises (other than bad usage or Ctrl-C) is reported as
    failed, with a warning, and the others still run."""
    start = time.perf_counter()
    try:
        if name == "pipeline":
            return run_pipeline(data.scans, config, progress)
        return run_odometry(name, data.scans, config, progress)
    except (UserError, KeyboardInterrupt):
        raise
    except Exception as exc:  # one method's failure must not lose the others
        first = (str(exc).strip().splitlines() or [""])[0]
        message = f"{type(exc).__name__}: {first}".rstrip(": ")
        warn(f"{name} failed on {data.name}: {message}")
        return MethodRun(name, None, time.perf_counter() - start, error=message)

