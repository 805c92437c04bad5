"""Compiled surface-pair histogram: `pair_histogram.pair_histogram` as one numba loop.

The numpy version builds the ``n (n - 1) / 2`` pair arrays of a keyframe's surface
samples (up to 125,000 pairs at 500 samples) and bins them with `np.bincount`; the
place database describes every keyframe this way, so it is a hot path of the
pipeline.  This kernel walks the same pairs once, without the temporary arrays,
and adds the same weights to the same bins (`pair_histogram`'s docstring has the
equations): ``d = |x_b - x_a|`` [m], ``alpha = arcsin |n . u|`` at both ends, bin
``(floor(d / max_distance * n_distance), floor(alpha / (pi/2) * n_angle))``, weight
``w_a w_b`` [m^2].  The angle bin is found without the arcsine: alpha lies in bin
k when ``sin(k pi / (2 n_angle)) <= |n . u| < sin((k + 1) pi / (2 n_angle))``
(arcsin is increasing on [0, 1]).  Only the order of the floating-point sums
differs from numpy's, so the histograms agree to rounding.

The count of edges at or below ``c = |n . u|`` is read from a table instead of
comparing c with every edge: with T buckets (a power of two, so ``c T`` and
``sin_k T`` are exact), an edge whose bucket ``floor(sin_k T)`` lies two or more
below c's bucket ``floor(c T)`` is below c and one two or more above is above it;
T is chosen so that the three buckets around any bucket hold at most one edge, and
c is compared with that one only.  The count is the same integer, so the histogram
is the same to the bit as counting (`_pair_kernel_counting`, kept for angle bins
too many for a table).

numba is imported with this module, which `pair_histogram` loads on first use;
kernels are cached on disk (``cache=True``).
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


@numba.njit(cache=True, inline="always")
def _pair_bins(dx, dy, d2, nax, nay, nbx, nby, dscale, n_distance, n_angle):
    """A pair's offset ``(dx, dy)`` [m] (``d2`` its square, > 0) and the normals at its
    ends: the first index of its distance bin's row in the flat histogram (``dscale``
    bins per m) and ``|n . u|`` at both ends.  Inlined into both pair kernels."""
    d = math.sqrt(d2)
    inv = 1.0 / d
    ux, uy = dx * inv, dy * inv
    row = min(int(d * dscale), n_distance - 1) * n_angle
    return row, abs(nax * ux + nay * uy), abs(nbx * ux + nby * uy)


@numba.njit(cache=True)
def _pair_kernel(p, nrm, w, max_distance, n_distance, n_angle, base, near, buckets, hist):
    """The pairs' histogram (module docstring) with the angle bins from the table
    `base`, `near` of `angle_table` (`buckets` entries)."""
    n = p.shape[0]
    dscale = n_distance / max_distance
    max_d2 = max_distance * max_distance
    top = buckets - 1
    for a in range(n - 1):
        ax, ay = p[a, 0], p[a, 1]
        nax, nay = nrm[a, 0], nrm[a, 1]
        wa = w[a]
        for b in range(a + 1, n):
            dx = p[b, 0] - ax
            dy = p[b, 1] - ay
            d2 = dx * dx + dy * dy  # squared first: most far pairs skip the root
            if not (d2 > 0.0 and d2 < max_d2):
                continue
            row, ca, cb = _pair_bins(dx, dy, d2, nax, nay, nrm[b, 0], nrm[b, 1], dscale,
                                     n_distance, n_angle)
            ww = wa * w[b]
            ia = max(min(int(ca * buckets), top), 0)
            ib = max(min(int(cb * buckets), top), 0)
            hist[row + base[ia] + (near[ia] <= ca)] += ww
            hist[row + base[ib] + (near[ib] <= cb)] += ww


def angle_table(edges: Array, max_buckets: int = 1 << 12
                ) -> tuple[NDArray[np.int64], Array, int] | None:
    """``(base, near, T)`` of the module docstring for the sorted angle-bin edges
    ``sin_k`` in (0, 1): per bucket i, the number of edges in buckets ``<= i - 2``
    and the one edge in buckets ``i - 1 .. i + 1`` (inf: none); T the smallest power
    of two (from 16) that leaves at most one edge there.  None when even
    `max_buckets` does not separate the edges."""
    buckets = 16
    while buckets <= max_buckets:
        of = np.floor(edges * buckets).astype(np.int64)
        i = np.arange(buckets)
        lo = np.searchsorted(of, i - 1, side="left")
        hi = np.searchsorted(of, i + 1, side="right")
        if np.all(hi - lo <= 1):
            near = np.full(buckets, np.inf)
            one = hi > lo
            near[one] = edges[lo[one]]
            return lo.astype(np.int64), near, buckets
        buckets *= 2
    return None


@numba.njit(cache=True)
def _pair_kernel_counting(p, nrm, w, max_distance, n_distance, n_angle, edges, hist):
    n = p.shape[0]
    dscale = n_distance / max_distance
    max_d2 = max_distance * max_distance
    n_edges = edges.shape[0]
    for a in range(n - 1):
        ax, ay = p[a, 0], p[a, 1]
        nax, nay = nrm[a, 0], nrm[a, 1]
        wa = w[a]
        for b in range(a + 1, n):
            dx = p[b, 0] - ax
            dy = p[b, 1] - ay
            d2 = dx * dx + dy * dy  # squared first: most far pairs skip the root
            if not (d2 > 0.0 and d2 < max_d2):
                continue
            row, ca, cb = _pair_bins(dx, dy, d2, nax, nay, nrm[b, 0], nrm[b, 1], dscale,
                                     n_distance, n_angle)
            ww = wa * w[b]
            # Angle bins: the number of edges sin(alpha_k) <= |n . u|, counted without
            # branches (a data-dependent loop exit mispredicts on every other pair).
            ka = 0
            kb = 0
            for k in range(n_edges):
                ka += edges[k] <= ca
                kb += edges[k] <= cb
            hist[row + ka] += ww
            hist[row + kb] += ww


@numba.njit(cache=True)
def surface_samples_kernel(v, step, max_edge, max_range):
    """`pair_histogram.surface_samples_numpy` of the ``(N, 2)`` vertices `v` [m]:
    ``(points, normals, weights)`` with the same arithmetic per sample (edge ``e =
    v[i + 1] - v[i]`` closing the ring, length by ``hypot``, ``c = max(1, rint(L /
    step))`` samples at ``v + ((k + 1/2) / c) e``, normal ``(e_y, -e_x) / L``, weight
    ``L / c``)."""
    n = v.shape[0]
    keep = np.zeros(n, dtype=np.bool_)
    count = np.zeros(n, dtype=np.int64)
    total = 0
    for i in range(n):
        j = i + 1 if i < n - 1 else 0
        ex = v[j, 0] - v[i, 0]
        ey = v[j, 1] - v[i, 1]
        length = math.hypot(ex, ey)
        if (math.hypot(v[i, 0], v[i, 1]) < max_range and math.hypot(v[j, 0], v[j, 1])
                < max_range and length < max_edge and length > 0):
            keep[i] = True
            count[i] = max(1, np.int64(np.rint(length / step)))
            total += count[i]
    points = np.empty((total, 2))
    normals = np.empty((total, 2))
    weights = np.empty(total)
    row = 0
    for i in range(n):
        if not keep[i]:
            continue
        j = i + 1 if i < n - 1 else 0
        ex = v[j, 0] - v[i, 0]
        ey = v[j, 1] - v[i, 1]
        length = math.hypot(ex, ey)
        c = count[i]
        nx = ey / length
        ny = -ex / length
        w = length / c
        for k in range(c):
            t = (k + 0.5) / c
            points[row, 0] = v[i, 0] + t * ex
            points[row, 1] = v[i, 1] + t * ey
            normals[row, 0] = nx
            normals[row, 1] = ny
            weights[row] = w
            row += 1
    return points, normals, weights


def pair_histogram_compiled(
    points: Array,
    normals: Array,
    weights: Array,
    *,
    max_distance: float,
    n_distance: int,
    n_angle: int,
) -> Array:
    """``(n_distance, n_angle)`` weighted pair histogram [m^2]: the numpy version's
    result (module docstring) from one compiled pass over the pairs."""
    hist = np.zeros(n_distance * n_angle)
    p = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 2)
    if len(p) >= 2:
        nrm = np.ascontiguousarray(normals, dtype=np.float64).reshape(-1, 2)
        w = np.ascontiguousarray(weights, dtype=np.float64).ravel()
        edges = np.sin(np.arange(1, n_angle) * (0.5 * np.pi / n_angle))
        table = _table(int(n_angle))
        if table is None:
            _pair_kernel_counting(p, nrm, w, float(max_distance), int(n_distance),
                                  int(n_angle), edges, hist)
        else:
            base, near, buckets = table
            _pair_kernel(p, nrm, w, float(max_distance), int(n_distance), int(n_angle),
                         base, near, buckets, hist)
    return hist.reshape(n_distance, n_angle)


@functools.lru_cache(maxsize=8)
def _table(n_angle: int) -> tuple[NDArray[np.int64], Array, int] | None:
    """`angle_table` of the edges of `n_angle` bins (made once per bin count)."""
    return angle_table(np.sin(np.arange(1, n_angle) * (0.5 * np.pi / n_angle)))


__all__ = ["pair_histogram_compiled", "surface_samples_kernel"]
