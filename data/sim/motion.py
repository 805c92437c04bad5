"""Simulated robot motion along a world's route, and drifting wheel odometry.

Frames and units: poses are ``(x, y, theta)`` [m, m, rad] of the sensor, which sits
at the robot's reference point (no mounting offset), in the world frame (ground
truth) or in the odometry frame (odometry).  Times in seconds.

Trajectory (`drive`): the robot drives `laps` laps of the world's closed route
(a figure-eight, see `data.sim.worlds`), always in the same direction, at a
constant `speed` [m/s]; a scan is taken every ``1 / rate_hz`` seconds, i.e. every
``speed / rate_hz`` metres (0.125 m by default).  So that a revisit is never an exact
repeat, the robot's path is offset sideways from the route by a smooth function of
the distance travelled, ``o(s) = lateral_offset * sum_i w_i sin(2 pi s / L_i + p_i)``
with three random wavelengths ``L_i`` in 6-20 m and weights summing to one
(``|o| <= lateral_offset``).  The heading is the tangent of that path.  The
ground truth is exact: the poses at the scan stamps, no noise.

Odometry (`wheel_odometry`): each true increment between consecutive scans,
``(dx, dy, dtheta) = between(pose[k-1], pose[k])`` with ``d = |(dx, dy)|``, is
measured as

    dx'     = (1 + scale_bias) dx + n_x,   n_x ~ N(0, trans_sigma^2 d)
    dy'     = (1 + scale_bias) dy + n_y,   n_y ~ N(0, lateral_sigma^2 d)
    dtheta' = (1 + rot_scale_bias) dtheta + heading_bias d + n_t,
              n_t ~ N(0, rot_sigma_per_m^2 d + rot_sigma_per_rad^2 |dtheta|)

and the measured increments are composed from the first true pose.  The noise
*variance* grows linearly with the distance and rotation of each increment (a
random walk), so the accumulated drift does not depend on the scan rate; the
biases are systematic (wheel radius error, wheel base error, and a yaw drift per
metre) and make the odometry error grow steadily with distance.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

from data import se2
from data.errors import UserError

Array = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class MotionConfig:
    """How the robot drives the route (see module docstring).

    Attributes:
        speed: forward speed [m/s].
        rate_hz: scan rate [Hz].
        laps: number of laps of the closed route (>= 1; 2 revisits every place).
        lateral_offset: largest sideways deviation from the route [m].
        start_time: stamp of the first scan [s] (not 0: ROS treats 0 as "no time").
    """

    speed: float = 0.5
    rate_hz: float = 4.0
    laps: float = 2.0
    lateral_offset: float = 0.3
    start_time: float = 1.0

    def __post_init__(self) -> None:
        if not (self.speed > 0.0 and self.rate_hz > 0.0):
            raise UserError(
                f"speed and scan rate must be positive, got {self.speed}, {self.rate_hz}"
            )
        if not self.laps > 0.0:
            raise UserError(f"laps must be positive, got {self.laps}")
        if self.lateral_offset < 0.0:
            raise UserError(f"lateral offset must be >= 0, got {self.lateral_offset}")

    def to_json(self) -> dict[str, float]:
        """Plain dict of the parameters."""
        return asdict(self)


@dataclass(frozen=True, slots=True)
class OdometryNoise:
    """Wheel odometry error model (see module docstring for the equations).

    Attributes:
        trans_sigma: forward noise [m / sqrt(m)] (std after 1 m of travel).
        lateral_sigma: sideways noise [m / sqrt(m)].
        rot_sigma_per_m: heading noise per distance [rad / sqrt(m)].
        rot_sigma_per_rad: heading noise per rotation [rad / sqrt(rad)].
        scale_bias: systematic relative error of travelled distance (0.01 = +1 %).
        rot_scale_bias: systematic relative error of measured rotation.
        heading_bias: systematic yaw drift [rad/m].
    """

    trans_sigma: float = 0.02
    lateral_sigma: float = 0.01
    rot_sigma_per_m: float = 0.01
    rot_sigma_per_rad: float = 0.03
    scale_bias: float = 0.015
    rot_scale_bias: float = 0.01
    heading_bias: float = 0.002

    def to_json(self) -> dict[str, float]:
        """Plain dict of the parameters."""
        return asdict(self)


def _closed_tangent(route: Array) -> Array:
    """Unit tangents ``(R, 2)`` of a closed polyline (central differences)."""
    t = np.roll(route, -1, axis=0) - np.roll(route, 1, axis=0)
    return t / np.linalg.norm(t, axis=1, keepdims=True)


def drive(
    route: Array, config: MotionConfig, rng: np.random.Generator
) -> tuple[Array, Array]:
    """Stamps ``(K,)`` [s] and exact sensor poses ``(K, 3)`` along a closed route.

    Args:
        route: ``(R, 2)`` closed polyline [m] (last vertex joins the first), finely
            and roughly uniformly sampled.
        config: speed, scan rate, laps, lateral offset, start time.
        rng: draws the lateral offset's wavelengths, weights and phases.
    """
    route = np.asarray(route, dtype=float).reshape(-1, 2)
    closed = np.vstack([route, route[:1]])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    lap = arc[-1]
    tangent = _closed_tangent(route)
    tangent = np.vstack([tangent, tangent[:1]])
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])  # left of travel
    total = config.laps * lap
    ds_dense = 0.01
    s = np.arange(0.0, total + 2 * ds_dense, ds_dense)
    wavelength = rng.uniform(6.0, 20.0, size=3)
    weight = rng.uniform(0.5, 1.0, size=3)
    weight /= weight.sum()
    phase = rng.uniform(0.0, 2.0 * np.pi, size=3)
    offset = config.lateral_offset * (
        weight * np.sin(2.0 * np.pi * s[:, None] / wavelength + phase)
    ).sum(axis=1)
    sl = s % lap

    def at(values: Array) -> Array:
        return np.column_stack([np.interp(sl, arc, values[:, i]) for i in range(2)])

    path = at(closed) + offset[:, None] * at(normal)
    grad = np.gradient(path, ds_dense, axis=0)
    heading = np.unwrap(np.arctan2(grad[:, 1], grad[:, 0]))
    step = config.speed / config.rate_hz
    s_scan = np.arange(0.0, total + 1e-9, step)
    xy = np.column_stack([np.interp(s_scan, s, path[:, i]) for i in range(2)])
    theta = se2.wrap_angle(np.interp(s_scan, s, heading))
    stamps = config.start_time + s_scan / config.speed
    return stamps, np.column_stack([xy, theta])


def wheel_odometry(
    poses: Array, noise: OdometryNoise, rng: np.random.Generator
) -> Array:
    """Drifting odometry poses ``(K, 3)`` for true poses ``(K, 3)`` (see module docstring).

    The first odometry pose equals the first true pose; the rest compose the
    noisy, biased increments.  Vectorised (cumulative sums), no loop over poses.
    """
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    if len(poses) < 2:
        return poses.copy()
    inc = se2.between(poses[:-1], poses[1:])  # (K-1, 3) in the robot frame
    d = np.hypot(inc[:, 0], inc[:, 1])
    rot = np.abs(inc[:, 2])
    n = len(inc)
    sx = noise.trans_sigma * np.sqrt(d)
    sy = noise.lateral_sigma * np.sqrt(d)
    st = np.sqrt(noise.rot_sigma_per_m**2 * d + noise.rot_sigma_per_rad**2 * rot)
    dx = (1.0 + noise.scale_bias) * inc[:, 0] + sx * rng.standard_normal(n)
    dy = (1.0 + noise.scale_bias) * inc[:, 1] + sy * rng.standard_normal(n)
    dt = (1.0 + noise.rot_scale_bias) * inc[:, 2] + noise.heading_bias * d
    dt = dt + st * rng.standard_normal(n)
    theta = poses[0, 2] + np.concatenate([[0.0], np.cumsum(dt)])  # unwrapped headings
    c, s = np.cos(theta[:-1]), np.sin(theta[:-1])
    x = poses[0, 0] + np.concatenate([[0.0], np.cumsum(c * dx - s * dy)])
    y = poses[0, 1] + np.concatenate([[0.0], np.cumsum(s * dx + c * dy)])
    return np.column_stack([x, y, se2.wrap_angle(theta)])
