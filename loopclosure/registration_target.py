"""The target of 2D registration, prepared once for many sources: a KD-tree over its
points, a unit normal per point from local PCA, and which points are line-like.

Points are ``(M, 2)`` arrays [m] in the target frame T.  For each point, its
`normal_neighbors` nearest neighbours within `normal_radius` (itself included) give the
covariance ``C`` (2x2); with ``a = C_xx, b = C_xy, c = C_yy`` its eigenvalues are
``lambda = (a + c) / 2 -+ sqrt(((a - c) / 2)^2 + b^2)`` and the principal axis has
angle ``phi = atan2(2 b, a - c) / 2``; the normal is ``(-sin phi, cos phi)``.  A point
is usable when it has at least `min_normal_neighbors` neighbours and is line-like,
``lambda_min <= max_normal_ratio * lambda_max``.  Corners, clutter and isolated
points stay in the tree but a source point whose nearest neighbour is one of them
gets no correspondence (so a point near a corner is never pulled onto the other
wall), unless `point_to_point_clutter` is set and the nearest neighbour is
clutter (enough neighbours, not line-like): then the correspondence is a
point-to-point one (`loopclosure.registration`).  Isolated points never match.  All
vectorised over points; no loop.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from loopclosure.icp_types import IcpConfig, as_points

Array = NDArray[np.float64]


def estimate_normals(
    points: Array, tree: cKDTree, config: IcpConfig
) -> tuple[Array, NDArray[np.bool_], Array]:
    """Unit normals ``(N, 2)``, a line-like mask ``(N,)`` and ``lambda_min / lambda_max``.

    Local PCA over each point's neighbours (module docstring), vectorised over points.
    The ratio is ``inf`` where a point has fewer than `min_normal_neighbors`
    neighbours (isolated: neither line nor clutter).
    """
    n = len(points)
    k = min(config.normal_neighbors, n)
    if n < config.min_normal_neighbors:
        return np.zeros((n, 2)), np.zeros(n, dtype=bool), np.full(n, np.inf)
    dist, idx = tree.query(points, k=k, distance_upper_bound=config.normal_radius)
    dist = dist.reshape(n, k)
    idx = idx.reshape(n, k)
    found = np.isfinite(dist)
    padded = np.vstack([points, np.zeros((1, 2))])
    neigh = padded[np.where(found, idx, n)]  # (n, k, 2); missing -> zero, weight 0
    w = found.astype(float)
    count = w.sum(axis=1)
    mean = (neigh * w[..., None]).sum(axis=1) / count[:, None]
    centred = (neigh - mean[:, None, :]) * w[..., None]
    a = (centred[..., 0] ** 2).sum(axis=1) / count
    b = (centred[..., 0] * centred[..., 1]).sum(axis=1) / count
    c = (centred[..., 1] ** 2).sum(axis=1) / count
    half_diff = 0.5 * (a - c)
    root = np.sqrt(half_diff**2 + b**2)
    lam_max = 0.5 * (a + c) + root
    lam_min = 0.5 * (a + c) - root
    phi = 0.5 * np.arctan2(2.0 * b, a - c)
    normals = np.column_stack([-np.sin(phi), np.cos(phi)])
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(lam_max > 0, np.maximum(lam_min, 0.0) / lam_max, 1.0)
    enough = count >= config.min_normal_neighbors
    ratio = np.where(enough, ratio, np.inf)
    line_like = enough & (ratio <= config.max_normal_ratio)
    return normals, line_like, ratio


#: Normal estimator of a `RegistrationTarget`: ``(points (M, 2) [m], config) ->
#: (normals (M, 2), line-like mask (M,), lambda_min / lambda_max (M,), inf where a
#: point has too few neighbours)``, the contract of `estimate_normals` (e.g.
#: `loopclosure.fast_icp.estimate_normals_fast`, the same equations compiled).
NormalsFn = Callable[[Array, IcpConfig], tuple[Array, NDArray[np.bool_], Array]]

_UNBUILT = object()  # `RegistrationTarget.tree` not made yet


class RegistrationTarget:
    """A target point set prepared once: KD-tree, normals and which points are line-like.

    Attributes:
        points: ``(M, 2)`` the points in the target frame [m].
        normals: ``(M, 2)`` their unit normals (meaningless where not `usable`).
        usable: ``(M,)`` line-like points with a normal (matched point to line).
        clutter: ``(M,)`` points with enough neighbours that are not line-like
            (matched point to point with `IcpConfig.point_to_point_clutter`).
        config: the `IcpConfig` the normals were made with (and the default for
            `register`).
        derived: other products of the points, made and cached by their users (e.g.
            the geometric check's likelihood grid), by a key of their parameters.

    `normals`, a `NormalsFn`, replaces `estimate_normals` (which queries the
    KD-tree); the tree is then made on first use of `tree` (a target screened out
    before any KD-tree query never makes it).
    """

    __slots__ = ("_tree", "clutter", "config", "derived", "normals", "points", "usable")

    def __init__(self, points: ArrayLike, config: IcpConfig | None = None, *,
                 normals: NormalsFn | None = None) -> None:
        self.config = config or IcpConfig()
        pts = as_points(points, "target points")
        self.points = pts
        self.derived: dict = {}
        self._tree: object = None
        if len(pts) >= self.config.min_normal_neighbors:
            if normals is None:
                self._tree = cKDTree(pts)
                self.normals, self.usable, ratio = estimate_normals(pts, self._tree, self.config)
            else:
                self._tree = _UNBUILT
                self.normals, self.usable, ratio = normals(pts, self.config)
            self.clutter = np.isfinite(ratio) & ~self.usable
        else:
            self.normals, self.usable = np.zeros((len(pts), 2)), np.zeros(len(pts), dtype=bool)
            self.clutter = np.zeros(len(pts), dtype=bool)
        if not self.matchable.any():
            self._tree = None

    @property
    def tree(self) -> cKDTree | None:
        """KD-tree over all `points`; None when no point is `matchable` (nothing for
        ICP to match)."""
        if self._tree is _UNBUILT:
            self._tree = cKDTree(self.points)
        return self._tree  # type: ignore[return-value]

    @property
    def matchable(self) -> NDArray[np.bool_]:
        """``(M,)`` the points ICP matches: line-like ones, plus clutter with
        `IcpConfig.point_to_point_clutter`."""
        if self.config.point_to_point_clutter:
            return self.usable | self.clutter
        return self.usable

    def __len__(self) -> int:
        """Number of target points ICP can match (`matchable`)."""
        return int(self.matchable.sum())


__all__ = ["NormalsFn", "RegistrationTarget", "estimate_normals"]
