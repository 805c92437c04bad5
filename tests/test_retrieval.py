"""Retrieval measures against hand-checked cases."""

from __future__ import annotations

import numpy as np
import pytest

from evaluation.retrieval import best_fscore, bullseye, curves, roc_auc


def _perfect() -> tuple[np.ndarray, np.ndarray]:
    labels = np.array(["a", "a", "b", "b"])
    d = np.array([[0, 1, 5, 6], [1, 0, 7, 5], [5, 7, 0, 2], [6, 5, 2, 0]], dtype=float)
    return d, labels


def test_perfect_separation() -> None:
    d, labels = _perfect()
    assert bullseye(d, labels) == 100.0
    assert roc_auc(d, labels) == 1.0
    assert best_fscore(d, labels) == 1.0


def test_hand_checked_bullseye_and_auc() -> None:
    # Class a = {0, 1, 2}, class b = {3}: n = 3 for a (k = 6 covers everything), 1 for b.
    labels = np.array(["a", "a", "a", "b"])
    d = np.array(
        [[0, 1, 4, 2], [1, 0, 3, 5], [4, 3, 0, 6], [2, 5, 6, 0]],
        dtype=float,
    )
    # b: k = 2 nearest = {3 (itself), 0}: 1 hit of 1.  a: all 3 hits each.  (9 + 1) / 10.
    assert bullseye(d, labels) == pytest.approx(100.0)
    labels2 = np.array(["a", "a", "b", "b"])
    d2 = np.array([[0, 1, 2, 3], [1, 0, 4, 5], [2, 4, 0, 6], [3, 5, 6, 0]], dtype=float)
    # Pairs: (0,1)=1 pos, (0,2)=2 neg, (0,3)=3 neg, (1,2)=4 neg, (1,3)=5 neg, (2,3)=6 pos.
    # Positives closer than negatives: pos 1 beats all 4 negatives, pos 6 beats none -> 4/8.
    assert roc_auc(d2, labels2) == pytest.approx(0.5)
    # Best F: threshold 1 -> P=1, R=0.5, F=2/3; threshold 6 -> P=2/6, R=1, F=0.5.
    assert best_fscore(d2, labels2) == pytest.approx(2 / 3)


def test_bullseye_counts_only_the_2n_nearest() -> None:
    # Shapes on a line; distance = |x_i - x_j|.  Classes of n = 2, so k = 4 of 6 retrieved.
    x = np.array([0.0, 10.0, 1.0, 11.0, 30.0, 60.0])
    labels = np.array(["a", "a", "b", "b", "c", "c"])
    d = np.abs(x[:, None] - x[None, :])
    # Query 4 (x=30) retrieves {4, 3, 1, 2}: 1 hit; every other query finds both of its class.
    assert bullseye(d, labels) == pytest.approx(100 * 11 / 12)


def test_ties_count_half_in_auc() -> None:
    labels = np.array(["a", "a", "b"])
    d = np.ones((3, 3)) - np.eye(3)
    assert roc_auc(d, labels) == pytest.approx(0.5)
    c = curves(d, labels)
    assert len(c.thresholds) == 1 and c.recall[-1] == 1.0


def test_auc_of_a_single_class_is_a_user_error() -> None:
    from data.errors import UserError

    with pytest.raises(UserError, match="labels must give both"):
        roc_auc(np.ones((3, 3)) - np.eye(3), np.array(["a", "a", "a"]))
