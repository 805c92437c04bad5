"""Place-recognition data sets of the Box and Surface worlds (the paper's section III.A).

The place-recognition paper (``papers/shape-matching-place-recognition.txt``)
scans 11 places 21 times each "with varying orientation and
displacement" (its real data set: 12 scans per place on a circle of 0.6 m
diameter).  Here:

* Places (`place_poses`): `places` points in the world's free space, chosen by
  farthest-point sampling among random free candidates that keep at least
  ``displacement + clearance`` metres from every wall, so the places are spread
  over the whole world and at least `min_separation` metres apart (else
  `UserError`).
* Scans: each place is scanned `scans_per_place` times from a position drawn
  uniformly in the disc of radius `displacement` [m] around it (default 0.3 m, the
  radius of the paper's 0.6 m circle) with a heading uniform in ``[-pi, pi)``, by
  a 360-degree `LaserModel` (noise and dropouts included).

Units and frames: metres, radians; poses ``(x, y, theta)`` of the sensor in the
world frame.  Each returned `Scan` carries its true pose in `Scan.odom` (there is no
odometry here; the exact pose lets evaluations check relative poses), its
position in the data set in `Scan.index` and ``stamp = index`` [s] (a sequence
number, not a time).  The world is the one `simulate_run` builds for the same seed.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from data.raycast import LaserModel, cast
from data.sim.run import STREAM_LASER, STREAM_PLACES, STREAM_WORLD, check_world, streams
from data.sim.worlds import World, make_world
from data.types import Scan

Array = NDArray[np.float64]


def place_poses(
    world: World,
    rng: np.random.Generator,
    *,
    places: int = 11,
    scans_per_place: int = 21,
    displacement: float = 0.3,
    clearance: float = 0.5,
    min_separation: float = 2.5,
    candidates: int = 4000,
) -> tuple[list[str], Array, Array]:
    """Labels, place centres ``(places, 2)`` and scan poses ``(places * scans_per_place, 3)``.

    Labels are ``place00``, ``place01``, ...; poses are grouped by place, in label
    order.  See the module docstring for the sampling.
    """
    if places < 1 or scans_per_place < 1:
        raise UserError(f"need at least one place and one scan, got {places} x {scans_per_place}")
    if displacement < 0.0:
        raise UserError(f"displacement must be >= 0, got {displacement}")
    xmin, ymin, xmax, ymax = world.bounds
    cand = rng.uniform([xmin, ymin], [xmax, ymax], size=(candidates, 2))
    cand = cand[world.is_free(cand, margin=displacement + clearance)]
    if len(cand) < places:
        raise UserError(
            f"only {len(cand)} free spots with {displacement + clearance:.2f} m clearance "
            f"in the {world.name} world; cannot place {places} places"
        )
    chosen = [int(rng.integers(len(cand)))]
    nearest = np.linalg.norm(cand - cand[chosen[0]], axis=1)
    for _ in range(places - 1):  # farthest-point sampling: one step per place
        chosen.append(int(np.argmax(nearest)))
        nearest = np.minimum(nearest, np.linalg.norm(cand - cand[chosen[-1]], axis=1))
    centres = cand[chosen]
    if places > 1:
        d = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
        closest = float(d[~np.eye(places, dtype=bool)].min())
        if closest < min_separation:
            raise UserError(
                f"{places} places in the {world.name} world are only {closest:.2f} m apart "
                f"(need {min_separation} m): use fewer places"
            )
    n = places * scans_per_place
    radius = displacement * np.sqrt(rng.random(n))
    bearing = rng.uniform(-np.pi, np.pi, size=n)
    heading = rng.uniform(-np.pi, np.pi, size=n)
    xy = np.repeat(centres, scans_per_place, axis=0)
    xy = xy + radius[:, None] * np.column_stack([np.cos(bearing), np.sin(bearing)])
    labels = [f"place{i:02d}" for i in range(places)]
    return labels, centres, np.column_stack([xy, heading])


def place_dataset(
    world: str = "box",
    *,
    places: int = 11,
    scans_per_place: int = 21,
    seed: int = 0,
    displacement: float = 0.3,
    laser: LaserModel | None = None,
    clearance: float = 0.5,
    min_separation: float = 2.5,
) -> list[tuple[str, Scan]]:
    """The paper's Box / Surface place data set: ``(label, scan)`` grouped by place.

    Args:
        world: ``"box"`` or ``"surface"``.
        places: number of places (classes), labelled ``place00`` ...
        scans_per_place: scans per place.
        seed: non-negative integer; same seed, same world as `simulate_run`.
        displacement: radius [m] of the disc the scan positions are drawn from.
        laser: the sensor (default: `LaserModel()`, 360 degrees, 360 beams).
        clearance: distance [m] every scan position keeps from the walls.
        min_separation: smallest allowed distance [m] between place centres.
    """
    check_world(world)
    laser = laser or LaserModel()
    rngs = streams(seed)
    w = make_world(world, rngs[STREAM_WORLD])
    labels, _, poses = place_poses(
        w, rngs[STREAM_PLACES], places=places, scans_per_place=scans_per_place,
        displacement=displacement, clearance=clearance, min_separation=min_separation,
    )
    ranges = cast(w, poses, laser, rngs[STREAM_LASER])
    return [
        (labels[i // scans_per_place], laser.scan(r, stamp=float(i), odom=pose, index=i))
        for i, (r, pose) in enumerate(zip(ranges, poses, strict=True))
    ]
