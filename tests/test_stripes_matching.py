"""Trimming, Bhattacharyya distance (Eq. 6), Eq. 5, the lambda search and the database."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data.errors import UserError
from loopclosure.stripes.database import StripeDatabase
from loopclosure.stripes.descriptor import StripeDescriptor
from loopclosure.stripes.matching import (
    LAMBDA_PAPER,
    bhattacharyya,
    feature_distances,
    retrieval_fitness,
    search_weights,
    stratified_split,
    stripe_distance,
    trim_pair,
    trim_range,
)


def _desc(features, name=None) -> StripeDescriptor:
    f = np.asarray(features, float).reshape(-1, 3)
    return StripeDescriptor(f, np.ones(len(f), dtype=np.int64), name)


def test_bhattacharyya_identical_is_zero():
    assert bhattacharyya(1.3, 0.7, 1.3, 0.7) == pytest.approx(0.0, abs=1e-15)


def test_bhattacharyya_by_hand():
    # mu 0, var 1 against mu 1, var 3:  1/4 ln(1/4 (1/3 + 3 + 2)) + 1/4 * 1 / 4
    expected = 0.25 * math.log(0.25 * (1 / 3 + 3 + 2)) + 0.25 * 1 / 4
    assert bhattacharyya(0.0, 1.0, 1.0, 3.0) == pytest.approx(expected)
    assert expected == pytest.approx(0.1344205, abs=1e-7)


def test_bhattacharyya_zero_variances_are_finite():
    assert bhattacharyya(2.0, 0.0, 2.0, 0.0) == 0.0
    far = bhattacharyya(0.0, 0.0, 1.0, 0.0)
    assert np.isfinite(far) and far > 1e3


def test_trim_range():
    assert tuple(map(int, trim_range(10, 7))) == (2, 9)  # 1.5 rounds up at the front
    assert tuple(map(int, trim_range(10, 6))) == (2, 8)
    assert tuple(map(int, trim_range(5, 5))) == (0, 5)
    assert tuple(map(int, trim_range(5, 0))) == (3, 3)
    with pytest.raises(UserError, match="0 <= n <= m"):
        trim_range(3, 4)


def test_trim_pair_keeps_the_middle_in_order():
    a = np.arange(3 * 3, dtype=float).reshape(3, 3)
    b = np.arange(8 * 3, dtype=float).reshape(8, 3)
    ta, tb = trim_pair(a, b)
    np.testing.assert_array_equal(ta, a)
    np.testing.assert_array_equal(tb, b[3:6])  # (8 - 3) / 2 = 2.5 -> 3 in front, 2 behind
    tb2, ta2 = trim_pair(b, a)
    np.testing.assert_array_equal(tb2, b[3:6])
    np.testing.assert_array_equal(ta2, a)


def test_distance_eq5_by_hand():
    a = _desc([[1, 2, 0], [1, 4, 0]])  # l: mean 1 var 0; d: mean 3 var 1; o: 0, 0
    b = _desc([[1, 2, 0], [1, 4, 0], [9, 9, 9], [1, 3, 1], [1, 3, -1]])
    # b trimmed to 2: front round(1.5) = 2, keeps rows 2..3 -> [9,9,9], [1,3,1]
    fd = feature_distances(a, b)
    mu_b = np.array([5.0, 6.0, 5.0])
    var_b = np.array([16.0, 9.0, 16.0])
    mu_a, var_a = np.array([1.0, 3.0, 0.0]), np.array([1e-6, 1.0, 1e-6])
    np.testing.assert_allclose(fd, bhattacharyya(mu_a, var_a, mu_b, var_b))
    assert stripe_distance(a, b) == pytest.approx(np.dot(LAMBDA_PAPER, fd) / 3)


def test_empty_sets_raise():
    with pytest.raises(UserError):
        feature_distances(_desc(np.zeros((0, 3))), _desc([[1, 2, 3]]))
    with pytest.raises(UserError, match="empty stripe set"):
        StripeDatabase([_desc([[1, 1, 1]]), _desc(np.zeros((0, 3)), "bad")])


features = st.lists(st.tuples(*[st.floats(-5, 5, allow_nan=False)] * 3), min_size=1,
                    max_size=30)


@settings(max_examples=40, deadline=None)
@given(st.lists(features, min_size=1, max_size=8), features)
def test_database_equals_pairwise_distance(objects, query):
    descs = [_desc(o) for o in objects]
    q = _desc(query)
    db = StripeDatabase(descs)
    got = db.distances(q)
    want = np.array([stripe_distance(q, d) for d in descs])
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)
    assert np.isfinite(got).all() and (got >= -1e-12).all()
    # Symmetric, zero on the diagonal.
    sym = [stripe_distance(d, q) for d in descs]
    np.testing.assert_allclose(want, sym, rtol=1e-9, atol=1e-12)


def test_database_query_ranks_itself_first():
    rng = np.random.default_rng(0)
    descs = [_desc(rng.normal(loc=i, size=(int(rng.integers(5, 60)), 3))) for i in range(50)]
    db = StripeDatabase(descs)
    d = db.pairwise()
    np.testing.assert_allclose(np.diag(d), 0.0, atol=1e-9)
    np.testing.assert_allclose(d, d.T, atol=1e-9)
    idx, dist = db.query(descs[17], k=3)
    assert idx[0] == 17 and dist[0] == pytest.approx(0.0, abs=1e-9)


def test_stratified_split_and_fitness():
    labels = ["a"] * 6 + ["b"] * 4
    tr, te = stratified_split(labels, 0.5, seed=1)
    assert sorted(np.concatenate([tr, te]).tolist()) == list(range(10))
    assert sum(labels[i] == "a" for i in tr) == 3 and sum(labels[i] == "b" for i in tr) == 2
    # Perfect distances: same class at 0.1, other classes at 1.
    lab = np.array(labels)
    d = np.where(lab[:, None] == lab[None, :], 0.1, 1.0)
    assert retrieval_fitness(d, labels) == 1.0
    assert retrieval_fitness(1.0 - d, labels) < 0.2


def test_lambda_search_finds_the_informative_feature():
    # Feature 1 separates the classes; features 0 and 2 are noise that mislead.
    rng = np.random.default_rng(5)
    labels = np.repeat(np.arange(5), 8)
    n = len(labels)
    good = np.where(labels[:, None] == labels[None, :], 0.1, 1.0) + rng.uniform(0, 0.3, (n, n))
    noise = rng.uniform(0, 3, (n, n, 2))
    fd = np.stack([noise[..., 0], good, noise[..., 1]], axis=-1)
    tr, _ = stratified_split(labels.astype(str), 0.5, seed=0)
    res = search_weights(fd, labels.astype(str), tr, iterations=200, seed=2)
    assert res.weights[1] > 0.6
    assert res.fitness > 0.9
    assert sum(res.weights) == pytest.approx(1.0)
    with pytest.raises(UserError):
        search_weights(fd, labels.astype(str), [0])


def test_objects_of_only_short_stripes_give_finite_distances():
    from loopclosure.stripes.descriptor import describe_stripes

    tiny = describe_stripes([np.array([[0.0, 0.0], [1.0, 0.0]])] * 3)  # d = o = 0, l = 1
    tiny2 = describe_stripes([np.array([[0.0, 0.0]])] * 5)
    line = describe_stripes([np.column_stack([np.arange(20.0), np.zeros(20)])] * 4)
    for a in (tiny, tiny2, line):
        for b in (tiny, tiny2, line):
            dist = stripe_distance(a, b)
            assert np.isfinite(dist) and dist >= 0
    assert stripe_distance(tiny, tiny2) == pytest.approx(0.0, abs=1e-12)
    assert stripe_distance(tiny, line) > 1.0
