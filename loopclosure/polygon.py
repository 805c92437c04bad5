"""Scans as polygons: the shape every matcher compares.

A `Polygon` is an ``(N, 2)`` float array of vertices in the sensor frame [m],
counter-clockwise, closed implicitly (the last vertex connects to the first; the
first vertex is not repeated).

Rule that turns a `Scan` into a polygon (`polygon_from_scan`):

1. Beams with a real return keep their end point.
2. Beams without a return (reading ``>= max_range``) are open space: their vertex
   is placed along the beam at ``range_cap`` (default: the scan's max range, capped
   by `PolygonConfig.range_cap`).  A place recogniser must see open space as open.
3. Readings that are NaN, -inf, zero or ``<= min_range`` are unknown: dropped, so
   the polygon edge joins their neighbours (``+inf`` is "no return", as in ROS).
4. A scan that covers less than 360 degrees (the gap between its last and first
   beam is larger than `max_gap_deg`) is closed through the sensor origin: the
   origin becomes a vertex.  For sensors with less than 360 degrees the SLAM
   pipeline builds a 360-degree virtual scan from the local map instead, which
   this rule then turns into a polygon without the origin vertex.
5. Consecutive duplicate vertices are removed; fewer than 3 distinct vertices or a
   zero area raise `DegeneratePolygonError`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from data.types import Scan

Array = NDArray[np.float64]


class DegeneratePolygonError(UserError):
    """A scan or contour that does not make a polygon (too few points, zero area)."""


@dataclass(slots=True)
class PolygonConfig:
    """Parameters of the scan -> polygon rule (see module docstring).

    Attributes:
        range_cap: no-return beams and longer readings are placed at
            ``min(range_cap, scan.max_range)`` [m].
        max_gap_deg: an angular gap larger than this between the last and the
            first beam means the scan is not a full circle [deg].
        min_vertices: fewer distinct vertices than this is degenerate.
    """

    range_cap: float = 30.0
    max_gap_deg: float = 10.0
    min_vertices: int = 3


def signed_area(vertices: Array) -> float:
    """Shoelace signed area [m^2]; positive for counter-clockwise vertices."""
    x, y = vertices[:, 0], vertices[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _tolerance(vertices: Array) -> float:
    """Length below which two vertices are the same point, relative to the extent."""
    extent = float(np.ptp(vertices, axis=0).max()) if len(vertices) else 0.0
    return 1e-12 * max(1.0, extent, float(np.abs(vertices).max(initial=0.0)) * 1e-3)


def _drop_duplicates(vertices: Array, tol: float) -> Array:
    step = np.linalg.norm(vertices - np.roll(vertices, 1, axis=0), axis=1)
    keep = step > tol
    if not keep.any():
        return vertices[:1]
    return vertices[keep]


class Polygon:
    """Closed counter-clockwise polygon in the sensor frame [m] (see module docstring)."""

    __slots__ = ("vertices",)

    def __init__(self, vertices: Array, *, min_vertices: int = 3) -> None:
        v = np.asarray(vertices, dtype=float).reshape(-1, 2)
        if not np.all(np.isfinite(v)):
            v = v[np.all(np.isfinite(v), axis=1)]
        tol = _tolerance(v)
        if len(v) > 1 and np.linalg.norm(v[0] - v[-1]) <= tol:
            v = v[:-1]
        v = _drop_duplicates(v, tol)
        if len(v) < min_vertices:
            raise DegeneratePolygonError(
                f"polygon has {len(v)} distinct vertices, needs {min_vertices}"
            )
        area = signed_area(v)
        if abs(area) < 1e-12:
            raise DegeneratePolygonError("polygon has zero area")
        if area < 0:
            v = v[::-1].copy()
        self.vertices = v

    def __len__(self) -> int:
        return len(self.vertices)

    def __repr__(self) -> str:
        return f"Polygon({len(self)} vertices, area {self.area:.3f} m^2)"

    @property
    def area(self) -> float:
        """Enclosed area [m^2] (positive)."""
        return signed_area(self.vertices)

    @property
    def perimeter(self) -> float:
        """Length of the closed boundary [m]."""
        return float(self.edge_lengths().sum())

    def edge_lengths(self) -> Array:
        """``(N,)`` length of edge i (vertex i to vertex i+1, wrapping) [m]."""
        return np.linalg.norm(np.roll(self.vertices, -1, axis=0) - self.vertices, axis=1)

    def centroid(self) -> Array:
        """Area centroid (centre of gravity of the enclosed region) [m]."""
        v = self.vertices
        nxt = np.roll(v, -1, axis=0)
        cross = v[:, 0] * nxt[:, 1] - nxt[:, 0] * v[:, 1]
        a = cross.sum() / 2.0
        cx = ((v[:, 0] + nxt[:, 0]) * cross).sum() / (6.0 * a)
        cy = ((v[:, 1] + nxt[:, 1]) * cross).sum() / (6.0 * a)
        return np.array([cx, cy])

    def resample(self, n: int) -> Array:
        """``(n, 2)`` points equally spaced by arc length along the boundary, from vertex 0."""
        # Hot path of every matcher's `describe`: the same arithmetic as
        # ``interp(linspace(0, L, n, endpoint=False), cumsum(edge_lengths), closed)`` with
        # fewer numpy calls (results are bit-identical).
        v = self.vertices
        closed = np.concatenate((v, v[:1]))
        xs = np.ascontiguousarray(closed.T)  # (2, N + 1): x row, y row
        d = xs[:, 1:] - xs[:, :-1]
        d *= d
        cum = np.empty(len(v) + 1)
        cum[0] = 0.0
        np.cumsum(np.sqrt(d[0] + d[1]), out=cum[1:])
        s = np.arange(n, dtype=float)
        s *= cum[-1] / n
        out = np.empty((n, 2))
        out[:, 0] = np.interp(s, cum, xs[0])
        out[:, 1] = np.interp(s, cum, xs[1])
        return out

    def contains(self, points: Array) -> NDArray[np.bool_]:
        """Even-odd point-in-polygon test of ``(M, 2)`` points (vectorised over points, edges)."""
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        a = self.vertices
        b = np.roll(a, -1, axis=0)
        px, py = p[:, 0:1], p[:, 1:2]
        crosses = (a[None, :, 1] > py) != (b[None, :, 1] > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_at = a[None, :, 0] + (py - a[None, :, 1]) * (b[None, :, 0] - a[None, :, 0]) / (
                b[None, :, 1] - a[None, :, 1]
            )
        inside = crosses & (px < x_at)
        return (inside.sum(axis=1) % 2) == 1

    def rotated(self, angle: float) -> Polygon:
        """The same polygon rotated by `angle` [rad] about the sensor origin."""
        c, s = np.cos(angle), np.sin(angle)
        return Polygon(self.vertices @ np.array([[c, s], [-s, c]]))

    def translated(self, offset: Array) -> Polygon:
        """The same polygon shifted by `offset` ``(2,)`` [m]."""
        return Polygon(self.vertices + np.asarray(offset, dtype=float))


def polygon_from_scan(scan: Scan, config: PolygonConfig | None = None) -> Polygon:
    """Polygon of a scan by the rule in the module docstring."""
    cfg = config or PolygonConfig()
    r = np.asarray(scan.ranges, dtype=float)
    a = np.asarray(scan.angles, dtype=float)
    cap = min(cfg.range_cap, scan.max_range)
    with np.errstate(invalid="ignore"):
        unknown = ~np.isfinite(r) & ~np.isposinf(r)
        unknown |= r <= max(scan.min_range, 0.0)
        no_return = ~unknown & (r >= scan.max_range)
    keep = ~unknown
    if keep.sum() < cfg.min_vertices:
        raise DegeneratePolygonError(
            f"scan {scan.index} at t={scan.stamp:.3f} has {int(keep.sum())} usable beams"
        )
    rr = np.where(no_return, cap, np.minimum(r, cap))[keep]
    aa = a[keep]
    pts = np.column_stack([rr * np.cos(aa), rr * np.sin(aa)])
    step = abs(a[1] - a[0]) if len(a) > 1 else 0.0
    covered = (a[-1] - a[0]) + step if len(a) > 1 else 0.0
    if 2 * np.pi - covered > np.deg2rad(cfg.max_gap_deg):
        pts = np.vstack([pts, [[0.0, 0.0]]])
    return Polygon(pts, min_vertices=cfg.min_vertices)


def polygon_within(polygon: Polygon, radius: float) -> Polygon:
    """The polygon as seen within `radius` [m] of the sensor origin.

    Every vertex farther than `radius` from the origin is pulled in along its own ray
    to distance `radius` (v -> v * radius / |v|); nearer vertices are kept.  For a scan
    polygon this is rule 2 of the module docstring with ``range_cap = radius``, i.e.
    `polygon_from_scan` with that cap, applied to a polygon already built: a place is
    what lies within `radius` of the sensor.  Vertices that fall on one point (readings
    along one beam, both beyond `radius`) are merged as in `Polygon`.
    """
    if not (np.isfinite(radius) and radius > 0):
        raise UserError(f"radius must be a positive length [m], got {radius}")
    v = polygon.vertices
    r = np.hypot(v[:, 0], v[:, 1])
    far = r > radius
    if not far.any():
        return polygon
    out = v.copy()
    out[far] *= (radius / r[far])[:, None]
    return Polygon(out)
