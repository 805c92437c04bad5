"""Compiled FLIRT beta-grids: `flirt_features.beta_grids`' hit and miss counts in one loop.

The numpy version builds ``(F, B)`` arrays of features by beams and a ``(P, k)``
array of chord samples for every polygon, a few dozen numpy calls per keyframe whose
temporaries and per-call overhead dominate at the place database's sizes (about 40
features, 128 beams).  This kernel walks the same features and beams once, with the
same arithmetic in the same order (the equations are in
`loopclosure.matchers.flirt_features`' docstring, step 4):

- hits: beam end ``e_b`` inside feature f's support disc, ``0 < |e_b - p_f|^2 < R_f^2``,
  counted in its bin;
- misses: the chord of the beam ``v + t (e_b - v)``, ``t in [0, 1]``, through the disc
  (``|w_f + t d_b|^2 = R_f^2`` with ``w_f = v - p_f``, ``d_b = e_b - v``), sampled at
  ``t_0 + (t_1 - t_0)(s + 1/2) / k``; each bin the samples enter counts once, except
  the bin the beam ends in;
- bins: ring ``floor(r rings / R)`` (outer ring clipped), sector
  ``floor((atan2(y, x) - o) sectors / (2 pi) + 1/2) mod sectors`` (sector 0 centred on
  the feature's axis ``o``).  With an even number of sectors the sector is found
  without the arctangent (a scalar ``atan2`` is most of the cost per chord sample):
  the offset is turned by ``-(o - pi / sectors)``, so that sector 0 begins at angle
  0; the sign of its y coordinate picks the half turn (``[0, pi)`` or
  ``[pi, 2 pi)``, the latter turned back by pi), and the sector within the half turn
  is the number of borders ``2 pi m / sectors`` (``m = 1 .. sectors / 2 - 1``) whose
  cross product with the offset is ``>= 0``.

Lengths in the polygon's units, angles in radians.  The counts equal the numpy
version's except for a sample that lies on a bin border to within rounding (the
arctangent, and the product ``w_f . d_b`` that numpy sums by BLAS, round
differently from this arithmetic), which may fall on either side; `beta_grids`
turns the counts into the Beta posterior.

numba is imported with this module, which `flirt_features` loads on first use;
kernels are cached on disk (``cache=True``).
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, inline="always")
def _bin(x, y, ring_scale, orient, rings, sectors, rot_c, rot_s, border_c, border_s, zero):
    """Bin ``ring * sectors + sector`` of offset ``(x, y)`` from the feature (module
    docstring).  ``(rot_c, rot_s)`` is the direction ``o - pi / sectors`` where sector 0
    begins and ``(border_c[m], border_s[m])`` the border ``2 pi m / sectors``
    (``m = 1 .. sectors / 2 - 1``) of the half turn, so that the sector comes from the
    signs of cross products instead of an arctangent (an even number of sectors).
    ``zero`` is the sector of a zero offset, whose arctangent ``atan2(0, 0)`` is 0."""
    r = math.sqrt(x * x + y * y)
    ring = min(int(r * ring_scale), rings - 1)  # ring_scale = rings / R
    if sectors % 2 == 1:
        turns = (math.atan2(y, x) - orient) * (sectors / (2.0 * math.pi)) + (2 * sectors + 0.5)
        return ring * sectors + int(turns) % sectors
    u = rot_c * x + rot_s * y  # the offset turned by -(o - pi / sectors)
    v = rot_c * y - rot_s * x
    sector = 0
    if not (v > 0.0 or (v == 0.0 and u > 0.0)):  # the second half turn [pi, 2 pi)
        u, v = -u, -v
        sector = sectors // 2
    for m in range(border_c.shape[0]):
        sector += border_c[m] * v - border_s[m] * u >= 0.0
    if x == 0.0 and y == 0.0:  # a select, not a call: the loop stays tight
        sector = zero
    return ring * sectors + sector


@numba.njit(cache=True)
def beta_grid_counts(points, radius, orientations, ends, view, rings, sectors, chord_samples):
    """Hit and miss counts ``(F, rings * sectors)`` of every feature's beta-grid.

    Args: feature centres ``points`` (F, 2), support radii ``radius`` (F,) and bin-0
    axes ``orientations`` (F,) [rad]; beam end points ``ends`` (B, 2); the viewpoint
    ``view`` (2,) every beam starts from; grid size and chord samples per beam.
    """
    n_feat = points.shape[0]
    n_beams = ends.shape[0]
    nb = rings * sectors
    hits = np.zeros((n_feat, nb), dtype=np.int64)
    misses = np.zeros((n_feat, nb), dtype=np.int64)
    end_bin = np.empty(n_beams, dtype=np.int64)
    dx = np.empty(n_beams)
    dy = np.empty(n_beams)
    aa = np.empty(n_beams)
    fracs = np.empty(chord_samples)  # the chord samples' fractions, divided once
    for s in range(chord_samples):
        fracs[s] = (s + 0.5) / chord_samples
    half = np.arange(1, sectors // 2) * (2.0 * math.pi / sectors)
    border_c, border_s = np.cos(half), np.sin(half)
    for b in range(n_beams):
        dx[b] = ends[b, 0] - view[0]
        dy[b] = ends[b, 1] - view[1]
        a = dx[b] * dx[b] + dy[b] * dy[b]
        aa[b] = a if a > 0 else 1.0
    for f in range(n_feat):
        px, py = points[f, 0], points[f, 1]
        rad, orient = radius[f], orientations[f]
        rot_c = math.cos(orient - math.pi / sectors)
        rot_s = math.sin(orient - math.pi / sectors)
        r2 = rad * rad
        ring_scale = rings / rad
        zero = int((0.0 - orient) * (sectors / (2.0 * math.pi)) + (2 * sectors + 0.5)) % sectors
        for b in range(n_beams):
            ex = ends[b, 0] - px
            ey = ends[b, 1] - py
            d2 = ex * ex + ey * ey
            end_bin[b] = -1
            if d2 < r2 and d2 > 0.0:  # the feature's own sample (d2 = 0) has no direction
                end_bin[b] = _bin(ex, ey, ring_scale, orient, rings, sectors, rot_c, rot_s,
                                  border_c, border_s, zero)
                hits[f, end_bin[b]] += 1
        wx = view[0] - px
        wy = view[1] - py
        c = (wx * wx + wy * wy) - r2
        for b in range(n_beams):
            a = aa[b]
            b2 = wx * dx[b] + wy * dy[b]
            disc = b2 * b2 - a * c
            if not disc > 0.0:
                continue
            root = math.sqrt(disc)
            t0 = max((-b2 - root) / a, 0.0)
            t1 = min((-b2 + root) / a, 1.0)
            if not t1 > t0:
                continue
            prev = -2
            for s in range(chord_samples):
                t = t0 + (t1 - t0) * fracs[s]
                k = _bin(wx + t * dx[b], wy + t * dy[b], ring_scale, orient, rings, sectors,
                         rot_c, rot_s, border_c, border_s, zero)
                if k == end_bin[b]:
                    k = -1  # a beam ending in this bin is a hit there, not a miss
                if k >= 0 and k != prev:
                    misses[f, k] += 1
                prev = k
    return hits, misses


@numba.njit(cache=True)
def beta_posterior(hits, misses, prior_hit, prior_miss):
    """The Beta posterior of every bin of the counts of `beta_grid_counts`, as
    `flirt_features._posterior` makes it: occupancy ``(hits + a0) / (hits + a0 + misses
    + b0)`` and evidence ``hits + a0 + misses + b0`` (float32), ``(F, rings * sectors)``,
    with the same operations in the same order (the same bits)."""
    occupancy = np.empty(hits.shape)
    evidence = np.empty(hits.shape, dtype=np.float32)
    for f in range(hits.shape[0]):
        for j in range(hits.shape[1]):
            alpha = hits[f, j] + prior_hit
            total = alpha + misses[f, j] + prior_miss
            occupancy[f, j] = alpha / total
            evidence[f, j] = np.float32(total)
    return occupancy, evidence


__all__ = ["beta_grid_counts", "beta_posterior"]
