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

It does not change when the object turns on the table (rings about the centroid),
when it is mirrored, or when it is scaled (depths and radii are divided by the
object's own size).  Distance of two reliefs: the mean absolute difference
``1/K sum_k |R[k] - R'[k]|`` (unitless).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import DataError, UserError

Array = NDArray[np.float64]

#: Rings of the relief.
RELIEF_RINGS = 8
#: Radius (in units of the footprint's RMS radius) the rings cover; beyond it, the last.
RELIEF_REACH = 2.0
#: Percentile of the heights taken as the object's top.
TOP_PERCENTILE = 98.0


@dataclass(frozen=True, slots=True)
class ReliefConfig:
    """Parameters of the relief (module docstring).

    Attributes:
        rings: number of rings ``K``.
        reach: the rings split ``rho`` in ``[0, reach)`` evenly (RMS radii).
        top_percentile: percentile of the heights that is the object's top [%].
    """

    rings: int = RELIEF_RINGS
    reach: float = RELIEF_REACH
    top_percentile: float = TOP_PERCENTILE

    def __post_init__(self) -> None:
        if self.rings < 1:
            raise UserError(f"relief rings must be at least 1, got {self.rings}")
        if not self.reach > 0:
            raise UserError(f"relief reach must be positive, got {self.reach}")
        if not 0.0 < self.top_percentile <= 100.0:
            raise UserError(f"top percentile must be in (0, 100], got {self.top_percentile}")


@dataclass(frozen=True, slots=True)
class StripeRelief:
    """One object's relief: ``(K,)`` mean depths per ring (unitless), and a name."""

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
    total = np.bincount(ring, weights=depth, minlength=cfg.rings)
    return StripeRelief(np.where(count > 0, total / np.maximum(count, 1), 0.0), name)


class ReliefDatabase:
    """Many objects' reliefs, queried in one vectorised pass.

    Args:
        reliefs: one `StripeRelief` per object, all with the same ring count.
    """

    def __init__(self, reliefs: Sequence[StripeRelief]) -> None:
        self.reliefs = list(reliefs)
        shapes = {r.relief.shape for r in self.reliefs}
        if len(shapes) > 1:
            raise UserError(f"every relief must have one shape, got {sorted(shapes)}")
        self.stack = (np.stack([r.relief for r in self.reliefs]) if self.reliefs
                      else np.zeros((0, RELIEF_RINGS)))

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
