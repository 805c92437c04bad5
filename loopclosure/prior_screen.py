"""The pre-ICP screens of a pose-gated check, stopped as soon as they pass.

A check from a prior (`loopclosure.geometric_check.verify`) runs no ICP when its
guesses' best coarse overlap score is below ``min_prior_overlap`` ("no overlap at
the prior") or their best overlap bound below what the check accepts ("no fit
within reach").  `loopclosure.grid_overlap.overlap_screen` computes both figures of
every guess over every source point; the check only asks whether the two maxima
reach their bars.  Both figures are sums of non-negative terms over the points,

    S_k = (1 / N) sum_i max(0, 1 - (d_ik / g)^2) [d_ik < g, point matchable],
    B_k = (1 / N) #{i : d_ik <= r},

(the score at ICP's gate ``g``, the bound at reach ``r``; ``d_ik`` the distance of
point ``i`` moved by guess ``k`` to its nearest map point), so a partial sum never
exceeds the full one (IEEE addition of a non-negative term never lowers a sum, and
the division by ``N`` is monotonic): once ``max_k S_k`` over the partial sums
reaches its bar and ``max_k B_k`` reaches its own, the full maxima reach them too,
and the screen passes whatever the remaining points and guesses hold.
`screen_passes` stops there; a screen that does not pass visits every point of
every guess, and its maxima are the full ones, to the bit.  The lazy grid's normals
that the stopped part would have resolved are resolved by ICP instead, by the same
computation (`loopclosure.grid_target.resolve_point`), so ICP and every figure of
the check are unchanged.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from loopclosure.grid_overlap import _screen_point
from loopclosure.grid_target import GridTarget
from loopclosure.icp_types import as_points
from loopclosure.kernel_cache import drop_stale

Array = NDArray[np.float64]


@numba.njit(cache=True)
def _screen_until_kernel(src, guesses, gate, reach, ox, oy, cell, nx, ny, start, pts, kind,
                         params, normals, anchors, min_score, min_bound):
    """`loopclosure.grid_overlap._screen_kernel`'s sums, point by point, guess by
    guess, stopped once the running maxima reach both bars: ``(passed, score,
    bound)``, the maxima (lower bounds when stopped early; the full maxima, starting
    from 0, otherwise)."""
    n = src.shape[0]
    best_score = 0.0
    best_bound = 0.0
    if best_score >= min_score and best_bound >= min_bound:
        return True, best_score, best_bound
    for g in range(guesses.shape[0]):
        c, s = np.cos(guesses[g, 2]), np.sin(guesses[g, 2])
        score = 0.0
        hits = 0
        for i in range(n):
            px = c * src[i, 0] - s * src[i, 1] + guesses[g, 0]
            py = s * src[i, 0] + c * src[i, 1] + guesses[g, 1]
            hit, term = _screen_point(px, py, gate, reach, ox, oy, cell, nx, ny, start, pts,
                                      kind, params, normals, anchors)
            hits += hit
            score += term
            if (max(best_score, score / n) >= min_score
                    and max(best_bound, hits / n) >= min_bound):
                return True, max(best_score, score / n), max(best_bound, hits / n)
        best_score = max(best_score, score / n)
        best_bound = max(best_bound, hits / n)
    return False, best_score, best_bound


def screen_passes(source: ArrayLike, grid: GridTarget, guesses: ArrayLike, gate: float,
                  reach: float, min_score: float, min_bound: float) -> tuple[bool, float, float]:
    """Whether the best coarse overlap score of `guesses` (``(K, 3)``, poses of the
    source frame in the grid's frame [m, m, rad]) at ICP's gate `gate` [m] reaches
    `min_score` and their best overlap bound at `reach` [m] reaches `min_bound`
    (`loopclosure.grid_overlap.overlap_screen`'s two figures; a bar of 0 always
    holds), stopping once both do (module docstring).

    Returns ``(passed, score, bound)``: when not passed, the two maxima exactly as
    ``overlap_screen(...)[i].max(initial=0.0)`` gives them (every point of every
    guess visited); when passed, lower bounds of them.  Zeros, not passed unless both
    bars are 0, without source or map points."""
    src = np.ascontiguousarray(as_points(source, "source points"))
    g = np.ascontiguousarray(np.asarray(guesses, dtype=float).reshape(-1, 3))
    if len(src) == 0 or len(grid.input_points) == 0:
        return bool(0.0 >= min_score and 0.0 >= min_bound), 0.0, 0.0
    nx, ny = grid.shape
    passed, score, bound = _screen_until_kernel(
        src, g, float(gate), float(reach), float(grid.origin[0]), float(grid.origin[1]),
        grid.cell, nx, ny, grid.start, grid.points, grid.kind, grid.params, grid.normals,
        grid.anchors, float(min_score), float(min_bound))
    return bool(passed), float(score), float(bound)


# numba's cache does not see edits of the callees' files (`loopclosure.kernel_cache`).
drop_stale(__name__, ("loopclosure.grid_nearest", "loopclosure.grid_target",
                      "loopclosure.grid_overlap"))


__all__ = ["screen_passes"]
