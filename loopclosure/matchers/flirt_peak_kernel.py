"""Compiled FLIRT detector: the responses (`flirt_features._responses`) and the peak
test (`flirt_features._local_maxima`), each as one loop.

Responses: the scale-normalised displacement of step 3 of `flirt_features`' docstring,
``delta = ((c - c_sigma) . n_sigma) / (sigma h)`` with ``n_sigma = (t_y, -t_x) / |t|``
(``|t| = sqrt(t_x^2 + t_y^2)``, 1 where it is 0), from the smoothed curve and its
derivative given as complex ``x + i y`` ``(L, N)`` arrays; the same operations in
the same order as `flirt_features._responses_numpy` (its norm, its two-term
einsum and its divisions), so the same bits, without its dozen temporaries.

Peak test: the detector keeps a response ``a[l, n]`` (scale level l, circular curve position n,
dimensionless) that exceeds every one of its eight neighbours in the 3 x 3 box
(levels ``l - 1 .. l + 1``, positions ``n - 1 .. n + 1`` modulo N; a level outside
``0 .. L - 1`` is ``-inf``) by the relative margin ``strict``:
``a[l, n] > b (1 + strict) + strict tiny`` with b the neighbours' maximum and tiny
the smallest normal double.  The numpy version builds that maximum from eight
rolled copies of the array, a few dozen numpy calls per keyframe on arrays of a few
thousand responses, where the per-call overhead is most of the cost; this kernel
takes the same maximum of the same values (a NaN among them gives NaN, as
`np.maximum`) and applies the same comparison with the same two roundings, so the
mask is identical.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True)
def responses_kernel(curve, smooth, deriv, sigmas, step):
    """``(L, N)`` scale-normalised displacements (module docstring) of the ``(N, 2)``
    curve [length], its complex smoothed copies and derivatives ``(L, N)`` [length,
    length per sample], the scales ``sigmas`` (L,) [samples] and the step [length]."""
    levels, n = smooth.shape
    delta = np.empty((levels, n))
    for lv in range(levels):
        scale = sigmas[lv] * step
        for i in range(n):
            tx = deriv[lv, i].real
            ty = deriv[lv, i].imag
            speed = math.sqrt(tx * tx + ty * ty)
            if not speed > 0:
                speed = 1.0
            nx = ty / speed
            ny = -tx / speed
            disp = (curve[i, 0] - smooth[lv, i].real) * nx + (curve[i, 1] - smooth[lv, i].imag) * ny
            delta[lv, i] = disp / scale
    return delta


@numba.njit(cache=True)
def local_maxima_kernel(a, scale, offset):
    """Boolean ``(L, N)`` mask ``a > b * scale + offset`` of module docstring's b,
    with ``scale = 1 + strict`` and ``offset = strict * tiny``."""
    levels, n = a.shape
    out = np.zeros((levels, n), dtype=np.bool_)
    for lv in range(levels):
        lo = max(lv - 1, 0)
        hi = min(lv + 1, levels - 1)
        for i in range(n):
            left = i - 1 if i > 0 else n - 1
            right = i + 1 if i < n - 1 else 0
            best = -np.inf
            for row in range(lo, hi + 1):  # levels outside the array are -inf
                for ds in range(3):  # positions n - 1, n, n + 1 (circular)
                    if row == lv and ds == 1:
                        continue
                    v = a[row, left if ds == 0 else (i if ds == 1 else right)]
                    if v != v or best != best:
                        best = np.nan
                    elif v > best:
                        best = v
            out[lv, i] = a[lv, i] > best * scale + offset
    return out


@numba.njit(cache=True)
def peak_candidates_kernel(delta, min_response, scale, offset):
    """The detector's interest-point candidates of the ``(L, N)`` responses `delta`:
    the cells whose ``|delta|`` passes the peak test of `local_maxima_kernel` on the
    array ``|delta|`` and is at least `min_response`, in row-major order (that of
    ``np.nonzero``): their levels, positions and ``|delta|``."""
    mag = np.abs(delta)
    peak = local_maxima_kernel(mag, scale, offset)
    levels, n = mag.shape
    count = 0
    for lv in range(levels):
        for i in range(n):
            if peak[lv, i] and mag[lv, i] >= min_response:
                count += 1
    level = np.empty(count, dtype=np.intp)
    idx = np.empty(count, dtype=np.intp)
    value = np.empty(count)
    k = 0
    for lv in range(levels):
        for i in range(n):
            if peak[lv, i] and mag[lv, i] >= min_response:
                level[k] = lv
                idx[k] = i
                value[k] = mag[lv, i]
                k += 1
    return level, idx, value


__all__ = ["local_maxima_kernel", "peak_candidates_kernel", "responses_kernel"]
