"""The input of `loopclosure bench slam`: the scans every method maps, read once into memory.

`load_input` reads the first ``limit`` scans of a log or bag (all when None; reading
stops there) before any timing, so every method maps the same scans and no method's
time includes reading.  ``scan.index`` is the scan's position in that list.

GMapping-corrected logs carry the corrected poses in their odometry fields: the
wheel row would be the reference itself.  ``odometry_noise=SEED`` replaces every
scan's odometry with the simulator's drifting wheel-odometry model
(`data.sim.motion.wheel_odometry`, default `OdometryNoise`, generator seeded with
SEED) applied to the logged poses, as ``benchmarks/odometry.py`` does; the logged
poses stay available as the reference (`evaluation.slam_reference.logged_reference`),
which therefore requires ``odometry_noise``.

Trajectories are evaluated at `evaluation_stamps`: the scan stamps when they are
unique, else the scan index (0, 1, ...), the rule `loopclosure run` stamps its
output with (`slam.outputs.output_stamps`).
"""

from __future__ import annotations

import dataclasses
import itertools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError, warn
from data.types import PointCloud, Scan
from slam.odometry import scan_odometry

Array = NDArray[np.float64]
Progress = Callable[[str, int, int], None]
"""``progress(stage, done, total)``: called while loading and running each method."""


def no_progress(stage: str, done: int, total: int) -> None:
    """A `Progress` that shows nothing."""
    return None


@dataclass(slots=True)
class SlamInput:
    """The scans every method maps, in source order (``scan.index`` = position).

    Attributes:
        name: the source as shown in reports (its path).
        scans: the scans (odometry replaced when `odometry_noise` is set).
        read_s: seconds spent reading them.
        logged_poses: ``(N, 3)`` odometry poses as logged (before any replacement), or
            None when some scan has none.
        odometry_noise: seed of the synthetic wheel odometry, or None (logged odometry).
    """

    name: str
    scans: list[Scan | PointCloud]
    read_s: float
    logged_poses: Array | None
    odometry_noise: int | None = None

    @property
    def stamps(self) -> Array:
        """``(N,)`` scan stamps [s] as logged."""
        return np.array([float(s.stamp) for s in self.scans])


def load_input(
    path: Path,
    *,
    limit: int | None = None,
    odometry_noise: int | None = None,
    topic: str | None = None,
    odom_topic: str | None = None,
    strict: bool = False,
    progress: Progress = no_progress,
) -> SlamInput:
    """Read the first `limit` scans (all when None) of a log or bag into memory.

    Raises:
        UserError / DataError: missing or unreadable input, `limit` < 2, fewer than two
            scans, `odometry_noise` on input without odometry or on point clouds.
    """
    from data.sources import open_source

    if limit is not None and limit < 2:
        raise UserError(f"--limit must be at least 2 scans, got {limit}")
    if odometry_noise is not None and odometry_noise < 0:
        raise UserError(f"--odometry-noise must be a seed >= 0, got {odometry_noise}")
    source = open_source(path, topic=topic, odom_topic=odom_topic, strict=strict)
    start = time.perf_counter()
    total = limit or 0
    scans: list[Any] = []
    for n, scan in enumerate(itertools.islice(iter(source), limit), 1):
        scans.append(scan if scan.index == n - 1 else dataclasses.replace(scan, index=n - 1))
        if n % 100 == 0:
            progress("reading", n, max(total, n))
    progress("reading", len(scans), len(scans))
    read_s = time.perf_counter() - start
    if len(scans) < 2:
        raise UserError(f"{path}: {len(scans)} scan(s) read; the benchmark needs at least 2")
    odom = [scan_odometry(s) for s in scans]
    logged = np.array(odom) if all(o is not None for o in odom) else None
    if odometry_noise is not None:
        if logged is None or any(isinstance(s, PointCloud) for s in scans):
            missing = sum(o is None for o in odom)
            raise UserError(
                f"{path}: --odometry-noise needs planar scans that all carry odometry "
                f"({missing} of {len(scans)} have none)"
            )
        scans = synthetic_odometry(scans, logged, odometry_noise)
    return SlamInput(str(path), scans, read_s, logged, odometry_noise)


def synthetic_odometry(scans: Sequence[Scan], poses: Array, seed: int) -> list[Scan]:
    """`scans` with ``odom`` replaced by drifting wheel odometry of the true `poses` ``(N, 3)``.

    The simulator's model (`data.sim.motion.wheel_odometry`, default `OdometryNoise`,
    ``numpy.random.default_rng(seed)``); the first odometry pose equals the first pose.
    """
    from data.sim.motion import OdometryNoise, wheel_odometry

    noisy = wheel_odometry(np.asarray(poses, float), OdometryNoise(), np.random.default_rng(seed))
    return [dataclasses.replace(s, odom=o) for s, o in zip(scans, noisy, strict=True)]


def evaluation_stamps(stamps: Array) -> tuple[Array, str]:
    """Stamps of the evaluated trajectories: the scan stamps if unique, else the scan index.

    The rule of `slam.outputs.output_stamps` (without its warning).
    """
    stamps = np.asarray(stamps, dtype=float)
    if len(np.unique(stamps)) == len(stamps):
        return stamps, "scan stamps"
    return np.arange(len(stamps), dtype=float), "scan index"


def warn_without_odometry(data: SlamInput, methods: Sequence[str]) -> None:
    """One warning when the wheel method runs on scans without odometry."""
    if "wheel" in methods and data.logged_poses is None:
        missing = sum(scan_odometry(s) is None for s in data.scans)
        warn(f"{data.name}: {missing} of {len(data.scans)} scans have no odometry: the wheel "
             "row holds its last pose there")
