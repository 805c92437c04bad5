"""Nearest neighbours in the cells of a `loopclosure.grid_target.GridTarget`, compiled
(numba, ``cache=True``): the search of the compiled ICP (`loopclosure.icp_kernel`)
and of the overlap screens (`loopclosure.grid_overlap`).

The map points are bucketed in square cells of side ``cell`` [m] (a CSR layout:
points sorted by cell, one start offset ``start`` per cell, cell ``(i, j)`` at flat
index ``i * ny + j``, cell ``(0, 0)``'s lower-left corner at ``(ox, oy)``).  A query
at ``p`` with gate ``d`` visits the cells within ``ceil(d / cell)`` rings of ``p``'s
cell and keeps the nearest point with ``|p - q| <= d`` (inclusive, as
`cKDTree.query` with ``distance_upper_bound``), exact for any gate; among
equidistant points the lowest index wins (ties may resolve differently from the
KD-tree).  `_match` finds the correspondences of a whole source point set at one
pose, reusing the previous iteration's neighbours where a distance bound proves
them unchanged.  Positions in metres, angles in radians.
"""

from __future__ import annotations

import numba
import numpy as np

from loopclosure.grid_target import resolve_point
from loopclosure.kernel_cache import drop_stale


@numba.njit(cache=True)
def _wrap(a):
    """Angle `a` [rad] wrapped to ``[-pi, pi)``."""
    return (a + np.pi) % (2.0 * np.pi) - np.pi


@numba.njit(cache=True)
def _scan_cell(c, px, py, start, pts, best, best_d2):
    for k in range(start[c], start[c + 1]):
        dx = pts[k, 0] - px
        dy = pts[k, 1] - py
        d2 = dx * dx + dy * dy
        if d2 < best_d2 or (d2 == best_d2 and (best < 0 or k < best)):
            best, best_d2 = k, d2
    return best, best_d2


#: Slack [m] taken off a cell's gap to a query before the gap may skip the cell
#: (`_nearest`): far above the rounding of a cell border or a point's offset (a
#: point's cell is found by flooring its offset over the cell side), far below any
#: distance that decides a match.
_BOX_SLACK = 1e-9


@numba.njit(cache=True)
def _cell_gap(i, ci, f, cell):
    """Gap [m] along one axis between a query in cell ``ci`` (offset `f` from that
    cell's lower border) and cell ``i``, less `_BOX_SLACK`, never negative (0 for the
    query's own cell)."""
    if i < ci:
        return max(f + (ci - i - 1) * cell - _BOX_SLACK, 0.0)
    if i > ci:
        return max((i - ci) * cell - f - _BOX_SLACK, 0.0)
    return 0.0


@numba.njit(cache=True)
def _nearest(px, py, gate, ox, oy, cell, nx, ny, start, pts):
    """Index of the nearest grid point within `gate` of ``(px, py)`` (-1: none) and its
    distance.  Cells are visited ring by ring (Chebyshev distance from the query's cell);
    after ring ``r`` nothing nearer than ``r * cell + m`` can remain (``m``: distance of
    the query to its own cell's border), so the search stops there once a point at most
    that far is found.  A cell whose box lies farther from the query than the best
    point so far (its gaps ``g_x, g_y`` to the query less `_BOX_SLACK` each, ``g_x^2
    + g_y^2 > d_best^2``) is not scanned: none of its points could replace the best,
    not even by a tie, so the answer is the full scan's."""
    ci = int(np.floor((px - ox) / cell))
    cj = int(np.floor((py - oy) / cell))
    fx = px - ox - ci * cell
    fy = py - oy - cj * cell
    margin = max(min(fx, cell - fx, fy, cell - fy), 0.0)
    rings = int(np.ceil(gate / cell))
    best, best_d2 = -1, gate * gate
    for r in range(rings + 1):
        for i in range(ci - r, ci + r + 1):
            if i < 0 or i >= nx:
                continue
            gx = _cell_gap(i, ci, fx, cell)
            gx2 = gx * gx
            if gx2 > best_d2:
                continue
            edge = i == ci - r or i == ci + r
            step = 1 if edge else 2 * r
            j = cj - r
            while j <= cj + r:
                if 0 <= j < ny:
                    gy = _cell_gap(j, cj, fy, cell)
                    if gx2 + gy * gy <= best_d2:
                        best, best_d2 = _scan_cell(i * ny + j, px, py, start, pts, best,
                                                   best_d2)
                if step == 0:
                    break
                j += step
        if best >= 0 and best_d2 <= (r * cell + margin) ** 2:
            break
    return best, np.sqrt(best_d2)


@numba.njit(cache=True)
def _scan_cell_bound(c, px, py, start, pts, best, best_d2, other_d2):
    """`_scan_cell`, also keeping the smallest squared distance `other_d2` of the
    points it met that are not the best (a replaced best included)."""
    for k in range(start[c], start[c + 1]):
        dx = pts[k, 0] - px
        dy = pts[k, 1] - py
        d2 = dx * dx + dy * dy
        if d2 < best_d2 or (d2 == best_d2 and (best < 0 or k < best)):
            if best >= 0 and best_d2 < other_d2:
                other_d2 = best_d2
            best, best_d2 = k, d2
        elif d2 < other_d2:
            other_d2 = d2
    return best, best_d2, other_d2


@numba.njit(cache=True)
def _nearest_bound(px, py, gate, ox, oy, cell, nx, ny, start, pts):
    """`_nearest` (the same cells visited, the same answer) and a lower bound [m] on
    the distance from ``(px, py)`` of every grid point other than the answer (of
    every point when there is none): the nearest of the others it met, the gaps of
    the cells it skipped (less `_BOX_SLACK`) and, beyond the rings it visited, the
    query's distance to their outer border (less `_BOX_SLACK`).  `_match` keeps an
    answer while the point moves less than half the difference."""
    ci = int(np.floor((px - ox) / cell))
    cj = int(np.floor((py - oy) / cell))
    fx = px - ox - ci * cell
    fy = py - oy - cj * cell
    margin = max(min(fx, cell - fx, fy, cell - fy), 0.0)
    rings = int(np.ceil(gate / cell))
    best, best_d2 = -1, gate * gate
    other_d2 = np.inf
    beyond = rings * cell + margin
    for r in range(rings + 1):
        for i in range(ci - r, ci + r + 1):
            if i < 0 or i >= nx:
                continue
            gx = _cell_gap(i, ci, fx, cell)
            gx2 = gx * gx
            if gx2 > best_d2:
                other_d2 = min(other_d2, gx2)  # every cell of column i in this ring
                continue
            edge = i == ci - r or i == ci + r
            step = 1 if edge else 2 * r
            j = cj - r
            while j <= cj + r:
                if 0 <= j < ny:
                    gy = _cell_gap(j, cj, fy, cell)
                    g2 = gx2 + gy * gy
                    if g2 <= best_d2:
                        best, best_d2, other_d2 = _scan_cell_bound(i * ny + j, px, py, start,
                                                                   pts, best, best_d2, other_d2)
                    elif g2 < other_d2:
                        other_d2 = g2
                if step == 0:
                    break
                j += step
        if best >= 0 and best_d2 <= (r * cell + margin) ** 2:
            beyond = r * cell + margin
            break
    beyond = max(beyond - _BOX_SLACK, 0.0)
    return best, np.sqrt(best_d2), np.sqrt(min(other_d2, beyond * beyond))


#: Slack [m] of `_match`'s reuse test: far above the rounding of the distances and
#: of a moved point's coordinates, far below any distance between map points.
_REUSE_SLACK = 1e-9


@numba.njit(cache=True)
def _match(src, x, gate, ox, oy, cell, nx, ny, start, pts, kind, sel, jdx, dist, params,
           normals, anchors, near, bound, last, norms):
    """Rows of the correspondences at pose `x`: point-to-line rows first, then the x rows
    and the y rows of the point-to-point matches.  Returns (rows, lines, points).  A
    nearest point of unknown kind (a lazy grid) is resolved first (`resolve_point`).

    Nearest neighbours carried between the iterations of one run: `near` and `bound`
    hold each source point's nearest map point (-1: none within the gate when it was
    searched) and a lower bound [m] on the distance of every other map point (of
    every point for -1; `_nearest_bound`), at pose
    `last` (``last[3] = 0``: none yet); `norms` the points' distances from the source
    origin [m].  A point moves by at most ``delta = |dtheta| |p| + |dt|`` from `last`
    to `x`; where its nearest point, at distance ``d`` now, is nearer than ``bound -
    delta`` (less `_REUSE_SLACK`), no other point can be as near, so it is the
    answer of a new search (and none within the gate stays none while ``bound - delta``
    exceeds the gate, which never grows); the bound becomes ``bound - delta``.  Other
    points search again.  The same correspondences as searching every point."""
    n = src.shape[0]
    c, s = np.cos(x[2]), np.sin(x[2])
    lines = 0
    clut = 0
    csel = np.empty(n, dtype=np.int64)
    cj = np.empty(n, dtype=np.int64)
    cd = np.empty(n)
    carry = last[3] > 0.0
    turn = abs(_wrap(x[2] - last[2]))
    shift = np.hypot(x[0] - last[0], x[1] - last[1])
    gate2 = gate * gate
    for i in range(n):
        px = c * src[i, 0] - s * src[i, 1] + x[0]
        py = s * src[i, 0] + c * src[i, 1] + x[1]
        found = False
        if carry:
            delta = (turn * norms[i] + shift) * (1.0 + _REUSE_SLACK) + _REUSE_SLACK
            left = bound[i] - delta
            j = near[i]
            if j >= 0:
                dx = pts[j, 0] - px
                dy = pts[j, 1] - py
                d2 = dx * dx + dy * dy
                d = np.sqrt(d2)
                if d < left:  # still the nearest; a match if within the gate
                    found = True
                    bound[i] = left
                    if d2 > gate2:
                        j = -1
            elif left > gate:
                found = True
                bound[i] = left
        if not found:
            j, d, b = _nearest_bound(px, py, gate, ox, oy, cell, nx, ny, start, pts)
            near[i] = j
            bound[i] = b
        if j < 0:
            continue
        if kind[j] < 0:
            resolve_point(j, pts, ox, oy, cell, nx, ny, start, params, normals, anchors, kind)
        if kind[j] == 1:
            sel[lines] = i
            jdx[lines] = j
            dist[lines] = d
            lines += 1
        elif kind[j] == 2:
            csel[clut] = i
            cj[clut] = j
            cd[clut] = d
            clut += 1
    for a in range(2):
        for k in range(clut):
            r = lines + a * clut + k
            sel[r] = csel[k]
            jdx[r] = cj[k]
            dist[r] = cd[k]
    last[0] = x[0]
    last[1] = x[1]
    last[2] = x[2]
    last[3] = 1.0
    return lines + 2 * clut, lines, lines + clut


# numba's cache does not see edits of the callees' files (`loopclosure.kernel_cache`).
drop_stale(__name__, ("loopclosure.grid_target",))
