"""Compiled steps 1-2 of `virtual_scan.virtual_scan`: candidates and the front-most one.

The numpy version expands every map point to its candidate beams with `np.repeat`
and finds the front-most candidate of each (beam, side) with one `np.lexsort`; on a
keyframe's local map (thousands of points, a few candidates each) the sort and the
temporaries dominate.  These kernels walk the same candidates in the same order
(point by point, beams counter-clockwise) with the same arithmetic:

- point ``i`` at bearing ``pos_i`` [beam units] and half-width ``half_i`` [beam
  units] is a candidate of the beams ``j = ceil(pos_i - half_i) .. floor(pos_i + half_i)``
  (not yet wrapped), offset ``dphi = (j - pos_i) step`` [rad] (beam bearing minus
  point bearing);
- its along-beam distance ``r_i cos(dphi)`` [m] is computed by the caller with numpy
  (the same cosine as before);
- of the candidates with ``along > 0``, each (beam ``j mod beams``, side
  ``dphi < 0``) keeps the smallest along-beam distance, the first in that order on
  ties (what the stable sort kept).

The results are the numpy version's exactly.  numba is imported with this module,
which `virtual_scan` loads on first use; kernels are cached on disk (``cache=True``).
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True)
def candidates(pos, half, step):
    """Candidate (point, beam) pairs: point ids, unwrapped beam indices and offsets
    ``dphi`` [rad], point by point and beam by beam (module docstring)."""
    n = pos.shape[0]
    lo = np.empty(n, dtype=np.intp)
    total = 0
    for i in range(n):
        lo[i] = math.ceil(pos[i] - half[i])
        total += math.floor(pos[i] + half[i]) - lo[i] + 1
    pid = np.empty(total, dtype=np.intp)
    beam = np.empty(total, dtype=np.intp)
    dphi = np.empty(total)
    at = 0
    for i in range(n):
        for j in range(lo[i], math.floor(pos[i] + half[i]) + 1):
            pid[at] = i
            beam[at] = j
            dphi[at] = (j - pos[i]) * step
            at += 1
    return pid, beam, dphi


@numba.njit(cache=True)
def front_most(pid, beam, dphi, along, beams):
    """Per (beam, side), row ``2 j + side``: the front-most candidate's point id (-1:
    none), along-beam distance [m] (inf: none) and ``|dphi|`` [rad] (module docstring)."""
    best_pt = np.full(2 * beams, -1, dtype=np.intp)
    best_along = np.full(2 * beams, np.inf)
    best_off = np.full(2 * beams, np.inf)
    for c in range(pid.shape[0]):
        if not along[c] > 0.0:
            continue
        key = 2 * (beam[c] % beams) + (1 if dphi[c] < 0.0 else 0)
        if along[c] < best_along[key]:
            best_pt[key] = pid[c]
            best_along[key] = along[c]
            best_off[key] = abs(dphi[c])
    return best_pt, best_along, best_off


__all__ = ["candidates", "front_most"]
