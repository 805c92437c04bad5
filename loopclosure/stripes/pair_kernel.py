"""Compiled gathering of the point pairs of many stripes (`profile.stripe_shape`).

`profile._distance_and_elevation` needs, for every stripe of a batch ``(K, S, 2)``
(float32) and every pair ``i > m`` of its points (in the order of
``numpy.tril_indices(S, k=-1)``: ``i`` ascending, then ``m``), the absolute coordinate
differences ``|x_i - x_m|`` and ``|y_i - y_m|``.  numpy's fancy indexing of the
``(K, S(S-1)/2)`` pair arrays spends most of its time gathering; here one compiled
loop writes them.  A float32 subtraction and its absolute value are exact IEEE
operations, so the arrays are the same to the bit.

numba is imported with this module, which `profile` loads on first use; the kernel is
cached on disk (``cache=True``).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def pair_gaps(points):
    """``(dx, dy)``, each ``(K, S(S-1)/2)`` float32: ``|p_i - p_m|`` per coordinate of
    every pair ``i > m`` of each stripe's points `points` ``(K, S, 2)`` float32."""
    k, s = points.shape[0], points.shape[1]
    n_pairs = s * (s - 1) // 2
    dx = np.empty((k, n_pairs), np.float32)
    dy = np.empty((k, n_pairs), np.float32)
    for n in range(k):
        q = 0
        for i in range(1, s):
            xi = points[n, i, 0]
            yi = points[n, i, 1]
            for m in range(i):
                dx[n, q] = abs(xi - points[n, m, 0])
                dy[n, q] = abs(yi - points[n, m, 1])
                q += 1
    return dx, dy
