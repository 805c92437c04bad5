"""Retrieval figures of an object set's distance matrix, as the stripes paper defines them.

Paper: "Stripes-based Object Matching" (``papers/stripes-object-matching.txt``),
Section VI.B-C.  Every scanned object is a query against the whole set, itself
included, so position 1 is always the query itself (the paper's row starts at 100):

- Table I (`retrieval_counts`): for positions 1..k (k = 10), how many queries have an
  object of their own class at that position.
- Table II (`class_accuracy`): per query, the fraction of same-class objects among its
  k nearest (itself included, as Table I: the paper's Table II means times 10 equal
  its Table I sums, e.g. 81.2 % and 812 for "Our"); averaged over the queries of
  each class.
- Bull's eye (`evaluation.retrieval.bullseye`): same-class hits among the 2n nearest
  (n = class size), the query included.
- Nearest-neighbour precision: Table I position 2 divided by the number of queries.

Ranking rule: the query is put first (a matcher whose self-distance is not the
smallest is not rewarded or punished for it); other ties keep the set's order (stable
sort).  With several scans per object the nearest neighbour is usually another scan
of the *same* object, so `evaluate` also gives every figure with the query's sibling
scans removed from its ranking ("other objects").
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError
from evaluation.retrieval import bullseye

Array = NDArray[np.float64]


def _ranking(
    distances: ArrayLike, exclude: NDArray[np.bool_] | None = None
) -> tuple[NDArray[np.intp], NDArray[np.bool_]]:
    """Each query's ranking (query first, stable) and which ranked entries are valid."""
    d = np.array(distances, dtype=float)
    if d.ndim != 2 or d.shape[0] != d.shape[1]:
        raise UserError(f"distances must be a square (M, M) matrix, got shape {d.shape}")
    m = d.shape[0]
    d[~np.isfinite(d)] = np.inf
    valid = np.ones((m, m), dtype=bool)
    if exclude is not None:
        ex = np.asarray(exclude, dtype=bool).copy()
        np.fill_diagonal(ex, False)
        valid = ~ex
        d[ex] = np.inf
    np.fill_diagonal(d, -np.inf)
    order = np.argsort(d, axis=1, kind="stable")
    # Excluded entries sort last (inf) but may tie with real inf distances: mask them.
    return order, np.take_along_axis(valid, order, axis=1)


def _hits(
    distances: ArrayLike,
    labels: ArrayLike,
    k: int,
    exclude: NDArray[np.bool_] | None = None,
) -> NDArray[np.bool_]:
    """``(M, k)`` same-class flags of each query's k nearest (False beyond the set's size)."""
    lab = np.asarray(labels)
    order, valid = _ranking(distances, exclude)
    kk = min(int(k), len(lab))
    out = np.zeros((len(lab), int(k)), dtype=bool)
    out[:, :kk] = (lab[order[:, :kk]] == lab[:, None]) & valid[:, :kk]
    return out


def retrieval_counts(
    distances: ArrayLike,
    labels: ArrayLike,
    k: int = 10,
    exclude: NDArray[np.bool_] | None = None,
) -> NDArray[np.int64]:
    """Table I: ``(k,)`` number of queries with a same-class object at positions 1..k.

    Positions beyond the set's size (sets of fewer than k objects) count 0.

    Args:
        distances: ``(M, M)`` distances, row i = query i against every object.
        labels: ``(M,)`` class of each object.
        k: deepest position.
        exclude: ``(M, M)`` True where object j must not be retrieved for query i
            (e.g. other scans of the query's own object); the diagonal is ignored.
    """
    return _hits(distances, labels, k, exclude).sum(axis=0).astype(np.int64)


def query_accuracy(
    distances: ArrayLike,
    labels: ArrayLike,
    k: int = 10,
    exclude: NDArray[np.bool_] | None = None,
) -> Array:
    """``(M,)`` fraction of same-class objects among each query's k nearest (itself included).

    The denominator is always k (the paper's "ratio between the matched objects and
    10"), so a set smaller than k cannot reach 1.
    """
    h = _hits(distances, labels, k, exclude)
    return h.sum(axis=1) / float(h.shape[1])


def class_accuracy(
    distances: ArrayLike,
    labels: ArrayLike,
    k: int = 10,
    exclude: NDArray[np.bool_] | None = None,
) -> dict[str, float]:
    """Table II: class -> mean of `query_accuracy` over the queries of that class.

    Classes appear in order of first occurrence in `labels`.
    """
    lab = np.asarray(labels)
    acc = query_accuracy(distances, lab, k, exclude)
    classes = list(dict.fromkeys(lab.tolist()))
    return {str(c): float(acc[lab == c].mean()) for c in classes}


def same_object_mask(objects: ArrayLike) -> NDArray[np.bool_]:
    """``(M, M)`` True where two scans come from the same object (the diagonal too)."""
    o = np.asarray(objects)
    return o[:, None] == o[None, :]


def cross_pose(distances: ArrayLike, labels: ArrayLike, objects: ArrayLike) -> dict[str, float]:
    """Different-pose figures (module docstring): ``instance`` and ``other_object``.

    Empty dict when no object has two scans.  Objects with a single scan take part
    neither as query nor in the database.
    """
    d = np.asarray(distances, dtype=float)
    lab = np.asarray(labels)
    obj = np.asarray(objects)
    ids = [o for o in dict.fromkeys(obj.tolist()) if np.count_nonzero(obj == o) >= 2]
    if len(ids) < 2:
        return {}
    first = np.array([np.flatnonzero(obj == o)[0] for o in ids])
    second = np.array([np.flatnonzero(obj == o)[1] for o in ids])
    sub = np.where(np.isfinite(d), d, np.inf)[np.ix_(first, second)]
    n = len(ids)
    instance = float(np.mean(np.argmin(sub, axis=1) == np.arange(n)))
    other = sub.copy()
    np.fill_diagonal(other, np.inf)
    nearest = np.argmin(other, axis=1)
    same = lab[second][nearest] == lab[first]
    return {"instance": instance, "other_object": float(np.mean(same)), "queries": float(n)}


@dataclass(slots=True)
class MethodResult:
    """Retrieval figures of one method on the scanned set.

    Attributes:
        name: ``stripes`` or a matcher name.
        distances: ``(M, M)`` distance matrix (row = query).
        seconds: representation + matching of the whole set [s].
        top_counts: Table I row (positions 1..k).
        class_accuracy: Table II row (class -> fraction).
        bullseye: Bull's eye [%].
        nn_precision: position 2 / queries.
        top_counts_other: Table I row with each query's sibling scans removed.
        class_accuracy_other: Table II row with sibling scans removed.
        nn_precision_other: nearest *other object* of the same class / queries.
        options: matcher options used (e.g. ``scale_invariant``).
        different_pose: `cross_pose` figures (empty with one scan per object).
    """

    name: str
    distances: Array
    seconds: float
    top_counts: NDArray[np.int64]
    class_accuracy: dict[str, float]
    bullseye: float
    nn_precision: float
    top_counts_other: NDArray[np.int64]
    class_accuracy_other: dict[str, float]
    nn_precision_other: float
    options: dict[str, Any] = field(default_factory=dict)
    different_pose: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """Figures of the method (without the distance matrix)."""
        return {
            "top10_counts": self.top_counts.tolist(),
            "class_accuracy": self.class_accuracy,
            "bullseye": self.bullseye,
            "nn_precision": self.nn_precision,
            "top10_counts_other_objects": self.top_counts_other.tolist(),
            "class_accuracy_other_objects": self.class_accuracy_other,
            "nn_precision_other_objects": self.nn_precision_other,
            "seconds": self.seconds,
            "options": self.options,
            "different_pose": self.different_pose,
        }


def evaluate(
    name: str,
    distances: Array,
    labels: Sequence[str],
    objects: ArrayLike,
    seconds: float,
    k: int = 10,
    options: dict[str, Any] | None = None,
) -> MethodResult:
    """All retrieval figures of one distance matrix (see the module docstring)."""
    lab = np.asarray(labels)
    d = np.asarray(distances, dtype=float)
    siblings = same_object_mask(objects)
    np.fill_diagonal(siblings, False)
    counts = retrieval_counts(d, lab, k)
    counts_other = retrieval_counts(d, lab, k, exclude=siblings)
    m = len(lab)
    d_b = np.where(np.isfinite(d), d, np.finfo(float).max)
    return MethodResult(
        name=name,
        distances=d,
        seconds=float(seconds),
        top_counts=counts,
        class_accuracy=class_accuracy(d, lab, k),
        bullseye=bullseye(d_b, lab),
        nn_precision=float(counts[1] / m) if len(counts) > 1 else 0.0,
        top_counts_other=counts_other,
        class_accuracy_other=class_accuracy(d, lab, k, exclude=siblings),
        nn_precision_other=float(counts_other[1] / m) if len(counts_other) > 1 else 0.0,
        options=dict(options or {}),
        different_pose=cross_pose(d, lab, objects),
    )
