"""Simulated planar worlds made of line segments: the Box and the Surface world.

Frames and units: every coordinate is in the world frame, metres; the arena spans
``[0, W] x [0, H]``.  A `World` is a set of closed wall loops (the outer wall and
the boundary of every obstacle), their segments ``(S, 2, 2)`` (``segments[s, 0]``
is the start point, ``segments[s, 1]`` the end point), and the *route*: a closed,
smooth, self-crossing figure-eight that the simulated robot drives (see
`data.sim.motion`).  Every obstacle keeps at least `clearance` metres from the route,
so the robot always has free space around it.

Free space is decided with the even-odd rule over all wall segments: a point is
free when a ray from it crosses the walls an odd number of times (inside the outer
wall, outside every obstacle).  Obstacle loops never overlap, so the rule holds.

The two generators follow the synthetic data sets of the place-recognition paper
(``papers/shape-matching-place-recognition.txt``, section III.A):

* **Box** (`box_world`): a rectangular walled arena with randomly placed boxes
  (rectangles) of random size and orientation.  Boxes are drawn, rejected if
  they come closer than `clearance` to the route, leave the arena, or come closer
  than `gap` to an already accepted box (separating-axis test), until `boxes` are
  placed.  Cluttered, and every box has four 90-degree corners.
* **Surface** (`surface_world`): the paper's "3D undulated surface" cut by the
  laser plane, modelled as smooth hills standing in a valley whose rim undulates:
  each hill's cut is a smooth closed blob, ``r(phi) = R (1 + sum_{m=2..5} a_m
  cos(m phi + p_m))`` stretched along a random axis (1-1.6x) and rotated, and the
  rim is a rounded rectangle (corner radius 2 m) displaced along its normal by a
  sum of six random sines of 3-10 m wavelength.  Every wall is a smooth curve
  finely discretised (`spacing`, 0.1 m); blobs whose outline bends with a radius
  below `min_radius` are discarded and the rim's undulation is flattened until it
  meets the same bound, so no wall has a corner: the largest turning angle
  between consecutive wall segments stays below ``spacing / min_radius``
  (about 30 degrees) while every box corner turns 90 degrees.  Blobs are placed
  like boxes: `clearance` from the route, `gap` from the rim and from each other
  (and never nested).  A cluttered, unstructured world with no significant points.
  (Contours of a random height field were tried first: near the field's saddle
  points they pinch into sharp bends, i.e. corners, so they are not used.)

Both generators take a `numpy.random.Generator` and are deterministic for it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError

Array = NDArray[np.float64]

WORLDS = ("box", "surface")
ROUTE_SPACING = 0.05  # [m] spacing of the stored route polyline
_CHUNK = 2_000_000  # max elements of a (points x segments) temporary


# --------------------------------------------------------------------------- geometry


def segments_from_loops(loops: list[Array]) -> Array:
    """Segments ``(S, 2, 2)`` [m] of closed polylines (each ``(M, 2)``, last joins first)."""
    if not loops:
        return np.zeros((0, 2, 2))
    parts = [np.stack([lp, np.roll(lp, -1, axis=0)], axis=1) for lp in loops]
    return np.concatenate(parts, axis=0).astype(float)


def point_segment_distance(points: Array, segments: Array) -> Array:
    """``(P,)`` distance [m] from each point ``(P, 2)`` to the nearest segment ``(S, 2, 2)``.

    Vectorised over points and segments, chunked over points to bound memory.
    Returns ``inf`` for every point when there is no segment.
    """
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    out = np.full(len(points), np.inf)
    if len(segments) == 0 or len(points) == 0:
        return out
    ax, ay = segments[:, 0, 0], segments[:, 0, 1]
    ex, ey = segments[:, 1, 0] - ax, segments[:, 1, 1] - ay
    inv = 1.0 / np.maximum(ex * ex + ey * ey, 1e-300)
    step = max(1, _CHUNK // len(segments))
    for i in range(0, len(points), step):
        wx = points[i : i + step, 0:1] - ax
        wy = points[i : i + step, 1:2] - ay
        u = np.clip((wx * ex + wy * ey) * inv, 0.0, 1.0)
        wx -= u * ex
        wy -= u * ey
        out[i : i + step] = np.sqrt(np.min(wx * wx + wy * wy, axis=1))
    return out


def crossing_parity(points: Array, segments: Array) -> NDArray[np.bool_]:
    """``(P,)`` True where a ray from the point towards +x crosses an odd number of segments."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    out = np.zeros(len(points), dtype=bool)
    if len(segments) == 0 or len(points) == 0:
        return out
    ax, ay = segments[:, 0, 0], segments[:, 0, 1]
    bx, by = segments[:, 1, 0], segments[:, 1, 1]
    dy = np.where(by != ay, by - ay, 1.0)
    step = max(1, _CHUNK // len(segments))
    for i in range(0, len(points), step):
        px, py = points[i : i + step, 0:1], points[i : i + step, 1:2]
        straddle = (ay > py) != (by > py)
        x_cross = ax + (py - ay) * (bx - ax) / dy
        out[i : i + step] = (np.count_nonzero(straddle & (px < x_cross), axis=1) % 2) == 1
    return out


def turning_angles(loop: Array) -> Array:
    """``(M,)`` absolute turning angle [rad] at each vertex of a closed polyline ``(M, 2)``.

    0 for a straight continuation, pi/2 at a rectangle's corner.
    """
    d = np.roll(loop, -1, axis=0) - loop
    heading = np.arctan2(d[:, 1], d[:, 0])
    turn = heading - np.roll(heading, 1)
    return np.abs((turn + np.pi) % (2.0 * np.pi) - np.pi)


def loop_area(loop: Array) -> float:
    """Signed shoelace area [m^2] of a closed polyline; positive counter-clockwise."""
    x, y = loop[:, 0], loop[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def resample_closed(points: Array, spacing: float) -> Array:
    """Closed polyline resampled at (nearly) uniform arc-length `spacing` [m]."""
    closed = np.vstack([points, points[:1]])
    seg = np.linalg.norm(np.diff(closed, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(3, round(s[-1] / spacing))
    q = np.linspace(0.0, s[-1], n, endpoint=False)
    return np.column_stack([np.interp(q, s, closed[:, 0]), np.interp(q, s, closed[:, 1])])


# --------------------------------------------------------------------------- world


@dataclass(slots=True)
class World:
    """A planar world of wall segments with a drivable route (world frame, metres).

    Attributes:
        name: ``"box"`` or ``"surface"``.
        loops: closed wall polylines ``(M, 2)`` (last vertex joins the first): the
            outer wall first, then one per obstacle.
        bounds: ``(xmin, ymin, xmax, ymax)`` of the arena [m].
        route: ``(R, 2)`` closed polyline the robot drives, spaced `ROUTE_SPACING`.
        clearance: minimum distance [m] from the route to every wall.
        params: generator parameters (JSON-serialisable).
        segments: ``(S, 2, 2)`` wall segments of all loops (derived).
    """

    name: str
    loops: list[Array]
    bounds: tuple[float, float, float, float]
    route: Array
    clearance: float
    params: dict[str, Any] = field(default_factory=dict)
    segments: Array = field(init=False)

    def __post_init__(self) -> None:
        self.loops = [np.asarray(lp, dtype=float).reshape(-1, 2) for lp in self.loops]
        self.route = np.asarray(self.route, dtype=float).reshape(-1, 2)
        self.segments = segments_from_loops(self.loops)

    @property
    def route_length(self) -> float:
        """Length [m] of one lap of the closed route."""
        return float(np.sum(np.linalg.norm(np.roll(self.route, -1, axis=0) - self.route, axis=1)))

    def distance_to_walls(self, points: Array) -> Array:
        """``(P,)`` distance [m] from each point ``(P, 2)`` to the nearest wall segment."""
        return point_segment_distance(points, self.segments)

    def is_free(self, points: Array, margin: float = 0.0) -> NDArray[np.bool_]:
        """``(P,)`` True for points ``(P, 2)`` in free space at least `margin` [m] from walls."""
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        free = crossing_parity(points, self.segments)
        if margin > 0.0 and free.any():
            free[free] = self.distance_to_walls(points[free]) > margin
        return free

    def to_json(self) -> dict[str, Any]:
        """Plain dict: name, bounds, clearance, segments, route, params."""
        return {
            "name": self.name,
            "bounds": list(self.bounds),
            "clearance": self.clearance,
            "segments": np.round(self.segments, 6).tolist(),
            "route": np.round(self.route, 6).tolist(),
            "params": self.params,
        }


# --------------------------------------------------------------------------- route


def figure_eight_route(
    rng: np.random.Generator,
    size: tuple[float, float],
    margin: float,
    perturbation: float = 0.3,
) -> Array:
    """A smooth closed figure-eight ``(R, 2)`` [m] inside ``[margin, W - margin] x [...]``.

    A lemniscate of Gerono ``(sin t, sin t cos t)`` plus random 2nd and 3rd
    harmonics of amplitude up to `perturbation` [m] (relative to a unit half
    size of 10 m), scaled to span exactly the arena minus `margin`, and
    resampled every `ROUTE_SPACING` metres.  It crosses itself once near the
    centre of the arena and its two lobes leave room for obstacles inside.
    """
    w, h = size
    if w - 2 * margin <= 1.0 or h - 2 * margin <= 1.0:
        raise UserError(f"arena {w} x {h} m too small for a route with margin {margin} m")
    t = np.linspace(0.0, 2.0 * np.pi, 4000, endpoint=False)
    coeff = rng.uniform(-perturbation, perturbation, size=(2, 2, 2)) / 10.0
    harm = [np.cos(m * t) for m in (2, 3)] + [np.sin(m * t) for m in (2, 3)]
    basis = np.stack(harm)  # (4, T)
    x = np.sin(t) + coeff[0].reshape(-1) @ basis
    y = np.sin(t) * np.cos(t) + coeff[1].reshape(-1) @ basis
    x = margin + (x - x.min()) / (x.max() - x.min()) * (w - 2 * margin)
    y = margin + (y - y.min()) / (y.max() - y.min()) * (h - 2 * margin)
    route = resample_closed(np.column_stack([x, y]), ROUTE_SPACING)
    # Start at the point nearest the arena centre (the self-crossing).
    start = int(np.argmin(np.linalg.norm(route - [w / 2, h / 2], axis=1)))
    return np.roll(route, -start, axis=0)


# --------------------------------------------------------------------------- box world


def _rect_corners(centre: Array, half: Array, angle: Array) -> Array:
    """``(n, 4, 2)`` counter-clockwise corners of rectangles."""
    c, s = np.cos(angle), np.sin(angle)
    sx = np.array([-1.0, 1.0, 1.0, -1.0])
    sy = np.array([-1.0, -1.0, 1.0, 1.0])
    u = sx[None] * half[:, 0:1]
    v = sy[None] * half[:, 1:2]
    x = centre[:, 0:1] + c[:, None] * u - s[:, None] * v
    y = centre[:, 1:2] + s[:, None] * u + c[:, None] * v
    return np.stack([x, y], axis=-1)


def _separated(cand: Array, placed: Array, gap: float) -> bool:
    """True when rectangle `cand` ``(4, 2)`` is > `gap` apart from every one in `placed`.

    Separating-axis test on the edge normals of both rectangles (vectorised over
    `placed` ``(n, 4, 2)``); a gap along one axis bounds the Euclidean distance.
    """
    if len(placed) == 0:
        return True
    a = np.broadcast_to(cand, placed.shape)
    axes = np.concatenate([a[:, 1:3] - a[:, 0:2], placed[:, 1:3] - placed[:, 0:2]], axis=1)
    axes = axes / np.linalg.norm(axes, axis=-1, keepdims=True)  # (n, 4, 2)
    pa = np.einsum("nkj,ncj->nkc", axes, a)
    pb = np.einsum("nkj,ncj->nkc", axes, placed)
    sep = (pa.max(-1) + gap < pb.min(-1)) | (pb.max(-1) + gap < pa.min(-1))
    return bool(np.all(sep.any(axis=1)))


def box_world(
    rng: np.random.Generator,
    *,
    size: tuple[float, float] = (24.0, 18.0),
    margin: float = 3.0,
    boxes: int = 45,
    side_range: tuple[float, float] = (0.3, 2.0),
    clearance: float = 1.0,
    gap: float = 0.4,
) -> World:
    """Walled arena ``size`` [m] with `boxes` random rectangles (see module docstring).

    Args:
        rng: random generator (the only source of randomness).
        size: arena width and height [m].
        margin: distance [m] from the arena walls to the route's bounding box.
        boxes: most boxes to place; fewer are placed when no more fit among the
            candidates drawn (``params["boxes_placed"]`` tells how many).
        side_range: box side lengths are uniform in this range [m].
        clearance: minimum distance [m] from the route to any box.
        gap: minimum separation [m] between boxes and from boxes to the outer wall.
    """
    w, h = size
    route = figure_eight_route(rng, size, margin)
    probe = route[:: max(1, round(0.2 / ROUTE_SPACING))]
    n_cand = 40 * boxes
    centre = rng.uniform([0.0, 0.0], [w, h], size=(n_cand, 2))
    half = rng.uniform(side_range[0], side_range[1], size=(n_cand, 2)) / 2.0
    angle = rng.uniform(0.0, np.pi / 2.0, size=n_cand)
    corners = _rect_corners(centre, half, angle)
    inside = np.all(
        (corners[..., 0] > gap) & (corners[..., 0] < w - gap)
        & (corners[..., 1] > gap) & (corners[..., 1] < h - gap),
        axis=1,
    )
    # Exact distance from each route probe to each rectangle, in the box frame.
    rel = probe[None] - centre[:, None]
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    u = np.abs(c * rel[..., 0] + s * rel[..., 1]) - half[:, 0:1]
    v = np.abs(-s * rel[..., 0] + c * rel[..., 1]) - half[:, 1:2]
    dist = np.hypot(np.maximum(u, 0.0), np.maximum(v, 0.0)).min(axis=1)
    ok = np.flatnonzero(inside & (dist > clearance))
    placed = np.zeros((0, 4, 2))
    for i in ok:  # greedy acceptance over candidates (world building, not a hot path)
        if len(placed) >= boxes:
            break
        if _separated(corners[i], placed, gap):
            placed = np.concatenate([placed, corners[i][None]], axis=0)
    outer = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])
    params = {
        "size": [w, h],
        "margin": margin,
        "boxes": boxes,
        "boxes_placed": len(placed),
        "side_range": list(side_range),
        "clearance": clearance,
        "gap": gap,
    }
    return World("box", [outer, *placed], (0.0, 0.0, w, h), route, clearance, params)


# --------------------------------------------------------------------------- surface world


def _min_radius(loop: Array) -> float:
    """Smallest radius of curvature [m] of a closed polyline (segment length / turning)."""
    seg = np.linalg.norm(np.roll(loop, -1, axis=0) - loop, axis=1)
    r = 0.5 * (seg + np.roll(seg, 1)) / np.maximum(turning_angles(loop), 1e-12)
    return float(r.min())


def _undulating_wall(
    rng: np.random.Generator, size: tuple[float, float], inset: float, amplitude: float
) -> Array:
    """Closed smooth outer wall ``(M, 2)`` [m], counter-clockwise, spaced `ROUTE_SPACING`.

    A rectangle inset by `inset` with corners rounded to radius 2 m, displaced
    along its normal by a sum of random sines with wavelengths of 3-10 m whose
    amplitudes add up to `amplitude`.
    """
    w, h = size
    rc = 2.0
    lo, hi = np.array([inset + rc, inset + rc]), np.array([w - inset - rc, h - inset - rc])
    phi = np.linspace(0.0, 2.0 * np.pi, 2000, endpoint=False)
    c, s = np.cos(phi), np.sin(phi)
    # Rounded rectangle: each quadrant's arc centred on the matching inner corner.
    cx = np.where(c >= 0, hi[0], lo[0])
    cy = np.where(s >= 0, hi[1], lo[1])
    base = np.column_stack([cx + rc * c, cy + rc * s])
    base = resample_closed(base, ROUTE_SPACING)
    tangent = np.roll(base, -1, axis=0) - np.roll(base, 1, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.column_stack([tangent[:, 1], -tangent[:, 0]])  # outward for CCW
    perim = len(base) * ROUTE_SPACING
    arc = np.arange(len(base)) * ROUTE_SPACING
    cycles = rng.integers(round(perim / 10.0), round(perim / 3.0) + 1, size=6)
    weights = rng.uniform(0.5, 1.0, size=6)
    weights *= amplitude / weights.sum()
    phase = rng.uniform(0.0, 2.0 * np.pi, size=6)
    offset = (weights * np.sin(2.0 * np.pi * cycles * arc[:, None] / perim + phase)).sum(axis=1)
    return base + offset[:, None] * normal


def _blobs(
    rng: np.random.Generator,
    n: int,
    radius_range: tuple[float, float],
    roughness: float,
    min_radius: float,
) -> tuple[Array, Array]:
    """``n`` candidate smooth blobs centred on the origin: ``(n, T, 2)`` outlines and
    their bounding radii ``(n,)`` [m]; blobs that bend tighter than `min_radius` are
    dropped.

    Outline: ``r(phi) = R (1 + sum_{m=2..5} a_m cos(m phi + p_m))`` with ``R`` uniform
    in `radius_range` and ``a_m`` uniform in ``[0, roughness / m]``, stretched along
    a random axis by 1 to 1.6 and rotated at random.
    """
    phi = np.linspace(0.0, 2.0 * np.pi, 256, endpoint=False)
    m = np.arange(2, 6)
    amp = rng.uniform(0.0, 1.0, size=(n, len(m))) * roughness / m
    phase = rng.uniform(0.0, 2.0 * np.pi, size=(n, len(m)))
    base = rng.uniform(radius_range[0], radius_range[1], size=n)
    wave = np.cos(m[None, :, None] * phi[None, None, :] + phase[..., None])
    r = base[:, None] * (1.0 + np.einsum("nm,nmt->nt", amp, wave))
    pts = np.stack([r * np.cos(phi) * rng.uniform(1.0, 1.6, size=(n, 1)), r * np.sin(phi)], -1)
    ang = rng.uniform(0.0, np.pi, size=n)
    c, s = np.cos(ang)[:, None], np.sin(ang)[:, None]
    pts = np.stack([c * pts[..., 0] - s * pts[..., 1], s * pts[..., 0] + c * pts[..., 1]], -1)
    seg = np.linalg.norm(np.roll(pts, -1, axis=1) - pts, axis=-1)
    d = np.roll(pts, -1, axis=1) - pts
    heading = np.arctan2(d[..., 1], d[..., 0])
    turn = np.abs((heading - np.roll(heading, 1, axis=1) + np.pi) % (2.0 * np.pi) - np.pi)
    radius = 0.5 * (seg + np.roll(seg, 1, axis=1)) / np.maximum(turn, 1e-12)
    ok = radius.min(axis=1) >= min_radius
    return pts[ok], np.linalg.norm(pts[ok], axis=-1).max(axis=1)


def surface_world(
    rng: np.random.Generator,
    *,
    size: tuple[float, float] = (24.0, 18.0),
    margin: float = 3.0,
    blobs: int = 40,
    radius_range: tuple[float, float] = (0.25, 0.9),
    roughness: float = 0.3,
    wall_amplitude: float = 0.7,
    clearance: float = 1.0,
    gap: float = 0.4,
    spacing: float = 0.1,
    min_radius: float = 0.2,
) -> World:
    """Smooth undulating walls and smooth blob obstacles (see module docstring).

    Args:
        rng: random generator (the only source of randomness).
        size: arena width and height [m]; the outer wall undulates inside it.
        margin: distance [m] from the arena edge to the route's bounding box.
        blobs: most blob obstacles to place; fewer are placed when no more fit
            among the candidates drawn (``params["blobs_placed"]`` tells how many).
        radius_range: mean blob radius is uniform in this range [m].
        roughness: strength of the blobs' 2nd-5th harmonics (0 gives ellipses).
        wall_amplitude: peak normal displacement [m] of the outer wall's undulation.
        clearance: minimum distance [m] from the route to any wall.
        gap: minimum distance [m] between blobs and from blobs to the outer wall.
        spacing: wall vertex spacing [m].
        min_radius: smallest radius of curvature [m] of any wall.
    """
    w, h = size
    route = figure_eight_route(rng, size, margin)
    inset = wall_amplitude + 0.1
    outer = _undulating_wall(rng, size, inset, wall_amplitude)
    for _ in range(5):  # flatten undulations that bend too sharply
        if _min_radius(outer) >= min_radius:
            break
        wall_amplitude *= 0.7
        outer = _undulating_wall(rng, size, inset, wall_amplitude)
    outer = resample_closed(outer, spacing)
    from scipy.spatial import cKDTree

    n_cand = 40 * blobs
    shapes, reach = _blobs(rng, n_cand, radius_range, roughness, min_radius)
    centre = rng.uniform([0.0, 0.0], [w, h], size=(len(shapes), 2))
    coarse = shapes[:, ::4] + centre[:, None]  # (n, 64, 2) outline samples, < 0.2 m apart

    # Clearance from the route and the outer wall, measured to dense samples of
    # both (<= 5 cm apart, so at 1 m the error is < 1 mm): centres first, then the
    # full outlines of candidates whose reach could touch them.  Then greedy
    # acceptance against the blobs already placed (world building, not a hot path).
    ok = crossing_parity(centre, segments_from_loops([outer]))
    dense_outer = resample_closed(outer, ROUTE_SPACING)
    for pts, limit in ((route, clearance + 0.02), (dense_outer, gap + 0.02)):
        tree = cKDTree(pts)
        d_centre = tree.query(centre)[0]
        ok &= d_centre > limit
        check = np.flatnonzero(ok & (d_centre <= reach + limit))  # outline may reach it
        d_outline = tree.query((shapes[check] + centre[check, None]).reshape(-1, 2))[0]
        ok[check] = d_outline.reshape(len(check), -1).min(axis=1) > limit
    placed: list[int] = []
    for i in np.flatnonzero(ok):
        if len(placed) >= blobs:
            break
        near = [j for j in placed if np.hypot(*(centre[j] - centre[i])) < reach[j] + reach[i] + gap]
        if near:
            others = segments_from_loops(list(coarse[near]))
            if crossing_parity(centre[i], others)[0]:
                continue  # centre inside a placed blob
            if crossing_parity(centre[near], segments_from_loops([coarse[i]])).any():
                continue  # a placed blob's centre inside this one
            if point_segment_distance(coarse[i], others).min() <= gap:
                continue
        placed.append(int(i))
    loops = [outer] + [resample_closed(shapes[i] + centre[i], spacing) for i in placed]
    params = {
        "size": [w, h],
        "margin": margin,
        "blobs": blobs,
        "blobs_placed": len(placed),
        "radius_range": list(radius_range),
        "roughness": roughness,
        "wall_amplitude": round(wall_amplitude, 4),
        "clearance": clearance,
        "gap": gap,
        "spacing": spacing,
        "min_radius": min_radius,
    }
    return World("surface", loops, (0.0, 0.0, w, h), route, clearance, params)


def make_world(name: str, rng: np.random.Generator, **kwargs: Any) -> World:
    """`box_world` or `surface_world` by name; unknown names raise `UserError`."""
    if name == "box":
        return box_world(rng, **kwargs)
    if name == "surface":
        return surface_world(rng, **kwargs)
    raise UserError(f"unknown world {name!r}: choose one of {', '.join(WORLDS)}")
