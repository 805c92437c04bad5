"""The relief: how far an object's scanned surface lies below its top, ring by ring.

Paper: "Stripes-based Object Matching" (``papers/stripes-object-matching.txt``).  The
paper reads each stripe's shape in pixels and drops the heights the scanner measures
("the calculated distance values are not needed"); it is silent on how the stripes of
one object relate to each other in height.  This module is a third signal on the same
stripes, beside the paper's descriptor and the stripe profile (`profile`): the
stripes' rows turned into heights above the table (the scanner's calibration, e.g.
`data.stripe_scanner.StripeScan.height_map`) and read as one top view.

Why: the stripe profile describes every stripe in units of its own width (so a flat
box top, a Lego brick's studded top and a can's lid give nearly the same stripes) and
shape context reads only the footprint's outline; neither says how deep the visible
surface falls below the object's top relative to its size: zero over a box, a few
per cent over studs and lids, a dome's steady fall towards the rim, a cup's hollow.
Measured on real scanned meshes (YCB) the relief repeats over the members of a class
of different sizes (balls, stacking cups) and separates classes that the other two
signals confuse (Lego bricks against food boxes).

Definition.  Input: heights ``z`` [m] on a top-view grid (rows along the sweep, cell
``(row_m, column_m)`` metres apart; NaN where nothing was seen).  With ``A`` the seen
area (cells times cell area), ``r_eq = sqrt(A / pi)`` (the radius of a disc of the same
area), ``top`` the `ReliefConfig.top_percentile` percentile of the heights (robust to a
few outlying pixels) and ``(x, y)`` the cell centres in metres:

- depth of a cell ``q = max(top - z, 0) / r_eq`` (unitless: a size-free depth);
- radius of a cell ``rho = |(x, y) - c| / r_rms`` with ``c`` the centroid of the seen
  cells and ``r_rms`` their root-mean-square distance to it (unitless; a disc has
  ``rho <= sqrt(2)``);
- ring ``k`` (``k = 0 .. K-1``, ``K`` = `ReliefConfig.rings`) holds the cells with
  ``k <= rho K / reach < k + 1`` (``reach`` = `ReliefConfig.reach`; the last ring also
  holds every cell beyond); the relief is ``R[k]`` = the mean depth ``q`` of ring
  ``k``, 0 for a ring without cells (the footprint does not reach it).

The fine relief (a second ring vector beside ``R``, in millimetres at a fixed
physical scale): the size-free depth ``q`` makes a large studded baseplate (studs a few
millimetres deep over a footprint of 15 cm) as flat as a box top, whose depth is the
scanner's noise, because both divide by the footprint.  Surface texture has an absolute
size (a stud, a lid's rim, a ridge), so the fine relief keeps it:

- local top of a cell ``t = max z`` over the seen cells in the square of side ``w``
  (`ReliefConfig.fine_window` [m]) centred on it, aligned with the grid (`local_top`);
- fine depth ``f = min(t - z, c) / c`` (``c`` = `ReliefConfig.fine_cap` [m]; unitless,
  in [0, 1]): 0 on a flat top and on any surface whose slope is small over ``w``,
  growing with texture up to ``c`` deep; deeper falls (a cup's hollow, a ball's rim)
  saturate at 1 and are left to ``R``;
- ``F[k]`` = the mean ``f`` of ring ``k`` (same rings as ``R``).

The descriptor is ``[R, F]`` (``2K`` values; ``R`` alone with ``fine_window = 0``).
The window spans the gaps between studs and ridges a few millimetres apart and the cap
keeps texture apart from shape (a few millimetres against the centimetres a dome or
hollow falls).

``R`` does not change when the object turns on the table (rings about the centroid),
when it is mirrored, or when it is scaled (depths and radii are divided by the
object's own size); ``F`` changes with turns only as far as the grid-aligned square
covers other cells (the square's corners reach ``sqrt(2) w / 2``, its sides ``w / 2``),
not with mirrors, and, on purpose, does with size.  Distance of two reliefs: the mean
absolute difference over the ring values,
``1/(2K) sum_k (|R[k] - R'[k]| + |F[k] - F'[k]|)`` (unitless).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import maximum_filter

from data.errors import DataError, UserError

Array = NDArray[np.float64]

#: Rings of the relief.
RELIEF_RINGS = 8
#: Radius (in units of the footprint's RMS radius) the rings cover; beyond it, the last.
RELIEF_REACH = 2.0
#: Percentile of the heights taken as the object's top.
TOP_PERCENTILE = 98.0
#: Side of the fine relief's local-top square [m] (module docstring).
FINE_WINDOW = 0.012
#: Depth at which the fine relief saturates [m] (module docstring).
FINE_CAP = 0.010


@dataclass(frozen=True, slots=True)
class ReliefConfig:
    """Parameters of the relief (module docstring).

    Attributes:
        rings: number of rings ``K``.
        reach: the rings split ``rho`` in ``[0, reach)`` evenly (RMS radii).
        top_percentile: percentile of the heights that is the object's top [%].
        fine_window: side of the fine relief's local-top square [m]; 0: no fine
            relief (the descriptor is ``R`` alone).
        fine_cap: depth at which the fine relief saturates [m].
    """

    rings: int = RELIEF_RINGS
    reach: float = RELIEF_REACH
    top_percentile: float = TOP_PERCENTILE
    fine_window: float = FINE_WINDOW
    fine_cap: float = FINE_CAP

    def __post_init__(self) -> None:
        if self.rings < 1:
            raise UserError(f"relief rings must be at least 1, got {self.rings}")
        if not self.reach > 0:
            raise UserError(f"relief reach must be positive, got {self.reach}")
        if not 0.0 < self.top_percentile <= 100.0:
            raise UserError(f"top percentile must be in (0, 100], got {self.top_percentile}")
        if self.fine_window < 0:
            raise UserError(f"fine window must be >= 0, got {self.fine_window}")
        if not self.fine_cap > 0:
            raise UserError(f"fine cap must be positive, got {self.fine_cap}")


@dataclass(frozen=True, slots=True)
class StripeRelief:
    """One object's relief: ``(2K,)`` mean depths per ring, ``[R, F]`` (unitless; ``(K,)``
    ``R`` alone without the fine relief), and a name."""

    relief: Array
    name: str | None = None


def describe_relief(
    heights: ArrayLike,
    cell: tuple[float, float],
    config: ReliefConfig | None = None,
    name: str | None = None,
) -> StripeRelief:
    """The relief of one object's top view (module docstring).

    Args:
        heights: ``(rows, columns)`` heights above the table [m]; NaN where nothing
            was seen.
        cell: ``(row_m, column_m)`` spacing of the rows and of the columns [m].
        config: relief parameters.
        name: object identifier used in messages.

    Raises:
        DataError: no finite height.
        UserError: a cell spacing that is not positive.
    """
    cfg = config or ReliefConfig()
    z = np.asarray(heights, dtype=float)
    dy, dx = (float(c) for c in cell)
    if not (dy > 0 and dx > 0):
        raise UserError(f"cell spacing must be positive, got {cell}")
    rows, cols = np.nonzero(np.isfinite(z))
    if len(rows) == 0:
        raise DataError(name, "no height seen: the object has no relief")
    h = z[rows, cols]
    r_eq = np.sqrt(len(h) * dx * dy / np.pi)
    depth = np.maximum(np.percentile(h, cfg.top_percentile) - h, 0.0) / r_eq
    x, y = cols * dx, rows * dy
    rad = np.hypot(x - x.mean(), y - y.mean())
    rms = np.sqrt(np.mean(rad**2))
    rho = rad / rms if rms > 0 else np.zeros_like(rad)
    ring = np.minimum((rho * cfg.rings / cfg.reach).astype(np.int64), cfg.rings - 1)
    count = np.bincount(ring, minlength=cfg.rings)

    def ring_means(values: Array) -> Array:
        total = np.bincount(ring, weights=values, minlength=cfg.rings)
        return np.where(count > 0, total / np.maximum(count, 1), 0.0)

    coarse = ring_means(depth)
    if cfg.fine_window == 0:
        return StripeRelief(coarse, name)
    r0, c0 = rows.min(), cols.min()  # the seen cells' bounding box: an exact crop
    box = z[r0:rows.max() + 1, c0:cols.max() + 1]
    top = local_top(box, (dy, dx), cfg.fine_window)[rows - r0, cols - c0]
    fine = np.minimum(top - h, cfg.fine_cap) / cfg.fine_cap
    return StripeRelief(np.concatenate([coarse, ring_means(fine)]), name)


def local_top(heights: ArrayLike, cell: tuple[float, float], window: float) -> Array:
    """Highest seen height in the square of side `window` [m] centred on every cell
    (axis-aligned on the ``(row_m, column_m)`` grid `cell`, an odd number of cells per
    side, at least one) [m].  NaN cells are never the top; a cell whose square holds
    no seen cell gets -inf.  A square, not a disc: the maximum filter is separable (one
    pass per axis), a disc's is not and costs the square of the window in cells."""
    z = np.asarray(heights, dtype=float)
    dy, dx = (float(c) for c in cell)
    size = (2 * int(window / 2 / dy) + 1, 2 * int(window / 2 / dx) + 1)
    return maximum_filter(np.where(np.isfinite(z), z, -np.inf), size=size,
                          mode="constant", cval=-np.inf)


class ReliefDatabase:
    """Many objects' reliefs, queried in one vectorised pass.

    Args:
        reliefs: one `StripeRelief` per object, all with the same length (ring count
            and fine relief or not).
    """

    def __init__(self, reliefs: Sequence[StripeRelief]) -> None:
        self.reliefs = list(reliefs)
        shapes = {r.relief.shape for r in self.reliefs}
        if len(shapes) > 1:
            raise UserError(f"every relief must have one shape, got {sorted(shapes)}")
        self.stack = (np.stack([r.relief for r in self.reliefs]) if self.reliefs
                      else np.zeros((0, 2 * RELIEF_RINGS)))

    def __len__(self) -> int:
        return len(self.reliefs)

    def distances(self, query: StripeRelief) -> Array:
        """``(M,)`` mean absolute ring differences of the query to every object."""
        q = np.asarray(query.relief, dtype=float)
        if q.shape != self.stack.shape[1:]:
            raise UserError(f"query relief has shape {q.shape}, the database "
                            f"{self.stack.shape[1:]}")
        return np.abs(self.stack - q[None]).mean(axis=1)

    def pairwise(self) -> Array:
        """``(M, M)`` distances (symmetric, zero diagonal)."""
        s = self.stack
        return np.abs(s[:, None] - s[None]).mean(axis=2)
