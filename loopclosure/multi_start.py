"""Multi-start registration: ICP from several initial guesses, the best run wins.

A loop-closure candidate (`loopclosure.geometric_check`) or a lost odometry front
end (`slam.odometry.icp2d`) knows the relative pose only roughly: a few headings
(`loopclosure.headings`, in its convention: the heading of the source frame in the
target frame) and a translation.  `initial_guesses` crosses every heading with
every translation offset; `register_multi` runs point-to-line ICP
(`loopclosure.registration.register`) from each and keeps the best.

Frames and units as in `loopclosure.registration`: guesses and results are poses
``(x, y, theta)`` [m, m, rad] of the source frame in the target frame.

Ranking: the best result is the one with the highest ``fitness``; ties (within
1e-9) go to the lower ``rms``; failed runs rank last.  Many guesses can first be
ranked without ICP by `overlap_scores` (one KD-tree query for all guesses) and only
the best `keep` refined.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data import se2
from data.errors import UserError
from loopclosure.registration import (
    IcpConfig,
    IcpResult,
    RegistrationTarget,
    as_points,
    register,
)

if TYPE_CHECKING:
    from loopclosure.fast_icp import GridTarget

Array = NDArray[np.float64]


def initial_guesses(
    initial: ArrayLike = (0.0, 0.0, 0.0),
    headings: ArrayLike | None = None,
    offsets: ArrayLike | None = None,
) -> Array:
    """``(K, 3)`` start poses: every heading times every translation offset.

    Args:
        initial: ``(3,)`` base guess; its heading is used when `headings` is None.
        headings: ``(H,)`` absolute headings [rad] to try (the base heading is
            always tried first).
        offsets: ``(T, 2)`` translation offsets [m] added to the base translation
            (``(0, 0)`` is always tried first).
    """
    base = np.asarray(initial, dtype=float).reshape(3)
    heads = [float(base[2])]
    if headings is not None:
        heads += [float(h) for h in np.atleast_1d(np.asarray(headings, dtype=float))]
    offs = np.zeros((1, 2))
    if offsets is not None:
        offs = np.vstack([offs, np.asarray(offsets, dtype=float).reshape(-1, 2)])
    hh, oo = np.meshgrid(np.arange(len(heads)), np.arange(len(offs)), indexing="ij")
    guesses = np.column_stack(
        [base[0] + offs[oo.ravel(), 0], base[1] + offs[oo.ravel(), 1],
         np.asarray(heads)[hh.ravel()]]
    )
    # Drop duplicates (same heading twice), keeping the first of each: rows equal
    # once rounded to 1e-9 (a dict of a few dozen tuples, not a sort of the rows).
    key = np.round(np.column_stack([guesses[:, :2], se2.wrap_angle(guesses[:, 2])]), 9)
    first: dict[tuple[float, ...], int] = {}
    for i, row in enumerate(map(tuple, key.tolist())):
        first.setdefault(row, i)
    if len(first) == len(guesses):
        return guesses
    return guesses[np.fromiter(first.values(), dtype=np.int64, count=len(first))]


@dataclass(slots=True)
class MultiResult:
    """Best of several ICP runs (`register_multi`).

    Attributes:
        best: the winning `IcpResult` (highest fitness, then lowest rms).
        results: every run, in the order of the guesses.
        guesses: ``(K, 3)`` the initial guesses.
    """

    best: IcpResult
    results: list[IcpResult]
    guesses: Array


def _better(a: IcpResult, b: IcpResult) -> bool:
    """True if `a` ranks above `b` (ok first, then fitness, then rms)."""
    if a.ok != b.ok:
        return a.ok
    if abs(a.fitness - b.fitness) > 1e-9:
        return a.fitness > b.fitness
    return a.rms < b.rms


def overlap_scores(
    source: ArrayLike, target: RegistrationTarget, guesses: ArrayLike, tolerance: float
) -> Array:
    """``(K,)`` coarse score of each guess without ICP (for pre-screening many guesses).

    ``mean_i max(0, 1 - (d_i / tolerance)^2)`` with ``d_i`` the distance of source
    point i, moved by the guess, to its nearest target point if that is
    `RegistrationTarget.matchable` (0 otherwise and beyond `tolerance`).  One
    KD-tree query for all guesses together (vectorised over guesses and points).
    """
    g = np.asarray(guesses, dtype=float).reshape(-1, 3)
    src = as_points(source, "source points")
    if target.tree is None or len(src) == 0 or len(g) == 0:
        return np.zeros(len(g))
    c, s = np.cos(g[:, 2]), np.sin(g[:, 2])
    x = c[:, None] * src[None, :, 0] - s[:, None] * src[None, :, 1] + g[:, 0, None]
    y = s[:, None] * src[None, :, 0] + c[:, None] * src[None, :, 1] + g[:, 1, None]
    moved = np.stack([x, y], axis=-1).reshape(-1, 2)
    dist, idx = target.tree.query(moved, k=1, distance_upper_bound=tolerance)
    found = np.isfinite(dist)
    found[found] = target.matchable[idx[found]]
    score = np.where(found, 1.0 - (np.where(found, dist, 0.0) / tolerance) ** 2, 0.0)
    return score.reshape(len(g), len(src)).mean(axis=1)


def register_multi(
    source: ArrayLike,
    target: RegistrationTarget | None,
    guesses: ArrayLike,
    *,
    config: IcpConfig | None = None,
    keep: int | None = None,
    prescreen_tolerance: float = 0.2,
    compiled: bool = False,
    grid: GridTarget | None = None,
    join: bool = True,
) -> MultiResult:
    """ICP from each of `guesses` (``(K, 3)``, see `initial_guesses`); the best wins.

    Ranking (documented score): `IcpResult.fitness` (truncated-quadratic overlap at
    a fixed tolerance, comparable between runs), ties broken by the lower `rms`;
    failed runs rank last.  With `keep`, the guesses are first ranked by
    `overlap_scores` (tolerance `prescreen_tolerance` [m]) and ICP runs from the
    best `keep` only (`MultiResult.results` and `guesses` then hold those).  One
    Python loop over the hypotheses that run ICP (not over points).  With `compiled`
    each ICP is `loopclosure.fast_icp.register_target` (the same maths, numba), on
    `grid` (a `loopclosure.fast_icp.GridTarget` of `target`) when the caller has made
    it (e.g. for `loopclosure.fast_icp.overlap_bound`); the prescreen then scores on
    that grid (`loopclosure.fast_icp.overlap_screen`, the same score without the
    KD-tree), and `target` may be None.  `join`: compiled runs that meet an earlier
    run's end stop there with its result (`loopclosure.fast_icp.register_target`);
    False runs each to its own end, as the numpy runs do.
    """
    g = np.asarray(guesses, dtype=float).reshape(-1, 3)
    if len(g) == 0:
        raise UserError("register_multi needs at least one initial guess (guesses is empty)")
    src = as_points(source, "source points")
    on_grid = compiled and grid is not None
    if target is None and not on_grid:
        raise UserError("register_multi needs a target, or compiled ICP on a grid")
    if keep is not None and keep < len(g):
        if on_grid:
            from loopclosure import fast_icp  # numba loads on first use

            scores = fast_icp.overlap_screen(src, grid, g, prescreen_tolerance, 0.0)[0]
        else:
            scores = overlap_scores(src, target, g, prescreen_tolerance)
        g = g[np.sort(np.argsort(-scores, kind="stable")[: max(keep, 1)])]
    if compiled:
        from loopclosure import fast_icp  # numba loads on first use

        if grid is None:
            assert target is not None
            grid = fast_icp.GridTarget.from_target(target, fast_icp.TARGET_GRID_CELL)
        results = fast_icp.register_target(src, target, g, config=config, grid=grid,
                                           join=join)
    else:
        assert target is not None
        results = [register(src, target, guess, config=config) for guess in g]
    best = results[0]
    for res in results[1:]:
        if _better(res, best):
            best = res
    return MultiResult(best=best, results=results, guesses=g)
