"""A second ranking of the prefilter's shortlist by polar occupancy grids.

The place database's prefilter ranks every stored keyframe by a histogram of surface
pairs (`loopclosure.matchers.pair_histogram`): invariant to where in a place the
sensor stands, and for the same reason blind to *where* things are.  In a corridor or
an open campus many places give nearly the same histogram, and a true revisit can
rank 20th or 200th behind look-alikes.  A polar occupancy grid about the sensor
(rings x bearing sectors, the layout of Scan Context, Kim & Kim, IROS 2018; stored
by the database for its heading hypotheses, `loopclosure.headings.polar_occupancy`)
keeps that layout.  The two rankings fail on different queries, so the candidates
the verifiers see are the union of both: the K best by the prefilter distance p,
plus the `extra` best of the prefilter's `shortlist` by a score that also counts
the grids' agreement.

Equations (plain text)
----------------------
Dilation.  ``D(G)[i, s] = max(G[i, s], G[i, s +- 1], G[i +- 1, s])`` (circular in the
sector s, not in the ring i): a surface one ring or one sector away still overlaps,
so a revisit a metre or a few degrees off the stored pose keeps its overlap.

Similarity of the query grid Q with stored grid G_j, the best rotation by whole
sectors (circular cross-correlation along the sectors by FFT, summed over rings):

    c_j = max_k sum_i sum_s D(G_j)[i, s] D(Q)[i, s + k] / sqrt(|D(Q)| |D(G_j)|)

with |.| the number of occupied cells: the cosine of the two binary grids at the best
turn, in [0, 1] (0 when either grid is empty).

Shortlist score (unitless, smaller is better), over the `shortlist` keyframes with the
smallest p:

    p'_j = p_j - w c_j

(p is normalised by the database's typical distance between two places, so it is
about 1 between unrelated places; c, a cosine of dilated grids, is well above 0 for
any two places of one building and higher for a revisit; with w = 1 both are on the
same unitless footing, and the grids decide among places the histogram finds about
equally close).  The candidates are the K smallest p and, of the others in
the shortlist, the `extra` smallest p'.
"""

from __future__ import annotations

import numpy as np
import scipy.fft
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError

Array = NDArray[np.float64]


def dilate_polar(grids: ArrayLike) -> NDArray[np.bool_]:
    """``D(G)`` of the module docstring for ``(..., R, S)`` boolean grids (rings,
    sectors): each cell or'ed with its two sector neighbours (circular) and its two
    ring neighbours (not circular)."""
    g = np.asarray(grids, dtype=bool)
    out = g | np.roll(g, 1, axis=-1) | np.roll(g, -1, axis=-1)
    out[..., 1:, :] |= g[..., :-1, :]
    out[..., :-1, :] |= g[..., 1:, :]
    return out


def grid_similarity(query_grid: ArrayLike, stored_grids: ArrayLike) -> Array:
    """``(K,)`` similarity c_j in [0, 1] (module docstring) of the query's ``(R, S)``
    polar grid with each of K stored ``(K, R, S)`` grids, both dilated here.

    Raises:
        UserError: the grids' shapes disagree.
    """
    qb = np.asarray(query_grid, dtype=bool)
    gb = np.asarray(stored_grids, dtype=bool)
    if gb.ndim == 2:
        gb = gb[None]
    if qb.shape != gb.shape[1:]:
        raise UserError(f"polar grids disagree: query {qb.shape}, stored {gb.shape[1:]}")
    gb = dilate_polar(gb)
    return dilated_similarity(dilate_polar(qb), gb, np.count_nonzero(gb, axis=(1, 2)))


def dilated_similarity(query_dilated: ArrayLike, stored_dilated: ArrayLike,
                       stored_counts: ArrayLike) -> Array:
    """`grid_similarity` of grids dilated already: the query's ``D(Q)`` ``(R, S)``,
    the stored ``D(G_j)`` ``(K, R, S)`` and their occupied cell counts ``|D(G_j)|``
    ``(K,)`` (a database dilates and counts each stored grid once, when it is added)."""
    qb = np.asarray(query_dilated, dtype=bool)
    stored = np.asarray(stored_dilated)
    # A ring the query leaves empty adds only zeros to every sum: its stored rings are
    # not transformed (the sums of the others keep their order, so c is unchanged).
    rings = np.flatnonzero(qb.any(axis=1))
    if len(rings) < qb.shape[0]:
        stored = stored[:, rings]
    q, g = qb[rings].astype(np.float32), np.asarray(stored, dtype=np.float32)
    sectors = q.shape[-1]
    # float32 FFTs (scipy keeps the precision: a correlation of a few thousand cells
    # comes out within about 1e-3 of a cell); the ring sum is taken in frequency space.
    spec = (np.conj(scipy.fft.rfft(g, axis=2)) * scipy.fft.rfft(q, axis=1)[None]).sum(axis=1)
    best = scipy.fft.irfft(spec, n=sectors, axis=1).max(axis=1).astype(float)
    denom = np.sqrt(float(np.count_nonzero(qb)) * np.asarray(stored_counts, dtype=float))
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(denom > 0, best / denom, 0.0)
    return np.clip(c, 0.0, 1.0)


def union_of_rankings(prefilter: ArrayLike, similarity: ArrayLike, k: int, extra: int,
                      weight: float, ordered: bool = False) -> NDArray[np.intp]:
    """Positions of the candidates among a shortlist (module docstring): the `k`
    smallest `prefilter` distances p and, of the rest, the `extra` smallest
    ``p - weight * similarity``; returned in increasing p (ties by position).
    `ordered`: the shortlist is in the query's own order already (an interleave of
    rankings, `loopclosure.place_shortlist.rank_interleave`): its first `k`
    positions take the place of the `k` smallest p, and the result is in position
    order.

    Raises:
        UserError: the two arrays differ in length, or k, extra or weight is negative.
    """
    p = np.asarray(prefilter, dtype=float)
    c = np.asarray(similarity, dtype=float)
    if p.shape != c.shape or p.ndim != 1:
        raise UserError(f"shortlist distances {p.shape} and similarities {c.shape} disagree")
    if k < 0 or extra < 0 or not weight >= 0:
        raise UserError("k, extra and weight must be >= 0")
    by_p = np.arange(len(p)) if ordered else np.lexsort((np.arange(len(p)), p))
    base = by_p[:k]
    rest = by_p[k:]
    if extra and len(rest):
        score = p[rest] - weight * c[rest]
        rest = rest[np.lexsort((rest, score))][:extra]
        base = np.concatenate([base, rest])
    else:
        base = base.copy()
    if ordered:
        return np.sort(base)
    return base[np.lexsort((base, p[base]))]


__all__ = ["dilate_polar", "dilated_similarity", "grid_similarity", "union_of_rankings"]
