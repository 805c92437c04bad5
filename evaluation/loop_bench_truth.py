"""Truth and measures of `loopclosure bench loops`: revisits, top-1 precision-recall, recall@K.

Appearance-only loop detection as the literature measures it (e.g. FLIRT, Tipaldi and
Arras 2010; GLARE, Himstedt et al. 2014): every query keyframe proposes its single
best match in the database of older keyframes, with a score (higher = more
confident); a threshold on the score decides which proposals are loop closures.

Definitions (reference poses ``(x, y, theta)`` [m, m, rad], sensor frame, one per
keyframe; ``max_distance`` = 2 m by default):

* a query **has a revisit** when some keyframe of its database lies within
  ``max_distance`` of it in the reference (`revisit_truth`);
* a proposal is **correct** when the reference puts its two keyframes within
  ``max_distance`` (`place_correct`); after the geometric check it must also have
  been accepted and its relative pose (the query's pose in the match's frame) must
  agree with the reference's within ``trans_tol`` (0.2 m) and ``rot_tol_deg``
  (2 degrees) (`pose_correct`);
* **precision-recall curve** over the score threshold t (`pr_curve`): the proposals
  with score >= t are accepted; precision(t) = correct accepted / accepted, recall(t)
  = correct accepted / queries with a revisit.  One point per distinct score
  (ties are accepted together), plus the empty start (recall 0, precision 1).
  A query without a proposal (empty database, no descriptor) is never accepted.
* **recall at P% precision** (`recall_at_precision`): the largest recall of a curve
  point whose precision is at least P (1.0 for 100%; 0 when even the best-scored
  proposal is wrong);
* **average precision** (`average_precision`): the step sum
  ``sum_n (R_n - R_{n-1}) P_n`` over the curve points (scikit-learn's definition),
  with recall over the queries that have a revisit, so it is at most the largest
  recall reached;
* **recall@K** (`recall_at_k`): fraction of the queries with a revisit for which one
  of the K best-ranked database keyframes is within ``max_distance`` of the query.
* **unverifiable** (`within_reference_uncertainty`, a diagnosis beside the measures
  above, which it does not change): a wrong detection after the check whose place
  distance and pose errors are all within the tolerance plus ``k`` standard
  deviations of the reference's own relative pose between the two keyframes (a
  relations reference knows them: `evaluation.slam_reference.relative_sigmas`; a
  trajectory reference's come from its disagreement with its own scans:
  `evaluation.loop_bench_scan_truth`).
  The recall at 100% / 99% precision with those detections set aside (neither
  correct nor wrong) says how much of a cap the reference, not the detector, sets.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data import se2
from data.errors import UserError

Array = NDArray[np.float64]


def revisit_truth(
    query_xy: ArrayLike, database_xy: ArrayLike, max_distance: float = 2.0
) -> tuple[bool, Array]:
    """Whether a query has a revisit, and the distance [m] to every database keyframe.

    Args:
        query_xy: ``(2,)`` reference position of the query [m].
        database_xy: ``(M, 2)`` reference positions of its database keyframes [m].
        max_distance: revisit radius [m].
    """
    q = np.asarray(query_xy, float).reshape(2)
    db = np.asarray(database_xy, float).reshape(-1, 2)
    d = np.hypot(db[:, 0] - q[0], db[:, 1] - q[1])
    return bool(len(d) and d.min() <= max_distance), d


def place_correct(
    query_xy: ArrayLike, match_xy: ArrayLike, max_distance: float = 2.0
) -> NDArray[np.bool_]:
    """``(n,)`` True where the reference puts query and match within `max_distance` [m]."""
    q = np.asarray(query_xy, float).reshape(-1, 2)
    m = np.asarray(match_xy, float).reshape(-1, 2)
    return np.hypot(*(q - m).T) <= max_distance


def pose_errors(
    reference_query: ArrayLike, reference_match: ArrayLike, relative: ArrayLike
) -> Array:
    """``(n, 2)`` error of estimated relative poses against the reference: [m], [deg].

    `relative` is the query's pose in the match's frame ``(x, y, theta)``; the
    reference's is ``between(reference_match, reference_query)``.
    """
    ref = se2.between(np.asarray(reference_match, float).reshape(-1, 3),
                      np.asarray(reference_query, float).reshape(-1, 3))
    err = se2.between(ref, np.asarray(relative, float).reshape(-1, 3))
    return np.column_stack([np.hypot(err[:, 0], err[:, 1]), np.abs(np.degrees(err[:, 2]))])


def pose_correct(
    reference_query: ArrayLike,
    reference_match: ArrayLike,
    relative: ArrayLike,
    *,
    max_distance: float = 2.0,
    trans_tol: float = 0.2,
    rot_tol_deg: float = 2.0,
) -> NDArray[np.bool_]:
    """``(n,)`` True where the place is right (`place_correct`) and the relative pose agrees
    with the reference within `trans_tol` [m] and `rot_tol_deg` [deg]."""
    rq = np.asarray(reference_query, float).reshape(-1, 3)
    rm = np.asarray(reference_match, float).reshape(-1, 3)
    err = pose_errors(rq, rm, relative)
    return (place_correct(rq[:, :2], rm[:, :2], max_distance) & (err[:, 0] <= trans_tol)
            & (err[:, 1] <= rot_tol_deg))


@dataclass(slots=True, frozen=True)
class PRCurve:
    """A top-1 precision-recall curve (module docstring), best score first.

    Attributes:
        thresholds: ``(P,)`` score thresholds (decreasing; the first point, the empty
            set, has +inf).
        precision, recall: ``(P,)`` at each threshold.
        revisits: queries with a revisit (the recall denominator).
    """

    thresholds: Array
    precision: Array
    recall: Array
    revisits: int


def pr_curve(scores: ArrayLike, correct: ArrayLike, revisits: int) -> PRCurve:
    """Precision-recall of top-1 proposals over the score threshold (module docstring).

    Args:
        scores: ``(n,)`` score of each query's proposal, higher = more confident;
            NaN or -inf = no proposal (never accepted).
        correct: ``(n,)`` whether each proposal is correct.
        revisits: queries with a revisit (>= the number of correct proposals).

    Raises:
        UserError: shapes differ, or more correct proposals than revisits.
    """
    s = np.asarray(scores, float).reshape(-1)
    c = np.asarray(correct, bool).reshape(-1)
    if s.shape != c.shape:
        raise UserError(f"pr_curve: {len(s)} scores but {len(c)} correctness flags")
    proposed = np.isfinite(s) | (s == np.inf)
    s, c = s[proposed], c[proposed]
    if int(c.sum()) > revisits:
        raise UserError(f"pr_curve: {int(c.sum())} correct proposals but only {revisits} "
                        "revisits")
    order = np.argsort(-s, kind="stable")
    s, c = s[order], c[order]
    tp = np.cumsum(c)
    n = np.arange(1, len(s) + 1)
    last = np.r_[s[1:] != s[:-1], True] if len(s) else np.zeros(0, bool)
    tp, n, thr = tp[last], n[last], s[last]
    precision = np.r_[1.0, tp / np.maximum(n, 1)]
    recall = np.r_[0.0, tp / revisits] if revisits else np.zeros(len(tp) + 1)
    return PRCurve(np.r_[np.inf, thr], precision, recall, int(revisits))


def recall_at_precision(curve: PRCurve, precision: float) -> float:
    """Largest recall of a curve point with precision >= `precision` (0 if none but the
    empty start).  Precision 1.0 gives recall at 100% precision."""
    ok = curve.precision >= precision - 1e-12
    return float(curve.recall[ok].max()) if ok.any() else 0.0


def average_precision(curve: PRCurve) -> float:
    """``sum_n (R_n - R_{n-1}) P_n`` over the curve points (module docstring)."""
    return float(np.sum(np.diff(curve.recall) * curve.precision[1:]))


def recall_at_k(hits: ArrayLike, has_revisit: ArrayLike, ks: tuple[int, ...]) -> dict[int, float]:
    """Recall@K for every K of `ks` (module docstring).

    Args:
        hits: ``(n, Kmax)`` booleans, ``hits[i, r]`` True when the database keyframe
            ranked r (0-based) for query i is within the revisit radius (False past
            the end of a small database).
        has_revisit: ``(n,)`` the queries that have a revisit.
        ks: the K values (each >= 1).
    """
    h = np.asarray(hits, bool)
    rv = np.asarray(has_revisit, bool).reshape(-1)
    if h.ndim != 2 or len(h) != len(rv):
        raise UserError(f"recall_at_k: hits must be ({len(rv)}, K), got shape {h.shape}")
    if any(k < 1 for k in ks):
        raise UserError(f"recall_at_k: every K must be >= 1, got {ks}")
    n = int(rv.sum())
    out = {}
    for k in ks:
        found = h[:, :k].any(axis=1) & rv
        out[int(k)] = float(found.sum() / n) if n else 0.0
    return out


def within_reference_uncertainty(
    errors: ArrayLike, place_m: ArrayLike, sigmas: ArrayLike, *, max_distance: float = 2.0,
    trans_tol: float = 0.2, rot_tol_deg: float = 2.0, k: float = 3.0,
) -> NDArray[np.bool_]:
    """``(n,)`` True where a detection's errors are all inside the tolerances widened by
    `k` reference sigmas (module docstring, *unverifiable*).

    Args:
        errors: ``(n, 2)`` pose errors [m], [deg] (`pose_errors`).
        place_m: ``(n,)`` reference distance of the two keyframes [m].
        sigmas: ``(n, 3)`` standard deviations (x, y [m], theta [rad]) of the
            reference's relative pose; NaN (unknown) gives False.
    """
    e = np.asarray(errors, float).reshape(-1, 2)
    d = np.asarray(place_m, float).reshape(-1)
    sig = np.asarray(sigmas, float).reshape(-1, 3)
    s_m = np.hypot(sig[:, 0], sig[:, 1])
    s_deg = np.degrees(sig[:, 2])
    with np.errstate(invalid="ignore"):
        return ((e[:, 0] <= trans_tol + k * s_m) & (e[:, 1] <= rot_tol_deg + k * s_deg)
                & (d <= max_distance + k * s_m))


def curve_summary(curve: PRCurve) -> dict[str, float]:
    """Recall at 100% and 99% precision and average precision of one curve."""
    return {
        "recall_at_p100": recall_at_precision(curve, 1.0),
        "recall_at_p99": recall_at_precision(curve, 0.99),
        "average_precision": average_precision(curve),
    }
