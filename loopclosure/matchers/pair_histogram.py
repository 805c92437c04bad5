"""Surface-pair histogram: a place descriptor invariant to the robot's pose in the place.

Not one of the paper's eight matchers (``papers/shape-matching-place-recognition.txt``);
a prefilter for real laser places, where those eight lose.  The idea is the
point-pair feature of Drost et al. ("Model globally, match locally", CVPR 2010),
summed into one global histogram as the D2 shape distribution of Osada et al.
("Shape distributions", ACM TOG 2002) sums pair distances, and as GLARE (Himstedt et
al., IROS 2014) sums the relations of landmark pairs for laser place recognition.

Why.  The FFT and ring-projection descriptors are functions of the polygon around
one reference point (its area centroid).  On real scans that point moves with what
the sensor happens to see: an open door or a corridor end adds an open-space
vertex at the range cap and drags the centroid by metres, and every range then
changes.  A histogram over *pairs of surface points* has no reference point at all:
the relation of two wall points is the same from wherever in the room they are
seen, so the descriptor is invariant to rotation *and* translation of the sensor,
and an occluded or newly visible stretch of wall changes only its own share of
the pairs.

Equations (plain text)
----------------------
Surfaces.  Polygon edges (p_i, p_{i+1}) whose two vertices are real returns
(``|p| < max_range``: vertices at the range cap are open space, see
`loopclosure.polygon`) and that are shorter than `max_edge` (longer edges join two
surfaces across a depth jump) are surfaces.  Each is sampled at
``c = max(1, round(L / step))`` points at its sub-segment midpoints
``x = p_i + ((t + 1/2) / c)(p_{i+1} - p_i)``, t = 0 .. c-1, each with weight
``w = L / c`` [m] (its arc length) and the edge's unit normal
``n = (e_y, -e_x) / L``, e = p_{i+1} - p_i.

Pair features.  For every unordered pair (a, b) of samples with
``0 < d = |x_b - x_a| < max_distance``, and u = (x_b - x_a) / d:

    alpha_a = arcsin |n_a . u|,   alpha_b = arcsin |n_b . u|        in [0, pi/2]

(alpha = 0: the pair runs along the surface at a, pi/2: straight across it; the
absolute value makes it independent of the normal's sign).  The pair adds
``w_a w_b`` [m^2] to bin ``(floor(d / max_distance * n_distance),
floor(alpha / (pi/2) * n_angle))`` once with alpha_a and once with alpha_b (an
ordered-pair histogram, symmetric in a and b).  With the arc-length weights the
histogram approximates the integral over pairs of surface points, independent of
how densely the beams sample a wall (near walls get many beams, far ones few).

Descriptor and distance.

    h = H / sum(H),   D = sqrt(h)  (flattened, n_distance * n_angle floats, unitless)

compared by the Euclidean distance ||D_i - D_j||_2 (sqrt(2) times the Hellinger
distance of the two histograms, in [0, sqrt(2)]), so the database screens it with
one float32 matrix-vector product (`loopclosure.matchers.vector_search`).  A polygon
with no surface (every beam open) gets the zero vector: at distance 1 from every
real place (not 0: it matches nothing).

Cost.  ``O(n^2)`` pairs of n samples at `describe` (once per keyframe); more than
`max_samples` samples are thinned to every ceil(n / max_samples)-th one (weights
scaled by the stride), so a keyframe costs at most max_samples^2 / 2 pairs.

Parameters (`PairHistogramConfig`)
----------------------------------
- ``step`` = 0.25 m: sample spacing along surfaces.
- ``max_edge`` = 1.0 m: longer polygon edges are depth jumps, not surfaces.
- ``max_range`` = 19.5 m: vertices at or beyond are open space (the pipeline's
  virtual scans read 20 m for no return; the polygon rule caps at 30 m).
- ``max_distance`` = 10.0 m: longest pair (rooms and corridor stretches; longer
  pairs are the ones occlusion and the sensor's field of view change most).
- ``n_distance`` = 40 (0.25 m bins), ``n_angle`` = 8 (11.25 degree bins).
- ``max_samples`` = 500.
- ``compiled`` = True: the histogram comes from the numba kernel of
  `loopclosure.matchers.pair_kernel` (the same bins and weights in one pass, no
  temporary pair arrays); False keeps the numpy version, `pair_histogram`.
- ``scale_invariant`` = False: True (pixel-unit shape sets such as MPEG-7, whose
  contours are closed outlines without open space or depth jumps) ignores the
  lengths above and uses the polygon's extent E (largest vertex distance from the
  vertex mean): step E / 100, max_distance 2 E, every edge a surface.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from loopclosure.matchers.base import Matcher
from loopclosure.matchers.vector_search import VectorStack, stack_distances, stack_vectors
from loopclosure.polygon import Polygon

Array = NDArray[np.float64]


@dataclass(slots=True, frozen=True)
class PairHistogramConfig:
    """Parameters of the surface-pair histogram (see module docstring).

    Attributes:
        step: sample spacing along surfaces [m].
        max_edge: polygon edges longer than this are depth jumps [m].
        max_range: vertices this far from the sensor origin or farther are open space [m].
        max_distance: longest pair counted [m].
        n_distance: distance bins.
        n_angle: angle bins over [0, pi/2].
        max_samples: more samples than this are thinned by a stride.
        scale_invariant: lengths relative to the polygon's extent (MPEG-7).
        compiled: histogram from the numba kernel (False: numpy).
    """

    step: float = 0.25
    max_edge: float = 1.0
    max_range: float = 19.5
    max_distance: float = 10.0
    n_distance: int = 40
    n_angle: int = 8
    max_samples: int = 500
    scale_invariant: bool = False
    compiled: bool = True

    def __post_init__(self) -> None:
        for name in ("step", "max_edge", "max_range", "max_distance"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise UserError(f"pair histogram: {name} must be a positive length, got {v}")
        if self.n_distance < 1 or self.n_angle < 1 or self.max_samples < 2:
            raise UserError("pair histogram: n_distance, n_angle >= 1 and max_samples >= 2")

    @property
    def dim(self) -> int:
        """Length of the descriptor."""
        return self.n_distance * self.n_angle


def surface_samples(
    vertices: Array,
    *,
    step: float,
    max_edge: float,
    max_range: float,
) -> tuple[Array, Array, Array]:
    """Samples of the polygon's surface edges (module docstring), sensor frame [m].

    Compiled (`pair_kernel.surface_samples_kernel`: one loop over the edges, the same
    samples to the bit as `surface_samples_numpy`, without its dozen numpy calls per
    polygon).

    Returns:
        ``(n, 2)`` sample points [m], ``(n, 2)`` unit normals of their edges and ``(n,)``
        weights (arc length per sample [m]).
    """
    # numba loads on first use: importing the matchers stays light.
    from loopclosure.matchers.pair_kernel import surface_samples_kernel

    v = np.ascontiguousarray(np.asarray(vertices, float).reshape(-1, 2))
    return surface_samples_kernel(v, float(step), float(max_edge), float(max_range))


_LAST_SAMPLES: list[tuple | None] = [None]  # (vertices, their bytes, lengths, samples)


def polygon_samples(
    vertices: Array,
    *,
    step: float,
    max_edge: float,
    max_range: float,
) -> tuple[Array, Array, Array]:
    """`surface_samples` of a polygon's ``(N, 2)`` float vertices [m], remembered for the
    last array asked: the place database's pair histogram and polar grid sample the
    same keyframe with the same lengths, one after the other.  The memo answers only
    for the same array object with the same bytes and lengths (it holds the array,
    so its identity cannot pass to another), so the samples are those `surface_samples`
    gives; they are returned read-only (shared between callers)."""
    lengths = (float(step), float(max_edge), float(max_range))
    last = _LAST_SAMPLES[0]
    if (last is not None and last[0] is vertices and last[2] == lengths
            and last[1] == vertices.tobytes()):
        return last[3]
    out = surface_samples(vertices, step=step, max_edge=max_edge, max_range=max_range)
    for a in out:
        a.setflags(write=False)
    _LAST_SAMPLES[0] = (vertices, vertices.tobytes(), lengths, out)
    return out


def surface_samples_numpy(
    vertices: Array,
    *,
    step: float,
    max_edge: float,
    max_range: float,
) -> tuple[Array, Array, Array]:
    """`surface_samples` in numpy (the reference of the compiled kernel)."""
    v = np.asarray(vertices, float).reshape(-1, 2)
    w = np.roll(v, -1, axis=0)
    e = w - v
    length = np.hypot(e[:, 0], e[:, 1])
    real = np.hypot(v[:, 0], v[:, 1]) < max_range
    keep = real & np.roll(real, -1) & (length < max_edge) & (length > 0)
    v, e, length = v[keep], e[keep], length[keep]
    count = np.maximum(1, np.rint(length / step).astype(np.int64))
    edge = np.repeat(np.arange(len(v)), count)
    t = (np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count) + 0.5)
    t = t / count[edge]
    points = v[edge] + t[:, None] * e[edge]
    normals = (np.column_stack([e[:, 1], -e[:, 0]]) / length[:, None])[edge]
    return points, normals, (length / count)[edge]


def pair_histogram(
    points: Array,
    normals: Array,
    weights: Array,
    *,
    max_distance: float,
    n_distance: int,
    n_angle: int,
) -> Array:
    """``(n_distance, n_angle)`` weighted histogram H of the pair features [m^2] (docstring)."""
    p = np.asarray(points, float)
    hist = np.zeros(n_distance * n_angle)
    if len(p) < 2:
        return hist.reshape(n_distance, n_angle)
    a, b = np.triu_indices(len(p), 1)
    diff = p[b] - p[a]
    d = np.hypot(diff[:, 0], diff[:, 1])
    use = (d > 0) & (d < max_distance)
    a, b, diff, d = a[use], b[use], diff[use], d[use]
    u = diff / d[:, None]
    dbin = np.minimum((d * (n_distance / max_distance)).astype(np.int64), n_distance - 1)
    ww = weights[a] * weights[b]
    scale = n_angle / (0.5 * np.pi)
    for end in (a, b):
        cos = np.abs(np.einsum("ij,ij->i", normals[end], u))
        alpha = np.arcsin(np.minimum(cos, 1.0))
        abin = np.minimum((alpha * scale).astype(np.int64), n_angle - 1)
        hist += np.bincount(dbin * n_angle + abin, weights=ww, minlength=hist.size)
    return hist.reshape(n_distance, n_angle)


PairStack = VectorStack
"""Descriptors packed for `PairHistogramMatcher.distances` (`vector_search.VectorStack`)."""


class PairHistogramMatcher(Matcher):
    """Histogram of surface-point pairs (distance, angle to the normals); Euclidean of sqrt."""

    name = "pairs"
    rotation_invariant = True

    def __init__(self, config: PairHistogramConfig | None = None, **overrides: Any) -> None:
        cfg = config or PairHistogramConfig()
        known = {f.name for f in fields(PairHistogramConfig)}
        unknown = set(overrides) - known
        if unknown:
            raise UserError(
                f"unknown PairHistogramConfig fields: {', '.join(sorted(unknown))} "
                f"(known: {', '.join(sorted(known))})"
            )
        self.config = replace(cfg, **overrides)

    def describe(self, polygon: Polygon) -> NDArray[np.float32]:
        """``(n_distance * n_angle,)`` float32 square-rooted normalised histogram."""
        cfg = self.config
        v = np.asarray(polygon.vertices, float)
        step, max_edge, max_range, max_distance = (
            cfg.step, cfg.max_edge, cfg.max_range, cfg.max_distance
        )
        if cfg.scale_invariant:
            c = v.mean(axis=0)
            extent = float(np.hypot(*(v - c).T).max()) or 1.0
            v = (v - c) / extent
            step, max_edge, max_range, max_distance = 0.01, np.inf, np.inf, 2.0
        sample = surface_samples if cfg.scale_invariant else polygon_samples
        pts, nrm, w = sample(v, step=step, max_edge=max_edge, max_range=max_range)
        if len(pts) > cfg.max_samples:
            stride = -(-len(pts) // cfg.max_samples)
            pts, nrm, w = pts[::stride], nrm[::stride], w[::stride] * stride
        if cfg.compiled:
            # numba loads on first use: importing the matchers stays light.
            from loopclosure.matchers.pair_kernel import pair_histogram_compiled as build
        else:
            build = pair_histogram
        hist = build(pts, nrm, w, max_distance=max_distance,
                     n_distance=cfg.n_distance, n_angle=cfg.n_angle).ravel()
        total = hist.sum()
        if not total > 0:
            return np.zeros(cfg.dim, np.float32)
        return np.sqrt(hist / total).astype(np.float32)

    def stack(self, descriptors: Sequence[NDArray[np.float32]]) -> PairStack:
        """``(M, D)`` float32 matrix of descriptors and its row norms."""
        return stack_vectors(descriptors, self.config.dim)

    def distances(self, query: NDArray[np.float32], stacked: PairStack) -> Array:
        """``(M,)`` Euclidean distances of the query to every stacked descriptor."""
        return stack_distances(np.asarray(query, np.float32), stacked)

    def distance(self, a: NDArray[np.float32], b: NDArray[np.float32]) -> float:
        """Distance of two descriptors (same arithmetic as `distances`)."""
        return float(self.distances(a, self.stack([b]))[0])


__all__ = [
    "PairHistogramConfig",
    "PairHistogramMatcher",
    "pair_histogram",
    "polygon_samples",
    "surface_samples",
]
