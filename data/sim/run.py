"""A complete simulated run: world, laser, trajectory, odometry, and its files on disk.

`simulate_run` is the embedded demo of the project: a robot drives two laps of a
figure-eight through a Box or Surface world (`data.sim.worlds`), scanning with a
360-degree laser (`data.raycast`) while its wheel odometry drifts
(`data.sim.motion`).  Defaults: arena 24 m x 18 m, a route of about 63 m per lap,
0.5 m/s, 4 Hz, hence about 1,000 scans of 360 beams over 250 s; every place is
revisited on the second lap after a ~63 m excursion (and the figure-eight's crossing
twice per lap), so loop closures matter.

Units and frames: stamps in seconds; poses ``(x, y, theta)`` [m, m, rad] of the
sensor; ground truth in the world frame; `Scan.odom` in the odometry frame, which
coincides with the world frame at the first scan.

Randomness: one integer `seed` makes a `numpy.random.SeedSequence` whose children
drive, in this order, the world, the motion, the odometry and the laser noise, so
e.g. `place_dataset` with the same seed sees the same world.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data import se2
from data.errors import UserError
from data.raycast import LaserModel, cast
from data.sim.motion import MotionConfig, OdometryNoise, drive, wheel_odometry
from data.sim.worlds import WORLDS, World, make_world
from data.types import Scan, Trajectory

Array = NDArray[np.float64]

#: Child index of each random stream in ``SeedSequence(seed).spawn(STREAMS)``.
STREAM_WORLD, STREAM_MOTION, STREAM_ODOMETRY, STREAM_LASER, STREAM_PLACES = range(5)
STREAMS = 5


def streams(seed: int) -> list[np.random.Generator]:
    """Independent generators for world, motion, odometry, laser and places."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise UserError(f"seed must be a non-negative integer, got {seed!r}")
    return [np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(STREAMS)]


def check_world(name: str) -> str:
    """`name` if it is a known world, else `UserError` listing the choices."""
    if name not in WORLDS:
        raise UserError(f"unknown world {name!r}: choose one of {', '.join(WORLDS)}")
    return name


@dataclass(slots=True)
class SimulatedRun:
    """Everything a simulated run produced.

    Attributes:
        scans: one `Scan` per stamp; `Scan.odom` is the drifting odometry pose of the
            sensor, `Scan.index` its position.
        ground_truth: exact sensor poses at the scan stamps (world frame).
        odometry: the odometry poses of the scans as a trajectory (odometry frame).
        world: the world driven through.
        laser: the laser model.
        motion: speed, rate, laps, lateral offset, start time.
        odometry_noise: the odometry error model.
        seed: the seed of every random stream.
        params: all of the above parameters as plain JSON.
    """

    scans: list[Scan]
    ground_truth: Trajectory
    odometry: Trajectory
    world: World
    laser: LaserModel
    motion: MotionConfig
    odometry_noise: OdometryNoise
    seed: int
    params: dict[str, Any] = field(default_factory=dict)

    def revisits(self, radius: float = 1.0, min_gap_s: float = 30.0) -> NDArray[np.intp]:
        """``(M, 2)`` scan index pairs ``i < j`` whose true positions are within
        `radius` [m] while at least `min_gap_s` [s] apart: the true loop closures."""
        from scipy.spatial import cKDTree

        xy = self.ground_truth.xytheta()[:, :2]
        pairs = cKDTree(xy).query_pairs(radius, output_type="ndarray")
        if len(pairs) == 0:
            return np.zeros((0, 2), dtype=np.intp)
        pairs = np.sort(pairs, axis=1)
        gap = self.ground_truth.stamps[pairs[:, 1]] - self.ground_truth.stamps[pairs[:, 0]]
        pairs = pairs[gap >= min_gap_s]
        return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]

    def summary(self) -> dict[str, Any]:
        """Counts and figures of the run (for the CLI and `world.json`)."""
        gt = self.ground_truth.xytheta()
        od = self.odometry.xytheta()
        step = np.linalg.norm(np.diff(gt[:, :2], axis=0), axis=1)
        end = se2.between(gt[-1], od[-1])
        return {
            "world": self.world.name,
            "seed": self.seed,
            "scans": len(self.scans),
            "beams": self.laser.beams,
            "fov_deg": self.laser.fov_deg,
            "max_range": self.laser.max_range,
            "duration_s": float(self.ground_truth.stamps[-1] - self.ground_truth.stamps[0]),
            "path_length_m": float(step.sum()),
            "segments": len(self.world.segments),
            "revisit_pairs": len(self.revisits()),
            "odometry_end_error_m": float(np.hypot(end[0], end[1])),
            "odometry_end_error_deg": float(np.degrees(abs(end[2]))),
        }


def simulate_run(
    world: str = "box",
    *,
    seed: int = 0,
    fov_deg: float = 360.0,
    beams: int = 360,
    max_range: float = 25.0,
    noise_sigma: float = 0.01,
    dropout: float = 0.01,
    motion: MotionConfig | None = None,
    odometry_noise: OdometryNoise | None = None,
    world_params: dict[str, Any] | None = None,
) -> SimulatedRun:
    """Simulate a robot driving laps of a figure-eight in a Box or Surface world.

    Args:
        world: ``"box"`` or ``"surface"``.
        seed: non-negative integer; the same seed gives the same run.
        fov_deg, beams, max_range, noise_sigma, dropout: the `LaserModel`.
        motion: speed, scan rate, laps, lateral offset (default `MotionConfig()`).
        odometry_noise: odometry error model (default `OdometryNoise()`).
        world_params: keyword arguments of the world generator
            (`data.sim.worlds.box_world` / `surface_world`).

    Raises:
        UserError: unknown world, bad seed or bad laser / motion parameters.
    """
    check_world(world)
    laser = LaserModel(fov_deg=fov_deg, beams=beams, max_range=max_range,
                       noise_sigma=noise_sigma, dropout=dropout)
    motion = motion or MotionConfig()
    odometry_noise = odometry_noise or OdometryNoise()
    rngs = streams(seed)
    w = make_world(world, rngs[STREAM_WORLD], **(world_params or {}))
    stamps, truth = drive(w.route, motion, rngs[STREAM_MOTION])
    odom = wheel_odometry(truth, odometry_noise, rngs[STREAM_ODOMETRY])
    ranges = cast(w, truth, laser, rngs[STREAM_LASER])
    scans = [
        laser.scan(r, stamp=t, odom=o, index=i)
        for i, (t, r, o) in enumerate(zip(stamps, ranges, odom, strict=True))
    ]
    params = {
        "world": world,
        "seed": int(seed),
        "laser": laser.to_json(),
        "motion": motion.to_json(),
        "odometry_noise": odometry_noise.to_json(),
        "world_params": w.params,
    }
    return SimulatedRun(
        scans=scans,
        ground_truth=Trajectory.from_xytheta(stamps, truth),
        odometry=Trajectory.from_xytheta(stamps, odom),
        world=w,
        laser=laser,
        motion=motion,
        odometry_noise=odometry_noise,
        seed=int(seed),
        params=params,
    )


def write_run(run: SimulatedRun, out_dir: str | os.PathLike[str]) -> dict[str, Path]:
    """Write a run as files the project's readers read; returns name -> path.

    * ``simulation.clf``: CARMEN log (`data.carmen.write_log`): one ``ODOM`` line
      (the odometry pose) and one ``ROBOTLASER1`` line (ranges, beam geometry, max
      range, odometry pose of the sensor) per scan.
    * ``groundtruth.tum``: the true sensor pose at every scan stamp
      (`data.trajectory_io.write_tum`).
    * ``world.json``: world segments, route, bounds, every parameter, the seed and
      the run's summary.

    `out_dir` is created if needed.  Each file is written atomically.
    """
    from data.atomic_write import output_dir, write_text_atomic
    from data.carmen import write_log
    from data.trajectory_io import write_tum

    out = output_dir(out_dir)
    paths = {
        "log": out / "simulation.clf",
        "groundtruth": out / "groundtruth.tum",
        "world": out / "world.json",
    }
    carmen_params = {
        "robot_frontlaser_offset": 0.0,
        "robot_frontlaser_side_offset": 0.0,
        "robot_frontlaser_angular_offset": 0.0,
        "simulator_world": run.world.name,
        "simulator_seed": run.seed,
    }
    odometry = [(s.stamp, s.odom) for s in run.scans]
    write_log(paths["log"], run.scans, odometry=odometry, params=carmen_params)
    write_tum(paths["groundtruth"], run.ground_truth)
    payload = {
        "format": "loopclosure-simulation",
        "seed": run.seed,
        "params": run.params,
        "summary": run.summary(),
        "world": run.world.to_json(),
    }
    write_text_atomic(paths["world"], json.dumps(payload, indent=1) + "\n")
    return paths
