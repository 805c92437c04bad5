"""The canonical profile: virtual stripes cut along the footprint's long axis.

Paper: "Stripes-based Object Matching" (``papers/stripes-object-matching.txt``).  The
paper's stripes are the laser lines the scanner happens to draw: their direction is
the sweep's, so the same object placed at another yaw on the table gives other
stripes, and the stripe profile (`profile`) moves with it (a long box swept along its
length and across it are two different profiles).  The paper is silent on the
object's orientation under the laser.  This module cuts the object into *virtual*
stripes in a frame of its own, so the description does not depend on the scan
direction nor on the object's yaw.

Definition.  Input: heights ``z`` [m] on a top-view grid (rows along the sweep, cell
``(row_m, column_m)`` metres apart; NaN where nothing was seen), e.g.
`data.stripe_scanner.StripeScan.height_map`.  Seen cells are points ``(x, y) =
(column * column_m, row * row_m)`` [m] in the table plane:

1. Footprint frame: ``c`` the mean of the points, ``e_u`` the eigenvector of the
   largest eigenvalue of their 2 x 2 covariance (the long, principal axis; in closed
   form, `footprint_frame`), ``e_v`` perpendicular; ``u = (p - c) . e_u``,
   ``v = (p - c) . e_v`` [m].
2. Length: ``[u_lo, u_hi]`` the `CanonicalConfig.trim` and ``100 - trim`` percentiles
   of ``u`` (a few stray cells do not stretch it), ``L = u_hi - u_lo``; virtual stripe
   ``k = floor(K (u - u_lo) / L)`` clipped to ``0 .. K-1`` (``K`` =
   `CanonicalConfig.samples`).
3. Per virtual stripe (one `numpy.bincount` pass over the cells, no loop over
   stripes), with ``n_k`` its cells, ``top`` the `CanonicalConfig.top_percentile`
   percentile of all heights and ``W = A / L`` the mean width (``A`` the seen area):

   - ``w_k = n_k / mean_k n_k``: its width relative to the object's mean width (the
     virtual counterpart of Eq. 3's ``l``);
   - ``h_k = mean z / top``: its mean height relative to the object's top (1 for a
     box's flat top, pi/4 across a lying cylinder);
   - ``o_k = |mean v| / W``: how far its centre lies off the long axis, in mean
     widths (a banana's bend; 0 for a box or a can);

   every feature is 0 in a virtual stripe without cells.  (Each stripe's highest
   point over the top was tried as a fourth feature on the YCB sets and dropped: it
   repeats ``h`` and carries stray cells.)

The profile is the ``(K, 3)`` array ``[w, h, o]``: unitless, so free of the
object's size; free of its yaw and of the sweep direction (the frame is the
footprint's own), of a mirror (``|mean v|``) and, up to the sign of ``e_u``, which
the distance takes both ways, of the object being turned round.  Footprints with
two nearly equal principal moments (a square, a disc) have no stable long axis; a
disc's profile does not depend on it, a square's does (cut along a side or a
diagonal).

Distance of two profiles (as `profile.ProfileDatabase`): per feature ``f`` the mean
absolute difference over the ``K`` virtual stripes, divided by its median over the
database for this query, averaged over the features; the smaller of the profile
against the other and against the other reversed.  `CanonicalDatabase` does it for
every object at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import DataError, UserError
from loopclosure.stripes.profile import ProfileDatabase

Array = NDArray[np.float64]

#: Virtual stripes per object.
CANONICAL_SAMPLES = 16
#: Percentile trimmed at each end of the long axis [%].
CANONICAL_TRIM = 0.5
#: Percentile of the heights taken as the object's top [%] (as the relief's).
CANONICAL_TOP = 98.0
#: Names of the profile's features, in column order.
CANONICAL_FEATURES: tuple[str, str, str] = ("w", "h", "o")


@dataclass(frozen=True, slots=True)
class CanonicalConfig:
    """Parameters of the canonical profile (module docstring).

    Attributes:
        samples: virtual stripes ``K``.
        trim: percentile cut off each end of the long axis [%].
        top_percentile: percentile of the heights that is the object's top [%].
    """

    samples: int = CANONICAL_SAMPLES
    trim: float = CANONICAL_TRIM
    top_percentile: float = CANONICAL_TOP

    def __post_init__(self) -> None:
        if self.samples < 2:
            raise UserError(f"canonical samples must be at least 2, got {self.samples}")
        if not 0.0 <= self.trim < 50.0:
            raise UserError(f"canonical trim must be in [0, 50), got {self.trim}")
        if not 0.0 < self.top_percentile <= 100.0:
            raise UserError(f"top percentile must be in (0, 100], got {self.top_percentile}")


@dataclass(frozen=True, slots=True)
class CanonicalProfile:
    """One object's canonical profile.

    Attributes:
        profile: ``(K, 3)`` float64, row k = ``[w, h, o]`` of virtual stripe k
            (unitless, module docstring).
        length: the footprint's length ``L`` along its long axis [m].
        width: its mean width ``W = A / L`` [m].
        name: optional identifier used in messages.
    """

    profile: Array
    length: float
    width: float
    name: str | None = None


def footprint_frame(x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
    """``(u, v)`` [m]: the points ``(x, y)`` [m] (each ``(N,)``) in the frame of their
    principal axes, centred on their mean, ``u`` along the long axis (module docstring,
    step 1).

    The long axis is at the angle ``theta = atan2(2 s_xy, s_xx - s_yy) / 2`` from x, with
    ``s`` the central second moments of the points (the eigenvector of the largest
    eigenvalue of their covariance, in closed form):
    ``u = dx cos(theta) + dy sin(theta)``, ``v = -dx sin(theta) + dy cos(theta)``.

    The three moments are `numpy.einsum` sums of products, not ``@``: a 1-D ``@`` is a
    BLAS dot product, whose threads wait for busy cores (many times the arithmetic's
    cost on a shared machine); einsum's own loop has no threads (its summation order
    differs from BLAS's in the last bits).
    """
    dx = np.asarray(x, dtype=float)
    dy = np.asarray(y, dtype=float)
    dx = dx - dx.mean()
    dy = dy - dy.mean()
    sxy = np.einsum("i,i->", dx, dy)
    sxx = np.einsum("i,i->", dx, dx)
    syy = np.einsum("i,i->", dy, dy)
    theta = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    c, s = np.cos(theta), np.sin(theta)
    return dx * c + dy * s, dy * c - dx * s


def cut_profile(
    u: ArrayLike, v: ArrayLike, z: ArrayLike, cell_area: float,
    config: CanonicalConfig | None = None,
) -> tuple[Array, float, float]:
    """The virtual stripes of points in the footprint frame (module docstring, steps
    2-3): ``(profile (K, 3), L [m], W [m])``.

    `u`, `v` [m] from `footprint_frame`, `z` [m] the heights; all ``(N,)``, one entry
    per seen cell of area `cell_area` [m^2].  One `numpy.bincount` pass per feature
    over the cells, no loop over virtual stripes.
    """
    cfg = config or CanonicalConfig()
    u, v, z = (np.asarray(a, dtype=float) for a in (u, v, z))
    count = cfg.samples
    lo, hi = np.percentile(u, [cfg.trim, 100.0 - cfg.trim])
    length = float(hi - lo)
    if length > 0:
        k = np.clip(((u - lo) * (count / length)).astype(np.int64), 0, count - 1)
    else:  # one line of cells across: a single virtual stripe holds them all
        k = np.zeros(len(u), dtype=np.int64)
        length = float(np.sqrt(cell_area))
    n = np.bincount(k, minlength=count).astype(float)
    safe = np.maximum(n, 1.0)
    top = float(np.percentile(z, cfg.top_percentile))
    top = top if top > 0 else (float(np.max(np.abs(z))) or 1.0)
    width = len(u) * cell_area / length
    w = n / n.mean()
    h = np.bincount(k, weights=z, minlength=count) / safe / top
    o = np.abs(np.bincount(k, weights=v, minlength=count) / safe) / width
    return np.column_stack([w, h, o]), length, width


def describe_canonical(
    heights: ArrayLike,
    cell: tuple[float, float],
    config: CanonicalConfig | None = None,
    name: str | None = None,
) -> CanonicalProfile:
    """The canonical profile of one object's top view (module docstring).

    Args:
        heights: ``(rows, columns)`` heights above the table [m]; NaN where nothing
            was seen.
        cell: ``(row_m, column_m)`` spacing of the rows and of the columns [m].
        config: canonical-profile parameters.
        name: object identifier used in messages.

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
        raise DataError(name, "no height seen: the object has no canonical profile")
    u, v = footprint_frame(cols * dx, rows * dy)
    profile, length, width = cut_profile(u, v, z[rows, cols], dx * dy, config)
    return CanonicalProfile(profile, length, width, name)


class CanonicalDatabase(ProfileDatabase):
    """Many objects' canonical profiles, queried in one vectorised pass: the stripe
    profile's distance (`ProfileDatabase`: mean absolute difference per feature, the
    query forward and reversed, each feature divided by its median over the database).

    Args:
        profiles: one `CanonicalProfile` per object, all with the same ``K``.
    """

    EMPTY_SHAPE = (CANONICAL_SAMPLES, len(CANONICAL_FEATURES))
