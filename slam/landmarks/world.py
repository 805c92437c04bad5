"""A simulated planar world with known objects on the floor, and a robot run through it.

The walls, boxes and figure-eight route are `data.sim`'s Box world
(`data.sim.make_world`); the robot drives it with `data.sim.drive` and its wheel
odometry drifts as `data.sim.wheel_odometry` models.  On top of that, objects (meshes
from the stripe scanner's generators, or any mesh) rest on the floor beside the route
(`place_objects`), and the robot carries a push-broom laser (`sensor`) instead of a
horizontal one, scanning at its own rate: every scan is a robot pose.

Object placement: object ``i`` of ``n`` goes to a random point of the ``i``-th of ``n``
equal stretches of the route, at a random side and a lateral distance from the route
in `lateral`, with a random yaw; a candidate is rejected if it is closer than
`min_separation` to an object already placed, not free of walls and boxes by its
radius plus 0.3 m, or closer to another part of the route than its own lateral
distance minus 5 cm (near the figure-eight's crossing); up to 500 candidates per
object.  The world's route clearance (`clearance`, distance from the route to every
box and wall) must exceed the laser's reach plus the robot's lateral wander, so the
fan never meets a wall (`check_reach`).

Randomness: `data.sim.run.streams(seed)` gives the world, motion, odometry and laser
generators (as `data.sim.simulate_run`); objects are placed with the world's
generator after the world is built.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from data.sim import MotionConfig, OdometryNoise, World, drive, make_world, wheel_odometry
from data.sim.run import STREAM_LASER, STREAM_MOTION, STREAM_ODOMETRY, STREAM_WORLD, streams
from data.stripe_scanner.meshes import Mesh
from slam.landmarks.sensor import PlacedObject, PushBroomLaser, candidate_scans, cast, place_object

Array = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class WorldConfig:
    """The Box world and where objects go (module docstring), metres.

    Attributes:
        size: arena width and height.
        boxes: most boxes to place.
        clearance: distance from the route to every box and wall.
        margin: distance from the arena walls to the route's bounding box.
        lateral: range of an object's distance from the route.
        min_separation: smallest distance between two objects.
    """

    size: tuple[float, float] = (24.0, 18.0)
    boxes: int = 30
    clearance: float = 1.2
    margin: float = 3.0
    lateral: tuple[float, float] = (0.26, 0.38)
    min_separation: float = 1.5

    def to_json(self) -> dict[str, object]:
        """Plain dict of the parameters."""
        return asdict(self)


def _route_normals(route: Array) -> Array:
    """Unit left normals ``(R, 2)`` of a closed polyline (central differences)."""
    t = np.roll(route, -1, axis=0) - np.roll(route, 1, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return np.column_stack([-t[:, 1], t[:, 0]])


def place_objects(
    world: World,
    meshes: Sequence[Mesh],
    labels: Sequence[str],
    identities: Sequence[int],
    rng: np.random.Generator,
    config: WorldConfig | None = None,
) -> list[PlacedObject]:
    """Place every mesh beside the route (module docstring).

    Raises:
        UserError: an object finds no free place in its stretch of the route.
    """
    cfg = config or WorldConfig()
    route = world.route
    normal = _route_normals(route)
    n = len(meshes)
    placed: list[PlacedObject] = []
    for i, (mesh, label, ident) in enumerate(zip(meshes, labels, identities, strict=True)):
        lo, hi = int(len(route) * i / n), int(len(route) * (i + 1) / n)
        for _ in range(500):
            k = int(rng.integers(lo, max(hi, lo + 1)))
            lateral = float(rng.uniform(*cfg.lateral))
            side = 1.0 if rng.random() < 0.5 else -1.0
            pos = route[k] + side * lateral * normal[k]
            yaw = float(rng.uniform(0.0, 2.0 * np.pi))
            obj = place_object(mesh, (pos[0], pos[1], yaw), label, ident)
            if placed and min(np.hypot(*(p.pose[:2] - pos)) for p in placed) < cfg.min_separation:
                continue
            if not world.is_free(pos[None, :], margin=obj.radius + 0.3)[0]:
                continue
            if np.hypot(*(route - pos).T).min() < lateral - 0.05:
                continue
            placed.append(obj)
            break
        else:
            raise UserError(f"no free place for object {mesh.name} beside the route")
    return placed


def check_reach(world: World, truth: Array, laser: PushBroomLaser) -> float:
    """Smallest distance [m] from the robot's path to a wall; UserError if the fan can
    reach one (the ray caster does not model walls)."""
    step = max(1, len(truth) // 20_000)
    d = float(world.distance_to_walls(truth[::step, :2]).min())
    if d <= laser.reach + 0.05:
        raise UserError(f"walls come within {d:.2f} m of the robot's path but the push-broom "
                        f"laser reaches {laser.reach:.2f} m: raise the world's clearance")
    return d


@dataclass(slots=True)
class LandmarkRun:
    """A simulated run of the push-broom robot.

    Attributes:
        world: walls, boxes and route.
        objects: objects on the floor (library objects and distractors).
        laser: the sensor.
        stamps: ``(N,)`` time of every scan [s].
        truth: ``(N, 3)`` true robot pose of every scan (world frame).
        odom: ``(N, 3)`` odometry pose of every scan (odometry frame = world at scan 0).
        scan_ids: ``(S,)`` scans whose fan can meet an object (all others see bare floor).
        ranges: ``(S, B)`` their ranges [m] (0.0: no return).
        hits: ``(S, B)`` index into `objects` of what each beam hit (-1: floor / none);
            ground truth for the evaluation only, never used by the mapper.
        seed: the seed of every random stream.
    """

    world: World
    objects: list[PlacedObject]
    laser: PushBroomLaser
    stamps: Array
    truth: Array
    odom: Array
    scan_ids: NDArray[np.intp]
    ranges: Array
    hits: NDArray[np.int64]
    seed: int


def simulate_landmark_run(
    meshes: Sequence[Mesh],
    labels: Sequence[str],
    identities: Sequence[int],
    *,
    seed: int = 0,
    laser: PushBroomLaser | None = None,
    world: WorldConfig | None = None,
    motion: MotionConfig | None = None,
    odometry_noise: OdometryNoise | None = None,
) -> LandmarkRun:
    """Build the world, place the objects, drive, and scan (module docstring).

    `motion.rate_hz` is ignored: the scan rate is the laser's.
    """
    laser = laser or PushBroomLaser()
    wcfg = world or WorldConfig()
    mcfg = motion or MotionConfig(speed=0.5, laps=2.0, lateral_offset=0.05)
    mcfg = MotionConfig(speed=mcfg.speed, rate_hz=laser.rate_hz, laps=mcfg.laps,
                        lateral_offset=mcfg.lateral_offset, start_time=mcfg.start_time)
    rngs = streams(seed)
    w = make_world("box", rngs[STREAM_WORLD], size=wcfg.size, margin=wcfg.margin,
                   boxes=wcfg.boxes, clearance=wcfg.clearance)
    objects = place_objects(w, meshes, labels, identities, rngs[STREAM_WORLD], wcfg)
    stamps, truth = drive(w.route, mcfg, rngs[STREAM_MOTION])
    check_reach(w, truth, laser)
    odom = wheel_odometry(truth, odometry_noise or OdometryNoise(), rngs[STREAM_ODOMETRY])
    scan_ids = np.flatnonzero(candidate_scans(laser, truth, objects).any(axis=1))
    ranges, hits = cast(laser, truth[scan_ids], objects, rngs[STREAM_LASER])
    return LandmarkRun(w, objects, laser, stamps, truth, odom, scan_ids, ranges, hits, seed)
