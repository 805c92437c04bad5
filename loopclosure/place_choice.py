"""Which of a query's place matches the loop detector checks: the matches of several views
(databases) merged into one list, and the first distinct places among them."""

from __future__ import annotations

from collections.abc import Hashable, Sequence

import numpy as np
from numpy.typing import ArrayLike

from loopclosure.place_match import PlaceMatch


def merge_views(per_view: Sequence[Sequence[PlaceMatch]]) -> list[PlaceMatch]:
    """One query's matches in several views (databases), as one list: each stored
    keyframe once, as its match with the highest fused score, marked with that view's
    index (`PlaceMatch.view`); by decreasing fused score (ties: the database's own
    order, the first view first)."""
    found = [(m, view) for view, matches in enumerate(per_view) for m in matches]
    found.sort(key=lambda f: -f[0].score)
    return [m if m.view == view else m.with_view(view) for m, view in first_per_key(found)]


def first_per_key(found: Sequence[tuple[PlaceMatch, int]]) -> list[tuple[PlaceMatch, int]]:
    """The first ``(match, view)`` of every stored key in `found`, in order (a match
    is relabelled with its view only once it is kept: most of a merged list are
    duplicates)."""
    seen: set[Hashable] = set()
    return [f for f in found if not (f[0].key in seen or seen.add(f[0].key))]


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
    if limit <= 0 or not matches:
        return []
    keys = np.array([int(m.key) for m in matches], dtype=np.int64)
    # Same place, for every two matches: one array operation instead of a Python
    # call per pair (the same element-wise arithmetic, so the same verdicts).
    if positions is None:
        same = np.abs(keys[:, None] - keys[None, :]) <= 5
    else:
        xy = np.asarray(positions, dtype=float).reshape(-1, 2)[keys]
        same = np.hypot(xy[:, None, 0] - xy[None, :, 0],
                        xy[:, None, 1] - xy[None, :, 1]) <= separation
        if frames is not None:
            f = np.asarray(frames)[keys]
            same &= f[:, None] == f[None, :]
    rows = same.tolist()
    chosen: list[int] = []
    for i, row in enumerate(rows):
        if len(chosen) == limit:
            break
        if not any(row[j] for j in chosen):
            chosen.append(i)
    return [matches[i] for i in chosen]
