"""MRM: multi-scale convexity/concavity representation with dynamic-programming matching.

Paper: Kosnar, Vonasek, Kulich, Preucil, "Comparison of shape matching techniques for
place recognition" (``papers/shape-matching-place-recognition.txt``), Section II.A.7
("Multi-scale Shape Representation (MRM)"), which cites the original method: T. Adamek
and N. E. O'Connor, "A multiscale representation method for nonrigid shapes with a
single closed contour", IEEE Trans. Circuits Syst. Video Technol. 14(5):742-753, 2004
(the "MCC" representation).

Descriptor (``describe``), for a polygon P:

1. Resample the boundary to ``N = n_points`` points ``z_0(u)``, ``u = 0..N-1``
   (counter-clockwise, complex ``x + iy``), by ``sampling``:

   - ``"vertex"``: equally spaced in vertex index, the paper's "polygon P with n
     points": ``z_0(u) = (1 - w) v_k + w v_{k+1}`` with ``t = u V / N``,
     ``k = floor(t)``, ``w = t - k`` (V vertices, indices mod V).  A scan polygon
     has one vertex per beam, so this samples the place at equal bearing steps
     from the sensor and every direction weighs the same.
   - ``"arc"``: equally spaced by arc length along the boundary (Adamek &
     O'Connor's parametrisation of silhouettes).
   - ``"auto"`` (default): ``"arc"`` when ``scale_invariant`` (shape sets such as
     MPEG-7, whose simplified contours have few, unevenly spaced vertices),
     ``"vertex"`` otherwise (places).

   Why not arc length on places: a real place's boundary is mostly its least
   repeatable part -- the arcs of open space at the range cap and the depth
   jumps along the beams between a near and a far wall -- so equal arc-length
   samples land mostly there, and the nearby walls that identify the place get
   few of the N samples.
2. Smooth at ``K = n_scales`` levels ``sigma_k = k * sigma_step`` (k = 1..K, in
   units of the sample spacing; level 0 is the unsmoothed contour):
   ``z_k(u) = sum_v z_0(v) g_k(u - v)`` (circular convolution with a Gaussian of
   standard deviation sigma_k).  All levels at once by FFT: the transfer function
   of level k at frequency f (cycles per sample) is ``exp(-2 pi^2 sigma_k^2 f^2)``.
3. Convexity/concavity at level k: the displacement of each point between two
   consecutive levels, ``d(u, k) = s(u, k) * |z_k(u) - z_{k-1}(u)|``, with sign
   ``s = +1`` where the point moves towards the interior (the contour is locally
   convex, smoothing pulls it in) and ``-1`` where it moves outwards (concave):
   ``s = sign(<z_k(u) - z_{k-1}(u), n_in(u)>)``, ``n_in`` the inward normal of level
   k-1 (the tangent turned by +90 degrees for a counter-clockwise contour).
4. Descriptor: the ``(N, K)`` matrix d [m], plus the curve complexity
   ``C = (1/K) sum_k (max_u d(u, k) - min_u d(u, k))`` [m] (Adamek & O'Connor's
   normalisation term).  With ``scale_invariant`` the samples are first centred
   and divided by sqrt(area), and d, C are in those units.

Invariance: d uses only displacement lengths and their side of the contour, so
the descriptor is exactly invariant to rotation and translation, with no
reference point; the start sample is handled by the matching.

Matching (``distance``):

- Point cost ``c(u_a, u_b) = (1/K) sum_k |d_a(u_a, k) - d_b(u_b, k)|``.
- For a start offset ``s`` of contour b, the optimal monotone correspondence is
  the cheapest path through the cost table ``c(i, (j + s) mod N)`` from (0, 0) to
  (N-1, N-1) with steps (i-1, j), (i, j-1), (i-1, j-1) (classic DTW):
  ``D(i, j) = c(i, j) + min(D(i-1, j), D(i, j-1), D(i-1, j-1))``.
- ``cost = min_s D_s(N-1, N-1)``; the distance is
  ``2 cost / (N (C_a + C_b))`` (``normalisation="complexity"``, default: the
  paper's and the original's normalisation by the complexity of the compared
  curves; dimensionless), or ``cost / N`` (``normalisation="points"``: the mean
  per-point difference of convexity, in the contour's unit).  The complexity
  normalisation alone does not make the distance scale invariant: a copy of a
  room scaled by s has ``d_b = s d_a`` and ``C_b = s C_a``, so its distance is
  about ``2 |s - 1| / (s + 1)`` times a shape-dependent constant, not 0; it only
  makes the distance independent of the unit (both shapes scaled alike).  With
  ``scale_invariant`` the contour is also divided by sqrt(area), which makes it
  scale invariant.

Vectorisation: the DP runs row by row (N Python iterations) on arrays of shape
(database entries, start offsets, band width).  The horizontal step makes a row depend on
itself; it is solved exactly with a min-plus prefix scan,
``D(i, j) = P(i, j) + min_{k <= j} (D'(i, k) - P(i, k))`` where ``P`` is the
prefix sum of the row's costs and ``D'(i, k) = c(i, k) + min(D(i-1, k), D(i-1, k-1))``
(``np.minimum.accumulate``).

Start points: ``n_starts = None`` tries all N offsets (exact); an integer tries
only the offsets with the smallest un-warped (diagonal) cost
``sum_i c(i, (i + s) mod N)`` -- a coarse search that the DP then refines.
Adamek & O'Connor likewise restrict the start-point search to a few promising
candidates.  The restricted search can only find a cost >= the exact one (all N
offsets, no band).

Band: with ``band`` set, the path may leave the diagonal of the shifted table by
at most ``w = ceil(band * N)`` samples (a Sakoe-Chiba band): a correspondence
that slides more than w samples is not a deformation of the same shape but a
different start point, which the start search covers.

Parameters (`MRMConfig`):
    n_points: N, boundary samples (default 100, as in the original).
    n_scales: K, smoothing levels (default 10).
    sigma_step: sigma of level 1 and increment per level [samples] (default 1.0).
    n_starts: best un-warped start offsets refined by the DP (default 20 of
        N = 100; None = all N).
    band: half-width of the DP band as a fraction of N (default 0.2; None = the
        whole table).
    mirror: also match the mirrored contour of the query and keep the smaller
        cost (default False: a mirrored room is a different place).
    sampling: ``"vertex"``, ``"arc"`` or ``"auto"`` (default; see step 1).
    normalisation: ``"complexity"`` (default) or ``"points"`` (see Matching).
    scale_invariant: centre the contour and divide it by sqrt(area) (default
        False).
    chunk: database entries processed at once in `distances` (bounds memory;
        default 16).

Departures from the paper, and why:
- The smoothing is done by FFT (exact circular Gaussian convolution of the
  trigonometric interpolant of the samples) instead of a truncated spatial kernel:
  same result up to the kernel truncation, all levels in one pass.
- Places must not be scale invariant (rooms differ in scale): without
  ``scale_invariant`` the contour keeps its size in metres, and only the
  complexity normalisation of the paper is applied (see Matching).
- Places are sampled per vertex (per beam), not by arc length (step 1).
- Mirror matching is optional (off by default).
- Complexity is floored at 1e-9 times the perimeter so a circle (zero complexity)
  never gives a division by zero.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from loopclosure.matchers.base import Matcher
from loopclosure.polygon import Polygon

Array = NDArray[np.float64]


@dataclass(slots=True)
class MRMConfig:
    """Parameters of the MRM matcher (see module docstring for units and meaning)."""

    n_points: int = 100
    n_scales: int = 10
    sigma_step: float = 1.0
    n_starts: int | None = 20
    band: float | None = 0.2
    mirror: bool = False
    scale_invariant: bool = False
    sampling: str = "auto"
    normalisation: str = "complexity"
    chunk: int = 16

    def __post_init__(self) -> None:
        if self.n_points < 8:
            raise UserError(f"n_points must be >= 8, got {self.n_points}")
        if self.n_scales < 1:
            raise UserError(f"n_scales must be >= 1, got {self.n_scales}")
        if not self.sigma_step > 0:
            raise UserError(f"sigma_step must be > 0, got {self.sigma_step}")
        if self.n_starts is not None and self.n_starts < 1:
            raise UserError(f"n_starts must be >= 1 or None, got {self.n_starts}")
        if self.band is not None and not 0 < self.band <= 1:
            raise UserError(f"band must be in (0, 1] or None, got {self.band}")
        if self.sampling not in ("auto", "vertex", "arc"):
            raise UserError(f"sampling must be 'auto', 'vertex' or 'arc', got {self.sampling!r}")
        if self.normalisation not in ("complexity", "points"):
            raise UserError(
                f"normalisation must be 'complexity' or 'points', got {self.normalisation!r}"
            )
        if self.chunk < 1:
            raise UserError(f"chunk must be >= 1, got {self.chunk}")


@dataclass(slots=True)
class MRMDescriptor:
    """MCC representation of one contour.

    Attributes:
        mcc: ``(N, K)`` signed displacement [m] of each sample between levels k-1 and k
            (positive = convex).
        mirrored: ``(N, K)`` the same for the mirrored contour (only when
            ``config.mirror``; else None).
        complexity: Adamek & O'Connor's curve complexity [m] (floored, > 0).
    """

    mcc: Array
    mirrored: Array | None
    complexity: float


@dataclass(slots=True)
class MRMStack:
    """Many descriptors packed for `MRMMatcher.distances`.

    Attributes:
        mcc: ``(M, N, K)`` representations.
        complexity: ``(M,)`` complexities [m].
    """

    mcc: Array
    complexity: Array


def resample_by_vertex(vertices: Array, n: int) -> Array:
    """``(n, 2)`` points equally spaced in vertex index along the closed polygon.

    Point u lies at index ``t = u V / n`` of the ``(V, 2)`` `vertices`: linearly
    between vertex ``floor(t)`` and the next one (the last joins the first).
    Units as `vertices`.
    """
    v = np.asarray(vertices, dtype=float)
    t = np.arange(n) * (len(v) / n)
    k = np.floor(t).astype(np.intp)
    w = (t - k)[:, None]
    return v[k % len(v)] * (1.0 - w) + v[(k + 1) % len(v)] * w


def _mcc(z: NDArray[np.complex128], cfg: MRMConfig) -> tuple[Array, float]:
    """``(N, K)`` convexity/concavity of contour samples ``z`` (complex, CCW) and complexity."""
    n = len(z)
    f = np.fft.fftfreq(n)  # cycles per sample
    sig = cfg.sigma_step * np.arange(0, cfg.n_scales + 1)  # level 0 = unsmoothed
    gain = np.exp(-2.0 * np.pi**2 * sig[:, None] ** 2 * f[None, :] ** 2)  # (K+1, N)
    spec = np.fft.fft(z)[None, :] * gain
    levels = np.fft.ifft(spec, axis=1)  # (K+1, N)
    # Tangent dz/du of every level by spectral differentiation (exact for the interpolant).
    tangent = np.fft.ifft(spec * (2j * np.pi * f)[None, :], axis=1)
    disp = levels[1:] - levels[:-1]  # (K, N)
    inward = 1j * tangent[:-1]  # left normal of a CCW contour points inside
    sign = np.sign((disp * np.conj(inward)).real)
    d = (sign * np.abs(disp)).T  # (N, K)
    perimeter = float(np.abs(np.diff(np.append(z, z[:1]))).sum())
    complexity = float(np.mean(d.max(axis=0) - d.min(axis=0)))
    return d, max(complexity, 1e-9 * perimeter, 1e-300)


def _cost_tables(q: Array, db: Array) -> Array:
    """``(M, N, N)`` point costs ``(1/K) sum_k |q(i, k) - db_m(j, k)|``."""
    return np.abs(q[None, :, None, :] - db[:, None, :, :]).mean(axis=3)


def _start_offsets(cost: Array, n_starts: int | None) -> NDArray[np.intp]:
    """``(M, S)`` start offsets of contour b to try: all, or the best un-warped ones."""
    m, n, _ = cost.shape
    i = np.arange(n)
    if n_starts is None or n_starts >= n:
        return np.broadcast_to(i, (m, n))
    diag_idx = (i[:, None] + i[None, :]) % n  # [i, s] -> column of the offset-s diagonal
    diag = cost[:, i[:, None], diag_idx].sum(axis=1)  # (M, N): sum_i cost[i, (i + s) % n]
    return np.argpartition(diag, n_starts - 1, axis=1)[:, :n_starts]


def _dtw_cyclic(cost: Array, n_starts: int | None, band: int | None) -> Array:
    """``(M,)`` minimum over start offsets of the DTW path cost of each ``(N, N)`` table.

    The path of start offset s runs through ``cost[i, (j + s) % N]`` from (0, 0) to
    (N-1, N-1); with `band` w only cells with ``|i - j| <= w`` are allowed
    (Sakoe-Chiba band).  Rows are stored in band coordinates ``k = j - i + w``.
    """
    m, n, _ = cost.shape
    w = n - 1 if band is None else min(int(band), n - 1)
    width = 2 * w + 1
    starts = _start_offsets(cost, n_starts)  # (M, S)
    i = np.arange(n)
    j = i[:, None] - w + np.arange(width)[None, :]  # (N, W) column of band cell (i, k)
    valid = (j >= 0) & (j < n)
    # Band row r of start s covers columns (r - w + s + k) mod N, k = 0..W-1: one contiguous
    # window of the row repeated, gathered as whole windows.
    copies = 1 + -(-width // n)
    repeated = np.concatenate([cost] * copies, axis=2)  # (M, N, copies * N)
    windows = np.lib.stride_tricks.sliding_window_view(repeated, width, axis=2)
    first = (i[None, None, :] - w + starts[:, :, None]) % n  # (M, S, N)
    table = windows[np.arange(m)[:, None, None], i[None, None, :], first]  # (M, S, N, W)
    table = np.where(valid, table, 0.0)  # (M, S, N, W)
    # Invalid cells (outside the table) carry a huge penalty instead of a branch.
    big = 1e200
    csum = np.cumsum(table, axis=3)
    penalty = np.where(valid, 0.0, big)  # (N, W)
    entry = table - csum + penalty
    d_prev = np.full((*table.shape[:2], width + 1), big)
    d_prev[..., :width] = csum[:, :, 0] + penalty[0]  # row 0: path from (0, 0) rightwards
    up_diag = np.empty((*table.shape[:2], width))
    for r in range(1, n):
        # Entering cell k of row r from (r-1, j) at k+1 (vertical) or (r-1, j-1) at k,
        # then any number of horizontal steps: D(r, k) = P(k) + min_{l<=k}(D'(r, l) - P(l)).
        np.minimum(d_prev[..., 1:], d_prev[..., :-1], out=up_diag)
        up_diag += entry[:, :, r]
        np.minimum.accumulate(up_diag, axis=2, out=up_diag)
        np.add(up_diag, csum[:, :, r], out=d_prev[..., :width])
    return d_prev[..., w].min(axis=1)


class MRMMatcher(Matcher):
    """Adamek & O'Connor's multi-scale convexity/concavity matcher (see module docstring)."""

    name = "mrm"
    rotation_invariant = True

    def __init__(self, config: MRMConfig | None = None, **overrides: object) -> None:
        cfg = config or MRMConfig()
        if overrides:
            known = {f.name for f in fields(MRMConfig)}
            unknown = set(overrides) - known
            if unknown:
                raise UserError(
                    f"unknown MRM option(s): {', '.join(sorted(unknown))} "
                    f"(known: {', '.join(sorted(known))})"
                )
            cfg = replace(cfg, **overrides)  # type: ignore[arg-type]
        self.config = cfg

    def describe(self, polygon: Polygon) -> MRMDescriptor:
        """MCC representation of `polygon` (rotation, translation and start invariant)."""
        cfg = self.config
        arc = cfg.sampling == "arc" or (cfg.sampling == "auto" and cfg.scale_invariant)
        if arc:
            pts = polygon.resample(cfg.n_points)
        else:
            pts = resample_by_vertex(polygon.vertices, cfg.n_points)
        z = pts[:, 0] + 1j * pts[:, 1]
        if self.config.scale_invariant:
            z = (z - z.mean()) / np.sqrt(polygon.area)
        d, complexity = _mcc(z, self.config)
        mirrored = None
        if self.config.mirror:
            # Reflect about the x axis and reverse the order to stay counter-clockwise.
            mirrored, _ = _mcc(np.conj(z)[::-1], self.config)
        return MRMDescriptor(d, mirrored, complexity)

    def stack(self, descriptors: Sequence[MRMDescriptor]) -> MRMStack:
        """Pack descriptors into ``(M, N, K)`` and ``(M,)`` arrays."""
        if not descriptors:
            k = self.config.n_scales
            return MRMStack(np.zeros((0, self.config.n_points, k)), np.zeros(0))
        return MRMStack(
            np.stack([d.mcc for d in descriptors]),
            np.array([d.complexity for d in descriptors], dtype=float),
        )

    def distance(self, a: MRMDescriptor, b: MRMDescriptor) -> float:
        """Normalised optimal DP path cost between two descriptors (>= 0, finite)."""
        return float(self.distances(a, self.stack([b]))[0])

    def distances(self, query: MRMDescriptor, stacked: MRMStack) -> Array:
        """``(M,)`` distances of `query` to every stacked descriptor (vectorised over M)."""
        cfg = self.config
        m = len(stacked.complexity)
        out = np.empty(m)
        queries = [query.mcc] if query.mirrored is None else [query.mcc, query.mirrored]
        band = None if cfg.band is None else int(np.ceil(cfg.band * cfg.n_points))
        for lo in range(0, m, cfg.chunk):  # chunks bound memory; each chunk is vectorised
            db = stacked.mcc[lo : lo + cfg.chunk]
            cost = np.min(
                [_dtw_cyclic(_cost_tables(q, db), cfg.n_starts, band) for q in queries], axis=0
            )
            out[lo : lo + cfg.chunk] = cost
        n = cfg.n_points
        if cfg.normalisation == "complexity":
            out = 2.0 * out / (n * (query.complexity + stacked.complexity))
        else:
            out = out / n
        # Costs are sums of finite terms; the guard keeps a ranking usable whatever happens.
        return np.maximum(np.where(np.isfinite(out), out, np.finfo(float).max), 0.0)
