"""Why a true place misses the prefilter's shortlist: the geometry of every revisit.

`loopclosure bench loops` records, for every query with a revisit, its *nearest true
place*: the database keyframe nearest to it in the reference (within the revisit
radius), and three things about the pair that decide whether any place descriptor
can see them as one place:

* ``nearest_m``: their distance [m] in the reference;
* ``nearest_dtheta_deg``: the absolute difference of their reference headings
  [deg] (0: same direction of travel, 180: opposite; a sensor narrower than a full
  circle sees a different side of the place);
* ``nearest_overlap``: the share of the query's submap points (the map the geometric
  check registers, in the query's sensor frame) that lie within `OVERLAP_RADIUS` of
  a point of the place's submap once both are placed at their reference poses
  (`submap_overlap`): 1 when the query sees nothing the place did not, 0 for two
  places a wall apart.

and the rank (0-based) of the first true place in the combined prefilter's order
(``prefilter_rank``; -1 when none is among the first `max(RECALL_KS)`).
`miss_breakdown` bins the queries by each quantity and gives the prefilter's
recall@K per bin: a descriptor that fails at small distance and high overlap is the
descriptor's fault; one that fails only at low overlap meets the limit of what
the sensor saw.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from data import se2

Array = NDArray[np.float64]

OVERLAP_RADIUS = 0.2
"""Distance [m] within which a query submap point counts as seen by the place."""

DISTANCE_BINS = (0.0, 0.5, 1.0, 1.5, 2.0)
HEADING_BINS = (0.0, 30.0, 90.0, 150.0, 180.0)
OVERLAP_BINS = (0.0, 0.3, 0.5, 0.7, 1.0)


def nearest_place(
    reference: ArrayLike, query: int, candidates: ArrayLike
) -> tuple[int, float, float]:
    """``(key, distance [m], heading difference [deg])`` of the candidate keyframe
    nearest to `query` in `reference` (``(K, 3)`` poses ``(x, y, theta)``); ``(-1, nan,
    nan)`` without candidates."""
    ref = np.asarray(reference, float)
    cand = np.asarray(candidates, np.intp).reshape(-1)
    if len(cand) == 0:
        return -1, float("nan"), float("nan")
    d = np.hypot(*(ref[cand, :2] - ref[query, :2]).T)
    i = int(np.argmin(d))
    dth = abs(float(se2.wrap_angle(ref[cand[i], 2] - ref[query, 2])))
    return int(cand[i]), float(d[i]), float(np.degrees(dth))



def revisit_queries(
    detector: Any, reference: ArrayLike, radius: float = 2.0
) -> Iterator[tuple[int, NDArray[np.intp], Array, NDArray[np.bool_]]]:
    """The queries with a revisit, for scripts that study the place database offline.

    For every keyframe `k` the loop detector described (`detector.database`) and
    `reference` (``(K, 3)`` poses, NaN rows: none) covers: ``rows``, the database's
    rows (its keys in order) of the eligible older keyframes with a reference pose;
    ``true``, their reference distances to `k` [m]; ``near``, ``true <= radius``.
    Yields ``(k, rows, true, near)`` when some row is near.
    """
    ref = np.asarray(reference, float)
    db = detector.database
    keys = np.array(db.keys, dtype=np.intp)
    covered = np.isfinite(ref).all(axis=1)
    for k in range(len(ref)):
        if k not in db or not covered[k]:
            continue
        rows = np.flatnonzero(keys < k)
        rows = rows[detector.eligible(k)[keys[rows]] & covered[keys[rows]]]
        true = np.hypot(*(ref[keys[rows], :2] - ref[k, :2]).T)
        near = true <= radius
        if near.any():
            yield k, rows, true, near

def submap_overlap(
    query_points: ArrayLike, place_points: ArrayLike, query_pose: ArrayLike,
    place_pose: ArrayLike, radius: float = OVERLAP_RADIUS,
) -> float:
    """Share of `query_points` (``(N, 2)`` [m], query sensor frame) within `radius` [m]
    of a point of `place_points` (place sensor frame) when the two frames are at
    `query_pose` and `place_pose` (``(x, y, theta)``, a common frame); NaN when
    either set is empty."""
    q = np.asarray(query_points, float).reshape(-1, 2)
    p = np.asarray(place_points, float).reshape(-1, 2)
    if len(q) == 0 or len(p) == 0:
        return float("nan")
    rel = se2.between(np.asarray(place_pose, float), np.asarray(query_pose, float))
    q_in_place = se2.transform_points(rel, q)
    dist = cKDTree(p).query(q_in_place, distance_upper_bound=radius)[0]
    return float(np.mean(dist <= radius))


def _bins(values: Array, edges: Sequence[float]) -> list[tuple[str, NDArray[np.bool_]]]:
    out = []
    for i, (lo, hi) in enumerate(itertools.pairwise(edges)):
        last = i == len(edges) - 2
        sel = (values >= lo) & ((values <= hi) if last else (values < hi))
        out.append((f"{lo:g}-{hi:g}", sel))
    return out


def miss_breakdown(
    rank: ArrayLike, nearest_m: ArrayLike, nearest_dtheta_deg: ArrayLike,
    nearest_overlap: ArrayLike, k: int = 10,
) -> dict[str, list[tuple[str, int, float]]]:
    """Recall@`k` of the prefilter per bin of each quantity (module docstring), over
    the queries given (those with a revisit): quantity -> [(bin, queries, recall)]
    (recall NaN in an empty bin).  `rank` is -1 where no true place was ranked."""
    r = np.asarray(rank, int)
    found = (r >= 0) & (r < k)
    out: dict[str, list[tuple[str, int, float]]] = {}
    for name, values, edges in (
        ("nearest_m", nearest_m, DISTANCE_BINS),
        ("nearest_dtheta_deg", nearest_dtheta_deg, HEADING_BINS),
        ("nearest_overlap", nearest_overlap, OVERLAP_BINS),
    ):
        v = np.asarray(values, float)
        out[name] = [(label, int(sel.sum()), float(found[sel].mean()) if sel.any()
                      else float("nan")) for label, sel in _bins(v, edges)]
    return out


__all__ = ["OVERLAP_RADIUS", "miss_breakdown", "nearest_place", "submap_overlap"]
