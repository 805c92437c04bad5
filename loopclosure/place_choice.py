"""Which of a query's place matches the loop detector checks: the matches of several views
(databases) merged into one list, and the first distinct places among them."""

from __future__ import annotations

import dataclasses
from collections.abc import Hashable, Sequence

import numpy as np
from numpy.typing import ArrayLike

from loopclosure.place_database import PlaceMatch


def merge_views(per_view: Sequence[Sequence[PlaceMatch]]) -> list[PlaceMatch]:
    """One query's matches in several views (databases), as one list: each stored
    keyframe once, as its match with the highest fused score, marked with that view's
    index (`PlaceMatch.view`); by decreasing fused score (ties: the database's own
    order, the first view first)."""
    found = [m if m.view == view else dataclasses.replace(m, view=view)
             for view, matches in enumerate(per_view) for m in matches]
    found.sort(key=lambda m: -m.score)
    seen: set[Hashable] = set()
    return [m for m in found if not (m.key in seen or seen.add(m.key))]


def distinct_places(
    matches: Sequence[PlaceMatch], limit: int, positions: ArrayLike | None = None,
    frames: Sequence[int] | None = None, separation: float = 1.0,
) -> list[PlaceMatch]:
    """The first `limit` of `matches` (best first) that are distinct places.

    With `positions` (``(n, 2)`` map positions of keyframes ``0..n-1`` [m]) a match
    within `separation` [m] of one already taken, in the same frame (`frames`, the
    frame of every key; None: one frame), is the same place and is skipped.  Without
    positions a match within 5 keys of one taken is.  Positions are the better rule:
    on a log with one keyframe per metre, 5 keys span 5 m, and the keyframe next to
    a candidate that is 2.5 m from the query (not a revisit) may be 0.5 m from it.
    """
    if positions is None:
        def same(a: int, b: int) -> bool:
            return abs(a - b) <= 5
    else:
        xy = np.asarray(positions, dtype=float).reshape(-1, 2)

        def same(a: int, b: int) -> bool:
            return ((frames is None or frames[a] == frames[b])
                    and bool(np.hypot(*(xy[a] - xy[b])) <= separation))
    chosen: list[PlaceMatch] = []
    for m in matches:
        if len(chosen) == limit:
            break
        if not any(same(int(m.key), int(c.key)) for c in chosen):
            chosen.append(m)
    return chosen
