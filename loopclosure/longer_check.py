"""A prior-free check rejected as degenerate, judged again on longer submaps.

A corridor's two walls constrain the fit across the corridor and in heading, not
along it: the geometric check (`loopclosure.geometric_check`) measures that as the
smallest eigenvalue of the fit's translational information over its sum (its
*degeneracy*) and rejects a fit below ``min_degeneracy`` (or, for a partial
overlap, below ``min_degeneracy_partial``).  A submap of a few metres of a corridor
often holds nothing else; what pins the along-axis position (a corridor's end, a
crossing, a doorway's jambs, a room's walls) lies a few metres further on, seen from
keyframes outside it.

So a prior-free check rejected for its degeneracy alone (every rule before that one
held: matched length, free-space consistency, rms) is checked again, by the same
search and the same rules (`loopclosure.geometric_check.verify` with no prior), on
longer submaps: each of the two keyframes' submaps joined with the map of the
`longer_keyframes` keyframes of path behind it, in the same keyframe's sensor frame
(the host's ``trailing_map``).  The search starts from the heading of the degenerate
fit (and, as always, its opposite).  That check's verdict is the candidate's: its
pose, figures and reason (a rejection names both: the first check's rule, then the
longer check's).  A wrong fit slid along the corridor meets the longer submaps'
ends and openings in the other's free space (consistency) or off its walls
(fitness); a true revisit now has them where the other pass saw them.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import ArrayLike, NDArray

from loopclosure.geometric_check import (
    DEGENERATE,
    PARTIAL_DEGENERATE,
    GeometricCheckConfig,
    LoopVerification,
    verify,
)
from loopclosure.registration import RegistrationTarget

Array = NDArray[np.float64]


def is_degenerate(result: LoopVerification) -> bool:
    """The check was rejected for its degeneracy: the first rule that failed is
    ``min_degeneracy`` or ``min_degeneracy_partial`` (every earlier rule held)."""
    return not result.accepted and result.reason.startswith((DEGENERATE, PARTIAL_DEGENERATE))


def joined(*parts: ArrayLike) -> Array:
    """``(N, 2)`` points of several point sets of one frame, stacked [m]."""
    return np.vstack([np.asarray(p, dtype=float).reshape(-1, 2) for p in parts])


def recheck_longer(
    first: LoopVerification,
    query_points: ArrayLike,
    candidate_points: ArrayLike,
    *,
    max_distance: float | None,
    config: GeometricCheckConfig,
) -> LoopVerification:
    """The check of the same candidate on longer submaps (module docstring).

    Args:
        first: the degenerate verdict (`is_degenerate`); its heading seeds the search.
        query_points: ``(N, 2)`` the query's longer submap, its sensor frame [m].
        candidate_points: ``(M, 2)`` the candidate's longer submap, its sensor frame [m].
        max_distance: the loop detector's revisit radius [m] (None: no limit).
        config: the check's configuration (the same rules as the first check; its
            ``compiled_icp`` also picks the candidate's normal estimation).

    Returns:
        The longer check's verdict; a rejection's reason names the first check's
        rule and then the longer check's.
    """
    normals = None
    if config.compiled_icp:
        from loopclosure.fast_icp import estimate_normals_fast as normals  # numba

    target = RegistrationTarget(candidate_points, config.icp, normals=normals)
    second = verify(query_points, target, headings=[float(first.relative[2])],
                    max_distance=max_distance, config=config)
    if second.accepted:
        return second
    return dataclasses.replace(second, reason=f"{first.reason}; longer submaps: {second.reason}")
