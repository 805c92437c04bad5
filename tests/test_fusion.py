"""Score fusion: reciprocal rank fusion and the logistic model (loopclosure.fusion)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from loopclosure.fusion import (
    LogisticFusion,
    fit_logistic,
    log_features,
    ranks,
    reciprocal_rank_fusion,
    sigmoid,
)


def test_sigmoid_hand_values_and_extremes() -> None:
    z = np.array([0.0, np.log(3.0), -np.log(3.0), 1000.0, -1000.0])
    p = sigmoid(z)
    np.testing.assert_allclose(p[:3], [0.5, 0.75, 0.25], rtol=1e-12)
    assert p[3] == 1.0 and p[4] == 0.0
    assert np.isfinite(p).all()


def test_log_features_hand_case() -> None:
    f = log_features([[2.0, 0.0, np.inf, np.nan]], [2.0, 1.0, 1.0, 1.0], eps=1e-3)
    assert f[0, 0] == pytest.approx(np.log(1.001))
    assert f[0, 1] == pytest.approx(np.log(1e-3))
    assert np.isfinite(f).all()
    with pytest.raises(ValueError):
        log_features([[1.0]], [0.0])


def test_ranks_ties_share_the_lowest_rank() -> None:
    r = ranks([[3.0, 1.0, 2.0, 1.0], [0.5, 0.4, 0.3, 0.2]])
    np.testing.assert_array_equal(r, [[4, 1, 3, 1], [4, 3, 2, 1]])


def test_reciprocal_rank_fusion_hand_case() -> None:
    # Two matchers, three candidates: ranks (1, 2, 3) and (2, 1, 3), c = 1.
    d = np.array([[0.1, 0.2, 0.3], [5.0, 4.0, 6.0]])
    s = reciprocal_rank_fusion(d, constant=1.0)
    raw = np.array([1 / 2 + 1 / 3, 1 / 3 + 1 / 2, 1 / 4 + 1 / 4])
    np.testing.assert_allclose(s, raw * (2.0 / 2.0))
    # Ranked first by every matcher: score exactly 1.
    assert reciprocal_rank_fusion(np.array([[0.0, 1.0], [0.0, 2.0]]), 60.0)[0] == 1.0


@settings(max_examples=50, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 4), st.integers(1, 12)),
              elements=st.floats(0, 1e6)))
def test_rank_fusion_scores_in_unit_interval(d: np.ndarray) -> None:
    s = reciprocal_rank_fusion(d)
    assert np.all(s > 0) and np.all(s <= 1.0 + 1e-12)


def test_fit_logistic_separable_data_classifies_all_and_stays_finite() -> None:
    rng = np.random.default_rng(1)
    same = np.r_[np.ones(60, bool), np.zeros(140, bool)]
    # Same-place pairs have small distances on both matchers, different-place large ones.
    d = np.where(same[:, None], rng.uniform(0.01, 0.3, (200, 2)), rng.uniform(1.0, 5.0, (200, 2)))
    feats = log_features(d, [1.0, 1.0])
    model = fit_logistic(feats, same, names=("a", "b"))
    p = model.probability(feats)
    assert np.all((p > 0.5) == same)
    assert all(w < 0 for w in model.coefficients)  # larger distance, less likely the same
    assert np.isfinite(model.intercept) and np.all(np.isfinite(model.coefficients))
    assert model.names == ("a", "b")


def test_fit_logistic_recovers_known_model() -> None:
    rng = np.random.default_rng(7)
    n = 20000
    f = rng.normal(size=(n, 2))
    true_w, true_b = np.array([-1.5, 0.8]), -0.5
    y = rng.random(n) < sigmoid(true_b + f @ true_w)
    model = fit_logistic(f, y, ridge=0.0)
    np.testing.assert_allclose(model.coefficients, true_w, atol=0.08)
    assert model.intercept == pytest.approx(true_b, abs=0.08)


def test_calibrated_probabilities_match_frequencies() -> None:
    rng = np.random.default_rng(3)
    n = 20000
    f = rng.normal(size=(n, 1))
    y = rng.random(n) < sigmoid(1.0 - 2.0 * f[:, 0])
    p = fit_logistic(f, y).probability(f)
    assert np.all((p >= 0) & (p <= 1))
    # Reliability: in every decile of predicted probability, the observed frequency agrees.
    edges = np.quantile(p, np.linspace(0, 1, 11))
    which = np.clip(np.searchsorted(edges, p, side="right") - 1, 0, 9)
    for b in range(10):
        sel = which == b
        assert abs(p[sel].mean() - y[sel].mean()) < 0.04


@settings(max_examples=50, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 20), st.just(3)),
              elements=st.floats(0, 1e12)))
def test_score_is_a_probability_for_any_distances(d: np.ndarray) -> None:
    model = LogisticFusion(("a", "b", "c"), (-1.0, -2.0, -0.5), -3.0)
    p = model.score(d, [1.0, 0.5, 2.0])
    assert p.shape == (len(d),)
    assert np.all((p >= 0) & (p <= 1)) and np.isfinite(p).all()


def test_fit_logistic_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="both"):
        fit_logistic(np.zeros((5, 1)), np.ones(5, bool))
    with pytest.raises(ValueError, match="disagree"):
        fit_logistic(np.zeros((5, 1)), np.ones(4, bool))
    with pytest.raises(ValueError, match="finite"):
        fit_logistic(np.full((2, 1), np.nan), [True, False])
    with pytest.raises(ValueError):
        LogisticFusion(("a",), (1.0, 2.0), 0.0)
    with pytest.raises(ValueError):
        LogisticFusion(("a",), (np.nan,), 0.0)
