"""Contour sampling of FLIRT's detector: a metric step and the edges it leaves out.

The option of `loopclosure.matchers.flirt_features` (its docstring, "contour
sampling"): how many arc-length samples a boundary gets (`sample_count`), which of
them lie on kept edges (`kept_samples`: edges ending at or beyond a range from the
sensor origin, or spanning a depth jump, are dropped) and how far each sample is from
a dropped one (`border_distance`, so that interest points whose smoothing kernel
reaches a dropped edge are not taken).  Frames and units: the polygon's sensor frame
and length units (metres for scans); distances along the curve in samples.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from loopclosure.polygon import Polygon

Array = NDArray[np.float64]


def sample_count(polygon: Polygon, sample_step: float, n_samples: int, max_samples: int,
                 unit: float = 1.0) -> int:
    """Boundary samples N of `polygon`: `n_samples` when `sample_step` is 0, else the
    perimeter over the step (both in the polygon's units divided by `unit`), rounded
    and clipped to ``16 .. max_samples``."""
    if sample_step <= 0:
        return n_samples
    n = round(polygon.perimeter / unit / sample_step)
    return int(min(max(n, 16), max_samples))


def kept_samples(polygon: Polygon, n: int, max_range: float, max_jump: float = 0.0
                 ) -> NDArray[np.bool_]:
    """``(n,)`` True for the samples of ``polygon.resample(n)`` on a kept edge: one
    whose two ends both lie closer than `max_range` to the sensor origin (0: no
    limit) and, with `max_jump` > 0, whose ends' ranges differ by at most `max_jump`
    [polygon units] (a sample on a vertex belongs to the edge that starts there)."""
    v = polygon.vertices
    r = np.hypot(v[:, 0], v[:, 1])
    near = r < max_range if max_range > 0 else np.ones(len(v), dtype=bool)
    kept_edge = near & np.roll(near, -1)
    if max_jump > 0:
        kept_edge &= np.abs(np.roll(r, -1) - r) <= max_jump
    cum = np.concatenate(([0.0], np.cumsum(polygon.edge_lengths())))
    s = np.arange(n, dtype=float) * (cum[-1] / n)
    edge = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(v) - 1)
    return kept_edge[edge]


def border_distance(kept: NDArray[np.bool_]) -> Array:
    """``(N,)`` circular distance [samples] of every sample to the nearest sample that
    is not kept (``inf`` when all are kept; 0 on a dropped sample)."""
    n = len(kept)
    out_idx = np.flatnonzero(~kept)
    if not len(out_idx):
        return np.full(n, np.inf)
    ext = np.concatenate((out_idx - n, out_idx, out_idx + n))
    i = np.arange(n)
    pos = np.searchsorted(ext, i)
    return np.minimum(ext[pos] - i, i - ext[pos - 1]).astype(float)


__all__ = ["border_distance", "kept_samples", "sample_count"]
