"""FFT matcher: Fourier descriptors of the polar range function (paper Section II.A.1).

Paper: Kosnar, Vonasek, Kulich, Preucil, "Comparison of shape matching techniques for
place recognition" (``papers/shape-matching-place-recognition.txt``), Section II.A.1
("Fourier Transformation", "Fft" in its tables), after its reference [8] (Fourier
descriptors; Zhang & Lu, "A comparative study of Fourier descriptors for shape
representation and retrieval", 2002).  This is THE prefilter of the SLAM pipeline: cheap
to describe, a fixed-length vector, compared with one matrix-vector product against the
whole database.

Equations (plain text)
----------------------
Range function.  With c the reference point (see below) and the ray of bin j

    theta_j = 2 pi j / B,  j = 0 .. B-1,
    r_j     = distance from c along direction (cos theta_j, sin theta_j) to the boundary.

Every edge (p, q) of the polygon, translated so that c = 0, is intersected exactly
with the rays of the bins its angular sweep covers:  a ray d hits the line through p
with direction e = q - p at  t = (p x e) / (d x e)  (2-D cross products).  A polygon that
is not star-shaped from c is hit several times by one ray; `ray_hit` chooses the
farthest hit (default: the outer envelope, stable when a small object in the room
occludes part of a wall) or the nearest (what a sensor standing at c would see).  A
bin without any hit (only when c lies outside the polygon) gets r_j = 0.  All of this
is vectorised over edges and rays (``np.repeat`` over the bins each edge sweeps and one
``np.maximum.at`` reduction): O(N + B) per polygon, no B x N matrix.

Descriptor (the paper's X_k = sum_j r_j exp(-2 pi i j k / B)):

    a_k = |X_k| / B,   k = 0 .. K-1                 (metres; a_0 is the mean range)

Amplitudes are invariant to a cyclic shift of r, i.e. to a rotation of the polygon
about c.  With ``scale_invariant=True`` the descriptor is a_k / a_0 for k = 1 .. K
(dimensionless), the customary normalisation of Fourier descriptors.

Distance: Euclidean in K dimensions, s(D_i, D_j) = ||a^i - a^j||_2.

Heading estimate (`heading_from_range_functions`): the circular cross-correlation of
two range functions, computed by FFT,

    c_k = sum_j (r^a_j - mean r^a)(r^b_{j+k} - mean r^b) / (B std(r^a) std(r^b)),

is the Pearson correlation of r^b with r^a shifted by k bins; its peak k* (refined to
sub-bin precision by a parabola through the three samples around it) gives the
rotation angle = 2 pi k* / B such that polygon b ~ R(angle) . polygon a (both about
their own reference points), and c_{k*} in [-1, 1] as a confidence score.

Reference point
---------------
The area centroid of the polygon, not the sensor origin: the SLAM pipeline compares
scans of the same place from displaced positions, whose sensor origins differ but
whose enclosed regions (and centroids) nearly coincide.  A rotation about the sensor
origin rotates the centroid with the polygon, so the descriptor stays exactly
rotation invariant.

Parameters (`FFTConfig`)
------------------------
- ``n_bins`` B = 256: angle bins of the range function (1.4 degrees each, about the
  resolution of a 360-beam scan; a power of two keeps the FFT fast).
- ``n_harmonics`` K = 16: amplitudes kept.  Low harmonics carry the coarse shape, high
  ones mostly noise (paper, Fig. 1 used k = 30 for a reconstruction); the database scan
  costs O(K) per entry.
- ``ray_hit`` = "farthest": which boundary hit a ray keeps (see above).
- ``scale_invariant`` = False: places must not be scale invariant (rooms differing
  only in size are different places); True for MPEG-7.
- ``near_radius`` = None [m]: when set, the descriptor is that of the polygon as seen
  within this distance of the sensor origin (`loopclosure.polygon.polygon_within`:
  every farther vertex pulled in along its ray), reference point and range function
  included.  On 30 m virtual scans the far field (open space at the cap, walls seen
  from only some of the local maps' paths) dominates the area, so the centroid moves
  metres between two views of one place and the far ranges differ; within a few
  metres of the sensor the centroid moves centimetres.  Unused when scale invariant.
- ``far_weight`` w = 0.0: with ``near_radius`` set and w > 0 the descriptor is the
  near polygon's K amplitudes followed by w times the whole polygon's K amplitudes
  (about its own area centroid), 2K values: a faint far field, for places whose near
  field is open space (outdoors) while what is far away is seen from anywhere.  The
  Euclidean distance is then sqrt(||a_near - b_near||^2 + w^2 ||a_whole - b_whole||^2).
  Describing costs two range functions.  The range function and centre kept for the
  heading are the near polygon's.

Departures from the paper
-------------------------
- The paper samples the raw scan's range function around the sensor; we sample the
  polygon's range function around its centroid (rotation invariance about a point
  that does not move with the robot's displacement) on B uniform bins, which also
  handles scans with irregular or missing beams.
- Database comparison (`loopclosure.matchers.vector_search`) uses float32 and
  ||q||^2 + ||x||^2 - 2 q.x (one single-threaded matrix-vector product); entries whose squared
  distance is within 1e-4 of the norms (near-duplicates, where float32 cancellation
  matters) are recomputed exactly in float64, so identical shapes give exactly 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from functools import lru_cache
from typing import Any

import numpy as np
import scipy.fft
from numpy.typing import NDArray

from data.errors import UserError
from loopclosure.matchers.base import Matcher
from loopclosure.matchers.vector_search import VectorStack, stack_distances, stack_vectors
from loopclosure.polygon import Polygon, polygon_within

Array = NDArray[np.float64]

_TWO_PI = 2.0 * np.pi


@dataclass(slots=True, frozen=True)
class FFTConfig:
    """Parameters of the FFT matcher (see module docstring).

    Attributes:
        n_bins: number B of uniform angle bins of the range function.
        n_harmonics: number K of Fourier amplitudes in the descriptor.
        ray_hit: ``"farthest"`` or ``"nearest"`` boundary hit per ray.
        scale_invariant: divide amplitudes by the mean range (and drop it).
        near_radius: describe the polygon within this distance of the sensor [m]
            (None: the whole polygon).
        far_weight: weight of the whole polygon's amplitudes appended to the near
            polygon's (0: none; only with `near_radius`).
    """

    n_bins: int = 256
    n_harmonics: int = 16
    ray_hit: str = "farthest"
    scale_invariant: bool = False
    near_radius: float | None = None
    far_weight: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.far_weight) and self.far_weight >= 0):
            raise UserError(f"far_weight must be a finite weight >= 0, got {self.far_weight}")
        if self.near_radius is not None and not (
            np.isfinite(self.near_radius) and self.near_radius > 0
        ):
            raise UserError(f"near_radius must be a positive length [m], got {self.near_radius}")
        if self.n_bins < 8:
            raise UserError(f"n_bins must be >= 8, got {self.n_bins}")
        if not 1 <= self.n_harmonics <= self.n_bins // 2:
            raise UserError(
                f"n_harmonics must be in 1..n_bins/2 (1..{self.n_bins // 2} for n_bins = "
                f"{self.n_bins}), got {self.n_harmonics}"
            )
        if self.ray_hit not in ("farthest", "nearest"):
            raise UserError(f"ray_hit must be 'farthest' or 'nearest', got {self.ray_hit!r}")


@dataclass(slots=True, frozen=True)
class FFTDescriptor:
    """Descriptor of one polygon.

    Attributes:
        amplitudes: ``(K,)`` float32 Fourier amplitudes (metres, or unitless when
            scale invariant).
        range_function: ``(B,)`` range r_j [m] of bin j at angle 2 pi j / B about
            `centre`, in the polygon's own (sensor) frame orientation.
        centre: ``(2,)`` reference point (area centroid) in the sensor frame [m].
    """

    amplitudes: NDArray[np.float32]
    range_function: Array
    centre: Array


FFTStack = VectorStack
"""Many FFT descriptors packed for `FFTMatcher.distances`: ``matrix`` ``(M, K)`` float32
amplitudes and ``sqnorms`` ``(M,)`` their squared norms (`vector_search.VectorStack`)."""


def _centroid(closed: Array) -> Array:
    """Area centroid [m] of a closed ``(N + 1, 2)`` vertex array (last row = first row)."""
    x0, y0, x1, y1 = closed[:-1, 0], closed[:-1, 1], closed[1:, 0], closed[1:, 1]
    cross = x0 * y1 - x1 * y0
    six_area = 3.0 * cross.sum()
    return np.array([(x0 + x1) @ cross, (y0 + y1) @ cross]) / six_area


@lru_cache(maxsize=16)
def _ray_table(n_bins: int) -> tuple[Array, Array]:
    theta = np.arange(n_bins) * (_TWO_PI / n_bins)
    return np.cos(theta), np.sin(theta)


def range_function(vertices: Array, centre: Array, n_bins: int, ray_hit: str = "farthest") -> Array:
    """``(n_bins,)`` boundary distance [m] along rays at angles ``2 pi j / n_bins`` from `centre`.

    `vertices` is an ``(N, 2)`` closed polygon [m] (any orientation); every edge is
    intersected exactly with the rays its angular sweep covers.  Per ray the farthest
    (or nearest) hit is kept; rays that hit nothing get 0.
    """
    v = np.asarray(vertices, dtype=float)
    closed = np.concatenate([v, v[:1]]) - centre
    return _range_function_closed(closed, n_bins, ray_hit)


_ARANGE = np.arange(1 << 14, dtype=np.float64)
"""Cached 0, 1, 2, ... (sliced instead of a fresh `np.arange` per call)."""


def _arange(n: int) -> Array:
    global _ARANGE
    if n > len(_ARANGE):
        _ARANGE = np.arange(max(n, 2 * len(_ARANGE)), dtype=np.float64)
    return _ARANGE[:n]


def _range_function_closed(closed: Array, n_bins: int, ray_hit: str) -> Array:
    """`range_function` of a closed ``(N + 1, 2)`` vertex array already centred on c."""
    xy = np.ascontiguousarray(closed.T)  # (2, N + 1): x row, y row
    return _range_function_rows(xy, n_bins, ray_hit)


def _range_function_rows(xy: Array, n_bins: int, ray_hit: str) -> Array:
    """`range_function` of closed vertices given as rows ``xy = (x, y)``, ``(2, N + 1)``.

    Hot path of `FFTMatcher.describe`, written with few numpy calls (each costs about a
    microsecond on a few hundred vertices): the per-edge quantities are expanded to
    per-hit rows by one ``np.repeat`` of an ``(N, 4)`` block, bins wrap by a bit mask
    when `n_bins` is a power of two.  Integer-valued floats are exact, so the bins and
    hit distances are those of the straightforward formulation.
    """
    x, y = xy[0], xy[1]
    phi = np.arctan2(y, x)
    sweep = phi[1:] - phi[:-1]
    sweep -= _TWO_PI * np.rint(sweep / _TWO_PI)
    scale = n_bins / _TWO_PI
    n_edges = len(sweep)
    # Per edge: [bins swept, p x e, ey, ex, first bin] ((N, 5); bins are floor(angle)).
    per_edge = np.empty((n_edges, 5))
    a0 = np.multiply(phi[:-1], scale, out=per_edge[:, 0])
    a1 = sweep * scale
    a1 += a0
    np.floor(a0, out=a0)
    np.floor(a1, out=a1)
    klo = per_edge[:, 4]
    np.minimum(a0, a1, out=klo)
    counts_f = np.maximum(a0, a1, out=a0)
    counts_f -= klo
    klo += 1.0
    counts = counts_f.astype(np.int64)
    total = int(counts_f.sum())
    if total == 0:
        return np.zeros(n_bins)
    d = xy[:, 1:] - xy[:, :-1]  # edge vectors (ex, ey)
    ex, ey = d[0], d[1]
    pe = np.multiply(x[:-1], ey, out=per_edge[:, 1])
    pe -= y[:-1] * ex
    per_edge[:, 2] = ey
    per_edge[:, 3] = ex
    # Start of each edge's hits in the flat hit list, carried by the repeat as an offset:
    # hit h (global index) of edge e is bin klo_e + 1 + (h - start_e).
    start = np.cumsum(counts_f)
    start -= counts_f
    klo -= start
    hits = per_edge.repeat(counts, axis=0)  # (total, 5)
    kf = _arange(total) + hits[:, 4]
    k = kf.astype(np.int64)
    if n_bins & (n_bins - 1) == 0:
        k &= n_bins - 1
    else:
        k %= n_bins
    cos_t, sin_t = _ray_table(n_bins)
    den = cos_t[k] * hits[:, 2]
    den -= sin_t[k] * hits[:, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.divide(hits[:, 1], den)
    np.abs(t, out=t)
    t[~np.isfinite(t)] = 0.0
    # Star-shaped from the centre (every edge sweeps forward, once around): one hit per ray.
    if total == n_bins and abs(sweep.sum() - _TWO_PI) < 1.0 and sweep.min() >= 0:
        r = np.empty(n_bins)
        r[k] = t
        return r
    if ray_hit == "farthest":
        # Hits are >= 0, so starting from 0 equals starting from -inf and zeroing misses.
        r = np.zeros(n_bins)
        np.maximum.at(r, k, t)
        return r
    r = np.full(n_bins, np.inf)
    np.minimum.at(r, k, t)
    r[r == np.inf] = 0.0
    return r


def heading_from_range_functions(r_a: Array, r_b: Array) -> tuple[float, float]:
    """Rotation [rad] taking range function `r_a` onto `r_b`, and its correlation score.

    Both are ``(B,)`` range functions on the same uniform bins (`FFTDescriptor.
    range_function`).  Returns ``(angle, score)``: `angle` in (-pi, pi] such that
    ``r_b(theta) ~ r_a(theta - angle)``, i.e. polygon b ~ R(angle) . polygon a about
    their reference points (for scans: angle = heading of a's sensor minus heading of
    b's sensor when both see the same place); `score` is the Pearson correlation at the
    peak, in [-1, 1] (0 for a constant range function, where heading is undefined).
    """
    a = np.asarray(r_a, dtype=float)
    b = np.asarray(r_b, dtype=float)
    if a.shape != b.shape or a.ndim != 1:
        raise UserError(
            f"r_a and r_b must be equal-length 1-D range functions, got shapes {a.shape} "
            f"and {b.shape}"
        )
    n = len(a)
    a = a - a.mean()
    b = b - b.mean()
    denom = np.sqrt(float(a @ a) * float(b @ b))
    if denom <= 1e-12 * n:
        return 0.0, 0.0
    c = np.fft.irfft(np.conj(np.fft.rfft(a)) * np.fft.rfft(b), n=n) / denom
    k = int(np.argmax(c))
    cm, c0, cp = c[k - 1], c[k], c[(k + 1) % n]
    curv = cm - 2.0 * c0 + cp
    delta = 0.5 * (cm - cp) / curv if curv < 0 else 0.0
    delta = float(np.clip(delta, -0.5, 0.5))
    angle = (k + delta) * _TWO_PI / n
    angle = float((angle + np.pi) % _TWO_PI - np.pi)
    if angle == -np.pi:
        angle = np.pi
    score = float(np.clip(c0 - 0.25 * (cm - cp) * delta, -1.0, 1.0))
    return angle, score


class FFTMatcher(Matcher):
    """Fourier amplitudes of the centroid range function, Euclidean distance (prefilter)."""

    name = "fft"
    rotation_invariant = True

    def __init__(self, config: FFTConfig | None = None, **overrides: Any) -> None:
        cfg = config or FFTConfig()
        known = {f.name for f in fields(FFTConfig)}
        unknown = set(overrides) - known
        if unknown:
            raise UserError(
                f"unknown FFTConfig fields: {', '.join(sorted(unknown))} "
                f"(known: {', '.join(sorted(known))})"
            )
        self.config = replace(cfg, **overrides)

    def describe(self, polygon: Polygon) -> FFTDescriptor:
        """Range function about the centroid and its first K Fourier amplitudes."""
        cfg = self.config
        if cfg.near_radius is None or cfg.scale_invariant:
            amp, r, centre = self._amplitudes(polygon.vertices)
            return FFTDescriptor(amp.astype(np.float32), r, centre)
        amp, r, centre = self._amplitudes(polygon_within(polygon, cfg.near_radius).vertices)
        if cfg.far_weight > 0:
            far, _, _ = self._amplitudes(polygon.vertices)
            amp = np.concatenate([amp, cfg.far_weight * far])
        return FFTDescriptor(amp.astype(np.float32), r, centre)

    def _amplitudes(self, v: Array) -> tuple[Array, Array, Array]:
        """``(K,)`` amplitudes, ``(B,)`` range function and centre of vertices `v` [m]."""
        cfg = self.config
        n = len(v)
        xy = np.empty((2, n + 1))  # closed vertices as rows (x, y)
        xy[:, :n] = v.T
        xy[:, n] = v[0]
        x0, y0, x1, y1 = xy[0, :-1], xy[1, :-1], xy[0, 1:], xy[1, 1:]
        cross = x0 * y1
        cross -= x1 * y0
        centre = np.array([(x0 + x1) @ cross, (y0 + y1) @ cross]) / (3.0 * cross.sum())
        xy -= centre[:, None]
        r = _range_function_rows(xy, cfg.n_bins, cfg.ray_hit)
        spec = np.abs(scipy.fft.rfft(r))
        k = cfg.n_harmonics
        if cfg.scale_invariant:
            amp = spec[1 : k + 1] / max(spec[0], 1e-300)
        else:
            amp = spec[:k] * (1.0 / cfg.n_bins)
        return amp, r, centre

    @property
    def width(self) -> int:
        """Length of the amplitude vector: K, or 2K with a far field appended."""
        cfg = self.config
        far = cfg.near_radius is not None and cfg.far_weight > 0 and not cfg.scale_invariant
        return 2 * cfg.n_harmonics if far else cfg.n_harmonics

    def stack(self, descriptors: Sequence[FFTDescriptor]) -> FFTStack:
        """``(M, K)`` (or ``(M, 2K)``, `width`) float32 matrix of amplitudes and its row norms."""
        return stack_vectors([d.amplitudes for d in descriptors], self.width)

    def distances(self, query: FFTDescriptor, stacked: FFTStack) -> Array:
        """``(M,)`` Euclidean distances of the query amplitudes to every stacked row."""
        return stack_distances(query.amplitudes, stacked)

    def distance(self, a: FFTDescriptor, b: FFTDescriptor) -> float:
        """Euclidean distance of two descriptors (same arithmetic as `distances`)."""
        return float(self.distances(a, self.stack([b]))[0])

    def heading(self, a: FFTDescriptor, b: FFTDescriptor) -> tuple[float, float]:
        """`heading_from_range_functions` of two descriptors: ``(angle, score)``."""
        return heading_from_range_functions(a.range_function, b.range_function)
