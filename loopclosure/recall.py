"""What the prefilter keeps: recall@k of a place database against ground-truth labels.

A reporting helper, not used while mapping: it tells how many same-place keyframes
survive the prefilter's screening (`loopclosure.place_database`, step 1) for a set of
labelled queries, i.e. whether the K candidates handed to the verifiers can contain
the right answer at all.

For a query q with label l, let S be the stored keyframes labelled l (q itself left
out when it is stored) and T_k the k stored keyframes of smallest combined prefilter
distance p (exact float64, `PlaceDatabase.prefilter_distances`).  Then

    recall@k   = mean over queries of |S & T_k| / min(k, |S|)       in [0, 1]
    hit rate@k = fraction of queries with |S & T_k| > 0

over the queries with a non-empty S.
"""

from __future__ import annotations

from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from data.errors import UserError
from loopclosure.matchers.vector_search import smallest_k
from loopclosure.place_database import PlaceDatabase
from loopclosure.place_match import Descriptors
from loopclosure.polygon import Polygon


@dataclass(slots=True, frozen=True)
class StageRecall:
    """What one stage keeps: recall@k over a set of labelled queries.

    Attributes:
        k: candidates kept per query.
        recall: mean over queries of (same-place keyframes among the k) /
            min(k, same-place keyframes stored), in [0, 1].
        hit_rate: fraction of queries with at least one same-place keyframe among
            the k (queries without any stored same-place keyframe are left out).
        queries: queries counted.
    """

    k: int
    recall: float
    hit_rate: float
    queries: int


def prefilter_recall_at_k(
    database: PlaceDatabase,
    labels: Mapping[Hashable, Hashable] | Sequence[Hashable],
    ks: Sequence[int] = (1, 5, 10, 20, 50),
    *,
    queries: Sequence[tuple[Hashable, Polygon | Descriptors]] | None = None,
    exclude_self: bool = True,
) -> list[StageRecall]:
    """Prefilter recall@k of `database` against ground-truth place labels (module docstring).

    Args:
        database: the place database.
        labels: place label of every stored key (a mapping key -> label, or a
            sequence in insertion order).
        ks: the k values.
        queries: ``(label, polygon or descriptors)`` queries; default: every stored
            keyframe queried against all others (leave one out).
        exclude_self: in the leave-one-out default, leave the query itself out.

    Returns:
        One `StageRecall` per k.
    """
    lab = _label_array(database, labels)
    keys = database.keys
    if queries is None:
        items: list[tuple[Any, Polygon | Descriptors, int | None]] = [
            (lab[i], database.descriptors(key), i) for i, key in enumerate(keys)
        ]
    else:
        items = [(label, d, None) for label, d in queries]
    kmax = max(ks)
    hits = np.zeros((len(items), len(ks)))
    avail = np.zeros(len(items))
    for n, (label, query, own) in enumerate(items):
        combined, _ = database.prefilter_distances(query)
        same = lab == label
        if own is not None and exclude_self:
            combined[own] = np.inf
            same[own] = False
        order = smallest_k(combined, min(kmax, int(np.isfinite(combined).sum())))
        found = np.cumsum(same[order])
        avail[n] = same.sum()
        for t, k in enumerate(ks):
            hits[n, t] = found[min(k, len(found)) - 1] if len(found) else 0
    use = avail > 0
    out = []
    for t, k in enumerate(ks):
        denom = np.minimum(avail[use], k)
        out.append(
            StageRecall(
                k=int(k),
                recall=float(np.mean(hits[use, t] / denom)) if use.any() else 0.0,
                hit_rate=float(np.mean(hits[use, t] > 0)) if use.any() else 0.0,
                queries=int(use.sum()),
            )
        )
    return out


def _label_array(
    database: PlaceDatabase, labels: Mapping[Hashable, Hashable] | Sequence[Hashable]
) -> Any:
    if isinstance(labels, Mapping):
        return np.asarray([labels[k] for k in database.keys])
    arr = np.asarray(labels)
    if len(arr) != len(database):
        raise UserError(f"{len(arr)} labels for {len(database)} stored keyframes")
    return arr


__all__ = ["StageRecall", "prefilter_recall_at_k"]
