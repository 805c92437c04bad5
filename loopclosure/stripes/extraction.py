"""Stripes from laser-line camera images, binary stripe images and 3D points.

Paper: "Stripes-based Object Matching", Section III (stripe generation) and VI.C
("for each stripe, we only need O(l) for thinning and noise removing").

A stripe is an ordered ``(H, 2)`` float array of 2D points.  For images the points are
pixels ``(column, row)``, row 0 at the top.  An object is a list of stripes in scan
order (the laser's moving direction, or the slice order).

- `stripe_from_laser_image`: per column, start and end of the laser line by an
  adjustable threshold and the intensity-weighted row between them
  (`data.stripe_scanner.line_detector`); the stripe is ordered by column.
- `stripe_from_binary_image`: the paper's black/white stripe images.  ``method="thin"``
  thins the mask to one pixel (Zhang-Suen, vectorised over the image) and chains the
  pixels into one ordered path (`chain_pixels`); ``method="columns"`` takes the mean
  row of each column (fast, exact for one-pixel-per-column stripes).
- `stripes_from_points`: a 3D point cluster cut into parallel slices (planes normal to
  a sweep direction) or by LiDAR ring; one stripe per non-empty slice, slices in
  order; inside a slice the points are ordered along the slice's lateral axis.

Nearest-neighbour chaining (`chain_pixels`): inside each 8-connected run of skeleton
pixels the path follows the skeleton: pixels are ordered by their geodesic distance
along the run (8-neighbour steps of 1 or sqrt 2, scipy's compiled Dijkstra) from the
run's end with the smallest (column, row), so consecutive path points are neighbours
and no Python loop over pixels is needed; a short noise spur is interleaved with the
main line at its distance (its pixels are next to it anyway).  Across gaps the chain
jumps from its current end to the nearest end of a run not yet visited (a Python loop
over *runs* only, which are few).  The path starts at the run that holds the overall
smallest (column, row) end.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from data.errors import DataError, UserError, warn
from data.stripe_scanner.line_detector import laser_line_positions

Array = NDArray[np.float64]

_EIGHT = np.ones((3, 3), dtype=bool)


# ----------------------------------------------------------------------- camera images


def stripe_from_laser_image(image: ArrayLike, threshold: float) -> Array:
    """One stripe ``(K, 2)`` = (column, sub-pixel row) from a laser-line camera image.

    Args:
        image: ``(rows, columns)`` intensities.
        threshold: the adjustable detection threshold (image intensity units).

    Columns without the line are absent; the result is empty when nothing reaches the
    threshold.
    """
    cols, rows = laser_line_positions(image, threshold)
    return np.column_stack([cols.astype(float), rows])


def stripes_from_laser_images(
    images: Sequence[ArrayLike] | ArrayLike, threshold: float, name: str | None = None
) -> list[Array]:
    """One stripe per laser image, in image order; images without a line are skipped.

    A single warning reports how many images gave no stripe; all images empty is an error.
    """
    stripes = [stripe_from_laser_image(im, threshold) for im in images]
    kept = [s for s in stripes if len(s)]
    if not kept:
        raise DataError(name, f"no laser line above threshold {threshold} in any image")
    if len(kept) < len(stripes):
        warn(f"{name or 'laser images'}: {len(stripes) - len(kept)} of {len(stripes)} images "
             "had no laser line above the threshold (skipped)")
    return kept


# ----------------------------------------------------------------------- binary images


def _neighbours(m: NDArray[np.bool_]) -> list[NDArray[np.bool_]]:
    """P2..P9 of Zhang-Suen (N, NE, E, SE, S, SW, W, NW) for every pixel, zero-padded."""
    p = np.pad(m, 1)
    h, w = m.shape
    off = [(-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1)]
    return [p[1 + dr : 1 + dr + h, 1 + dc : 1 + dc + w] for dr, dc in off]


def thin(mask: ArrayLike, max_iterations: int = 100) -> NDArray[np.bool_]:
    """Zhang-Suen thinning of a binary image to one-pixel-wide 8-connected lines.

    Vectorised over the image: each sub-iteration evaluates every pixel at once; the
    number of iterations is about half the line width.
    """
    m = np.asarray(mask).astype(bool).copy()
    for _ in range(max_iterations):
        changed = False
        for step in (0, 1):
            n = _neighbours(m)
            b = np.sum(n, axis=0)
            seq = [*n, n[0]]
            a = np.sum([(~seq[k]) & seq[k + 1] for k in range(8)], axis=0)
            p2, p4, p6, p8 = n[0], n[2], n[4], n[6]
            if step == 0:
                c = ~(p2 & p4 & p6) & ~(p4 & p6 & p8)
            else:
                c = ~(p2 & p4 & p8) & ~(p2 & p6 & p8)
            remove = m & (b >= 2) & (b <= 6) & (a == 1) & c
            if remove.any():
                m &= ~remove
                changed = True
        if not changed:
            break
    return m


def chain_pixels(rows: ArrayLike, cols: ArrayLike) -> Array:
    """Order skeleton pixels into one path by nearest-neighbour chaining (module docstring).

    Returns ``(K, 2)`` (column, row) in path order.
    """
    r = np.asarray(rows, dtype=np.int64).ravel()
    c = np.asarray(cols, dtype=np.int64).ravel()
    n = len(r)
    if n == 0:
        return np.zeros((0, 2))
    r0, c0 = r.min(), c.min()
    h, w = r.max() - r0 + 3, c.max() - c0 + 3
    index = -np.ones((h, w), dtype=np.int64)
    rr, cc = r - r0 + 1, c - c0 + 1
    index[rr, cc] = np.arange(n)
    src, dst = [], []
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr == 0 and dc == 0:
                continue
            nb = index[rr + dr, cc + dc]
            ok = nb >= 0
            src.append(np.flatnonzero(ok))
            dst.append(nb[ok])
    s, d = np.concatenate(src), np.concatenate(dst)
    step = np.hypot(r[s] - r[d], c[s] - c[d])  # 1 or sqrt(2)
    graph = csr_matrix((step, (s, d)), shape=(n, n))
    degree = np.bincount(s, minlength=n)
    labels, _ = ndimage.label(index >= 0, structure=_EIGHT)
    comp = labels[rr, cc] - 1
    # Each run starts at its end (degree <= 1) with the smallest (column, row).
    order_key = np.lexsort((r, c, degree > 1, comp))
    first_of_run = np.r_[True, comp[order_key][1:] != comp[order_key][:-1]]
    starts = order_key[first_of_run]  # one per run, in run order
    # Order inside each run by geodesic distance along the skeleton from its start.
    geo = dijkstra(graph, directed=False, indices=starts, min_only=True)
    inside = np.lexsort((geo, comp))
    bounds = np.flatnonzero(np.diff(comp[inside])) + 1
    walks: list[NDArray[np.int64]] = list(np.split(inside, bounds))
    pts = np.column_stack([c, r]).astype(float)
    # Chain the runs: start at the run whose start has the smallest (column, row).
    starts = np.array([walk[0] for walk in walks])
    current = int(np.lexsort((r[starts], c[starts]))[0])
    path = [walks[current]]
    left = set(range(len(walks))) - {current}
    while left:
        tail = pts[path[-1][-1]]
        cand = np.array(sorted(left))
        heads = pts[[walks[k][0] for k in cand]]
        tails = pts[[walks[k][-1] for k in cand]]
        dh = np.hypot(*(heads - tail).T)
        dt = np.hypot(*(tails - tail).T)
        j = int(np.argmin(np.minimum(dh, dt)))
        k = int(cand[j])
        path.append(walks[k] if dh[j] <= dt[j] else walks[k][::-1])
        left.discard(k)
    return pts[np.concatenate(path)]


def stripe_from_binary_image(mask: ArrayLike, method: str = "thin") -> Array:
    """One ordered stripe ``(K, 2)`` = (column, row) from a black/white stripe image.

    Args:
        mask: ``(rows, columns)``; non-zero pixels belong to the stripe.
        method: ``"thin"`` (thinning + nearest-neighbour chaining) or ``"columns"``
            (mean row of each column, ordered by column).
    """
    m = np.asarray(mask).astype(bool)
    if m.ndim != 2:
        raise UserError(f"expected a 2D stripe image, got shape {m.shape}")
    if not m.any():
        return np.zeros((0, 2))
    if method == "columns":
        rr, cc = np.nonzero(m)
        cnt = np.bincount(cc, minlength=m.shape[1])
        tot = np.bincount(cc, weights=rr, minlength=m.shape[1])
        cols = np.flatnonzero(cnt)
        return np.column_stack([cols.astype(float), tot[cols] / cnt[cols]])
    if method != "thin":
        raise UserError(f"unknown stripe extraction method {method!r} (thin, columns)")
    # Thin only the bounding box of the stripe (cheap for a 600 x 712 image).
    rr, cc = np.nonzero(m)
    r0, r1, c0, c1 = rr.min(), rr.max() + 1, cc.min(), cc.max() + 1
    sk = thin(m[r0:r1, c0:c1])
    sr, sc = np.nonzero(sk)
    return chain_pixels(sr + r0, sc + c0)


# ----------------------------------------------------------------------- 3D points


def stripes_from_points(
    points: ArrayLike,
    spacing: float | None = 0.002,
    normal: ArrayLike = (1.0, 0.0, 0.0),
    up: ArrayLike = (0.0, 0.0, 1.0),
    rings: ArrayLike | None = None,
    resolution: float = 0.001,
    name: str | None = None,
) -> list[Array]:
    """Stripes of a 3D point cluster: one per slice, slices in order.

    Args:
        points: ``(P, 3)`` points [m] of one object cluster.
        spacing: slice thickness [m] along `normal` (parallel-plane slicing).
        normal: sweep direction; slices are planes normal to it, ordered along it.
        up: the direction mapped to the stripe's second coordinate (height).
        rings: ``(P,)`` integer LiDAR ring of each point; when given, one slice per
            ring (ordered by ring number) replaces the plane slicing.
        resolution: size of one stripe unit [m] (the "pixel" of the descriptor).
        name: cluster identifier used in messages.

    Each slice is expressed in its plane: ``u`` along the lateral axis ``up x normal``,
    ``v = -height`` along `up` (minus, so that up is towards smaller values as in an
    image), both divided by `resolution` and rounded to whole units; duplicate units in
    a slice are merged (as pixels of a binary image), and the points are ordered by
    ``u``.  For rings ``normal`` is ignored: ``u`` is the azimuth about the sensor's
    vertical times the ring's mean horizontal range and ``v = -`` range (the profile as
    the sensor sees it).

    Raises:
        DataError: no finite point, or the cluster gives no slice.
    """
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    finite = np.isfinite(p).all(axis=1)
    if rings is not None:
        ring = np.asarray(rings).reshape(-1)
        if len(ring) != len(p):
            raise UserError(f"rings must hold one ring number per point: {len(ring)} ring "
                            f"numbers for {len(p)} points")
        ring = ring[finite]
    p = p[finite]
    if len(p) == 0:
        raise DataError(name, "point cluster has no finite point")
    if resolution <= 0:
        raise UserError(f"resolution must be positive [m], got {resolution}")
    if rings is not None:
        slice_id = np.asarray(ring, dtype=np.int64)
        horiz = np.hypot(p[:, 0], p[:, 1])
        az = np.arctan2(p[:, 1], p[:, 0])
        centre = np.arctan2(np.sin(az).sum(), np.cos(az).sum())  # circular mean
        az = (az - centre + np.pi) % (2 * np.pi) - np.pi
        _, inv = np.unique(slice_id, return_inverse=True)
        mean_range = np.bincount(inv, weights=horiz) / np.bincount(inv)
        u = az * mean_range[inv]
        v = -horiz
    else:
        if spacing is None or spacing <= 0:
            raise UserError(f"slice spacing must be positive [m], got {spacing}")
        nrm = np.asarray(normal, dtype=float)
        nrm = nrm / np.linalg.norm(nrm)
        upv = np.asarray(up, dtype=float)
        upv = upv - nrm * (upv @ nrm)
        if np.linalg.norm(upv) < 1e-9:
            raise UserError("`up` must not be parallel to the slicing normal")
        upv /= np.linalg.norm(upv)
        lateral = np.cross(upv, nrm)
        t = p @ nrm
        slice_id = np.floor((t - t.min()) / spacing).astype(np.int64)
        u = p @ lateral
        v = -(p @ upv)
    ui = np.rint(u / resolution).astype(np.int64)
    vi = np.rint(v / resolution).astype(np.int64)
    key = np.unique(np.column_stack([slice_id, ui, vi]), axis=0)  # sorted by slice, u, v
    bounds = np.flatnonzero(np.diff(key[:, 0])) + 1
    stripes = [k[:, 1:].astype(float) for k in np.split(key, bounds)]
    stripes = [s for s in stripes if len(s)]
    if not stripes:
        raise DataError(name, "point cluster gives no stripe")
    return stripes
