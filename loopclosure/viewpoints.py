"""Offset viewpoints of a keyframe's place: virtual scans of its submap from beside it.

A place descriptor of a 360-degree virtual scan (`loopclosure.virtual_scan`) changes
with the viewpoint's translation: walls a metre away occlude others, the polygon's
open stretches move, the range cap cuts other surfaces.  A revisit that passes one
or two metres beside the old path therefore sees a different scan of the same place.
The submap of a stored keyframe is a point cloud, so the scans such a revisit would
read can be rendered: from viewpoints on rings of radius r around the keyframe's
sensor origin.  A stored keyframe is then described from each viewpoint as well
(`loopclosure.place_views`), and the prefilter's distance of a query to it is the
smallest over its viewpoints (the query keeps its own single description).

Frames and units: the keyframe's sensor frame (x forward, counter-clockwise angles),
metres.  Viewpoint i of a ring of n at radius r sits at

    o_i = r (cos b_i, sin b_i),   b_i = pi / 2 + 2 pi i / n           (i = 0 .. n-1)

so the first viewpoints of a ring are beside the path (left, then right for n = 2),
where a revisit beside the old path stands.  Its virtual scan is the scan of the
submap points translated by -o_i, with the keyframe's heading (the descriptors are
rotation invariant).

Free space.  A viewpoint is used only where a robot could stand: the keyframe's own
virtual scan (from the origin) must see at least ``r + clearance`` along the
bearing b_i (the straight path from the keyframe to the viewpoint crosses no
surface; a beam without a return counts as open), and no submap point may lie
within ``clearance`` of o_i.  A viewpoint inside a wall or behind it would describe
a place no revisit can read.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError
from data.types import Scan
from loopclosure.place_views import prefilter_vector
from loopclosure.polygon import DegeneratePolygonError, PolygonConfig, polygon_from_scan
from loopclosure.virtual_scan import virtual_scan

Array = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class ViewpointConfig:
    """Where a stored keyframe is also described from (module docstring).

    Attributes:
        radii: ring radii [m] (empty: no offset viewpoint).
        count: viewpoints per ring (the first two beside the path).
        clearance: least free distance around a viewpoint and beyond it along the
            keyframe's beam towards it [m].
    """

    radii: tuple[float, ...] = ()
    count: int = 6
    clearance: float = 0.3

    def __post_init__(self) -> None:
        if any(not (np.isfinite(r) and r > 0) for r in self.radii):
            raise UserError(f"viewpoint radii must be positive lengths [m], got {self.radii}")
        if self.count < 1:
            raise UserError(f"viewpoints per ring must be >= 1, got {self.count}")
        if not (np.isfinite(self.clearance) and self.clearance >= 0):
            raise UserError(f"viewpoint clearance must be >= 0 m, got {self.clearance}")

    @property
    def enabled(self) -> bool:
        """Whether any offset viewpoint is asked for."""
        return bool(self.radii)


def ring_offsets(config: ViewpointConfig) -> Array:
    """``(len(radii) * count, 2)`` viewpoints o_i [m, sensor frame], ring by ring."""
    b = np.pi / 2 + 2 * np.pi * np.arange(config.count) / config.count
    unit = np.column_stack([np.cos(b), np.sin(b)])
    return np.concatenate([r * unit for r in config.radii]) if config.radii else np.zeros((0, 2))


def free_offsets(points: ArrayLike, own_scan: Scan, config: ViewpointConfig) -> Array:
    """The viewpoints of `ring_offsets` that lie in free space (module docstring).

    Args:
        points: ``(M, 2)`` submap points [m, sensor frame].
        own_scan: the keyframe's 360-degree virtual scan of those points (from the
            origin, bearings from -pi in equal steps).
        config: the rings.
    """
    offsets = ring_offsets(config)
    if len(offsets) == 0:
        return offsets
    pts = np.asarray(points, float).reshape(-1, 2)
    ranges = np.asarray(own_scan.ranges, float)
    n = len(ranges)
    bearing = np.arctan2(offsets[:, 1], offsets[:, 0])
    beam = np.mod(np.rint((bearing + np.pi) * n / (2 * np.pi)).astype(np.intp), n)
    dist = np.hypot(offsets[:, 0], offsets[:, 1])
    open_ray = ranges[beam] >= dist + config.clearance
    if len(pts):
        gap = np.hypot(pts[None, :, 0] - offsets[:, None, 0],
                       pts[None, :, 1] - offsets[:, None, 1]).min(axis=1)
        open_ray &= gap >= config.clearance
    return offsets[open_ray]


def viewpoint_scans(
    points: ArrayLike, own_scan: Scan, config: ViewpointConfig, beams: int = 360,
    max_range: float = 20.0,
) -> list[Scan]:
    """Virtual scans of the submap `points` (``(M, 2)`` [m], sensor frame) from every
    free viewpoint (`free_offsets`), in ring order; each `Scan.odom` is its
    viewpoint ``(x, y, 0)``."""
    pts = np.asarray(points, float).reshape(-1, 2)
    return [
        virtual_scan(pts - o, beams, max_range, stamp=own_scan.stamp, odom=(o[0], o[1], 0.0))
        for o in free_offsets(pts, own_scan, config)
    ]


def viewpoint_vectors(
    points: ArrayLike, own_scan: Scan, config: ViewpointConfig, database: Any,
    polygon: PolygonConfig | None = None, beams: int = 360, max_range: float = 20.0,
) -> dict[str, Array] | None:
    """The prefilter vectors of every free viewpoint's scan (`viewpoint_scans`) as a
    place database stores them (`loopclosure.place_views`): ``{stage: (V, D)}`` for
    the prefilter stages of `database` (a `loopclosure.place_database.PlaceDatabase`);
    None when no viewpoint is free or makes a polygon."""
    stages = tuple(database.config.prefilter)
    rows: dict[str, list[Array]] = {s: [] for s in stages}
    for scan in viewpoint_scans(points, own_scan, config, beams, max_range):
        try:
            poly = polygon_from_scan(scan, polygon)
        except DegeneratePolygonError:
            continue
        for s in stages:
            desc = database.matchers[s].describe(poly)
            rows[s].append(np.asarray(prefilter_vector(desc), float))
    if not rows[stages[0]]:
        return None
    return {s: np.stack(v) for s, v in rows.items()}


__all__ = ["ViewpointConfig", "free_offsets", "ring_offsets", "viewpoint_scans",
           "viewpoint_vectors"]
