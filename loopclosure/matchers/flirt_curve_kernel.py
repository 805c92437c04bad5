"""Compiled FLIRT curve steps: the arc-length resampling with the perimeter, and the
beta-grids' viewpoint test, each as one loop instead of a dozen numpy calls.

Resampling (step 1 of `flirt_features`' docstring): `Polygon.resample` and
`Polygon.perimeter` of the same polygon in one pass.  Edge i runs from vertex i to
vertex i + 1 (the last one closing the ring), its length is
``sqrt(dx^2 + dy^2)`` [length] (the arithmetic of both numpy versions), the
cumulative lengths ``cum`` are summed in order (`np.cumsum`), and sample k of n lies
at arc length ``s_k = k (cum[N] / n)`` from vertex 0, interpolated linearly as
`np.interp` does (``y_j`` where ``s_k`` equals ``cum[j]``, else ``slope (s_k -
cum[j]) + y_j`` with ``slope = (y_{j+1} - y_j) / (cum[j+1] - cum[j])`` on the edge
with ``cum[j] <= s_k < cum[j+1]``).  The caller sums the returned edge lengths with
`np.sum` (numpy's pairwise summation, what `Polygon.perimeter` does), so both
results are those of the numpy versions to the bit.

Viewpoint (`flirt_features._viewpoint`, mode "auto"): whether the beams start from
the sensor origin, i.e. whether the origin is one of the vertices (every coordinate
of some vertex at most ``1e-9`` times the largest absolute coordinate: a scan of
less than 360 degrees) or lies inside the polygon by the even-odd rule of
`Polygon.contains` (edge ``a -> b`` crosses the ray ``y = 0, x > 0`` when
``(a_y > 0) != (b_y > 0)`` and ``0 < a_x + (0 - a_y)(b_x - a_x) / (b_y - a_y)``),
with that method's operations in its order, so the same answer.

numba is imported with this module, which `flirt_features` loads on first use;
kernels are cached on disk (``cache=True``).
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True)
def resample_kernel(v, n):
    """``(n, 2)`` samples equally spaced by arc length along the closed polygon of the
    ``(N, 2)`` vertices `v` from vertex 0, and the ``(N,)`` edge lengths (module
    docstring) [length]."""
    m = v.shape[0]
    lengths = np.empty(m)
    cum = np.empty(m + 1)
    cum[0] = 0.0
    total = 0.0
    for i in range(m):
        j = i + 1 if i < m - 1 else 0
        dx = v[j, 0] - v[i, 0]
        dy = v[j, 1] - v[i, 1]
        lengths[i] = math.sqrt(dx * dx + dy * dy)
        total += lengths[i]
        cum[i + 1] = total
    scale = cum[m] / n
    out = np.empty((n, 2))
    j = 0
    for k in range(n):
        s = k * scale
        while j < m - 1 and cum[j + 1] <= s:
            j += 1
        nxt = j + 1 if j < m - 1 else 0
        if s == cum[j]:
            out[k, 0] = v[j, 0]
            out[k, 1] = v[j, 1]
        else:
            width = cum[j + 1] - cum[j]
            out[k, 0] = (v[nxt, 0] - v[j, 0]) / width * (s - cum[j]) + v[j, 0]
            out[k, 1] = (v[nxt, 1] - v[j, 1]) / width * (s - cum[j]) + v[j, 1]
    return out, lengths


@numba.njit(cache=True)
def origin_view_kernel(v):
    """True when the beams start at the sensor origin: it is a vertex of the ``(N, 2)``
    vertices `v` or lies inside their polygon (module docstring)."""
    m = v.shape[0]
    size = 0.0
    for i in range(m):
        size = max(size, abs(v[i, 0]), abs(v[i, 1]))
    nearest = np.inf
    for i in range(m):
        nearest = min(nearest, max(abs(v[i, 0]), abs(v[i, 1])))
    if nearest <= 1e-9 * size:
        return True
    inside = False
    for i in range(m):
        j = i + 1 if i < m - 1 else 0
        ax, ay, bx, by = v[i, 0], v[i, 1], v[j, 0], v[j, 1]
        if (ay > 0.0) != (by > 0.0) and 0.0 < ax + (0.0 - ay) * (bx - ax) / (by - ay):
            inside = not inside
    return inside


__all__ = ["origin_view_kernel", "resample_kernel"]
