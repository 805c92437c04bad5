"""2D laser simulator: the embedded demo and the synthetic data sets of the paper.

Modules: `worlds` (Box and Surface worlds of line segments, with a drivable
figure-eight route), `motion` (trajectory along the route, drifting wheel
odometry), `run` (a complete simulated run and its files), `places`
(place-recognition data sets).  The laser itself is `data.raycast` (plain
geometry, re-exported here: `LaserModel`, `cast`, `trace`).

Everything is deterministic for a seed: randomness comes only from
`numpy.random.Generator` objects passed down (see `data.sim.run.streams`).
"""

from data.raycast import LaserModel, cast, trace
from data.sim.motion import MotionConfig, OdometryNoise, drive, wheel_odometry
from data.sim.places import place_dataset, place_poses
from data.sim.run import SimulatedRun, simulate_run, write_run
from data.sim.worlds import WORLDS, World, box_world, make_world, surface_world, turning_angles

__all__ = [
    "WORLDS",
    "LaserModel",
    "MotionConfig",
    "OdometryNoise",
    "SimulatedRun",
    "World",
    "box_world",
    "cast",
    "drive",
    "make_world",
    "place_dataset",
    "place_poses",
    "simulate_run",
    "surface_world",
    "trace",
    "turning_angles",
    "wheel_odometry",
    "write_run",
]
