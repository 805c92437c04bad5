"""Occupancy-grid maps from laser scans and their poses (log-odds, ray-traced free space).

Frames and units: poses are ``(x, y, theta)`` of the *sensor* in the map frame
[m, m, rad]; scan ranges [m] and bearings [rad] are in the sensor frame
(`data.types.Scan`).  The grid is axis-aligned with the map frame: cell
``(row, col)`` covers ``x in [ox + col * res, ox + (col + 1) * res)`` and
``y in [oy + row * res, oy + (row + 1) * res)``, where ``(ox, oy) = origin`` is the
lower-left corner of cell ``(0, 0)`` and ``res`` the resolution [m/cell].  Arrays
are stored with row 0 at the *smallest* y (the order of ROS ``nav_msgs/OccupancyGrid``
data); images (`OccupancyGrid.trinary`, the PGM and PNG files) are flipped so that
image row 0 is the *largest* y, as ROS map_server expects.

Beams (`build_occupancy_grid`):

* a **return** (finite, ``> min_range``, ``< max_range`` of its scan) no farther than
  `MapConfig.max_hit_range` marks its end cell as a *hit* and every cell between the
  sensor's cell and the end cell as a *miss*;
* a return farther than `max_hit_range` (a stray long beam) is clipped there: misses
  up to the clip point, no hit;
* a **no-return** beam (reading ``>= max_range`` or ``+inf``) clears free space up to
  ``min(no_return_range, scan.max_range)`` and marks no hit;
* **invalid** readings (NaN, ``-inf``, ``<= min_range``, zero) are ignored.

Ray tracing is Bresenham's line between the centres of the start and end cells,
for all beams at once: a beam spanning ``n = max(|d_col|, |d_row|)`` cells visits
the cells ``start + floor(k * (end - start) / n + 1/2)`` for ``k = 0 .. n - 1`` (and
``k = n`` when it has no hit), computed in fixed point.  Beams are sorted by length
and traced in groups as ``(beams, steps)`` arrays by broadcasting (about
`MapConfig.chunk_cells` entries per group, or a quarter of the grid's cells if
more); hit and miss counts (int32: a cell gains at most one miss per beam) are
accumulated with `np.bincount` on flat cell indices, in bands of about a million
cells on large grids.  Scans are read in chunks of about 50,000 beams, twice (the
extent first, then the counts), which bounds the memory.  There
is no Python loop over beams or cells (only over scans, to gather their arrays,
and over chunks and groups).

Sensor model: each cell keeps its hit and miss counts.  Its log-odds is
``L = hits * l(p_hit) + misses * l(p_miss)`` with ``l(p) = ln(p / (1 - p))``, clamped to
``[l(p_min), l(p_max)]``; its occupancy probability is ``1 / (1 + exp(-L))``.
Defaults: ``p_hit = 0.7`` (``l = +0.847``), ``p_miss = 0.45`` (``l = -0.201``: a hit
outweighs four passes, since beams from other poses graze wall cells),
``p_min = 0.12``, ``p_max = 0.97``.  On the simulated Box world mapped from ground
truth, ``p_miss`` 0.40 / 0.45 / 0.48 leaves 86 / 92 / 95 % of the wall cells
occupied and 99.6 / 99.1 / 98.2 % of the seen free space free.  Summing evidence
(clamping once at the end instead of after every update) makes the map independent
of the scan order, which suits an offline map from an optimised trajectory; a cell
never observed keeps ``L = 0``, i.e. ``p = 0.5`` (unknown).

Classification (`trinary`, the PGM): occupied when ``p > occupied_thresh`` (0.65),
free when ``p < free_thresh`` (0.196), unknown otherwise; pixels 0 (black,
occupied), 254 (free) and 205 (unknown), the values ROS map_saver writes.  With the
YAML's ``negate: 0`` a reader computes ``occ = (255 - pixel) / 255``: 1.0, 0.004 and
0.196 (just above ``free_thresh``), so ROS map_server and nav2 map_server read the
same three classes back (see `slam.map_io`).

Extent: the bounding box of the sensor positions and the (clipped) beam end points,
plus `margin_cells`, with the origin on a multiple of the resolution.  A box larger
than `max_cells` cells is mapped at a coarser resolution (the smallest integer
multiple that fits), with a warning.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from os import PathLike
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError, warn
from data.types import Scan
from slam.memory import release_free_memory

Array = NDArray[np.float64]
PathArg = str | PathLike[str]

#: Pixel values of the trinary image (ROS map_saver's).
PIXEL_OCCUPIED, PIXEL_FREE, PIXEL_UNKNOWN = 0, 254, 205


def logit(p: float) -> float:
    """``ln(p / (1 - p))`` of a probability in ``(0, 1)``."""
    return math.log(p / (1.0 - p))


@dataclass(frozen=True, slots=True)
class MapConfig:
    """Parameters of an occupancy map (see module docstring).

    Attributes:
        resolution: cell size [m].
        p_hit: occupancy probability of one hit (> 0.5).
        p_miss: occupancy probability of one pass-through (< 0.5).
        p_min, p_max: clamp of the cell probability.
        occupied_thresh: ``p`` above this is occupied (PGM black; YAML key).
        free_thresh: ``p`` below this is free (PGM white; YAML key).
        max_hit_range: returns farther than this [m] only clear free space up to it.
        no_return_range: no-return beams clear free space up to this [m] (also capped
            by the scan's max range).
        margin_cells: cells added around the bounding box of the data.
        max_cells: largest grid (rows x cols) before the resolution is coarsened.
        chunk_cells: ray-traced cells per vectorised group (bounds memory); a group
            also holds at least a quarter of the grid's cells, since counting it
            costs one pass over the grid.
    """

    resolution: float = 0.05
    p_hit: float = 0.7
    p_miss: float = 0.45
    p_min: float = 0.12
    p_max: float = 0.97
    occupied_thresh: float = 0.65
    free_thresh: float = 0.196
    max_hit_range: float = 30.0
    no_return_range: float = 5.0
    margin_cells: int = 2
    max_cells: int = 16_000_000
    chunk_cells: int = 250_000

    def __post_init__(self) -> None:
        def bad(msg: str) -> None:
            raise UserError(f"map config: {msg}")

        if not (math.isfinite(self.resolution) and self.resolution > 0):
            bad(f"resolution must be a positive number of metres, got {self.resolution}")
        if not (0.5 < self.p_hit < 1.0):
            bad(f"p_hit must be in (0.5, 1), got {self.p_hit}")
        if not (0.0 < self.p_miss < 0.5):
            bad(f"p_miss must be in (0, 0.5), got {self.p_miss}")
        if not (0.0 < self.p_min < 0.5 < self.p_max < 1.0):
            bad(f"need 0 < p_min < 0.5 < p_max < 1, got {self.p_min}, {self.p_max}")
        if not (0.0 <= self.free_thresh < self.occupied_thresh <= 1.0):
            bad(
                "need 0 <= free_thresh < occupied_thresh <= 1, got "
                f"{self.free_thresh}, {self.occupied_thresh}"
            )
        for name in ("max_hit_range", "no_return_range"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                bad(f"{name} must be a non-negative number of metres, got {v}")
        if self.margin_cells < 0 or self.max_cells < 1 or self.chunk_cells < 1:
            bad("margin_cells >= 0, max_cells >= 1 and chunk_cells >= 1 are required")

    def to_json(self) -> dict[str, Any]:
        """Plain dict of the parameters (for config.yaml)."""
        return asdict(self)


@dataclass(slots=True)
class OccupancyGrid:
    """Hit and miss counts on a regular grid (see module docstring for frames).

    Attributes:
        hits: ``(H, W)`` int32, times a beam ended in the cell; row 0 = smallest y.
        misses: ``(H, W)`` int32, times a beam passed through the cell.
        origin: ``(2,)`` map-frame position of the lower-left corner of cell (0, 0) [m].
        resolution: cell size [m].
        config: the sensor model and thresholds used to read the counts.
    """

    hits: NDArray[np.int32]
    misses: NDArray[np.int32]
    origin: Array
    resolution: float
    config: MapConfig = field(default_factory=MapConfig)

    def __post_init__(self) -> None:
        self.hits = np.asarray(self.hits, dtype=np.int32)
        self.misses = np.asarray(self.misses, dtype=np.int32)
        self.origin = np.asarray(self.origin, dtype=float).reshape(2)
        if self.hits.ndim != 2 or self.hits.shape != self.misses.shape:
            raise UserError(
                f"OccupancyGrid: hits and misses must be 2-D arrays of one shape, got "
                f"{self.hits.shape} and {self.misses.shape}"
            )

    # ------------------------------------------------------------------ geometry

    @property
    def shape(self) -> tuple[int, int]:
        """``(rows, cols)`` = ``(H, W)``."""
        return (int(self.hits.shape[0]), int(self.hits.shape[1]))

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """``(x_min, x_max, y_min, y_max)`` of the grid in the map frame [m]."""
        h, w = self.shape
        ox, oy = self.origin
        return (ox, ox + w * self.resolution, oy, oy + h * self.resolution)

    def world_to_cell(self, xy: ArrayLike) -> NDArray[np.intp]:
        """``(M, 2)`` integer ``(row, col)`` of the cells holding map points ``(M, 2)``.

        Points outside the grid get indices outside ``[0, H) x [0, W)``.
        """
        p = np.asarray(xy, dtype=float).reshape(-1, 2)
        cr = np.floor((p - self.origin) / self.resolution).astype(np.intp)
        return cr[:, ::-1].copy()

    def cell_centres(self, cells: ArrayLike) -> Array:
        """``(M, 2)`` map-frame centres [m] of cells given as ``(row, col)`` ``(M, 2)``."""
        rc = np.asarray(cells, dtype=float).reshape(-1, 2)
        return self.origin + (rc[:, ::-1] + 0.5) * self.resolution

    # ------------------------------------------------------------------ occupancy

    def log_odds(self) -> NDArray[np.float32]:
        """``(H, W)`` clamped log-odds ``hits * l(p_hit) + misses * l(p_miss)``."""
        c = self.config
        lo = np.multiply(self.hits, np.float32(logit(c.p_hit)), dtype=np.float32)
        lo += np.multiply(self.misses, np.float32(logit(c.p_miss)), dtype=np.float32)
        np.clip(lo, logit(c.p_min), logit(c.p_max), out=lo)
        return lo

    def probabilities(self) -> NDArray[np.float32]:
        """``(H, W)`` occupancy probability in ``[p_min, p_max]``; 0.5 where unobserved."""
        p = self.log_odds()  # the logistic, in place: one grid-sized array in memory
        np.negative(p, out=p)
        np.exp(p, out=p)
        p += np.float32(1.0)
        np.reciprocal(p, out=p)
        return p

    def observed(self) -> NDArray[np.bool_]:
        """``(H, W)`` cells at least one beam reached."""
        return (self.hits > 0) | (self.misses > 0)

    def occupied(self, thresh: float | None = None) -> NDArray[np.bool_]:
        """``(H, W)`` cells with ``p > thresh`` (default `MapConfig.occupied_thresh`)."""
        t = self.config.occupied_thresh if thresh is None else thresh
        return self.probabilities() > t

    def free(self, thresh: float | None = None) -> NDArray[np.bool_]:
        """``(H, W)`` cells with ``p < thresh`` (default `MapConfig.free_thresh`)."""
        t = self.config.free_thresh if thresh is None else thresh
        return self.probabilities() < t

    def trinary(self) -> NDArray[np.uint8]:
        """``(H, W)`` uint8 image, row 0 = largest y: 0 occupied, 254 free, 205 unknown."""
        p = self.probabilities()
        img = np.full(p.shape, PIXEL_UNKNOWN, dtype=np.uint8)
        img[p < self.config.free_thresh] = PIXEL_FREE
        img[p > self.config.occupied_thresh] = PIXEL_OCCUPIED
        return img[::-1].copy()


# ---------------------------------------------------------------------- building


@dataclass(slots=True)
class _Beams:
    """Flat arrays of every usable beam: sensor position, end point, hit flag."""

    start: Array  # (B, 2) sensor position in the map frame [m]
    end: Array  # (B, 2) end point (hit) or clear-up-to point (no hit) [m]
    hit: NDArray[np.bool_]  # (B,)
    sensors: Array  # (S, 2) positions of the scans with a finite pose (for the extent)


def _gather_beams(scans: Sequence[Scan], poses: Array, cfg: MapConfig) -> _Beams:
    """Every usable beam of `scans` in the map frame, by the rules of the module docstring."""
    n_beams = np.array([len(s.ranges) for s in scans], dtype=np.intp)
    ranges = np.concatenate([np.asarray(s.ranges, dtype=float) for s in scans])
    angles = np.concatenate([np.asarray(s.angles, dtype=float) for s in scans])
    if len(angles) != len(ranges):
        raise UserError("a scan has different numbers of ranges and angles")
    max_r = np.repeat([float(s.max_range) for s in scans], n_beams)
    min_r = np.repeat([max(float(s.min_range), 0.0) for s in scans], n_beams)
    scan_id = np.repeat(np.arange(len(scans)), n_beams)
    with np.errstate(invalid="ignore"):
        no_return = np.isposinf(ranges) | (np.isfinite(ranges) & (ranges >= max_r))
        ret = np.isfinite(ranges) & (ranges > min_r) & (ranges < max_r)
    ok_pose = np.all(np.isfinite(poses), axis=1)
    ret &= ok_pose[scan_id]
    no_return &= ok_pose[scan_id]
    length = np.where(ret, np.minimum(ranges, cfg.max_hit_range), 0.0)
    length = np.where(no_return, np.minimum(cfg.no_return_range, max_r), length)
    hit = ret & (ranges <= cfg.max_hit_range)
    use = (ret | no_return) & (length > 0.0)
    sid, length, hit = scan_id[use], length[use], hit[use]
    bearing = poses[sid, 2] + angles[use]
    start = poses[sid, :2]
    end = start + length[:, None] * np.column_stack([np.cos(bearing), np.sin(bearing)])
    return _Beams(start=start, end=end, hit=hit, sensors=poses[ok_pose, :2])


def _grid_frame(
    lo: Array, hi: Array, cfg: MapConfig, resolution: float
) -> tuple[Array, int, int, float]:
    """Origin, rows, cols and resolution of the grid covering ``[lo, hi]`` (module docstring)."""
    factor = 1
    while True:
        res = resolution * factor
        origin = (np.floor(lo / res) - cfg.margin_cells) * res
        cols, rows = (np.floor((hi - origin) / res) + 1 + cfg.margin_cells).astype(int)
        if rows * cols <= cfg.max_cells:
            break
        factor = max(factor + 1, math.ceil(factor * math.sqrt(rows * cols / cfg.max_cells)))
    if factor > 1:
        warn(
            f"occupancy map of {hi[0] - lo[0]:.0f} m x {hi[1] - lo[1]:.0f} m is too large at "
            f"{resolution:g} m per cell (more than {cfg.max_cells:,} cells): using {res:g} m"
        )
    return origin, int(rows), int(cols), res


_FIX_BITS = 16  # fractional bits of the fixed-point line stepping in `_trace`


def _trace(
    start: NDArray[np.intp],
    end: NDArray[np.intp],
    hit: NDArray[np.bool_],
    cols: int,
    misses: NDArray[np.int32],
    budget: int,
) -> None:
    """Add the miss counts of the Bresenham lines ``start -> end`` (cells ``(col, row)``)
    to `misses` ``(n_cells,)``, in place.

    A beam with a hit visits ``n = max(|dc|, |dr|)`` cells (its end cell excluded),
    one without ``n + 1``; step ``k`` is at ``start + floor(k * (end - start) / n + 1/2)``,
    in fixed point with `_FIX_BITS` fractional bits (exact at ``k = n``).  Beams are
    sorted by cell count and traced in groups as ``(beams, steps)`` arrays of about
    `budget` entries by broadcasting; the padding of shorter beams goes to a dummy
    cell that is dropped.
    """
    d = end - start
    n = np.abs(d).max(axis=1)
    count = n + (~hit)
    use = np.flatnonzero(count > 0)
    use = use[np.argsort(count[use], kind="stable")]
    if len(use) == 0:
        return
    n_cells = len(misses)
    count = count[use]
    k_max = int(count[-1])
    one = 1 << _FIX_BITS
    wide = k_max >= (1 << (30 - _FIX_BITS)) or n_cells >= (1 << 31) - 1
    itype = np.int64 if wide else np.int32
    slope_r = np.round(d[use, 1] * one / np.maximum(n[use], 1)).astype(itype)
    slope_c = np.round(d[use, 0] * one / np.maximum(n[use], 1)).astype(itype)
    base = (start[use, 1] * cols + start[use, 0]).astype(itype)
    steps = np.arange(k_max, dtype=itype)
    half = itype(one // 2)
    i, n_beams = 0, len(use)
    while i < n_beams:
        # Group [i, j): its longest beam (sorted: the last) times its size fits the budget.
        j = min(n_beams, i + max(1, budget // int(count[i])))
        width = int(count[j - 1])
        j = min(j, i + max(1, budget // width))
        width = int(count[j - 1])
        k = steps[None, :width]
        row = k * slope_r[i:j, None]
        row += half
        row >>= _FIX_BITS  # arithmetic shift: floor
        row *= cols
        flat = k * slope_c[i:j, None]
        flat += half
        flat >>= _FIX_BITS
        flat += row
        flat += base[i:j, None]
        flat[k >= count[i:j, None]] = n_cells
        _add_counts(misses, flat.ravel())
        i = j


_BAND_CELLS = 1 << 20  # cells counted per `np.bincount` of `_add_counts` (8 MB of int64)


def _add_counts(counts: NDArray[np.int32], flat: NDArray[np.integer]) -> None:
    """``counts[c] += (number of c in flat)``, in place; indices outside ``counts`` (the
    padding cell) are dropped.  Grids larger than `_BAND_CELLS` are counted in bands
    of that many cells, so the count's transient never holds a whole large grid."""
    n_cells = len(counts)
    for lo in range(0, n_cells, _BAND_CELLS):
        hi = min(lo + _BAND_CELLS, n_cells)
        sel = flat if lo == 0 and hi == n_cells else flat[(flat >= lo) & (flat < hi)] - lo
        counts[lo:hi] += np.bincount(sel, minlength=hi - lo + 1)[: hi - lo]


def build_occupancy_grid(
    scans: Iterable[Scan],
    poses: ArrayLike,
    resolution: float | None = None,
    *,
    config: MapConfig | None = None,
) -> OccupancyGrid:
    """Occupancy grid of `scans` taken at sensor `poses` (rules in the module docstring).

    Args:
        scans: the scans; ranges and bearings in their sensor frame.
        poses: ``(N, 3)`` sensor poses ``(x, y, theta)`` in the map frame, one per scan.
            Scans whose pose is not finite are skipped (with one warning).
        resolution: cell size [m]; overrides `config.resolution`.
        config: sensor model, thresholds and limits (default `MapConfig()`).

    Raises:
        UserError: no scans, or a pose count that differs from the scan count.
    """
    cfg = config or MapConfig()
    if resolution is not None:
        cfg = MapConfig(**{**cfg.to_json(), "resolution": float(resolution)})
    scan_list = list(scans)
    p = np.asarray(poses, dtype=float)
    if not scan_list:
        raise UserError("no scans to build an occupancy map from")
    if p.ndim != 2 or p.shape[1] != 3 or len(p) != len(scan_list):
        raise UserError(
            f"occupancy map needs one (x, y, theta) pose per scan: {len(scan_list)} scans, "
            f"poses of shape {p.shape}"
        )
    bad_pose = ~np.all(np.isfinite(p), axis=1)
    if bad_pose.all():
        raise UserError("occupancy map: no scan has a finite pose")
    if bad_pose.any():
        warn(f"occupancy map: skipped {int(bad_pose.sum())} scans with non-finite poses")
    # Two passes over chunks of scans bound the memory: the extent, then the counts.
    chunks = _chunks(scan_list)
    lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
    for a, b in chunks:
        beams = _gather_beams(scan_list[a:b], p[a:b], cfg)
        pts = np.vstack([beams.sensors, beams.end])
        if len(pts):
            lo, hi = np.minimum(lo, pts.min(axis=0)), np.maximum(hi, pts.max(axis=0))
    origin, rows, cols, res = _grid_frame(lo, hi, cfg, cfg.resolution)
    if res != cfg.resolution:
        cfg = MapConfig(**{**cfg.to_json(), "resolution": res})
    n_cells = rows * cols
    hits = np.zeros(n_cells, dtype=np.int32)
    misses = np.zeros(n_cells, dtype=np.int32)
    for a, b in chunks:
        beams = _gather_beams(scan_list[a:b], p[a:b], cfg)
        start = np.floor((beams.start - origin) / res).astype(np.intp)
        end = np.floor((beams.end - origin) / res).astype(np.intp)
        end_flat = end[beams.hit, 1] * cols + end[beams.hit, 0]
        _add_counts(hits, end_flat)
        _trace(start, end, beams.hit, cols, misses, max(cfg.chunk_cells, n_cells // 4))
        release_free_memory()  # the chunk's transients, not resident under the next chunk
    shape = (rows, cols)
    return OccupancyGrid(
        hits=hits.reshape(shape),
        misses=misses.reshape(shape),
        origin=origin,
        resolution=res,
        config=cfg,
    )


_CHUNK_BEAMS = 50_000  # beams gathered at a time by `build_occupancy_grid`


def _chunks(scans: Sequence[Scan]) -> list[tuple[int, int]]:
    """``[(a, b), ...]`` ranges of scans holding about `_CHUNK_BEAMS` beams each."""
    ends = np.cumsum([len(s.ranges) for s in scans])
    cuts = np.searchsorted(ends, np.arange(1, 1 + int(ends[-1]) // _CHUNK_BEAMS) * _CHUNK_BEAMS)
    edges = np.unique(np.concatenate([[0], cuts + 1, [len(scans)]]).clip(0, len(scans)))
    return [(int(a), int(b)) for a, b in itertools.pairwise(edges)]

