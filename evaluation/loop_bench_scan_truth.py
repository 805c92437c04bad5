"""How far a trajectory reference disagrees with its own scans, near one keyframe.

A reference trajectory (a corrected log's GMapping poses, a TUM file) carries no
uncertainty of its own, yet it is a scan matcher's estimate too: where it bends, the
relative pose it gives two keyframes can be off by a degree or more, and a fit that
agrees with the scans is then judged wrong at the benchmark's 2-degree tolerance.
The scans themselves say where: keyframe ``k``'s scan, placed by the reference among
the scans of the keyframes just before it (``k - half .. k - 1``), and among those just
after it, should sit where ICP leaves it.  `scan_disagreement` is how far ICP moves
it (point to line, `loopclosure.registration.register`, from the reference's
placement, a 1 m gate then a 0.3 m one), the larger of the two sides: a rotation
[rad] and a translation [m], the latter across the fit's weak axis only (its least
translational information: a scan in a corridor slides along it by whatever the
search happens to settle on, which says nothing of the reference).  Poses that hold
their scans together move them little.

`disagreement_sigmas` turns the two keyframes' moves of each detection into the
``(x, y, theta)`` standard deviations that `evaluation.loop_bench_truth.
within_reference_uncertainty` widens the tolerance by (``k`` of them, 3 by default):
the moves of the two keyframes add in quadrature, and the result is divided by that
``k`` so the tolerance widens by the measured disagreement itself, not by three times
it.  It only marks wrong detections as *unverifiable* beside the measures; it never
changes which detections count as correct.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data import se2
from loopclosure.registration import IcpConfig, RegistrationTarget, register

Array = NDArray[np.float64]

#: ICP of one scan onto its neighbours, run to convergence: a wide gate (a degree
#: turns a wall 8 m away by 0.14 m), then a tight one from where it ends.
WIDE_ICP = IcpConfig(max_correspondence_distance=1.0, max_iterations=100,
                     translation_tolerance=1e-6, rotation_tolerance=1e-7)
FINE_ICP = IcpConfig(max_correspondence_distance=0.3, max_iterations=200,
                     translation_tolerance=1e-6, rotation_tolerance=1e-7)
#: `within_reference_uncertainty`'s default ``k``: the sigmas are the moves over it.
SIGMA_K = 3.0


def scan_disagreement(points: Sequence[ArrayLike], poses: ArrayLike, key: int,
                      half: int = 5) -> tuple[float, float]:
    """How far ICP moves keyframe `key`'s scan onto its neighbours' as `poses` place them.

    Each side on its own: the keyframes ``key - half .. key - 1`` (those with a pose),
    then ``key + 1 .. key + half``; the larger move of the two (by its rotation).  A
    reference that kinks at `key` (its pose turned against the keyframes before it, and
    those after it turned with it) moves the scan fully onto one side and not at all
    onto the other: both sides at once would split the kink.

    Args:
        points: every keyframe's scan points, ``(M_i, 2)`` [m] in its sensor frame.
        poses: ``(n, 3)`` the reference's keyframe poses [m, m, rad] (NaN rows: none).
        key: the keyframe.
        half: neighbours on each side.

    Returns:
        ``(metres, radians)`` of the move (absolute; the metres across ICP's weak axis,
        `loopclosure.registration.IcpResult.degenerate_axis`), NaN when `key` has no pose or
        neither side has two neighbours with one (or ICP fails on both).
    """
    p = np.asarray(poses, dtype=float).reshape(-1, 3)
    if not np.isfinite(p[key]).all():
        return float("nan"), float("nan")
    scan = np.asarray(points[key], float).reshape(-1, 2)
    best = (float("nan"), float("nan"))
    for side in (range(max(0, key - half), key), range(key + 1, min(len(p), key + half + 1))):
        ids = [j for j in side if np.isfinite(p[j]).all()]
        if len(ids) < 2:
            continue
        others = np.vstack([se2.transform_points(se2.between(p[key], p[j]),
                                                 np.asarray(points[j], float).reshape(-1, 2))
                            for j in ids])
        target = RegistrationTarget(others, FINE_ICP)
        r = register(scan, target, np.zeros(3), config=WIDE_ICP)
        if r.ok:
            r = register(scan, target, r.pose, config=FINE_ICP)
        if not r.ok:
            continue
        weak = np.asarray(r.degenerate_axis, float).reshape(2)
        across = float(abs(r.pose[0] * weak[1] - r.pose[1] * weak[0]))  # off the weak axis
        move = (across, abs(float(se2.wrap_angle(r.pose[2]))))
        if not move[1] <= best[1]:  # NaN best: any move
            best = move
    return best


def disagreement_sigmas(moves: ArrayLike, pairs: ArrayLike, k: float = SIGMA_K) -> Array:
    """``(m, 3)`` sigmas (x, y [m], theta [rad]) of keyframe `pairs` ``(m, 2)``.

    `moves` ``(n, 2)``: each keyframe's `scan_disagreement` (metres, radians).  The
    pair's moves add in quadrature and are divided by `k` (module docstring); the
    translation is split evenly over x and y (their hypot is the move).  NaN where
    either keyframe's move is unknown."""
    mv = np.asarray(moves, float).reshape(-1, 2)
    pr = np.asarray(pairs, np.intp).reshape(-1, 2)
    both = np.sqrt(mv[pr[:, 0]] ** 2 + mv[pr[:, 1]] ** 2) / k
    out = np.empty((len(pr), 3))
    out[:, 0] = out[:, 1] = both[:, 0] / np.sqrt(2.0)
    out[:, 2] = both[:, 1]
    return out
