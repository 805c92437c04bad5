"""Polar occupancy grids of the place database (`loopclosure.place_database`).

Every keyframe's surface samples (`loopclosure.matchers.pair_histogram`, sensor
frame [m]) binned into ``grid_rings`` x ``grid_sectors`` cells out to ``grid_range`` m
about the sensor origin (`loopclosure.headings.polar_occupancy`), stored bit-packed
(300 bytes a keyframe) under the descriptor key `GRID`.  They feed the grid heading
hypotheses (`loopclosure.place_headings`) and the grid similarity c of the
shortlist (`loopclosure.grid_rerank`), for which `DilatedGrids` keeps every row's
dilated grid and its occupied cell count, made once at insertion.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from loopclosure.grid_rerank import dilate_polar, dilated_similarity
from loopclosure.headings import polar_occupancy
from loopclosure.matchers.pair_histogram import PairHistogramConfig, polygon_samples
from loopclosure.place_config import PlaceDatabaseConfig
from loopclosure.place_rows import FloatRows
from loopclosure.polygon import Polygon

Array = NDArray[np.float64]
GRID = "grid"
"""Descriptor key of the bit-packed polar occupancy grid of the grid headings."""
_GRID_SAMPLES = PairHistogramConfig()


def polar_grid(polygon: Polygon, cfg: PlaceDatabaseConfig) -> NDArray[np.uint8]:
    """Bit-packed polar occupancy grid of the polygon's surface samples (sensor frame;
    `polygon_samples`: the pair histogram's samples when the lengths agree)."""
    pts, _, _ = polygon_samples(
        polygon.vertices, step=_GRID_SAMPLES.step, max_edge=_GRID_SAMPLES.max_edge,
        max_range=min(_GRID_SAMPLES.max_range, cfg.grid_range),
    )
    return np.packbits(polar_occupancy(pts, cfg.grid_rings, cfg.grid_sectors, cfg.grid_range))


def unpack_grid(packed: NDArray[np.uint8], cfg: PlaceDatabaseConfig) -> NDArray[np.bool_]:
    """``(grid_rings, grid_sectors)`` occupancy of a bit-packed grid."""
    n = cfg.grid_rings * cfg.grid_sectors
    return np.unpackbits(packed, count=n).reshape(cfg.grid_rings, cfg.grid_sectors)


class DilatedGrids:
    """Per row, its polar grid dilated (`grid_rerank.dilate_polar`, bit-packed; zeros
    for a row without a grid) and the dilated grid's occupied cells."""

    def __init__(self, cfg: PlaceDatabaseConfig) -> None:
        self._cfg = cfg
        self._cells = cfg.grid_rings * cfg.grid_sectors
        self._dilated = FloatRows((self._cells + 7) // 8, dtype=np.uint8)
        self._counts = FloatRows(1)

    def append(self, packed: NDArray[np.uint8] | None) -> None:
        """Store the next row's dilated grid and its count (zeros without a grid)."""
        if packed is None:
            self._dilated.append(np.zeros((self._cells + 7) // 8, np.uint8))
            self._counts.append([0.0])
            return
        dilated = dilate_polar(unpack_grid(packed, self._cfg))
        self._dilated.append(np.packbits(dilated.ravel()))
        self._counts.append([np.count_nonzero(dilated)])

    def similarity(self, query: NDArray[np.uint8], rows: NDArray[np.intp]) -> Array:
        """``(len(rows),)`` grid similarity c of the bit-packed query grid with those
        rows (0 where a row has no grid: its dilated grid is empty)."""
        if len(rows) == 0:
            return np.zeros(len(rows))
        cfg = self._cfg
        stored = np.unpackbits(self._dilated.data[rows], axis=1, count=self._cells)
        return dilated_similarity(
            dilate_polar(unpack_grid(query, cfg)),
            stored.reshape(-1, cfg.grid_rings, cfg.grid_sectors),
            self._counts.data[rows, 0])


__all__ = ["GRID", "DilatedGrids", "polar_grid", "unpack_grid"]
