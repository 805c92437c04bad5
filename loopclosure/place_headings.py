"""Heading hypotheses of a place query's candidates (`loopclosure.place_database`).

For every candidate, headings [rad] of the query in the candidate's frame
(`loopclosure.headings`, whose docstring defines the convention), best first: first
the ``grid_headings`` peaks of the correlation of the two places' polar occupancy
grids about their sensor origins (`headings_from_polar_grids`; grids of
`loopclosure.place_grids`), then the ``n_headings`` peaks of the circular
cross-correlation of the two range functions about the centroids
(`headings_from_range_functions`), less those within 5 degrees of a grid
hypothesis; both vectorised over the K candidates.  The two producers' scores are
not comparable: the order is the producers' order, then each one's score.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from data import se2
from loopclosure.headings import headings_from_polar_grids, headings_from_range_functions
from loopclosure.matchers.fft import FFTDescriptor
from loopclosure.place_config import PlaceDatabaseConfig
from loopclosure.place_grids import GRID, unpack_grid
from loopclosure.place_match import Descriptors
from loopclosure.place_rows import FloatRows

Array = NDArray[np.float64]
HEADING = "heading"
"""Descriptor key of the FFT descriptor behind the range-function headings when FFT
is no stage."""
_SAME_HEADING = np.radians(5.0)


def candidate_headings(
    q: Descriptors,
    cand: NDArray[np.intp],
    stored: Sequence[Descriptors],
    ranges: FloatRows | None,
    cfg: PlaceDatabaseConfig,
    grid_on: bool,
) -> tuple[Array, Array]:
    """``(K, H)`` headings [rad] and scores (-inf: none) of the candidate rows `cand`,
    best first.

    Args:
        q: the query's descriptors.
        cand: ``(K,)`` insertion rows of the candidates.
        stored: every row's stored descriptors (their `GRID` grids are read).
        ranges: every row's range function (None: no range hypotheses).
        cfg: the database's parameters (``n_headings``, ``grid_headings``, grid shape).
        grid_on: whether the database stores polar grids.
    """
    n = cfg.n_headings
    parts: list[tuple[Array, Array]] = []
    grids = [stored[i].get(GRID) for i in cand.tolist()]
    if grid_on and q.get(GRID) is not None and all(g is not None for g in grids):
        stacked = np.stack([unpack_grid(g, cfg) for g in grids])
        parts.append(headings_from_polar_grids(unpack_grid(q[GRID], cfg), stacked,
                                               cfg.grid_headings))
    if n > 0 and ranges is not None:
        fft: FFTDescriptor = q.get("fft", q.get(HEADING))
        angles, scores = headings_from_range_functions(
            fft.range_function, ranges.data[cand], n
        )
        if parts:  # drop range hypotheses a grid hypothesis already holds
            ga, gs = parts[0]
            diff = np.abs(se2.wrap_angle(angles[:, :, None] - ga[:, None, :]))
            dup = ((diff < _SAME_HEADING) & np.isfinite(gs)[:, None, :]).any(axis=2)
            scores = np.where(dup, -np.inf, scores)
        parts.append((angles, scores))
    if not parts:
        return np.zeros((len(cand), 0)), np.zeros((len(cand), 0))
    angles = np.concatenate([a for a, _ in parts], axis=1)
    scores = np.concatenate([r for _, r in parts], axis=1)
    # Keep the producers' order, each one's hypotheses by score; missing ones last.
    order = np.argsort(~np.isfinite(scores), axis=1, kind="stable")
    return np.take_along_axis(angles, order, 1), np.take_along_axis(scores, order, 1)


def as_hypotheses(angles: Array, scores: Array) -> list[tuple[tuple[float, float], ...]]:
    """Per candidate (row of the ``(K, H)`` arrays), its finite ``(heading, score)``
    hypotheses, best first (`loopclosure.place_match.PlaceMatch.headings`)."""
    return [
        tuple((float(a), float(r)) for a, r in zip(angles[j], scores[j], strict=True)
              if np.isfinite(r))
        for j in range(len(angles))
    ]


__all__ = ["HEADING", "as_hypotheses", "candidate_headings"]
