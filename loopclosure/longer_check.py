"""A prior-free check rejected as degenerate, judged again on longer submaps.

A corridor's two walls constrain the fit across the corridor and in heading, not
along it: the geometric check (`loopclosure.geometric_check`) measures that as the
smallest eigenvalue of the fit's translational information over its sum (its
*degeneracy*) and rejects a fit below ``min_degeneracy`` (or, for a partial overlap,
below ``min_degeneracy_partial``). A submap of a few metres of a corridor often
holds nothing else; what pins the along-axis position (a corridor's end, a crossing,
a doorway's jambs, a room's walls) lies a few metres further on, seen from keyframes
outside it.

So, when ``longer_path_m`` or ``longer_keyframes`` is set (off by default), a
prior-free check rejected for its degeneracy alone (every rule before that one held:
matched length, free-space consistency, rms) is checked again, by the same search and
the same rules (`loopclosure.geometric_check.verify` with no prior), on longer
submaps: each of the two keyframes' submaps joined with the map of the keyframes of
path behind it, in the same keyframe's sensor frame (the host's ``trailing_map``):
the fewest whose path reaches ``longer_path_m`` metres (`trailing_count`), else
``longer_keyframes`` of them.  A path length, because keyframes lie a few decimetres
apart indoors and metres apart outdoors: a count means paths of very different
length.  The length trades two errors: a few metres of path still fit a look-alike
stretch elsewhere (another corridor of the same width and openings), while over
tens of metres the front end's drift bends the submap's far end (heading errors of
1-2 degrees over 20-40 m of an outdoor log); the along-axis answer itself comes from
the nearest features that pin it.
The search starts from the heading of the degenerate fit (and, as always, its
opposite). A wrong fit slid along the corridor meets the longer submaps' ends and
openings in the other's free space (consistency) or off its walls (fitness); a true
revisit now has them where the other pass saw them.

The longer check decides, and it gives the one number the first check lacked: the
translation along the first fit's degenerate axis
(`LoopVerification.degenerate_axis`, the candidate's frame). The heading and the
translation across that axis stay the first fit's, which its short submaps constrain
well: the longer submaps reach metres to tens of metres of front-end path, whose
drift can tilt their far ends. A longer fit more than the check's
``ambiguity_distance`` across the axis or ``ambiguity_angle_deg`` in heading from
the first fit is a different answer and rejects the candidate. The verdict carries
the longer check's figures and covariance; a rejection's reason names the first
check's rule, then the longer check's.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data import se2
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


def trailing_count(poses: ArrayLike | None, key: int, config: GeometricCheckConfig) -> int:
    """How many keyframes behind `key` its longer submap joins (module docstring).

    With ``longer_path_m`` set and `poses` reaching `key`, the fewest keyframes
    ``key - n .. key`` whose path (the sum of the steps between consecutive poses of
    `poses`, ``(n, 3)`` map frame [m, rad]) reaches ``longer_path_m`` [m], or all of
    them back to keyframe 0 when the path is shorter; else ``longer_keyframes``.
    """
    path = config.longer_path_m
    if path <= 0 or poses is None:
        return config.longer_keyframes
    xy = np.asarray(poses, dtype=float).reshape(-1, 3)[:, :2]
    if len(xy) <= key:
        return config.longer_keyframes
    steps = np.hypot(*np.diff(xy[key::-1], axis=0).T)  # key-1 .. 0, walking back
    reached = np.flatnonzero(np.cumsum(steps) >= path)
    return int(reached[0]) + 1 if len(reached) else key


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
        The longer check's verdict, its pose the first fit's moved along the
        degenerate axis by the longer fit (module docstring).
    """
    second = longer_fit(first, query_points, candidate_points, max_distance=max_distance,
                        config=config)
    return judged(first, second, config)


def longer_fit(
    first: LoopVerification,
    query_points: ArrayLike,
    candidate_points: ArrayLike,
    *,
    max_distance: float | None,
    config: GeometricCheckConfig,
) -> LoopVerification:
    """The longer submaps' own verdict, its whole pose (`recheck_longer`'s arguments)."""
    normals = None
    if config.compiled_icp:
        from loopclosure.fast_icp import estimate_normals_fast as normals  # numba

    target = RegistrationTarget(candidate_points, config.icp, normals=normals)
    return verify(query_points, target, headings=[float(first.relative[2])],
                  max_distance=max_distance, config=config)


def departure(first: LoopVerification, second: LoopVerification) -> tuple[float, float, float]:
    """`second`'s pose from `first`'s: along `first`'s degenerate axis [m], the
    distance across it [m] and the heading difference [deg] (absolute)."""
    axis = np.asarray(first.degenerate_axis, dtype=float)
    step = second.relative[:2] - first.relative[:2]
    along = float(step @ axis)
    across = float(np.hypot(*(step - along * axis)))
    turn = abs(float(np.degrees(se2.wrap_angle(second.relative[2] - first.relative[2]))))
    return along, across, turn


def judged(first: LoopVerification, second: LoopVerification,
           config: GeometricCheckConfig) -> LoopVerification:
    """The candidate's verdict from the first check's and the longer fit's (module
    docstring)."""
    if not second.accepted:
        return dataclasses.replace(
            second, reason=f"{first.reason}; longer submaps: {second.reason}")
    along, across, turn = departure(first, second)
    if across > config.ambiguity_distance or turn > config.ambiguity_angle_deg:
        return dataclasses.replace(
            second, accepted=False,
            reason=f"{first.reason}; longer submaps fit elsewhere ({across:.2f} m across "
                   f"the degenerate axis, {turn:.1f} deg)")
    relative = first.relative.copy()
    relative[:2] += along * np.asarray(first.degenerate_axis, dtype=float)
    return dataclasses.replace(second, relative=relative)
