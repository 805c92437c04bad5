"""The surface context: the stripes' point context (Eq. 1-2) over pairs of the whole object.

Paper: "Stripes-based Object Matching" (``papers/stripes-object-matching.txt``), Section
IV.  The paper describes each stripe by the distances (Eq. 1, ``log(1 + ||p_i - p_m||)``)
and directions (Eq. 2, the angle of ``p_i - p_m``) of the pairs of its own points, and
drops the heights the scanner measures ("the calculated distance values are not
needed"); it never relates points of different stripes.  This module is a fourth
signal on the same stripes, beside the paper's descriptor, the stripe profile
(`profile`) and the relief (`relief`): the same two pair quantities taken over pairs of
points of the *whole* scanned surface in metres (the stripes' rows turned into heights
above the table by the scanner's calibration, e.g.
`data.stripe_scanner.StripeScan.height_map`), kept as a joint histogram instead of
two means.

Why: within one stripe the pairs see one cross-section; across stripes they see how
the object's parts lie relative to each other in 3D: a box top gives flat pairs at
every distance, a ball pairs whose elevation grows with their distance, a cup's rim
steep pairs over a short distance (rim to bottom), an upright bottle steep pairs
between the cap and the shoulders.  The profile sees each stripe in units of its own
width and the relief only the mean depth per ring; the outline matchers see no height
at all.

Definition.  Input: heights ``z`` [m] on a top-view grid (rows along the sweep, cell
``(row_m, column_m)`` metres apart; NaN where nothing was seen).  Points: the seen
cells as ``(x, y, z) = (column * column_m, row * row_m, z)`` metres (table frame, z up),
at most `SurfaceConfig.points` of them, drawn without replacement by a generator of
fixed seed (`SURFACE_SEED`, so one height map always gives one description; a
random draw and not a stride, which would alias with the grid's row width).  For
every pair ``i > m`` of points, ``v = p_i - p_m``:

- distance ``r = ||v||`` (Eq. 1's argument), taken as ``log(r / median r)``: the
  object's own median pair distance is the unit, so the description is scale free
  (members of one class differ in size), like Eq. 1's log;
- elevation ``e = atan(|v_z| / ||v_xy||)`` in ``[0, pi/2]`` (Eq. 2's angle measured
  from the table plane, folded so that it does not change when the object turns on
  the table or is mirrored: only the up axis is fixed);

the surface context is the joint histogram of ``(log(r / median r), e)`` over all
pairs: `SurfaceConfig.distance_bins` even bins over `SurfaceConfig.log_range` (values
outside go to the end bins) times `SurfaceConfig.elevation_bins` even bins over
``[0, pi/2]``, divided by the pair count (sums to 1).

Distance of two surface contexts: the L1 distance of the histograms,
``sum |S - S'|`` (unitless, in ``[0, 2]``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import DataError, UserError

Array = NDArray[np.float64]

#: Points drawn from the seen surface: 200 give 19,900 pairs, enough for a 64-bin
#: histogram, and keep the description at about a millisecond per object.
SURFACE_POINTS = 200
#: Bins of ``log(r / median r)``.
DISTANCE_BINS = 8
#: Bins of the elevation over ``[0, pi/2]``.
ELEVATION_BINS = 8
#: Range of ``log(r / median r)`` the distance bins cover: pairs from e^-2 (0.14) to
#: e^1 (2.7) times the median distance; the rest fall in the end bins.
LOG_RANGE: tuple[float, float] = (-2.0, 1.0)
#: Seed of the point draw.
SURFACE_SEED = 0


@dataclass(frozen=True, slots=True)
class SurfaceConfig:
    """Parameters of the surface context (module docstring).

    Attributes:
        points: at most this many surface points per object.
        distance_bins: bins of ``log(r / median r)``.
        elevation_bins: bins of the elevation ``[0, pi/2]``.
        log_range: ``(low, high)`` of the distance bins (log units).
    """

    points: int = SURFACE_POINTS
    distance_bins: int = DISTANCE_BINS
    elevation_bins: int = ELEVATION_BINS
    log_range: tuple[float, float] = LOG_RANGE

    def __post_init__(self) -> None:
        if self.points < 3:
            raise UserError(f"surface points must be at least 3, got {self.points}")
        if self.distance_bins < 1 or self.elevation_bins < 1:
            raise UserError(f"surface bins must be at least 1, got {self.distance_bins} x "
                            f"{self.elevation_bins}")
        if not self.log_range[0] < self.log_range[1]:
            raise UserError(f"log range must be increasing, got {self.log_range}")


@dataclass(frozen=True, slots=True)
class StripeSurface:
    """One object's surface context: ``(distance_bins, elevation_bins)`` shares of its
    point pairs (sum 1), and a name."""

    histogram: Array
    name: str | None = None


def surface_points(
    heights: ArrayLike, cell: tuple[float, float], points: int = SURFACE_POINTS,
    name: str | None = None,
) -> Array:
    """``(P, 3)`` points ``(x, y, z)`` [m] of the seen cells of a top view, at most `points`
    of them (module docstring: fixed-seed draw, in raster order).

    Raises:
        DataError: no finite height.
        UserError: a cell spacing that is not positive.
    """
    z = np.asarray(heights, dtype=float)
    dy, dx = (float(c) for c in cell)
    if not (dy > 0 and dx > 0):
        raise UserError(f"cell spacing must be positive, got {cell}")
    rows, cols = np.nonzero(np.isfinite(z))
    if len(rows) == 0:
        raise DataError(name, "no height seen: the object has no surface")
    if len(rows) > points:
        keep = np.sort(np.random.default_rng(SURFACE_SEED).choice(len(rows), points,
                                                                  replace=False))
        rows, cols = rows[keep], cols[keep]
    return np.column_stack([cols * dx, rows * dy, z[rows, cols]])


@lru_cache(maxsize=4)
def _pairs(n: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Index arrays ``(i, m)`` of the pairs ``i < m`` of ``n`` points (cached: one size
    serves every object with `SurfaceConfig.points` points)."""
    i, m = np.triu_indices(n, k=1)
    return i, m


def surface_histogram(points: ArrayLike, config: SurfaceConfig | None = None) -> Array:
    """The joint histogram of ``(log(r / median r), elevation)`` over all pairs of `points`
    ``(P, 3)`` [m, z up] (module docstring), ``(distance_bins, elevation_bins)``, sum 1.

    Fewer than two distinct points: all mass in the bin of the median distance and
    zero elevation.  Vectorised over the pairs, one coordinate at a time.
    """
    cfg = config or SurfaceConfig()
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    out = np.zeros((cfg.distance_bins, cfg.elevation_bins))
    i, m = _pairs(len(p))
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    dx, dy = x[i] - x[m], y[i] - y[m]
    vertical = np.abs(z[i] - z[m])
    h2 = dx * dx + dy * dy
    r2 = h2 + vertical * vertical
    ok = r2 > 0
    lo, hi = cfg.log_range
    if not ok.any():
        out[int(np.clip(-lo / (hi - lo) * cfg.distance_bins, 0, cfg.distance_bins - 1)), 0] = 1
        return out
    if not ok.all():
        r2, h2, vertical = r2[ok], h2[ok], vertical[ok]
    r = np.sqrt(r2)
    lr = np.log(r / np.median(r))
    bd = np.clip(((lr - lo) * (cfg.distance_bins / (hi - lo))).astype(np.int64), 0,
                 cfg.distance_bins - 1)
    be = np.minimum((np.arctan2(vertical, np.sqrt(h2)) * (2.0 / np.pi * cfg.elevation_bins))
                    .astype(np.int64), cfg.elevation_bins - 1)
    counts = np.bincount(bd * cfg.elevation_bins + be,
                         minlength=cfg.distance_bins * cfg.elevation_bins)
    return (counts / counts.sum()).reshape(out.shape)


def describe_surface(
    heights: ArrayLike,
    cell: tuple[float, float],
    config: SurfaceConfig | None = None,
    name: str | None = None,
) -> StripeSurface:
    """The surface context of one object's top view (module docstring).

    Args:
        heights: ``(rows, columns)`` heights above the table [m]; NaN where nothing
            was seen.
        cell: ``(row_m, column_m)`` spacing of the rows and of the columns [m].
        config: surface-context parameters.
        name: object identifier used in messages.

    Raises:
        DataError: no finite height.
        UserError: a cell spacing that is not positive.
    """
    cfg = config or SurfaceConfig()
    pts = surface_points(heights, cell, cfg.points, name)
    return StripeSurface(surface_histogram(pts, cfg), name)


class SurfaceDatabase:
    """Many objects' surface contexts, queried in one vectorised pass.

    Args:
        surfaces: one `StripeSurface` per object, all with the same bins.
    """

    def __init__(self, surfaces: Sequence[StripeSurface]) -> None:
        self.surfaces = list(surfaces)
        shapes = {s.histogram.shape for s in self.surfaces}
        if len(shapes) > 1:
            raise UserError(f"every surface context must have one shape, got {sorted(shapes)}")
        self.stack = (np.stack([s.histogram.ravel() for s in self.surfaces]) if self.surfaces
                      else np.zeros((0, DISTANCE_BINS * ELEVATION_BINS)))

    def __len__(self) -> int:
        return len(self.surfaces)

    def distances(self, query: StripeSurface) -> Array:
        """``(M,)`` L1 distances of the query's histogram to every object's."""
        q = np.asarray(query.histogram, dtype=float).ravel()
        if q.shape != self.stack.shape[1:]:
            raise UserError(f"query surface context has {q.size} bins, the database "
                            f"{self.stack.shape[1]}")
        return np.abs(self.stack - q[None]).sum(axis=1)

    def pairwise(self) -> Array:
        """``(M, M)`` distances (symmetric, zero diagonal)."""
        s = self.stack
        return np.abs(s[:, None] - s[None]).sum(axis=2)
