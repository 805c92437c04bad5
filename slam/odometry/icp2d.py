"""Scan-to-map 2D ICP odometry (the ``icp2d`` front end).

Each scan's valid end points (sensor frame, beams within ``[min_range, max_range]``,
voxel-downsampled to `source_voxel`) are registered by point-to-line ICP, with
clutter (vegetation, furniture) matched point to point (the maths of
`loopclosure.registration.register`, run by the compiled kernel
`loopclosure.fast_icp.register_fast`, or by the numpy reference with
``compiled=False``) onto a local map: the points of the last `map_keyframes` map
keyframes, in the odometry frame, merged and voxel-downsampled to `map_voxel`,
cropped to `map_radius` around the newest keyframe (with `cull_back_faces`, each
keyframe's points whose surface faces away from the newest keyframe's position, or
with ``facing_view="prediction"`` from the scan's predicted position, are left out:
`slam.odometry.facing`, normals from neighbours within `facing_gap`; the other face
of a thin wall seen earlier from its far side cannot pull a scan that sees only the
near one).  A scan becomes a map keyframe
when the pose has moved `keyframe_distance` or turned `keyframe_rotation` since the
last one; only then is the map's cell grid (`fast_icp.GridTarget`) rebuilt.  Its
normals are lazy (`loopclosure.grid_target`): a map point's normal is computed
the first time ICP or the search meets it as a nearest neighbour, the same figures
as computing all of them, for the part of the map the scans touch.  Where scans
lie farther apart than `keyframe_distance` (logs with a scan per metre), nearly every
scan is a keyframe and this is what keeps the rebuild cheap.

Prediction (initial guess and prior of ICP)
-------------------------------------------
* With odometry (``scan.odom``): the odometry increment since the previous scan,
  ``u = between(odom_prev, odom)``, with covariance `odometry_noise` (a
  `MotionNoise`).
* Without: constant velocity per scan step (the previous estimated increment;
  per step rather than per second because stamps can run backwards), covariance
  ``diag(velocity_sigma^2)``.

The prediction ``pose_prev ⊕ u`` starts ICP and, with `use_prior`, enters the
normal equations as a prior (``Lambda`` of `register`): directions the map does
not constrain (a corridor's axis) stay at the prediction instead of drifting.

Outputs (see `slam.odometry` for frames)
----------------------------------------
``covariance`` of the increment is the ICP covariance (``(H / sigma^2 + Lambda)^-1``,
see `loopclosure.registration`) rotated into the right-perturbation frame of the
new pose, plus ``diag(covariance_floor^2)``.  Treating the scan-to-map covariance
as the covariance of the increment ignores the map's own uncertainty; the floor
stands for it and for the optimism of the Gauss-Newton covariance.  With
``covariance_inflation="inliers"`` that sum is divided by the inlier ratio ``f`` of
the match (never below `min_inlier_ratio`): ``Sigma = (B^T C B + F) / f``, i.e. the
information of the increment in proportion to the fraction of the scan the map
explains; a scan that sees much the map lacks (weak overlap) says less about the
increment than one the map explains fully.  ``"none"`` (default) leaves it as is.

Search (when the prediction is poor)
------------------------------------
If ICP from the prediction fails or its fitness is below `search_below_fitness`,
a multi-hypothesis search runs (`_search`): headings {prediction, previous,
prediction + `search_turns_deg`, `search_headings` hypotheses from the normal
directions of scan and map} times positions {prediction + a grid of
`search_offsets` along and across the heading, previous position}, pre-screened
by `loopclosure.multi_start.overlap_scores` (its compiled twin on the map's grid
with `compiled`), ICP (compiled, on the same grid) from the best `search_keep`,
ranked by ``fitness * exp(-m^2 / 2)`` with ``m`` the deviation from the
prediction in units of `search_sigma` (a broad motion prior, so a symmetric
flip far from the prediction loses).  It matters for logs without odometry or
with large steps between scans; with dense odometry it almost never runs.

Graceful handling (status of `OdometryEstimate`)
------------------------------------------------
* ``no_points``: fewer than `min_points` usable points (all beams invalid, robot in
  open space): pose = prediction, covariance = prediction covariance times
  `fallback_inflation`; the map is not touched.
* ``failed``: ICP and search without a good match (inlier ratio below
  `min_inlier_ratio`, or RMS residual above `max_rms`): as ``no_points``, but the
  scan still becomes a map keyframe by the usual rule (at the predicted pose), so
  the map follows the robot into new areas.
* ``degenerate``: ICP solved but `IcpResult.degeneracy` is below
  `min_degeneracy`; the pose is kept (the prior fixed the weak direction, and the
  covariance is large along it).
* ``odometry_jump``: the odometry increment is implausible: longer than both
  `max_step` [m] and `jump_ratio` times the usual step of the last
  `jump_history` increments, or turning more than both `max_step_rotation` [rad]
  and `jump_ratio` times their usual turn (relative, so logs recorded at one scan
  per metre are not flagged all the time); usual is their median, or with
  ``jump_scale="largest"`` the largest of those that were not jumps (or were
  jumps the map confirmed, by their registered increment).  Kidnap, or
  a glitch of the log: ICP without prior is tried from the odometry prediction and
  from the previous pose (zero motion), then the search.  A match that is good and has at least
  `jump_fitness_ratio` times the median fitness of the last `jump_history`
  registered scans (a jump needs more evidence than a step) gives the pose
  (``extra["kidnap"] = False``).  With `jump_agreement` ``k > 0`` a good match that
  fails that fitness test still gives the pose when its increment ``d`` agrees with
  the odometry's ``u``: ``e^T C^-1 e <= k^2`` with ``e = between(u, d)`` (right
  perturbation) and ``C`` the odometry model's covariance of ``u``
  (`odometry_noise`); ``extra["agreed"] = True``.  Two independent sensors that
  place the scan at the same pose are evidence the robot was not carried away; the
  fitness test only doubts the match because a step over a metre sees less of the
  map than the turns on the spot that set the recent median.  Otherwise the robot was carried away
  (``extra["kidnap"] = True``): the pose follows the odometry, the covariance is
  ``diag(kidnap_sigma^2)`` (the increment is as good as unknown) and the map
  restarts from this scan.  With ``kidnap_noise="odometry"`` the covariance is
  instead the odometry's own model of that increment times `fallback_inflation`
  (as for a ``failed`` registration): the map restarts all the same, but the
  increment keeps the weight the odometry deserves.  A "jump" is judged against the
  recent steps, so on a log of one scan per metre an ordinary 1 m step after turns
  on the spot is one; given ``kidnap_sigma`` it is a free joint of the pose graph
  where any loop closing a cycle through it bends the trajectory (the whole
  discrepancy of the cycle goes into that one increment).

Every estimate carries ``extra``: points, map_points, keyframe (a map keyframe was
added), and after ICP inlier_ratio, rms, iterations, degeneracy, converged, search
(number of guesses, if it ran) and search_won.

Motion distortion (the robot moving during one sweep) is ignored by default: at
Intel's speeds (< 0.5 m/s, 75 Hz sweeps) it stays below 1 cm.  With ``deskew`` each
beam's end point is moved into the frame of the scan's stamp before anything else
(`deskew_points`): beam ``j`` (bearing ``a_j``, beams taken in index order from
the first bearing ``a_0``) is taken ``tau_j = (a_j - a_0) / (2 pi) * mirror_period``
after the stamp, plus one `mirror_period` for the odd beams of ``"interlaced"`` (a
SICK LMS at 0.5 degree takes the even beams in one turn of its mirror and the odd
ones in the next); the sensor's pose then is ``(tau_j / dt) * v`` in the stamp's
frame (constant velocity, the increment's ``(x, y, theta)`` scaled, its first-order
interpolation), with ``v`` the registered motion from the newest earlier scan at
least `deskew_baseline` before the previous one to the previous one and ``dt`` the
time between their stamps: the front end's own increments, not the odometry's
(whose heading error is larger than the distortion), over a baseline long enough
that the registration's millimetres and the stamps' jitter (scans a few
milliseconds apart) do not make a velocity.  The point is ``T((tau_j / dt) v) p_j``.
Not applied while no such pair of scans exists (the start, after a kidnap) or on an
odometry jump.
"""

from __future__ import annotations

import functools
import math
import statistics
import time
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from data import se2
from data.errors import UserError
from data.se2 import _wrap  # the scalar wrap `_between` must share with se2
from data.types import Scan
from loopclosure.headings import heading_hypotheses
from loopclosure.multi_start import MultiResult, initial_guesses, register_multi
from loopclosure.registration import (
    LINE_ANCHORS,
    IcpConfig,
    IcpResult,
    RegistrationTarget,
    body_covariance,
    register,
    voxel_downsample,
)
from slam.odometry import MotionNoise, OdometryEstimate, scan_odometry
from slam.odometry.facing import facing, scan_normals

if TYPE_CHECKING:
    from loopclosure.fast_icp import GridTarget

Array = NDArray[np.float64]

#: Beam timings of `Icp2dConfig.deskew`.
DESKEW_MODES = ("none", "sweep", "interlaced")
#: Earlier scans kept for the de-skew's velocity (`Icp2dConfig.deskew_baseline`).
TRACK_LENGTH = 64


@dataclass(frozen=True, slots=True)
class Icp2dConfig:
    """Parameters of the scan-to-map ICP odometry (module docstring).

    Attributes:
        icp: ICP and normal parameters (`loopclosure.registration.IcpConfig`);
            clutter (vegetation, poles) is matched point to point by default, at 0.3
            the weight of a wall's point-to-line row: it keeps outdoor logs
            registered where few map points are line-like, while walls dominate
            indoors.
        min_range: beams shorter than this are not used [m] (robot body).
        max_range: beams longer than this are not used [m] (sparse, noisy far walls).
        source_voxel: voxel of the scan's points [m] (0: all points).
        map_voxel: voxel of the local map [m].
        map_keyframes: number of recent map keyframes in the local map.
        map_radius: map points farther than this from the newest keyframe are
            dropped [m].
        keyframe_distance: travel that makes a new map keyframe [m].
        keyframe_rotation: rotation that makes a new map keyframe [rad].
        min_points: fewer usable points: status ``no_points``.
        min_inlier_ratio: fewer inliers: status ``failed``.
        max_rms: larger RMS residual of the inliers: status ``failed`` [m].
        min_degeneracy: smaller normalised translational eigenvalue: ``degenerate``.
        use_prior: the prediction is a prior of ICP.
        compiled: register with the compiled kernel (`loopclosure.fast_icp`, same
            maths and results); False runs the numpy reference
            (`loopclosure.registration.register`).
        line_anchor: where a wall's line passes (`loopclosure.fast_icp.ANCHORS`):
            ``"point"``, the nearest map point (a voxel centroid), or ``"mean"``,
            the mean of the neighbours its normal was fitted to (less noise);
            ``"mean"`` needs `compiled`.
        line_anchor_radius: the neighbours of that mean are within this distance of
            the point [m].
        line_anchor_band: and within this distance of the point's line [m] (inf: all).
        odometry_noise: covariance model of odometry increments.
        velocity_sigma: per-step standard deviations of the constant-velocity
            prediction (x [m], y [m], theta [rad]).
        covariance_floor: standard deviations added to every increment's covariance
            (x [m], y [m], theta [rad]).
        covariance_inflation: ``"none"`` or ``"inliers"``: the increment's covariance
            divided by the match's inlier ratio (module docstring).
        fallback_inflation: covariance multiplier of fallback estimates.
        max_step: odometry increments longer than this (and than `jump_ratio`
            times the recent median) are jumps [m].
        max_step_rotation: the same for the rotation [rad].
        jump_ratio: a jump is also this many times longer than the recent usual
            motion (`jump_scale`).
        jump_scale: the recent usual motion: ``"median"``, the median step and turn
            of the last `jump_history` odometry increments, or ``"largest"``, the
            largest of the last `jump_history` increments that were not jumps or
            were jumps the map confirmed (those by their registered increment: at
            the start of a log every step is a jump against an empty history).  The median
            flags an ordinary step as a jump on logs of about one scan per metre
            where the robot also turns on the spot (half the steps a few
            centimetres): the median falls to centimetres and the ordinary
            metre-long step exceeds `max_step`.
        jump_history: number of recent increments (and fitness values) of the medians.
        jump_fitness_ratio: a match after a jump needs this fraction of the median
            recent fitness.
        jump_agreement: or, when positive, a registered increment within this
            Mahalanobis distance [sigma] of the odometry increment under the
            odometry model's covariance (module docstring); 0: off.
        kidnap_sigma: standard deviations of a kidnapped increment (x [m], y [m],
            theta [rad]) with ``kidnap_noise="fixed"``.
        kidnap_noise: covariance of a kidnapped increment: ``"fixed"``,
            ``diag(kidnap_sigma^2)``; or ``"odometry"``, `odometry_noise` of the
            odometry increment times `fallback_inflation` (module docstring).
        search: run a multi-hypothesis search when the prediction registers badly.
        search_below_fitness: ICP fitness below this also triggers the search.
        search_headings: heading hypotheses of the search (besides prediction and
            previous heading).
        search_turns_deg: heading offsets from the prediction tried by the search [deg].
        search_offsets: position offsets of the search along and across the
            predicted heading (their grid) [m].
        search_keep: guesses that run ICP after pre-screening.
        search_sigma: broad prior of the search ranking: deviation from the
            prediction (translation [m], rotation [rad]).
        cull_back_faces: leave out of the local map the points of surfaces that face
            away from the newest keyframe's position (module docstring).
        facing_gap: largest distance [m] of a bearing neighbour that the normal of a
            keyframe point is computed from (`slam.odometry.facing.scan_normals`).
        facing_bend: largest turn [rad] between the steps to the two neighbours of a
            keyframe point that has a normal (more: no normal, the point is kept);
            pi: no such test.
        facing_view: where the culled faces are seen from: ``"keyframe"``, the
            newest keyframe's position (the map is culled when it is rebuilt), or
            ``"prediction"``, the predicted position of the scan being registered
            (the map is culled again before a scan whose prediction lies more than
            `facing_refresh` from the position it was last culled from; not on an
            odometry jump, whose prediction may be false).
        facing_refresh: distance [m] of the prediction from the last culling
            position that makes ``facing_view="prediction"`` cull again.
        deskew: ``"none"``, ``"sweep"`` or ``"interlaced"``: move each beam's point
            by the motion predicted between the stamp and the instant the beam was
            taken (module docstring).
        mirror_period: one turn of the laser's mirror [s] (1/75 s for a SICK LMS).
        deskew_baseline: shortest time [s] over which the de-skew's velocity is
            measured (module docstring).
    """

    icp: IcpConfig = field(
        default_factory=lambda: IcpConfig(point_to_point_clutter=True, clutter_weight=0.3)
    )
    min_range: float = 0.05
    max_range: float = 40.0
    source_voxel: float = 0.05
    map_voxel: float = 0.05
    map_keyframes: int = 30
    map_radius: float = 40.0
    keyframe_distance: float = 0.3
    keyframe_rotation: float = 0.2
    min_points: int = 20
    min_inlier_ratio: float = 0.25
    max_rms: float = 0.1
    min_degeneracy: float = 0.01
    use_prior: bool = True
    compiled: bool = True
    line_anchor: str = "point"
    line_anchor_radius: float = 0.2
    line_anchor_band: float = float("inf")
    odometry_noise: MotionNoise = field(default_factory=MotionNoise)
    velocity_sigma: tuple[float, float, float] = (0.2, 0.2, 0.2)
    covariance_floor: tuple[float, float, float] = (0.005, 0.005, 0.002)
    covariance_inflation: str = "none"
    fallback_inflation: float = 10.0
    max_step: float = 1.0
    max_step_rotation: float = 1.0
    jump_ratio: float = 10.0
    jump_scale: str = "median"
    jump_history: int = 20
    jump_fitness_ratio: float = 0.75
    jump_agreement: float = 0.0
    kidnap_sigma: tuple[float, float, float] = (10.0, 10.0, np.pi)
    kidnap_noise: str = "fixed"
    search: bool = True
    search_below_fitness: float = 0.3
    search_headings: int = 4
    search_turns_deg: tuple[float, ...] = (-45.0, -30.0, -15.0, 15.0, 30.0, 45.0)
    search_offsets: tuple[float, ...] = (-1.0, -0.5, 0.0, 0.5, 1.0)
    search_keep: int = 12
    search_sigma: tuple[float, float] = (1.0, 1.0)
    cull_back_faces: bool = False
    facing_gap: float = 0.25
    facing_bend: float = float(np.pi)
    facing_view: str = "keyframe"
    facing_refresh: float = 0.1
    deskew: str = "none"
    mirror_period: float = 1.0 / 75.0
    deskew_baseline: float = 0.1

    def __post_init__(self) -> None:
        positive = ("max_range", "map_voxel", "line_anchor_radius", "map_radius",
                    "keyframe_distance", "keyframe_rotation", "fallback_inflation",
                    "max_step", "max_step_rotation")
        for name in positive:
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise UserError(f"icp2d {name} must be a positive number, got {value}")
        if self.line_anchor not in LINE_ANCHORS:
            raise UserError(f"icp2d line_anchor must be one of {', '.join(LINE_ANCHORS)}, "
                            f"got {self.line_anchor!r}")
        if self.jump_scale not in ("median", "largest"):
            raise UserError(f"icp2d jump_scale must be median or largest, "
                            f"got {self.jump_scale!r}")
        if self.facing_view not in ("keyframe", "prediction"):
            raise UserError(f"icp2d facing_view must be keyframe or prediction, "
                            f"got {self.facing_view!r}")
        if not (np.isfinite(self.facing_refresh) and self.facing_refresh >= 0):
            raise UserError(f"icp2d facing_refresh must be >= 0, got {self.facing_refresh}")
        if self.deskew not in DESKEW_MODES:
            raise UserError(f"icp2d deskew must be one of {', '.join(DESKEW_MODES)}, "
                            f"got {self.deskew!r}")
        for name in ("mirror_period", "deskew_baseline"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise UserError(f"icp2d {name} must be positive, got {value}")
        if not (np.isfinite(self.jump_agreement) and self.jump_agreement >= 0):
            raise UserError(f"icp2d jump_agreement must be >= 0, got {self.jump_agreement}")
        if self.kidnap_noise not in ("fixed", "odometry"):
            raise UserError(f"icp2d kidnap_noise must be fixed or odometry, "
                            f"got {self.kidnap_noise!r}")
        if self.covariance_inflation not in ("none", "inliers"):
            raise UserError(f"icp2d covariance_inflation must be none or inliers, "
                            f"got {self.covariance_inflation!r}")
        if self.line_anchor != "point" and not self.compiled:
            raise UserError("icp2d line_anchor other than 'point' needs compiled=true")
        if self.map_keyframes < 1 or self.min_points < 3 or self.jump_history < 1:
            raise UserError("icp2d needs map_keyframes, jump_history >= 1 and min_points >= 3")
        for name in ("velocity_sigma", "covariance_floor", "kidnap_sigma"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (3,) or not np.all(np.isfinite(value)) or np.any(value < 0):
                raise UserError(f"icp2d {name} must be three numbers >= 0, got {value}")


def beam_delays(angles: Array, mirror_period: float, mode: str) -> Array:
    """Time [s] after the stamp at which each beam of bearings `angles` [rad] is taken
    (module docstring, *Motion distortion*): ``(a_j - a_0) / (2 pi) * mirror_period``,
    plus `mirror_period` for the odd beams when `mode` is ``"interlaced"``."""
    angles = np.asarray(angles, dtype=float)
    if mode == "none" or len(angles) == 0:
        return np.zeros(len(angles))
    delay = (angles - angles[0]) / (2.0 * np.pi) * mirror_period
    if mode == "interlaced":
        delay[1::2] += mirror_period
    return delay


def deskew_points(points: Array, delays: Array, increment: Array, dt: float) -> Array:
    """``(N, 2)`` sensor-frame `points` [m] taken `delays` [s] after the stamp, moved
    into the stamp's frame: ``T(s_j u) p_j`` with ``s_j = delays_j / dt`` and ``u``
    the ``(x, y, theta)`` `increment` over `dt` [s] (constant velocity, first order)."""
    frac = np.asarray(delays, dtype=float) / dt
    theta = frac * increment[2]
    c, s = np.cos(theta), np.sin(theta)
    x, y = points[:, 0], points[:, 1]
    return np.column_stack([c * x - s * y + frac * increment[0],
                            s * x + c * y + frac * increment[1]])


@functools.cache
def _fast():
    """`loopclosure.fast_icp`, imported on first use: numba (tens of MB, a fraction
    of a second) loads only when a scan is registered, not with the config."""
    from loopclosure import fast_icp

    return fast_icp


def _median(values: list[float]) -> float:
    """``float(statistics.median(values))`` of a non-empty list of floats: the middle
    value, or ``(a + b) / 2`` of the two middle ones, without its type dispatch."""
    ordered = sorted(values)
    half = len(ordered) // 2
    if len(ordered) % 2:
        return float(ordered[half])
    return float((ordered[half - 1] + ordered[half]) / 2)


def _between(a: Array, b: Array) -> tuple[float, float, float]:
    """``se2.between(a, b)`` of two ``(3,)`` poses [m, m, rad] as three floats: the same
    scalar operations in the same order (`se2.inverse`, then `se2.compose`, each on
    Python floats), so the same bits, without their array conversions (three calls
    per scan)."""
    ax, ay, at = a.tolist()
    bx, by, bt = b.tolist()
    c, s = math.cos(at), math.sin(at)
    ix, iy, it = -c * ax - s * ay, s * ax - c * ay, _wrap(-at)
    c, s = math.cos(it), math.sin(it)
    return ix + c * bx - s * by, iy + s * bx + c * by, _wrap(it + bt)


def _frame_rotation(theta: float) -> Array:
    """``blockdiag(R(theta), 1)``: right perturbation at heading theta -> additive."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class Icp2dOdometry:
    """``process(scan)``: scan-to-map ICP odometry (module docstring)."""

    name = "icp2d"

    def __init__(self, config: Icp2dConfig | None = None) -> None:
        self.config = config or Icp2dConfig()
        self.reset()

    def reset(self) -> None:
        """Forget the map and the motion: the next scan starts a new odometry frame."""
        cfg = self.config
        self._pose: Array | None = None
        self._odom: Array | None = None
        self._velocity = np.zeros(3)
        self._recent_steps: deque[tuple[float, float]] = deque(maxlen=cfg.jump_history)
        self._recent_fitness: deque[float] = deque(maxlen=cfg.jump_history)
        self._keyframes: deque[Array] = deque(maxlen=cfg.map_keyframes)
        self._normals: deque[Array] = deque(maxlen=cfg.map_keyframes)
        # ``np.vstack(self._keyframes)``, kept up to date as keyframes come and go
        # (`_add_keyframe`): one copy a keyframe instead of stacking all of them.
        self._stack: Array | None = None
        self._keyframe_pose: Array | None = None
        self._view: Array | None = None
        self._grid: GridTarget | None = None
        self._trig: tuple[Array, Array, Array] | None = None  # `_bearings`
        self._trig_source: Array | None = None  # `_bearings`: the array it came from
        self._floor_cov: Array | None = None  # `_floor`
        self._stamp: float | None = None  # stamp of the previous scan (`deskew`)
        # (stamp, pose) of the earlier scans, newest last (`deskew`'s velocity).
        self._track: deque[tuple[float, Array]] = deque(maxlen=TRACK_LENGTH)
        self.map_rebuilds = 0

    # ------------------------------------------------------------------ public

    @property
    def map_points(self) -> Array:
        """``(M, 2)`` points of the current local map (odometry frame) [m]."""
        if self._grid is None:
            return np.zeros((0, 2))
        return self._grid.input_points

    def process(self, scan: Scan) -> OdometryEstimate:
        """Estimate for the next scan (in source order)."""
        t0 = time.perf_counter()
        cfg = self.config
        if not isinstance(scan, Scan):
            raise UserError(
                f"icp2d odometry needs planar laser scans, got {type(scan).__name__}; "
                "use kiss-icp for point clouds"
            )
        points = self.scan_points(scan)
        odom = scan_odometry(scan)
        extra: dict[str, Any] = {"points": len(points)}
        if self._pose is None:
            pose = odom.copy() if odom is not None else np.zeros(3)
            self._odom = odom
            self._stamp = float(scan.stamp)
            self._accept(pose, np.zeros(3), points, extra, force_keyframe=True)
            return self._estimate(scan, pose, np.zeros(3), self._floor(), 0.0, "first", t0, extra)

        prev = self._pose
        u, u_cov, jump = self._prediction(odom)
        if odom is not None:
            self._odom = odom
        if cfg.deskew != "none":
            assert self._stamp is not None
            self._track.append((self._stamp, prev.copy()))
            if not jump:
                points = self._deskewed(scan, points)
                extra["points"] = len(points)
        self._stamp = float(scan.stamp)
        pred = se2.compose(prev, u)
        if jump:
            extra["odometry_step"] = u.copy()
        if len(points) < cfg.min_points or self._grid is None:
            if jump:
                return self._kidnap(scan, pred, u, u_cov, points, extra, t0)
            # No usable scan, or no map yet (every earlier scan was empty): predict.
            cov = u_cov * cfg.fallback_inflation
            enough = len(points) >= cfg.min_points
            status = "failed" if enough else "no_points"
            if enough:
                extra["reason"] = "no map yet"
            self._accept(pred, u, points, extra, force_keyframe=enough)
            return self._estimate(scan, pred, u, cov, 0.0, status, t0, extra)

        if (cfg.cull_back_faces and cfg.facing_view == "prediction" and not jump
                and self._view is not None
                and np.hypot(*(pred[:2] - self._view)) > cfg.facing_refresh):
            self._rebuild_map(pred[:2])
            if self._grid is None:  # nothing left to match: the keyframe's view
                self._rebuild_map()
            if self._grid is None:
                cov = u_cov * cfg.fallback_inflation
                self._accept(pred, u, points, extra)
                return self._estimate(scan, pred, u, cov, 0.0, "failed", t0, extra)
        if jump:  # the odometry may lie: no prior, try the prediction and standing still
            res = self._multi(points, np.vstack([pred, prev])).best
        else:
            res = self._register(points, pred, u_cov)
        if cfg.search and (not self._good(res) or res.fitness < cfg.search_below_fitness):
            res = self._search(points, prev, pred, res, extra)
        self._describe(res, extra)
        if jump and self._good(res) and self._recent_fitness:
            # A jump needs a match as good as the recent ones, not just a passable one.
            usual = float(statistics.median(self._recent_fitness))
            if res.fitness < cfg.jump_fitness_ratio * usual:
                if self._agrees(prev, res.pose, u, u_cov):
                    extra["agreed"] = True
                else:
                    extra["rejected_fitness"] = res.fitness
                    return self._kidnap(scan, pred, u, u_cov, points, extra, t0)
        if not self._good(res):
            if jump:
                return self._kidnap(scan, pred, u, u_cov, points, extra, t0)
            cov = u_cov * cfg.fallback_inflation
            self._accept(pred, u, points, extra)
            return self._estimate(scan, pred, u, cov, res.fitness, "failed", t0, extra)
        pose = res.pose
        delta = np.array(_between(prev, pose))
        if jump:
            status = "odometry_jump"
            extra["kidnap"] = False
            if cfg.jump_scale == "largest":
                self._recent_steps.append((float(np.hypot(delta[0], delta[1])),
                                           float(abs(delta[2]))))
        else:
            status = "degenerate" if res.degeneracy < cfg.min_degeneracy else "ok"
            self._recent_fitness.append(res.fitness)
        self._accept(pose, delta, points, extra)
        cov = self._increment_covariance(res, pose)
        return self._estimate(scan, pose, delta, cov, res.fitness, status, t0, extra)

    # ----------------------------------------------------------------- private

    def scan_points(self, scan: Scan) -> Array:
        """``(N, 2)`` points the front end registers: end points (sensor frame) of the
        beams within ``[min_range, max_range]``, voxel-downsampled to `source_voxel` [m]."""
        cfg = self.config
        r, angles = scan.ranges, scan.angles
        if (cfg.compiled and r.dtype == np.float64 and angles.dtype == np.float64
                and r.shape == angles.shape):
            # One compiled call on the bearings' cosines and sines, computed once per
            # laser (`_bearings`): the same points, to the bit.
            cosines, sines = self._bearings(angles)
            bounds = (max(scan.min_range, 0.0), scan.max_range, cfg.min_range, cfg.max_range)
            return _fast().beam_points_fast(r, cosines, sines, bounds, cfg.source_voxel)
        valid = scan.valid
        with np.errstate(invalid="ignore"):
            keep = valid & (r >= cfg.min_range) & (r <= cfg.max_range)
        pts = np.column_stack([r[keep] * np.cos(angles[keep]),
                               r[keep] * np.sin(angles[keep])])
        voxel = _fast().voxel_downsample_fast if cfg.compiled else voxel_downsample
        return voxel(pts, cfg.source_voxel)

    def _deskewed(self, scan: Scan, points: Array) -> Array:
        """`scan_points` of `scan` with every beam moved by `deskew_points` (the
        registered motion over at least `deskew_baseline`, `_track_velocity`);
        `points` unchanged while no tracked scan is that old."""
        cfg = self.config
        velocity, dt = self._track_velocity()
        if velocity is None:
            return points
        delays = beam_delays(scan.angles, cfg.mirror_period, cfg.deskew)
        r, angles = scan.ranges, scan.angles
        with np.errstate(invalid="ignore"):
            keep = scan.valid & (r >= cfg.min_range) & (r <= cfg.max_range)
        raw = np.column_stack([r[keep] * np.cos(angles[keep]), r[keep] * np.sin(angles[keep])])
        moved = deskew_points(raw, delays[keep], velocity, dt)
        voxel = _fast().voxel_downsample_fast if cfg.compiled else voxel_downsample
        return voxel(moved, cfg.source_voxel)

    def _track_velocity(self) -> tuple[Array | None, float]:
        """Registered increment ``(x, y, theta)`` from the newest tracked scan at least
        `deskew_baseline` [s] before the newest one to the newest one, and the time
        between them [s]; ``(None, 0)`` when no tracked scan is that old."""
        if not self._track:
            return None, 0.0
        t_last, p_last = self._track[-1]
        for t, p in reversed(self._track):
            dt = t_last - t
            if dt >= self.config.deskew_baseline:
                return se2.between(p, p_last), dt
        return None, 0.0

    def _bearings(self, angles: Array) -> tuple[Array, Array]:
        """``(cos, sin)`` of the beams' bearings `angles` [rad], kept for the next scan
        of the same laser (equal bearings: a cosine depends only on its bearing, so
        ``np.cos(angles)[keep]`` is ``np.cos(angles[keep])``)."""
        cached = self._trig
        if cached is not None and angles is self._trig_source:
            return cached[1], cached[2]  # the reader's one read-only array of a laser
        if (cached is not None and cached[0].shape == angles.shape
                and np.array_equal(cached[0], angles)):
            return cached[1], cached[2]
        a = np.array(angles, dtype=float)  # a copy: the key of the next comparison
        self._trig = (a, np.cos(a), np.sin(a))
        # The same object again is the same bearings only if nothing can write to it.
        self._trig_source = None if angles.flags.writeable else angles
        return self._trig[1], self._trig[2]

    def _prediction(self, odom: Array | None) -> tuple[Array, Array, bool]:
        """Increment ``u``, its covariance and whether it is an odometry jump."""
        cfg = self.config
        if odom is not None and self._odom is not None:
            ux, uy, ut = _between(self._odom, odom)
            step, turn = float(np.hypot(ux, uy)), abs(ut)
            usual_step, usual_turn = self._usual_motion()
            jump = bool(step > max(cfg.max_step, cfg.jump_ratio * usual_step)
                        or turn > max(cfg.max_step_rotation, cfg.jump_ratio * usual_turn))
            if cfg.jump_scale == "median" or not jump:
                # A lone jump hardly moves the median; the largest counts only the
                # increments that were not jumps (a jump the map confirms adds its
                # registered increment in `process`), so a kidnap does not raise it.
                self._recent_steps.append((step, turn))
            # `MotionNoise.covariance(u)` from the step it measures the same way.
            cov = cfg.odometry_noise.diagonal(step, abs(_wrap(ut)))
            return np.array([ux, uy, ut]), cov, jump
        u = self._velocity.copy()
        return u, np.diag(np.square(cfg.velocity_sigma)), False

    def _usual_motion(self) -> tuple[float, float]:
        """Step [m] and turn [rad] the jump rule scales by `jump_ratio`: the median
        (``jump_scale="median"``) or the largest (``"largest"``) of the recent
        increments, each taken separately; zero before the first."""
        if not self._recent_steps:
            return 0.0, 0.0
        steps = [s for s, _ in self._recent_steps]
        turns = [t for _, t in self._recent_steps]
        if self.config.jump_scale == "largest":
            return max(steps), max(turns)
        # A few dozen numbers: plain Python (np.median's per-call overhead is tens of
        # microseconds, paid at every scan); the mean of the two middle values for an
        # even count, as `statistics.median` takes it (`_median`).
        return _median(steps), _median(turns)

    def _register(self, points: Array, pred: Array, u_cov: Array) -> IcpResult:
        grid = self._grid
        assert grid is not None
        cfg = self.config
        if cfg.compiled:
            register_fast = _fast().register_fast

            def icp(*args, **kwargs):
                return register_fast(points, grid, *args, **kwargs)
        else:
            def icp(*args, **kwargs):
                return register(points, grid.target, *args, **kwargs)
        if not cfg.use_prior:
            return icp(pred, config=cfg.icp)
        rot = _frame_rotation(float(pred[2]))
        prior_cov = rot @ u_cov @ rot.T
        return icp(pred, config=cfg.icp, prior=pred, prior_covariance=prior_cov)

    def _search(
        self, points: Array, prev: Array, pred: Array, res: IcpResult, extra: dict[str, Any]
    ) -> IcpResult:
        """Multi-hypothesis ICP when the prediction did not register well (module doc).

        Ranking: ``fitness * exp(-m^2 / 2)``, ``m^2 = (|dt| / search_sigma[0])^2 +
        (dtheta / search_sigma[1])^2``, ``(dt, dtheta)`` the deviation from the
        prediction.  The best replaces `res` if it is good and ranks higher.
        """
        assert self._grid is not None
        cfg = self.config
        heads = heading_hypotheses(points, self._grid.input_points, count=cfg.search_headings,
                                   method="normals", config=cfg.icp)
        turns = np.radians(np.asarray(cfg.search_turns_deg, dtype=float))
        heads = np.concatenate([[pred[2], prev[2]], pred[2] + turns, heads])
        steps = np.asarray(cfg.search_offsets, dtype=float)
        along, across = np.meshgrid(steps, steps, indexing="ij")
        c, s = np.cos(pred[2]), np.sin(pred[2])
        offs = np.column_stack([c * along.ravel() - s * across.ravel(),
                                s * along.ravel() + c * across.ravel()])
        offs = np.vstack([offs, prev[:2] - pred[:2]])
        guesses = initial_guesses(pred, heads, offs)
        multi = self._multi(points, guesses, keep=cfg.search_keep)
        extra["search"] = len(guesses)
        best, best_rank = res, self._rank(res, pred) if res.ok else -1.0
        for cand in multi.results:
            rank = self._rank(cand, pred)
            if self._good(cand) and rank > best_rank:
                best, best_rank = cand, rank
        extra["search_won"] = best is not res
        return best

    def _multi(self, points: Array, guesses: Array, keep: int | None = None) -> MultiResult:
        """`register_multi` onto the local map: with `Icp2dConfig.compiled` the
        compiled ICP on the map's grid (guesses prescreened on it), else numpy ICP on
        its `RegistrationTarget`.  Runs are not joined: a joined run returns the pose
        an earlier run reached, within a few millimetres of its own, and the ranking
        (`_rank`) is then decided by those millimetres; unjoined, the compiled search
        picks the pose the numpy one picks."""
        assert self._grid is not None
        cfg = self.config
        if cfg.compiled:
            return register_multi(points, None, guesses, config=cfg.icp, keep=keep,
                                  compiled=True, grid=self._grid, join=False)
        return register_multi(points, self._grid.target, guesses, config=cfg.icp, keep=keep)

    def _rank(self, res: IcpResult, pred: Array) -> float:
        dev = se2.between(pred, res.pose)
        sig = self.config.search_sigma
        m2 = (np.hypot(dev[0], dev[1]) / sig[0]) ** 2 + (dev[2] / sig[1]) ** 2
        return float(res.fitness * np.exp(-0.5 * m2))

    def _agrees(self, prev: Array, pose: Array, u: Array, u_cov: Array) -> bool:
        """Whether the registered increment ``d = between(prev, pose)`` lies within
        `jump_agreement` sigmas of the odometry increment `u`: ``e^T u_cov^-1 e <= k^2``,
        ``e = between(u, d)`` (x [m], y [m], theta [rad], right perturbation); always
        False when `jump_agreement` is 0."""
        k = self.config.jump_agreement
        if k <= 0:
            return False
        e = se2.between(np.asarray(u, dtype=float), np.array(_between(prev, pose)))
        return bool(e @ np.linalg.solve(u_cov, e) <= k * k)

    def _good(self, res: IcpResult) -> bool:
        cfg = self.config
        return bool(res.ok and res.inlier_ratio >= cfg.min_inlier_ratio
                    and res.rms <= cfg.max_rms)

    def _kidnap(
        self, scan: Scan, pred: Array, u: Array, u_cov: Array, points: Array,
        extra: dict[str, Any], t0: float,
    ) -> OdometryEstimate:
        """The odometry jumped and the map does not confirm any motion: restart the map.

        `u_cov` is the odometry model's covariance of the increment `u`; the estimate's
        covariance is set by `kidnap_noise` (module docstring)."""
        cfg = self.config
        extra["kidnap"] = True
        self._track.clear()
        self._keyframes.clear()
        self._normals.clear()
        self._stack = None
        self._grid = None
        self._accept(pred, u, points, extra, force_keyframe=len(points) >= cfg.min_points)
        self._velocity = np.zeros(3)
        if cfg.kidnap_noise == "odometry":
            cov = u_cov * cfg.fallback_inflation
        else:
            cov = np.diag(np.square(cfg.kidnap_sigma))
        return self._estimate(scan, pred, u, cov, 0.0, "odometry_jump", t0, extra)

    def _accept(
        self,
        pose: Array,
        delta: Array,
        points: Array,
        extra: dict[str, Any],
        force_keyframe: bool = False,
    ) -> None:
        """Take `pose` as the new estimate; add a map keyframe if due."""
        cfg = self.config
        self._pose = np.asarray(pose, dtype=float).copy()
        self._velocity = np.asarray(delta, dtype=float).copy()
        due = force_keyframe
        if not due and self._keyframe_pose is not None and len(points) >= cfg.min_points:
            dx, dy, dt = _between(self._keyframe_pose, self._pose)
            due = bool(np.hypot(dx, dy) >= cfg.keyframe_distance
                       or abs(dt) >= cfg.keyframe_rotation)
        extra["keyframe"] = due
        if due:
            self._keyframe_pose = self._pose.copy()
            self._add_keyframe(se2.transform_points(self._pose, points))
            if cfg.cull_back_faces:
                c, s = np.cos(self._pose[2]), np.sin(self._pose[2])
                self._normals.append(scan_normals(points, cfg.facing_gap, cfg.facing_bend)
                                     @ np.array([[c, s], [-s, c]]))
            self._rebuild_map()

    def _add_keyframe(self, points: Array) -> None:
        """Append a keyframe's points ``(N, 2)`` [m] (odometry frame) to the map's
        keyframes (the oldest leaves a full window) and to their stack, which then
        holds the same rows as ``np.vstack`` of the window."""
        frames = self._keyframes
        drop = len(frames[0]) if len(frames) == frames.maxlen else 0
        frames.append(points)
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        self._stack = (pts.copy() if self._stack is None
                       else np.concatenate((self._stack[drop:], pts)))

    def _rebuild_map(self, view: Array | None = None) -> None:
        """Merge the keyframes into the local map; with `cull_back_faces`, the faces
        seen from `view` (``(2,)`` odometry frame [m]; the newest keyframe's position
        if None)."""
        cfg = self.config
        fast = _fast()
        voxel = fast.voxel_downsample_fast if cfg.compiled else voxel_downsample
        assert self._keyframe_pose is not None
        self._view = (self._keyframe_pose[:2] if view is None
                      else np.asarray(view, dtype=float)[:2]).copy()
        if cfg.cull_back_faces and len(self._normals) == len(self._keyframes):
            frames = [p[facing(p, n, self._view)]
                      for p, n in zip(self._keyframes, self._normals, strict=True)]
            stack = np.vstack(frames)
        else:
            assert self._stack is not None
            stack = self._stack
        pts = voxel(stack, cfg.map_voxel)
        if cfg.compiled:  # the same rows, compiled
            pts = fast.points_within(pts, self._keyframe_pose[:2], cfg.map_radius)
        else:
            pts = pts[np.hypot(*(pts - self._keyframe_pose[:2]).T) <= cfg.map_radius]
        if cfg.compiled:
            self._grid = fast.GridTarget(pts, cfg.icp, anchor=cfg.line_anchor,
                                         anchor_radius=cfg.line_anchor_radius,
                                         anchor_band=cfg.line_anchor_band, lazy=True)
        else:
            target = RegistrationTarget(pts, cfg.icp)
            self._grid = (fast.GridTarget.from_target(target) if target.tree is not None
                          else None)
        if self._grid is not None and not self._grid.matchable():
            self._grid = None
        self.map_rebuilds += 1

    def _increment_covariance(self, res: IcpResult, pose: Array) -> Array:
        """Body-frame covariance of an accepted increment (module docstring)."""
        cov = body_covariance(pose, res.covariance) + self._floor()
        if self.config.covariance_inflation == "inliers":
            cov = cov / max(res.inlier_ratio, self.config.min_inlier_ratio)
        return cov

    def _floor(self) -> Array:
        """``diag(covariance_floor^2) + 1e-12 I`` (made once: the config is frozen)."""
        if self._floor_cov is None:
            self._floor_cov = np.diag(np.square(self.config.covariance_floor)) + 1e-12 * np.eye(3)
        return self._floor_cov.copy()

    @staticmethod
    def _describe(res: IcpResult, extra: dict[str, Any]) -> None:
        extra.update(
            inlier_ratio=res.inlier_ratio, rms=res.rms, iterations=res.iterations,
            degeneracy=res.degeneracy, converged=res.converged,
        )

    def _estimate(
        self,
        scan: Scan,
        pose: Array,
        delta: Array,
        cov: Array,
        fitness: float,
        status: str,
        t0: float,
        extra: dict[str, Any],
    ) -> OdometryEstimate:
        extra["map_points"] = 0 if self._grid is None else len(self._grid.input_points)
        return OdometryEstimate(
            stamp=float(scan.stamp),
            index=int(scan.index),
            pose=np.asarray(pose, dtype=float).copy(),
            delta=np.asarray(delta, dtype=float).copy(),
            covariance=cov,
            fitness=float(fitness),
            seconds=time.perf_counter() - t0,
            status=status,
            extra=extra,
        )
