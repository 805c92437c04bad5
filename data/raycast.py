"""Vectorised ray casting of a planar laser against line-segment walls.

Plain geometry, below every user: the simulator (`data.sim`) casts its laser with it
and the plugin's virtual scans (`loopclosure.virtual_scan`) ray-cast wall segments
with `trace`.  Walls are ``(S, 2, 2)`` segment arrays, or anything with such a
``segments`` attribute (a `data.sim.worlds.World`); nothing here imports the
simulator.

Frames and units: poses are ``(x, y, theta)`` of the *sensor* in the world frame
[m, m, rad]; beam angles are in the sensor frame (0 along the sensor x axis,
counter-clockwise positive), as in `data.types.Scan`; ranges are metres.

Beam layout (`LaserModel.angles`):

* 360 degrees: ``N`` beams from ``-pi`` to ``pi - 2 pi / N`` (step ``2 pi / N``).
* less than 360 degrees: ``N`` beams centred on the x axis from ``-fov/2`` to
  ``+fov/2`` inclusive (step ``fov / (N - 1)``), as a SICK LMS in a CARMEN log
  (180 beams over 180 degrees step pi/179).

Readings (`cast`): the distance along each beam to the first wall it meets.  A
beam that meets nothing within `max_range` reads exactly `max_range` (no return).
Returns get additive Gaussian noise of standard deviation `noise_sigma`; every
return is clipped to stay a return, into ``[1 mm, max_range - 1 mm]`` (1 mm keeps
it below the no-return value even after a log rounds ranges to 0.1 mm).  Each
beam, return or not, drops out with probability `dropout` and then reads 0.0
(invalid).

Algorithm (`trace`): for every (pose, segment) pair the segment's two end points
give the angular interval it covers as seen from the pose, hence the contiguous
run of beam indices that can hit it (at most two runs when the interval wraps
past the first beam).  Those candidate (beam, segment) pairs are expanded with
`np.repeat`, intersected in closed form (ray ``p + t d`` with segment ``a + u e``:
``t = (w x e) / (d x e)``, ``u = (w x d) / (d x e)``, ``w = a - p``), and the nearest
hit per beam is kept with `np.minimum.at`.  Segments farther than `max_range` are
culled first.  The work is proportional to the number of candidate pairs, not to
beams x segments, and is chunked over poses to bound memory.  There is no Python
loop over beams or segments.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from data.types import Scan

Array = NDArray[np.float64]

_PAIR_BUDGET = 400_000  # (pose, segment) pairs per chunk
_EPS_ANGLE = 1e-9  # [rad] widening of segment intervals (beams through end points)
_EPS_U = 1e-9  # tolerance on the segment parameter u
_MIN_RETURN = 1e-3  # [m] smallest noisy return


class Walls(Protocol):
    """Anything holding ``(S, 2, 2)`` wall segments [m] (world frame), e.g. a
    `data.sim.worlds.World`."""

    segments: Array


@dataclass(frozen=True, slots=True)
class LaserModel:
    """A planar laser range finder (see module docstring for the beam layout).

    Attributes:
        fov_deg: field of view [deg], in ``(0, 360]``.
        beams: number of beams (>= 2).
        max_range: no-return reading and maximum range [m].
        noise_sigma: standard deviation of the Gaussian range noise on returns [m].
        dropout: probability that a beam reads 0.0 (invalid), in ``[0, 1)``.
    """

    fov_deg: float = 360.0
    beams: int = 360
    max_range: float = 25.0
    noise_sigma: float = 0.01
    dropout: float = 0.01

    def __post_init__(self) -> None:
        if not (0.0 < self.fov_deg <= 360.0):
            raise UserError(f"laser field of view must be in (0, 360] degrees, got {self.fov_deg}")
        if int(self.beams) != self.beams or self.beams < 2:
            raise UserError(f"laser needs an integer number of beams >= 2, got {self.beams}")
        if not (np.isfinite(self.max_range) and self.max_range > 0.0):
            raise UserError(f"laser max range must be positive, got {self.max_range}")
        if not (np.isfinite(self.noise_sigma) and self.noise_sigma >= 0.0):
            raise UserError(f"laser noise sigma must be >= 0, got {self.noise_sigma}")
        if not (0.0 <= self.dropout < 1.0):
            raise UserError(f"laser dropout probability must be in [0, 1), got {self.dropout}")

    @property
    def full_circle(self) -> bool:
        """True for a 360-degree scanner."""
        return bool(np.isclose(self.fov_deg, 360.0))

    @property
    def angle_min(self) -> float:
        """Bearing of the first beam [rad]."""
        return -np.pi if self.full_circle else -np.radians(self.fov_deg) / 2.0

    @property
    def angle_increment(self) -> float:
        """Angle between consecutive beams [rad]."""
        if self.full_circle:
            return 2.0 * np.pi / self.beams
        return np.radians(self.fov_deg) / (self.beams - 1)

    def angles(self) -> Array:
        """``(beams,)`` increasing beam bearings in the sensor frame [rad]."""
        return self.angle_min + self.angle_increment * np.arange(self.beams)

    def scan(self, ranges: Array, stamp: float, odom: Array | None = None, index: int = 0) -> Scan:
        """A `Scan` of this laser with the given ranges [m] and pose guess."""
        return Scan(
            stamp=float(stamp),
            ranges=np.asarray(ranges, dtype=float),
            angles=self.angles(),
            max_range=float(self.max_range),
            min_range=0.0,
            odom=None if odom is None else np.asarray(odom, dtype=float).copy(),
            index=index,
        )

    def to_json(self) -> dict[str, float | int]:
        """Plain dict of the parameters."""
        return asdict(self)


def trace(
    segments: Array,
    poses: Array,
    angle_min: float,
    angle_increment: float,
    beams: int,
    max_range: float,
) -> Array:
    """Exact distance [m] to the first wall along each beam, ``inf`` when none within range.

    Args:
        segments: ``(S, 2, 2)`` wall segments in the world frame [m].
        poses: ``(K, 3)`` sensor poses ``(x, y, theta)`` in the world frame.
        angle_min, angle_increment: bearing of beam 0 and the beam step [rad] in
            the sensor frame; beam ``j`` has bearing ``angle_min + j * angle_increment``.
        beams: number of beams ``N``.
        max_range: hits at or beyond this distance [m] are ignored.

    Returns:
        ``(K, N)`` ranges; a beam parallel to a segment does not hit it.

    Raises:
        ValueError: non-finite poses or segments (never passed on as NaN ranges).
    """
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    segments = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
    if not (np.isfinite(poses).all() and np.isfinite(segments).all()):
        raise UserError("trace: ray casting needs finite poses and segments")
    segments = segments[np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1) > 1e-12]
    out = np.full((len(poses), beams), np.inf)
    if len(segments) == 0 or len(poses) == 0:
        return out
    # End points shared by consecutive segments of a loop are handled once.
    vertices, index = np.unique(segments.reshape(-1, 2), axis=0, return_inverse=True)
    index = index.reshape(-1, 2)
    chunk = max(1, _PAIR_BUDGET // len(segments))
    for k0 in range(0, len(poses), chunk):
        out[k0 : k0 + chunk] = _trace_chunk(
            vertices, index, poses[k0 : k0 + chunk], angle_min, angle_increment, beams, max_range
        )
    return out


def _trace_chunk(
    vertices: Array,
    index: NDArray[np.intp],
    poses: Array,
    angle_min: float,
    step: float,
    beams: int,
    max_range: float,
) -> Array:
    """`trace` for one chunk of poses; segment ``s`` joins ``vertices[index[s]]``."""
    k_n, s_n = len(poses), len(index)
    ia, ib = index[:, 0], index[:, 1]
    # Vertices relative to each pose, and their bearings in beam units:
    # beta = (bearing - theta - angle_min) / step, modulo a full turn (n_turn).
    vx = vertices[None, :, 0] - poses[:, 0:1]  # (K, V)
    vy = vertices[None, :, 1] - poses[:, 1:2]
    n_turn = 2.0 * np.pi / step
    beta = np.arctan2(vy, vx)
    beta -= poses[:, 2:3] + angle_min
    beta *= 1.0 / step
    np.mod(beta, n_turn, out=beta)
    # Interval of each segment: from `lo_b` over `width` beam units (< half a turn).
    ba, bb = beta[:, ia], beta[:, ib]  # (K, S)
    delta = bb - ba
    delta -= np.where(delta >= 0.5 * n_turn, n_turn, 0.0)
    delta += np.where(delta < -0.5 * n_turn, n_turn, 0.0)
    lo_b = np.where(delta >= 0.0, ba, bb)
    width = np.abs(delta)
    eps = _EPS_ANGLE / step
    lo1 = np.ceil(lo_b - eps)
    top = lo_b + width + eps
    n1 = np.minimum(np.floor(top), beams - 1) - lo1 + 1  # beams lo1 .. min(top, N-1)
    n2 = np.minimum(np.floor(top - n_turn), beams - 1) + 1  # beams 0 .. wrapped part
    if np.isfinite(max_range):
        # Conservative cull: every point of the segment is farther than max range.
        ra = np.hypot(vx, vy)
        half = 0.5 * np.linalg.norm(vertices[ib] - vertices[ia], axis=1)
        far = np.minimum(ra[:, ia], ra[:, ib]) - half > max_range
        n1[far] = 0
        n2[far] = 0
    # Most (pose, segment) pairs fall between two beams: keep the others only.
    n1, n2, lo1 = n1.ravel(), n2.ravel(), lo1.ravel()
    sel1, sel2 = np.flatnonzero(n1 > 0), np.flatnonzero(n2 > 0)
    sel = np.concatenate([sel1, sel2])
    counts = np.concatenate([n1[sel1], n2[sel2]]).astype(np.intp)
    first = np.concatenate([lo1[sel1], np.zeros(len(sel2))]).astype(np.intp)
    # Expand to candidate (pose, segment, beam) triples.
    run = np.repeat(np.arange(len(counts)), counts)
    offset = np.cumsum(counts) - counts
    beam = first[run] + (np.arange(len(run)) - offset[run])
    pair = sel[run]
    k, s = np.divmod(pair, s_n)
    bearing = poses[k, 2] + angle_min + beam * step
    dx, dy = np.cos(bearing), np.sin(bearing)
    a = ia[s]
    wx, wy = vx[k, a], vy[k, a]  # a - p
    ex = vertices[ib[s], 0] - vertices[a, 0]
    ey = vertices[ib[s], 1] - vertices[a, 1]
    denom = dx * ey - dy * ex
    ok = np.abs(denom) > 1e-12
    denom = np.where(ok, denom, 1.0)
    t = (wx * ey - wy * ex) / denom
    u = (wx * dy - wy * dx) / denom
    ok &= (t > 0.0) & (t < max_range) & (u >= -_EPS_U) & (u <= 1.0 + _EPS_U)
    out = np.full(k_n * beams, np.inf)
    np.minimum.at(out, k[ok] * beams + beam[ok], t[ok])
    return out.reshape(k_n, beams)


def cast(
    world_or_segments: Walls | Array,
    poses: Array,
    laser: LaserModel,
    rng: np.random.Generator | None = None,
) -> Array:
    """Simulated readings ``(K, N)`` [m] of `laser` at sensor poses ``(K, 3)``.

    Args:
        world_or_segments: `Walls` (e.g. a `data.sim.worlds.World`) or a ``(S, 2, 2)``
            segment array (world frame, metres).
        poses: ``(K, 3)`` sensor poses ``(x, y, theta)`` in the world frame.
        laser: the sensor model.
        rng: source of noise and dropouts; None gives exact, complete readings.

    Returns:
        Ranges: misses read exactly ``laser.max_range``, dropouts 0.0, returns the
        exact distance plus Gaussian noise (see module docstring).
    """
    segments = getattr(world_or_segments, "segments", world_or_segments)
    exact = trace(
        np.asarray(segments, dtype=float),
        poses,
        laser.angle_min,
        laser.angle_increment,
        laser.beams,
        laser.max_range,
    )
    hit = np.isfinite(exact)
    top = max(laser.max_range - _MIN_RETURN, _MIN_RETURN)
    ranges = np.where(hit, np.clip(exact, _MIN_RETURN, top), laser.max_range)
    if rng is None:
        return ranges
    if laser.noise_sigma > 0.0:
        noisy = ranges + rng.normal(0.0, laser.noise_sigma, size=ranges.shape)
        ranges = np.where(hit, np.clip(noisy, _MIN_RETURN, top), ranges)
    if laser.dropout > 0.0:
        ranges[rng.random(ranges.shape) < laser.dropout] = 0.0
    return ranges
