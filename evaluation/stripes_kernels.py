"""Compiled loops of the stripes benchmark's fast paths (`stripes_objects`).

numba is imported with this module, which `stripes_objects` loads on first use; the
kernels are cached on disk (``cache=True``).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def fill_range_image(out, rows, points):
    """``out[rows[k], rint(points[k, 0])] = points[k, 1]`` for every k in order (the last
    point on a pixel stays), as `StripeScan.range_image`; False, with `out` untouched,
    when a column falls outside ``out`` (the caller then takes numpy's indexing rule)."""
    width = out.shape[1]
    cols = np.empty(len(rows), np.int64)
    for k in range(len(rows)):
        c = np.rint(points[k, 0])
        if not (0.0 <= c < width) or not (0 <= rows[k] < out.shape[0]):
            return False
        cols[k] = int(c)
    for k in range(len(rows)):
        out[rows[k], cols[k]] = points[k, 1]
    return True
