"""A candidate loop closure of one query, as the loop detector reports it: `LoopCandidate`
(`loopclosure.loop_detector`), with the appearance search's figures of its place."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from loopclosure.geometric_check import LoopVerification
from loopclosure.place_match import PlaceMatch

Array = NDArray[np.float64]


@dataclass(slots=True)
class LoopCandidate:
    """One candidate of one query, verified or rejected.

    Attributes:
        query: the new keyframe's key.
        match: the older keyframe's key.
        source: the search that proposed it: ``"pose"`` (pose-gated) or
            ``"appearance"`` (the place database; also when both proposed it).
        accepted: the geometric check accepted it.
        reason: why not (or ``"accepted"``).
        relative: ``(3,)`` pose of the query keyframe in the match's frame.
        covariance: ``3x3`` covariance of `relative` (floored).
        verification: the full geometric-check result.
        predicted_distance: distance [m] between the two keyframes' current estimates.
        prior: the check started from the predicted relative pose (the candidate lay
            inside the pose gate); else from the database's heading hypotheses.
        prefilter_distance: appearance: combined normalised prefilter distance
            (unitless; NaN for pose candidates).
        prefilter_rank: appearance: 0-based rank by prefilter distance (-1 for pose).
        fused_score: appearance: fused place-recognition score in [0, 1] (NaN for
            pose candidates).
        verifier_distances: appearance: each verifier's distance, by matcher name, in
            that matcher's unit (empty for pose candidates).
    """

    query: int
    match: int
    source: str
    accepted: bool
    reason: str
    relative: Array
    covariance: Array
    verification: LoopVerification | None = None
    predicted_distance: float = float("nan")
    prior: bool = False
    prefilter_distance: float = float("nan")
    prefilter_rank: int = -1
    fused_score: float = float("nan")
    verifier_distances: dict[str, float] = field(default_factory=dict)

    @classmethod
    def checked(
        cls,
        query: int,
        match: int,
        source: str,
        result: LoopVerification,
        *,
        predicted_distance: float = float("nan"),
        prior: bool = False,
        prefilter_distance: float = float("nan"),
        prefilter_rank: int = -1,
        fused_score: float = float("nan"),
        verifier_distances: dict[str, float] | None = None,
    ) -> LoopCandidate:
        """The candidate as the geometric check judged it, with its search's figures."""
        return cls(
            query=query, match=match, source=source, accepted=result.accepted,
            reason=result.reason, relative=result.relative, covariance=result.covariance,
            verification=result, predicted_distance=predicted_distance, prior=prior,
            prefilter_distance=prefilter_distance, prefilter_rank=prefilter_rank,
            fused_score=fused_score, verifier_distances=dict(verifier_distances or {}),
        )



def place_figures(m: PlaceMatch) -> dict:
    """The appearance search's figures of one match, as `LoopCandidate` fields."""
    return {
        "prefilter_distance": m.prefilter_distance, "prefilter_rank": m.prefilter_rank,
        "fused_score": m.score, "verifier_distances": m.verifier_distances,
    }
