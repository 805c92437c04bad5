"""Loop-closure precision and recall against reference poses.

A proposal joins two keyframes, identified by their stamps ``(stamp_a, stamp_b)``,
with a relative pose (pose of b in the frame of a, ``(x, y, theta)``) and a score
(higher = more confident).  With reference poses ``R_a, R_b`` at those stamps:

- the proposal is **true** when the reference puts the two poses within
  `max_distance` (default 2 m) of each other AND its relative pose agrees with the
  reference ``R_a^-1 R_b`` within `trans_tol` (0.2 m) and `rot_tol_deg` (2 deg);
  otherwise it is a false positive (a wrong place, or the right place with a wrong
  transform, which would bend the map just as badly);
- **recall** is over query keyframes: a keyframe *should* close a loop when some
  keyframe more than `min_separation` keyframes earlier lies within `max_distance`
  of it in the reference; it is *recalled* when an accepted true proposal has it as
  its later keyframe.  ``recall = recalled / should``.
- the **P-R curve** sweeps the score threshold over all proposals (accepted or not):
  at threshold s the proposals with score >= s count as accepted.

Stamps are matched to the reference within `stamp_tolerance` seconds; proposals
whose stamps the reference does not contain are counted as unverifiable and left
out of precision.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from data import se2
from data.types import Trajectory
from evaluation.relations_metric import lookup

Array = NDArray[np.float64]


@dataclass(slots=True)
class LoopProposal:
    """A proposed loop closure between the keyframes at `stamp_a` (earlier) and `stamp_b`."""

    stamp_a: float
    stamp_b: float
    relative: Array
    score: float
    accepted: bool = True


@dataclass(slots=True)
class LoopMetrics:
    """Precision/recall figures and the P-R curve."""

    proposals: int
    accepted: int
    true_positives: int
    false_positives: int
    unverifiable: int
    precision: float
    recall: float
    f1: float
    queries_with_loop: int
    queries_recalled: int
    curve_thresholds: Array = field(default_factory=lambda: np.zeros(0))
    curve_precision: Array = field(default_factory=lambda: np.zeros(0))
    curve_recall: Array = field(default_factory=lambda: np.zeros(0))
    is_true: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))
    errors: Array = field(default_factory=lambda: np.zeros((0, 3)))
    """``(proposals, 3)``: per proposal the reference distance of its two poses [m], and
    its relative pose's error against the reference: translation [m], rotation [deg]
    (absolute); NaN rows for unverifiable proposals."""

    def to_json(self) -> dict[str, float | int]:
        """The summary figures."""
        return {
            "proposals": self.proposals,
            "accepted": self.accepted,
            "true_positives": self.true_positives,
            "false_positives": self.false_positives,
            "unverifiable": self.unverifiable,
            "precision": self.precision,
            "recall": self.recall,
            "f1": self.f1,
            "queries_with_loop": self.queries_with_loop,
            "queries_recalled": self.queries_recalled,
        }


def _f1(p: float, r: float) -> float:
    return 2 * p * r / (p + r) if p + r > 0 else 0.0


def loop_queries(
    keyframe_xy: Array, max_distance: float, min_separation: int
) -> NDArray[np.bool_]:
    """Keyframes (in order) that should close a loop: an earlier keyframe more than
    `min_separation` keyframes back lies within `max_distance` metres."""
    tree = cKDTree(keyframe_xy)
    pairs = tree.query_pairs(max_distance, output_type="ndarray")
    should = np.zeros(len(keyframe_xy), dtype=bool)
    if len(pairs):
        far = np.abs(pairs[:, 1] - pairs[:, 0]) > min_separation
        should[pairs[far].max(axis=1)] = True
    return should


def evaluate_loops(
    proposals: Sequence[LoopProposal],
    reference: Trajectory,
    keyframe_stamps: Array,
    *,
    max_distance: float = 2.0,
    trans_tol: float = 0.2,
    rot_tol_deg: float = 2.0,
    min_separation: int = 10,
    stamp_tolerance: float = 0.01,
) -> LoopMetrics:
    """Precision, recall and P-R curve of `proposals` (see module docstring)."""
    ref_xyt = reference.xytheta()
    kf_idx = lookup(reference.stamps, np.asarray(keyframe_stamps, float), stamp_tolerance)
    kf_ok = kf_idx >= 0
    kf_xy = ref_xyt[kf_idx[kf_ok], :2]
    should = loop_queries(kf_xy, max_distance, min_separation) if len(kf_xy) > 1 else np.zeros(0)
    kf_stamps_ok = np.asarray(keyframe_stamps, float)[kf_ok]

    n = len(proposals)
    stamps_a = np.array([p.stamp_a for p in proposals], dtype=float)
    stamps_b = np.array([p.stamp_b for p in proposals], dtype=float)
    ia = lookup(reference.stamps, stamps_a, stamp_tolerance)
    ib = lookup(reference.stamps, stamps_b, stamp_tolerance)
    verifiable = (ia >= 0) & (ib >= 0)
    is_true = np.zeros(n, dtype=bool)
    errors = np.full((n, 3), np.nan)
    if verifiable.any():
        ra, rb = ref_xyt[ia[verifiable]], ref_xyt[ib[verifiable]]
        rel_ref = se2.between(ra, rb)
        rel_est = np.array([p.relative for p in proposals], dtype=float).reshape(-1, 3)[verifiable]
        err = se2.between(rel_ref, rel_est)
        close = np.linalg.norm(rb[:, :2] - ra[:, :2], axis=1) <= max_distance
        agree = (np.linalg.norm(err[:, :2], axis=1) <= trans_tol) & (
            np.abs(np.degrees(err[:, 2])) <= rot_tol_deg
        )
        is_true[verifiable] = close & agree
        errors[verifiable] = np.column_stack([
            np.linalg.norm(rb[:, :2] - ra[:, :2], axis=1),
            np.linalg.norm(err[:, :2], axis=1),
            np.abs(np.degrees(err[:, 2])),
        ])
    accepted = np.array([p.accepted for p in proposals], dtype=bool)
    scores = np.array([p.score for p in proposals], dtype=float)

    # The later keyframe of each proposal, as an index among the verifiable keyframes.
    later = np.where(stamps_b >= stamps_a, stamps_b, stamps_a)
    query = lookup(kf_stamps_ok, later, stamp_tolerance) if len(kf_stamps_ok) else -np.ones(n, int)

    def recall_of(mask: NDArray[np.bool_]) -> tuple[float, int]:
        hit = np.zeros(len(should), dtype=bool)
        q = query[mask & is_true]
        hit[q[q >= 0]] = True
        recalled = int((hit & should).sum())
        return (recalled / should.sum() if should.sum() else 0.0), recalled

    tp = int((accepted & is_true & verifiable).sum())
    fp = int((accepted & ~is_true & verifiable).sum())
    precision = tp / (tp + fp) if tp + fp else 1.0
    recall, recalled = recall_of(accepted)

    order = np.argsort(-scores, kind="stable")
    thresholds = np.unique(scores)[::-1]
    cum_tp = np.cumsum((is_true & verifiable)[order])
    cum_fp = np.cumsum((~is_true & verifiable)[order])
    last = np.searchsorted(-scores[order], -thresholds, side="right") - 1
    curve_p = cum_tp[last] / np.maximum(cum_tp[last] + cum_fp[last], 1)
    curve_r = np.array([recall_of(scores >= t)[0] for t in thresholds]) if len(thresholds) else []

    return LoopMetrics(
        proposals=n,
        accepted=int(accepted.sum()),
        true_positives=tp,
        false_positives=fp,
        unverifiable=int((~verifiable).sum()),
        precision=precision,
        recall=recall,
        f1=_f1(precision, recall),
        queries_with_loop=int(should.sum()),
        queries_recalled=recalled,
        curve_thresholds=thresholds,
        curve_precision=np.asarray(curve_p, dtype=float),
        curve_recall=np.asarray(curve_r, dtype=float),
        is_true=is_true,
        errors=errors,
    )
