"""Correlative scan matching: an exhaustive search of (x, y, theta) over a likelihood grid.

The prior-free geometric check (`loopclosure.geometric_check`, ``method =
"correlative"``) must find the pose of a query submap in a candidate's submap from
heading hypotheses alone.  Instead of ICP from many starts it scores every pose of
a lattice, as the correlative scan matcher of Olson (ICRA 2009) and the
exhaustive level of Cartographer's matcher (Hess et al., ICRA 2016) do:

    score(x, y, theta) = (1 / N) sum_i L(R(theta) p_i + (x, y))                  (1)

with ``p_i`` the N query points (query sensor frame [m]) and L the likelihood grid
of the candidate's submap (`LikelihoodGrid`, candidate sensor frame): for the
distance ``d`` [m] from a cell centre to the nearest candidate point (Euclidean
distance transform of the occupied cells, `scipy.ndimage.distance_transform_edt`),

    L = max(0, 1 - (d / sigma)^2)                                               (2)

the truncated quadratic of `loopclosure.registration`'s fitness, with a width
`sigma` [m] that covers the lattice step.  The grid has square cells of side
`resolution` [m]; a point scores the cell it falls in (no interpolation); L is
stored to 1/255.

Lattice (`search`): translations on a square of cells ``(x, y) = (i, j) * step``
with ``|i|, |j| <= radius / step`` about translation 0 (the sensor of a revisit is
within a couple of metres of the candidate's: the window is the loop detector's
``max_distance``), ``step`` a whole number of cells; headings every `angle_step`
[rad] within `angle_window` of each heading hypothesis (`loopclosure.headings`'
convention: the heading of the query in the candidate's frame).  Every pose is
scored (no pruning), in one compiled loop (numba, ``cache=True``) over headings,
points and translations: ``A * N * T^2`` grid reads.

`peaks` returns the best poses that are distinct (more than `separation` [m] or
`angle_separation` [rad] from every better one): the starts of the final ICP and
the runner-up of the ambiguity test.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from data import se2

Array = NDArray[np.float64]


class LikelihoodGrid:
    """The likelihood (2) of a submap on a square grid, candidate frame.

    Stored as ``uint8`` in units of 1/255 (a submap's grids stay in memory with its
    registration target; a 30 m x 30 m submap at 0.1 m takes 90 kB a grid).

    Attributes:
        values: ``(H, W)`` uint8 likelihood times 255, rounded; row = y, column = x.
        origin: ``(2,)`` (x, y) [m] of the lower-left corner of cell (0, 0).
        resolution: cell side [m].
        sigma: width of the truncated quadratic (2) [m].
    """

    __slots__ = ("origin", "resolution", "sigma", "values")

    def __init__(self, points: ArrayLike, resolution: float, sigma: float,
                 pad: float = 1.0) -> None:
        self.resolution = float(resolution)
        self.sigma = float(sigma)
        self.origin, distance = _distance(points, resolution, pad)
        self.values = _quantised(distance, sigma)

    @classmethod
    def widths(cls, points: ArrayLike, resolution: float, sigmas: ArrayLike,
               pad: float = 1.0) -> list[LikelihoodGrid]:
        """One grid per width in `sigmas` [m], from one distance transform."""
        origin, distance = _distance(points, resolution, pad)
        out = []
        for sigma in np.atleast_1d(np.asarray(sigmas, dtype=float)):
            grid = object.__new__(cls)
            grid.origin, grid.resolution, grid.sigma = origin, float(resolution), float(sigma)
            grid.values = _quantised(distance, sigma)
            out.append(grid)
        return out

    def likelihood(self) -> NDArray[np.float64]:
        """``(H, W)`` the likelihood (2) as floats in [0, 1]."""
        return self.values / 255.0


def _distance(points: ArrayLike, resolution: float, pad: float) -> tuple[Array, Array]:
    """Grid origin [m] and the distance [m] of every cell centre to the nearest
    occupied cell centre (inf everywhere when there are no points)."""
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(pts) == 0:
        return np.zeros(2), np.full((1, 1), np.inf)
    lo = pts.min(axis=0) - pad
    hi = pts.max(axis=0) + pad
    shape = np.ceil((hi - lo) / resolution).astype(int) + 1
    cells = np.floor((pts - lo) / resolution).astype(np.int64)
    free = np.ones((shape[1], shape[0]), bool)
    free[cells[:, 1], cells[:, 0]] = False
    return lo, ndimage.distance_transform_edt(free) * resolution


def _quantised(distance: Array, sigma: float) -> NDArray[np.uint8]:
    with np.errstate(invalid="ignore"):
        value = np.clip(1.0 - (distance / sigma) ** 2, 0.0, 1.0)
    return np.rint(255.0 * np.nan_to_num(value)).astype(np.uint8)


@numba.njit(cache=True)
def _correlate(px, py, angles, grid, split, x0, y0, inv_res, half, step, out):  # pragma: no cover
    """``(A, T, T)`` the means (1) over the points, their sums accumulated in the zeroed
    integer `out` of that shape, T = 2 half + 1;
    [a, j, i] = angle a, y shift j - half, x shift i - half (in lattice steps); `x0`,
    `y0`: the grid origin minus the lattice centre [m].  `split` ``(step, H,
    ceil(W / step))``: the grid's columns by their remainder modulo `step`,
    ``split[r, y, q] = grid[y, q step + r]`` (0 past the last column), so that a
    point's x shifts read one contiguous run.

    The sums are of whole numbers (the grid's uint8 values) in an integer `out`,
    exact in any order: a point whose whole window of shifts lies inside the grid is
    summed from `split` without bounds tests, the others cell by cell with them."""
    h, w = grid.shape
    t = 2 * half + 1
    reach = half * step
    for a in range(len(angles)):
        c = np.cos(angles[a])
        s = np.sin(angles[a])
        acc = out[a]
        for k in range(len(px)):
            x = c * px[k] - s * py[k]
            y = s * px[k] + c * py[k]
            ix = int(np.floor((x - x0) * inv_res))
            iy = int(np.floor((y - y0) * inv_res))
            if ix - reach >= 0 and ix + reach < w and iy - reach >= 0 and iy + reach < h:
                first = ix - reach
                part = split[first % step]
                q0 = first // step
                for j in range(t):
                    row = part[iy + (j - half) * step, q0:q0 + t]
                    dst = acc[j]
                    for i in range(t):  # contiguous: vectorised by the compiler
                        dst[i] += row[i]
                continue
            if ix + reach < 0 or ix - reach >= w or iy + reach < 0 or iy - reach >= h:
                continue  # the whole window off the grid: nothing to add
            for j in range(t):
                gy = iy + (j - half) * step
                if gy < 0 or gy >= h:
                    continue
                for i in range(t):
                    gx = ix + (i - half) * step
                    if 0 <= gx < w:
                        acc[j, i] += grid[gy, gx]
    return out / (255.0 * len(px))


def _split_columns(values: NDArray[np.uint8], step: int) -> NDArray[np.uint8]:
    """``(step, H, ceil(W / step))``: ``[r, y, q] = values[y, q step + r]``, 0 past W."""
    h, w = values.shape
    if step == 1:
        return values[None]
    width = -(-w // step)
    padded = np.zeros((h, width * step), dtype=np.uint8)
    padded[:, :w] = values
    return np.ascontiguousarray(padded.reshape(h, width, step).transpose(2, 0, 1))


@dataclass(slots=True)
class SearchResult:
    """Scores (1) of every lattice pose.

    Attributes:
        scores: ``(A, T, T)`` mean likelihood, [angle, y index, x index].
        angles: ``(A,)`` headings [rad].
        shifts: ``(T,)`` translations [m] of the lattice along x and along y, about
            `centre`.
        centre: ``(2,)`` centre of the translation square [m].
    """

    scores: Array
    angles: Array
    shifts: Array
    centre: Array

    def pose(self, flat: int) -> Array:
        """``(3,)`` pose (x, y, theta) of the lattice pose with flat index `flat`."""
        a, j, i = np.unravel_index(flat, self.scores.shape)
        return np.array([self.centre[0] + self.shifts[i], self.centre[1] + self.shifts[j],
                         self.angles[a]])


def search_angles(headings: ArrayLike, window: float, step: float) -> Array:
    """Headings [rad] every `step` within `window` of any hypothesis, on one lattice.

    The lattice is ``k * step`` (k integer), so nearby hypotheses share their angles;
    wrapped to [-pi, pi), sorted, unique.
    """
    h = np.atleast_1d(np.asarray(headings, dtype=float))
    if len(h) == 0:
        h = np.zeros(1)
    n = int(np.ceil(window / step))
    k = np.round(h / step).astype(np.int64)[:, None] + np.arange(-n, n + 1)[None, :]
    return np.unique(np.round(se2.wrap_angle(k.ravel() * step), 12))


def search(
    points: ArrayLike,
    grid: LikelihoodGrid,
    angles: ArrayLike,
    radius: float,
    step_cells: int,
    centre: ArrayLike = (0.0, 0.0),
) -> SearchResult:
    """Score (1) at every pose of the lattice (module docstring).

    Args:
        points: ``(N, 2)`` query points [m], query sensor frame.
        grid: the candidate's `LikelihoodGrid`.
        angles: ``(A,)`` headings [rad] (e.g. `search_angles`).
        radius: half side of the translation square about `centre` [m].
        step_cells: translation step in grid cells (step = step_cells * resolution).
        centre: ``(2,)`` centre of the translation square [m] (candidate frame).
    """
    c0 = np.asarray(centre, dtype=float).reshape(2)
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    ang = np.asarray(angles, dtype=float).reshape(-1)
    step = step_cells * grid.resolution
    half = int(np.floor(radius / step + 1e-9))
    shifts = np.arange(-half, half + 1) * step
    if len(pts) == 0 or len(ang) == 0:
        return SearchResult(np.zeros((len(ang), len(shifts), len(shifts))), ang, shifts, c0)
    # Cell of a point moved by a shift of whole cells = its cell shifted: exact.
    split = _split_columns(grid.values, int(step_cells))  # a copy of the grid: microseconds
    # int32 holds any sum of fewer than 2^31 / 255 points of at most 255.
    kind = np.int32 if 255 * len(pts) < 2**31 else np.int64
    means = _correlate(pts[:, 0].copy(), pts[:, 1].copy(), ang, grid.values, split,
                      float(grid.origin[0] - c0[0]), float(grid.origin[1] - c0[1]),
                      1.0 / grid.resolution, half, int(step_cells),
                      np.zeros((len(ang), len(shifts), len(shifts)), dtype=kind))
    return SearchResult(means, ang, shifts, c0)


def peaks(result: SearchResult, count: int, separation: float,
          angle_separation: float) -> tuple[Array, Array]:
    """The `count` best lattice poses, each more than `separation` [m] or
    `angle_separation` [rad] away from every better one (greedy non-maximum
    suppression, best first; vectorised over the lattice).

    Returns ``(poses (k, 3), scores (k,))``, k <= count.
    """
    s = result.scores.copy()
    if s.size == 0:
        return np.zeros((0, 3)), np.zeros(0)
    da = np.abs(se2.wrap_angle(result.angles[:, None] - result.angles[None, :]))
    sh = result.shifts
    poses, scores = [], []
    for _ in range(count):
        flat = int(np.argmax(s))
        best = float(s.ravel()[flat])
        if not np.isfinite(best):
            break
        a, j, i = np.unravel_index(flat, s.shape)
        poses.append(result.pose(flat))
        scores.append(best)
        near = np.hypot(sh[None, :] - sh[i], sh[:, None] - sh[j]) <= separation  # (y, x)
        s[da[a] <= angle_separation] = np.where(near, -np.inf, s[da[a] <= angle_separation])
    return np.array(poses).reshape(-1, 3), np.array(scores)
