"""Result types of the place database (`loopclosure.place_database`): one verified
candidate (`PlaceMatch`), the candidates of one query as arrays (`CandidateSet`), and
the descriptors of one keyframe (`Descriptors`).

Units: distances in each matcher's unit (prefilter p unitless after normalisation),
scores in [0, 1], headings in radians, stamps in seconds.
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from loopclosure.place_config import PREFILTER_STAGES

Array = NDArray[np.float64]
Descriptors = dict[str, Any]
"""Descriptors of one polygon: stage name -> that matcher's descriptor
(plus ``"heading"`` -> an `FFTDescriptor` when headings are on and FFT is no stage)."""


@dataclass(slots=True, frozen=True)
class PlaceMatch:
    """One verified candidate of a query.

    Attributes:
        key: the stored keyframe's key.
        prefilter_distance: combined normalised prefilter distance p (unitless).
        prefilter_rank: 0-based rank among the query's candidates by p (the K best
            are the K best of all allowed keyframes; the grids' extras follow).
        distances: raw distance per stage name (prefilter stages and verifiers),
            in each matcher's unit.
        score: fused score, higher = more likely the same place (a probability in
            [0, 1] with logistic fusion; in [0, 1] for every mode).
        headings: ``(heading [rad], correlation)`` hypotheses, best first: the heading
            of the query in the stored keyframe's frame (`loopclosure.headings`).
        stamp: the stored keyframe's stamp [s] (None if not given).
        pose: the stored keyframe's pose (as given at `add`, e.g. (x, y, theta)).
        view: which description of the stored keyframe matched, for a host that
            describes each keyframe more than once in databases of its own (the loop
            detector's wide view: 1); 0 from `query`.
    """

    key: Hashable
    prefilter_distance: float
    prefilter_rank: int
    distances: dict[str, float]
    score: float
    headings: tuple[tuple[float, float], ...]
    stamp: float | None = None
    pose: Any = None
    view: int = 0

    @property
    def verifier_distances(self) -> dict[str, float]:
        """Distances of the stages that are not prefilter stages."""
        return {k: v for k, v in self.distances.items() if k not in PREFILTER_STAGES}

    def with_view(self, view: int) -> PlaceMatch:
        """This match with `view` (``dataclasses.replace(self, view=view)``, without
        its per-call field introspection: the loop detector relabels thousands of
        matches per keyframe)."""
        return PlaceMatch(self.key, self.prefilter_distance, self.prefilter_rank,
                          self.distances, self.score, self.headings, self.stamp, self.pose,
                          view)

    def with_rank(self, rank: int) -> PlaceMatch:
        """This match with `prefilter_rank` `rank` (as `with_view`)."""
        return PlaceMatch(self.key, self.prefilter_distance, rank, self.distances,
                          self.score, self.headings, self.stamp, self.pose, self.view)


@dataclass(slots=True, frozen=True)
class CandidateSet:
    """The candidates of one query (the K best by p and the grids' extras) as
    arrays, in prefilter order.

    Attributes:
        indices: ``(C,)`` insertion indices of the C candidates.
        prefilter: ``(C,)`` combined normalised prefilter distance p (increasing).
        distances: ``(S, C)`` raw distance of every stage (`PlaceDatabaseConfig.stages`).
        scores: ``(C,)`` fused scores in [0, 1].
        prefilter_all: ``(M,)`` p of every stored keyframe (inf where not allowed;
            float32 screening values, relative error ~1e-6), or None unless asked
            for (`PlaceDatabase.candidates` ``keep_prefilter``).
    """

    indices: NDArray[np.intp]
    prefilter: Array
    distances: Array
    scores: Array
    prefilter_all: Array | None

    def order(self) -> NDArray[np.intp]:
        """Positions sorted by decreasing score, ties in prefilter order."""
        return np.lexsort((np.arange(len(self.scores)), -self.scores))


__all__ = ["CandidateSet", "Descriptors", "PlaceMatch"]
