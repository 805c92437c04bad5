"""Which side of a surface a laser saw: oriented normals of a scan and back-face culling.

A range beam ends on the face of a surface that looks towards the sensor; the other
face of the same wall, a wall's thickness away, is invisible from there.  A local map
merged from keyframes taken on both sides of a wall (a robot that walked along a
corridor, then enters the room behind it) holds both faces, and a scan from one side
can be pulled by ICP onto the face it cannot see: an offset of the wall's thickness
across it, at a fitness as good as the right pose's.

`scan_normals` gives every end point of a scan (sensor frame, sensor at the origin) the
unit normal of its local surface, from its two neighbours in bearing order, oriented
towards the sensor: ``n . (0 - p) > 0``; not where the three points bend (the two steps
``p - p_prev`` and ``p_next - p`` more than `max_bend` apart): a corner or clutter
(vegetation, chair legs) has no face to cull.  `facing`
keeps a map point ``p`` with oriented normal ``n`` (both in the map frame) when a
sensor at ``c`` sees the same face::

    n . (c - p) > 0

(back-face culling, as in rendering).  A point without a normal is kept.  Units:
metres, radians; frames as stated per function.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def scan_normals(points: Array, max_gap: float, max_bend: float = np.pi) -> Array:
    """``(N, 2)`` unit normals of a scan's end points `points` (``(N, 2)``, sensor frame
    [m], sensor at the origin), oriented towards the sensor; NaN rows where no bearing
    neighbour lies within `max_gap` [m], or both do and the two steps to them turn by
    more than `max_bend` [rad].

    The points are ordered by bearing; the tangent at point ``i`` is ``p[i+1] - p[i-1]``
    when both neighbours are within `max_gap` of it, the one-sided difference when one
    is, and the normal its left perpendicular ``(-t_y, t_x) / |t|``, flipped so that
    ``n . (-p) > 0``."""
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    n = len(pts)
    normals = np.full((n, 2), np.nan)
    if n < 2:
        return normals
    order = np.argsort(np.arctan2(pts[:, 1], pts[:, 0]), kind="stable")
    p = pts[order]
    nxt = np.vstack([p[1:], p[-1:]])
    prv = np.vstack([p[:1], p[:-1]])
    has_next = np.r_[np.hypot(*(p[1:] - p[:-1]).T) <= max_gap, False]
    has_prev = np.r_[False, has_next[:-1]]
    back, ahead = p - prv, nxt - p
    cross = back[:, 0] * ahead[:, 1] - back[:, 1] * ahead[:, 0]
    dot = np.einsum("ij,ij->i", back, ahead)
    straight = np.abs(np.arctan2(cross, dot)) <= max_bend
    both = has_next & has_prev
    a = np.where(has_prev[:, None], prv, p)
    b = np.where(has_next[:, None], nxt, p)
    t = b - a
    length = np.hypot(t[:, 0], t[:, 1])
    ok = (has_next | has_prev) & (straight | ~both) & (length > 0)
    normal = np.column_stack([-t[:, 1], t[:, 0]])
    normal[ok] /= length[ok, None]
    flip = np.einsum("ij,ij->i", normal, -p) < 0
    normal[flip] *= -1.0
    normal[~ok] = np.nan
    normals[order] = normal
    return normals


def facing(points: Array, normals: Array, viewpoint: Array) -> NDArray[np.bool_]:
    """``(N,)`` mask of the points (``(N, 2)`` [m]) whose oriented normals (``(N, 2)``,
    same frame; NaN: unknown) face `viewpoint` (``(2,)``, same frame): ``n . (c - p) > 0``,
    or the normal is unknown."""
    to_view = np.asarray(viewpoint, dtype=float)[:2] - points
    dot = np.einsum("ij,ij->i", normals, to_view)
    return np.isnan(dot) | (dot > 0)
