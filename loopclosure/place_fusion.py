"""Verify and fuse a place query's candidates (`loopclosure.place_database`, steps 2-3).

`stage_distances`: each verifier (any registered matcher) computes its `distances`
over the K candidates only, their descriptors stacked on demand (the database never
holds a stacked copy of an expensive descriptor); a non-finite or negative distance
becomes the largest float, resp. 0.

`StageFusion`: the fused score of the candidates.

From the ``(S, K)`` raw distances of every stage (prefilter stages first, then the
verifiers, `PlaceDatabaseConfig.stages` order) over K candidates and their combined
normalised prefilter distance p, by `PlaceDatabaseConfig.resolved_fusion`:

- ``"logistic"``: P(same place) = sigma(b + sum_s w_s log(d_s / scale_s + eps)) over
  every stage (`loopclosure.fusion.LogisticFusion`, its coefficients reordered to
  the stages);
- ``"rank"``: reciprocal rank fusion of the stages over the K candidates
  (`loopclosure.fusion.reciprocal_rank_fusion`);
- ``"verifier"``: exp(-mean_v d_v / scale_v) over the verifiers only;
- ``"prefilter"``: exp(-p).

Scores are in [0, 1], higher = more likely the same place.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from loopclosure.fusion import LogisticFusion, reciprocal_rank_fusion
from loopclosure.matchers.base import Matcher
from loopclosure.place_config import PlaceDatabaseConfig
from loopclosure.place_match import Descriptors

Array = NDArray[np.float64]


class StageFusion:
    """The fusion rule of one database's config, built once."""

    def __init__(self, cfg: PlaceDatabaseConfig) -> None:
        self._mode = cfg.resolved_fusion
        self._rank_constant = cfg.rank_constant
        self._base = len(cfg.prefilter)
        self._logistic: LogisticFusion | None = None
        if self._mode == "logistic":
            order = [cfg.logistic.names.index(s) for s in cfg.stages]
            self._logistic = LogisticFusion(
                cfg.stages,
                tuple(cfg.logistic.coefficients[i] for i in order),
                cfg.logistic.intercept,
                cfg.logistic.eps,
            )

    def scores(self, dist: Array, pre: Array, scales: Array) -> Array:
        """``(K,)`` fused scores in [0, 1] of ``(S, K)`` stage distances, ``(K,)``
        prefilter distances p and ``(S,)`` stage scales (each stage's unit)."""
        if self._logistic is not None:
            return self._logistic.score(dist.T, scales)
        if self._mode == "rank":
            return reciprocal_rank_fusion(dist, self._rank_constant)
        if self._mode == "verifier":
            base = self._base
            norm = dist[base:] / scales[base:, None]
            return np.exp(-norm.mean(axis=0))
        return np.exp(-pre)


def stage_distances(config: PlaceDatabaseConfig, matchers: Mapping[str, Matcher],
                    stored: Sequence[Descriptors], q: Descriptors, cand: NDArray[np.intp],
                    raw: Mapping[str, Array]) -> Array:
    """``(S, K)`` raw distances of every stage over the candidate rows `cand`: the
    prefilter stages' from `raw` (computed by the screen), the verifiers' from the
    query's descriptors `q` and the stored ones (`stored`, per row)."""
    out = np.empty((len(config.stages), len(cand)))
    for t, s in enumerate(config.prefilter):
        out[t] = raw[s]
    base = len(config.prefilter)
    for t, v in enumerate(config.verifiers):
        matcher = matchers[v]
        stacked = matcher.stack([stored[i][v] for i in cand.tolist()])
        d = np.asarray(matcher.distances(q[v], stacked), float)
        out[base + t] = np.where(np.isfinite(d), np.maximum(d, 0.0), np.finfo(float).max)
    return out


__all__ = ["StageFusion", "stage_distances"]
