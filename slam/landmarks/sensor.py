"""A push-broom line laser on a ground robot, ray cast against object meshes on the floor.

The sensor (`PushBroomLaser`) is a 2D line scanner of the profiler kind (e.g. a SICK
LMS4000: 70 degree fan, about 0.1 degree steps, hundreds of scans per second,
millimetre noise) mounted on the robot at `height` above the floor, looking forward
and down: its fan plane contains the robot's lateral axis and is pitched down by
`pitch_deg` from the horizontal.  As the robot drives, the fan sweeps over the floor
ahead; an object on the floor is cut by the fan in one profile per scan, ordered by
time: the stripes of the stripes paper, with the robot's motion as the scanner's
sweep.

Frames and units: robot pose ``(x, y, theta)`` [m, m, rad] in the world (or
odometry) frame; the robot frame has x forward, y left, z up, origin on the floor
under the sensor.  The sensor sits at ``(0, 0, height)``.  Beam ``j`` has the in-plane
angle ``phi_j`` (0 along the fan's forward-down axis, positive to the left), equally
spaced over ``[-fov/2, +fov/2]``; its direction in the robot frame is
``d_j = cos(phi_j) f + sin(phi_j) y`` with ``f = (cos pitch, 0, -sin pitch)`` and
``y = (0, 1, 0)``.  A range ``t`` puts the point at ``(0, 0, height) + t d_j``.

Ray casting (`cast`): every beam reads the first surface along it: the floor
(``z = 0``, in closed form) or an object's triangle.  Objects are cut by each scan's
fan plane (signed distances of the vertices to the plane, vectorised over scans and
vertices); each cut triangle gives a segment in the plane; a segment is expanded
over the beams its two end angles span (``np.repeat``), each beam is intersected
with it in closed form, and the nearest hit per (scan, beam) wins (one lexsort).  No
Python loop over beams, triangles or points: the loops are over objects and chunks
of scans.  Returns within `grazing_deg` of the surface tangent are lost; then
Gaussian range noise (`noise_sigma`) and random dropouts (range 0.0) as in
`data.raycast`.

What is not simulated: walls and boxes of the planar world.  The fan never reaches
them because the world is built with a route clearance larger than the fan's reach
(`PushBroomLaser.reach`; `world.check_reach` enforces it), so they would add no
return.  Scans whose fan footprint (the ground triangle under the fan: sensor foot
and both ends of the floor line) misses every object's bounding circle see only the
floor (`candidate_scans`); runs store only the others, since a bare-floor scan holds
no point above the floor for the segmentation to keep.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from data.stripe_scanner.meshes import Mesh
from data.stripe_scanner.scanner import place_on_table

Array = NDArray[np.float64]

_CHUNK = 2_000_000  # elements of one (scans x vertices) temporary


@dataclass(frozen=True, slots=True)
class PushBroomLaser:
    """The push-broom line laser (see module docstring).

    Attributes:
        height: sensor height above the floor [m].
        pitch_deg: fan plane tilt below the horizontal [deg].
        fov_deg: fan opening [deg].
        beams: beams per scan (equally spaced over the fan).
        rate_hz: scans per second.
        noise_sigma: range noise standard deviation [m].
        dropout: probability that a beam returns nothing (range 0.0).
        grazing_deg: incidence beyond which a surface returns nothing [deg].
    """

    height: float = 0.60
    pitch_deg: float = 40.0
    fov_deg: float = 70.0
    beams: int = 561
    rate_hz: float = 250.0
    noise_sigma: float = 0.001
    dropout: float = 0.002
    grazing_deg: float = 85.0

    def __post_init__(self) -> None:
        if not (self.height > 0 and 0 < self.pitch_deg < 90 and 0 < self.fov_deg < 170):
            raise UserError("push-broom laser: need height > 0, 0 < pitch < 90, 0 < fov < 170")
        if self.beams < 2 or not self.rate_hz > 0:
            raise UserError("push-broom laser: need at least 2 beams and a positive rate")

    @property
    def pitch(self) -> float:
        """Fan tilt [rad]."""
        return float(np.deg2rad(self.pitch_deg))

    @property
    def angles(self) -> Array:
        """``(B,)`` in-plane beam angles [rad], right (negative) to left."""
        half = np.deg2rad(self.fov_deg) / 2.0
        return np.linspace(-half, half, self.beams)

    @property
    def angle_step(self) -> float:
        """Angle between neighbouring beams [rad]."""
        return float(np.deg2rad(self.fov_deg) / (self.beams - 1))

    @property
    def forward(self) -> Array:
        """Fan's forward-down axis ``f`` in the robot frame."""
        return np.array([np.cos(self.pitch), 0.0, -np.sin(self.pitch)])

    def directions(self) -> Array:
        """``(B, 3)`` unit beam directions in the robot frame."""
        a = self.angles
        return np.cos(a)[:, None] * self.forward + np.sin(a)[:, None] * np.array([0, 1.0, 0])

    def floor_ranges(self) -> Array:
        """``(B,)`` range [m] of each beam to a bare, flat floor."""
        return self.height / (np.sin(self.pitch) * np.cos(self.angles))

    @property
    def reach(self) -> float:
        """Largest horizontal distance [m] from the sensor's foot to any point of the fan."""
        t = self.floor_ranges()
        p = t[:, None] * self.directions()
        return float(np.hypot(p[:, 0], p[:, 1]).max())

    def footprint(self) -> Array:
        """``(3, 2)`` ground triangle under the fan in the robot frame: foot, right, left end."""
        t = self.floor_ranges()[[0, -1]]
        p = t[:, None] * self.directions()[[0, -1]]
        return np.vstack([[0.0, 0.0], p[:, :2]])

    def points(self, ranges: Array) -> tuple[Array, NDArray[np.bool_]]:
        """Robot-frame points ``(..., B, 3)`` of ranges ``(..., B)``, and which are returns.

        Invalid beams (range 0 or not finite) get the point ``(0, 0, height)`` and
        False in the mask; never NaN.
        """
        r = np.asarray(ranges, dtype=float)
        ok = np.isfinite(r) & (r > 0)
        t = np.where(ok, r, 0.0)
        p = t[..., None] * self.directions()
        p[..., 2] += self.height
        return p, ok

    def to_json(self) -> dict[str, float | int]:
        """Plain dict of the parameters."""
        return asdict(self)


@dataclass(slots=True)
class PlacedObject:
    """An object mesh resting on the floor at a known planar pose.

    Attributes:
        name: object name (library identity, or a distractor's name).
        label: class.
        identity: index of the object in the library, -1 for an unknown object.
        pose: ``(x, y, yaw)`` of the object's footprint centre [m, m, rad] (world).
        vertices: ``(V, 3)`` placed vertices [m] (world frame, resting on z = 0).
        faces: ``(F, 3)`` vertex indices.
        radius: radius of the footprint's bounding circle about ``pose[:2]`` [m].
    """

    name: str
    label: str
    identity: int
    pose: Array
    vertices: Array
    faces: NDArray[np.int64]
    radius: float

    @property
    def height(self) -> float:
        """Top of the object above the floor [m]."""
        return float(self.vertices[:, 2].max())


def place_object(
    mesh: Mesh, pose: Sequence[float], label: str = "", identity: int = -1
) -> PlacedObject:
    """`mesh` yawed by ``pose[2]`` about its footprint centre, centred at ``pose[:2]``, on z = 0.

    The footprint centre is the centre of the mesh's axis-aligned bounding box (the rule
    of `data.stripe_scanner.scanner.place_on_table`).
    """
    x, y, yaw = (float(v) for v in pose)
    v = place_on_table(mesh.vertices, yaw, (x, y))
    radius = float(np.hypot(v[:, 0] - x, v[:, 1] - y).max())
    return PlacedObject(mesh.name, label, identity, np.array([x, y, yaw]), v,
                        np.asarray(mesh.faces, dtype=np.int64), radius)


def _point_triangle_distance(p: Array, tri: Array) -> Array:
    """``(S,)`` distance from points ``(S, 2)`` to triangles ``(S, 3, 2)`` (0 inside)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]

    def cross(u: Array, v: Array) -> Array:
        return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]

    s1, s2, s3 = cross(b - a, p - a), cross(c - b, p - b), cross(a - c, p - c)
    inside = ((s1 >= 0) & (s2 >= 0) & (s3 >= 0)) | ((s1 <= 0) & (s2 <= 0) & (s3 <= 0))
    best = np.full(len(p), np.inf)
    for u, v in ((a, b), (b, c), (c, a)):
        e = v - u
        w = np.clip(((p - u) * e).sum(1) / np.maximum((e * e).sum(1), 1e-300), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(p - (u + w[:, None] * e), axis=1))
    return np.where(inside, 0.0, best)


def candidate_scans(
    laser: PushBroomLaser, poses: Array, objects: Sequence[PlacedObject]
) -> NDArray[np.bool_]:
    """``(S, O)`` True where object o can meet scan s's fan (conservative tests).

    Every point of the fan below the sensor projects into the ground triangle
    `PushBroomLaser.footprint`; an object whose bounding circle keeps clear of it
    cannot be hit.  Nor can an object whose bounding sphere (centre at half its
    height above the footprint centre) lies wholly on one side of the fan's plane.
    """
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    out = np.zeros((len(poses), len(objects)), dtype=bool)
    if len(objects) == 0 or len(poses) == 0:
        return out
    tri = laser.footprint()
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    wx = poses[:, None, 0] + c[:, None] * tri[None, :, 0] - s[:, None] * tri[None, :, 1]
    wy = poses[:, None, 1] + s[:, None] * tri[None, :, 0] + c[:, None] * tri[None, :, 1]
    world_tri = np.stack([wx, wy], axis=-1)  # (S, 3, 2)
    reach = laser.reach
    origin, _, _, normal = _fan_axes(laser, poses)
    for o, obj in enumerate(objects):
        centre = obj.pose[:2]
        sphere = np.array([centre[0], centre[1], obj.height / 2.0])
        rho = np.hypot(obj.radius, obj.height / 2.0)
        plane = np.abs(((sphere - origin) * normal).sum(axis=1))
        near = np.flatnonzero((np.hypot(*(poses[:, :2] - centre).T) < reach + obj.radius)
                              & (plane <= rho))
        if len(near) == 0:
            continue
        d = _point_triangle_distance(np.broadcast_to(centre, (len(near), 2)), world_tri[near])
        out[near[d <= obj.radius], o] = True
    return out


def _fan_axes(laser: PushBroomLaser, poses: Array) -> tuple[Array, Array, Array, Array]:
    """Sensor origin, forward-down axis f, lateral axis y and plane normal n per scan (world)."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    cp, sp = np.cos(laser.pitch), np.sin(laser.pitch)
    origin = np.column_stack([poses[:, 0], poses[:, 1], np.full(len(poses), laser.height)])
    f = np.column_stack([cp * c, cp * s, np.full(len(poses), -sp)])
    y = np.column_stack([-s, c, np.zeros(len(poses))])
    n = np.cross(f, y)
    return origin, f, y, n


def _object_hits(
    laser: PushBroomLaser, poses: Array, obj: PlacedObject
) -> tuple[NDArray[np.intp], NDArray[np.intp], Array, Array]:
    """First hits of one object for scans ``(S, 3)``: scan, beam, range, |cos incidence|."""
    origin, f, y, n = _fan_axes(laser, poses)
    v, faces = obj.vertices, obj.faces
    step = laser.angle_step
    phi0 = float(laser.angles[0])
    tri = v[faces]
    tn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    tn /= np.maximum(np.linalg.norm(tn, axis=1, keepdims=True), 1e-300)
    out_s, out_b, out_t, out_c = [], [], [], []
    chunk = max(1, _CHUNK // max(len(v), 1))
    for k0 in range(0, len(poses), chunk):
        sl = slice(k0, k0 + chunk)
        o, fk, yk, nk = origin[sl], f[sl], y[sl], n[sl]
        dist = v @ nk.T - (o * nk).sum(1)[None, :]  # (V, S) signed distance to each plane
        side = dist > 0
        sa, sb, sc = side[faces[:, 0]], side[faces[:, 1]], side[faces[:, 2]]  # (F, S)
        cut = ~((sa == sb) & (sb == sc))
        fi, si = np.nonzero(cut)
        if len(fi) == 0:
            continue
        # The two crossing edges of each cut triangle and their crossing points.
        ea, eb = np.array([0, 1, 2]), np.array([1, 2, 0])
        da = dist[faces[fi][:, ea], si[:, None]]  # (P, 3)
        db = dist[faces[fi][:, eb], si[:, None]]
        crosses = (da > 0) != (db > 0)
        w = da / np.where(crosses, da - db, 1.0)
        pa, pb = tri[fi][:, ea], tri[fi][:, eb]  # (P, 3, 3)
        pts = pa + w[..., None] * (pb - pa)
        pick = np.argsort(~crosses, axis=1, kind="stable")[:, :2]
        two = np.take_along_axis(pts, pick[..., None], axis=1)  # (P, 2, 3)
        rel = two - o[si][:, None, :]
        ca = np.einsum("pkj,pj->pk", rel, fk[si])  # in-plane coordinates (P, 2)
        cb = np.einsum("pkj,pj->pk", rel, yk[si])
        ang = np.arctan2(cb, ca)
        lo = np.ceil((ang.min(1) - phi0) / step - 1e-9).astype(np.int64)
        hi = np.floor((ang.max(1) - phi0) / step + 1e-9).astype(np.int64)
        lo, hi = np.maximum(lo, 0), np.minimum(hi, laser.beams - 1)
        count = np.maximum(hi - lo + 1, 0)
        owner = np.repeat(np.arange(len(fi)), count)
        beam = np.repeat(lo, count) + (np.arange(int(count.sum())) - np.repeat(
            np.cumsum(count) - count, count))
        if len(owner) == 0:
            continue
        phi = phi0 + beam * step
        dx, dy = np.cos(phi), np.sin(phi)
        px, py = ca[owner, 0], cb[owner, 0]
        ex, ey = ca[owner, 1] - px, cb[owner, 1] - py
        den = dx * ey - dy * ex
        ok = np.abs(den) > 1e-15
        den = np.where(ok, den, 1.0)
        t = (px * ey - py * ex) / den
        u = (px * dy - py * dx) / den
        ok &= (t > 0) & (u >= -1e-9) & (u <= 1 + 1e-9)
        owner, beam, t, dx, dy = owner[ok], beam[ok], t[ok], dx[ok], dy[ok]
        scan = si[owner]
        d3 = dx[:, None] * fk[scan] + dy[:, None] * yk[scan]
        cos_inc = np.abs((tn[fi[owner]] * d3).sum(1))
        out_s.append(scan + k0)
        out_b.append(beam)
        out_t.append(t)
        out_c.append(cos_inc)
    if not out_s:
        e = np.zeros(0, dtype=np.intp)
        return e, e, np.zeros(0), np.zeros(0)
    s_all, b_all = np.concatenate(out_s), np.concatenate(out_b)
    t_all, c_all = np.concatenate(out_t), np.concatenate(out_c)
    order = np.lexsort((t_all, b_all, s_all))
    s_all, b_all, t_all, c_all = s_all[order], b_all[order], t_all[order], c_all[order]
    first = np.r_[True, (s_all[1:] != s_all[:-1]) | (b_all[1:] != b_all[:-1])]
    return s_all[first], b_all[first], t_all[first], c_all[first]


def cast(
    laser: PushBroomLaser,
    poses: Array,
    objects: Sequence[PlacedObject],
    rng: np.random.Generator | None = None,
) -> tuple[Array, NDArray[np.int64]]:
    """Ranges ``(S, B)`` [m] of the push-broom laser at robot poses ``(S, 3)`` (world frame).

    Returns the ranges (0.0 = dropout or lost at a grazing angle) and ``(S, B)`` the
    index of the object each beam hit (-1: floor or no return).  With `rng` None the
    ranges are exact and complete.
    """
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    if not np.isfinite(poses).all():
        raise UserError("ray casting needs finite poses (NaN or inf in `poses`)")
    n_s = len(poses)
    ranges = np.broadcast_to(laser.floor_ranges(), (n_s, laser.beams)).copy()
    hit = np.full((n_s, laser.beams), -1, dtype=np.int64)
    lost = np.zeros((n_s, laser.beams), dtype=bool)
    cand = candidate_scans(laser, poses, objects)
    cos_graze = np.cos(np.deg2rad(laser.grazing_deg))
    for o, obj in enumerate(objects):
        scans = np.flatnonzero(cand[:, o])
        if len(scans) == 0:
            continue
        s, b, t, ci = _object_hits(laser, poses[scans], obj)
        s = scans[s]
        closer = t < ranges[s, b]
        s, b, t, ci = s[closer], b[closer], t[closer], ci[closer]
        ranges[s, b] = t
        hit[s, b] = o
        lost[s, b] = ci < cos_graze
    hit[lost] = -1
    if rng is not None and laser.noise_sigma > 0:
        ranges = np.maximum(ranges + rng.normal(0.0, laser.noise_sigma, ranges.shape), 1e-3)
    ranges[lost] = 0.0
    if rng is not None and laser.dropout > 0:
        drop = rng.random(ranges.shape) < laser.dropout
        ranges[drop] = 0.0
        hit[drop] = -1
    return ranges, hit
