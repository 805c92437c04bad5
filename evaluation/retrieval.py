"""Retrieval measures of the place-recognition paper (Section III.B), from a distance matrix.

All functions take ``D`` (``(M, M)`` distances, row i = query i against all shapes,
0 = identical) and ``labels`` (``(M,)`` class of each shape).

- Bull's eye: for each query the ``k = 2n`` nearest shapes (the query itself
  included, as in the MPEG-7 convention) are retrieved, ``n`` being its class size;
  ``h_i`` same-class hits.  ``B = sum(h_i) / sum(n_i)`` (equal to the paper's
  ``sum h_i / (n |D|)`` when classes have equal size), in percent.
- ROC: every unordered pair ``i < j`` is one decision, positive when both shapes share
  a class; a pair is *accepted* when its distance is ``<= threshold``.  AUC is the
  Mann-Whitney statistic (probability that a random positive pair is closer than a
  random negative one, ties counting one half), exact, no curve sampling.
- Precision-recall and the best F-score ``F = 2PR / (P + R)`` over all thresholds.

The symmetrised distance ``(D + D.T) / 2`` is used for pairs, so asymmetric matchers
are scored on both directions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.stats import rankdata

from data.errors import UserError

Array = NDArray[np.float64]


def bullseye(distances: ArrayLike, labels: ArrayLike) -> float:
    """Bull's eye score [%] (query included among its own 2n nearest)."""
    d = np.asarray(distances, dtype=float)
    lab = np.asarray(labels)
    _, inverse, counts = np.unique(lab, return_inverse=True, return_counts=True)
    n = counts[inverse]
    # Stable sort; the query itself is placed first among equal distances.
    d = d.copy()
    np.fill_diagonal(d, -np.inf)
    order = np.argsort(d, axis=1, kind="stable")
    same = lab[order] == lab[:, None]
    rank = np.arange(d.shape[1])[None, :]
    hits = (same & (rank < 2 * n[:, None])).sum(axis=1)
    return float(100.0 * hits.sum() / n.sum())


def _pairs(distances: ArrayLike, labels: ArrayLike) -> tuple[Array, NDArray[np.bool_]]:
    d = np.asarray(distances, dtype=float)
    d = 0.5 * (d + d.T)
    lab = np.asarray(labels)
    iu = np.triu_indices(len(lab), k=1)
    return d[iu], lab[iu[0]] == lab[iu[1]]


def roc_auc(distances: ArrayLike, labels: ArrayLike) -> float:
    """Area under the ROC curve of pair classification by distance (Mann-Whitney, exact)."""
    score, positive = _pairs(distances, labels)
    n_pos, n_neg = int(positive.sum()), int((~positive).sum())
    if n_pos == 0 or n_neg == 0:
        raise UserError(
            f"roc_auc: labels must give both same-class and different-class pairs, got "
            f"{n_pos} same-class and {n_neg} different-class pairs"
        )
    ranks = rankdata(-score)  # higher rank = smaller distance = more similar
    return float((ranks[positive].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


@dataclass(slots=True)
class Curves:
    """Threshold sweeps over the sorted pair distances (one point per distinct distance)."""

    thresholds: Array
    tpr: Array
    fpr: Array
    precision: Array
    recall: Array


def curves(distances: ArrayLike, labels: ArrayLike) -> Curves:
    """ROC and precision-recall points for every distinct distance threshold."""
    score, positive = _pairs(distances, labels)
    order = np.argsort(score, kind="stable")
    s, p = score[order], positive[order]
    tp = np.cumsum(p)
    fp = np.cumsum(~p)
    last = np.r_[s[1:] != s[:-1], True]  # evaluate after the last pair of each tie group
    tp, fp, thr = tp[last], fp[last], s[last]
    n_pos, n_neg = max(int(p.sum()), 1), max(int((~p).sum()), 1)
    precision = tp / np.maximum(tp + fp, 1)
    return Curves(thr, tp / n_pos, fp / n_neg, precision, tp / n_pos)


def best_fscore(distances: ArrayLike, labels: ArrayLike) -> float:
    """Best balanced F-score over all thresholds (the paper's Table III)."""
    c = curves(distances, labels)
    denom = c.precision + c.recall
    f = np.where(denom > 0, 2 * c.precision * c.recall / np.where(denom > 0, denom, 1), 0.0)
    return float(f.max())
