"""Eq. 1-3 of the stripes paper on hand-computed stripes, and descriptor invariances."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from data.errors import DataError
from loopclosure.stripes.descriptor import (
    DescriptorConfig,
    describe_many,
    describe_stripes,
    point_context,
)

EXACT = DescriptorConfig(max_samples=None)


def test_straight_line_by_hand():
    # p = (0,0) (1,0) (2,0) (3,0): pair distances 1,2,1,3,2,1.
    line = np.array([[0, 0], [1, 0], [2, 0], [3, 0]], float)
    d, o = point_context([line], EXACT)
    assert d[0] == pytest.approx((5 * math.log(2) + 2 * math.log(3)) / 6)
    # Lower triangle: p_i - p_m = (+k, 0) -> angle 0 (not positive); upper: (-k, 0) -> pi.
    assert o[0] == pytest.approx(math.pi)


def test_l_shape_by_hand():
    # Right along the row, then one step to smaller y (up in an image).
    el = np.array([[0, 0], [1, 0], [2, 0], [2, -1]], float)
    d, o = point_context([el], EXACT)
    dists = [1, 2, 1, math.sqrt(5), math.sqrt(2), 1]
    assert d[0] == pytest.approx(np.mean(np.log1p(dists)))
    # Lower angles: 0, 0, 0, atan2(-1, 2), -pi/4, -pi/2 (no positive value).
    # Upper angles: pi, pi, pi, pi - atan(1/2), 3pi/4, pi/2 (all positive) -> chosen.
    upper = [math.pi, math.pi, math.pi, math.pi - math.atan(0.5), 3 * math.pi / 4, math.pi / 2]
    assert o[0] == pytest.approx(np.mean(upper))


def test_l_feature_and_short_stripes():
    stripes = [np.array([[0, 0], [1, 0], [2, 0], [3, 0]], float),
               np.array([[5.0, 5.0], [6.0, 5.0]]),
               np.column_stack([np.arange(6.0), np.zeros(6)])]
    desc = describe_stripes(stripes, EXACT)
    np.testing.assert_allclose(desc.l, [1.0, 0.5, 1.5])  # H / mean H = (4, 2, 6) / 4
    # The two-point stripe is too short (< 4 points): d = o = 0, as the authors' code.
    assert desc.d[1] == 0.0 and desc.o[1] == 0.0
    assert desc.d[0] > 0 and desc.d[2] > desc.d[0]
    assert np.isfinite(desc.features).all()


def test_empty_stripe_set_is_a_clear_error():
    with pytest.raises(DataError, match="empty stripe set"):
        describe_stripes([], name="obj7")
    with pytest.raises(DataError, match="obj7: empty stripe set"):
        describe_stripes([np.zeros((0, 2))], name="obj7")
    with pytest.raises(DataError, match="NaN"):
        describe_stripes([np.array([[0, 0], [np.nan, 1]])])


def test_sampling_keeps_features_close():
    t = np.linspace(0, np.pi, 400)
    arc = np.column_stack([200 * np.cos(t), -80 * np.sin(t)])
    full = describe_stripes([arc], EXACT)
    sampled = describe_stripes([arc], DescriptorConfig(max_samples=64))
    assert sampled.d[0] == pytest.approx(full.d[0], rel=0.02)
    assert sampled.o[0] == pytest.approx(full.o[0], abs=0.05)


def test_describe_many_equals_one_by_one():
    rng = np.random.default_rng(3)
    objects = [[rng.normal(size=(int(rng.integers(1, 90)), 2)) * 20 for _ in range(5)]
               for _ in range(4)]
    many = describe_many(objects)
    for obj, desc in zip(objects, many, strict=True):
        np.testing.assert_allclose(describe_stripes(obj).features, desc.features)


# Pixel-like coordinates on a 0.001 grid (the descriptor computes pair terms in float32).
coord = st.integers(-500_000, 500_000).map(lambda v: v / 1000)
stripe_points = arrays(np.float64, st.tuples(st.integers(4, 40), st.just(2)), elements=coord)


@settings(max_examples=60, deadline=None)
@given(stripe_points, coord, coord)
def test_translation_and_reversal_invariance(points, tx, ty):
    base = describe_stripes([points], EXACT).features
    shifted = describe_stripes([points + np.array([tx, ty])], EXACT).features
    np.testing.assert_allclose(shifted, base, atol=2e-3)
    reversed_ = describe_stripes([points[::-1]], EXACT).features
    np.testing.assert_allclose(reversed_, base, atol=1e-6)
    assert np.isfinite(base).all()
    assert 0 <= base[0, 1] and -math.pi <= base[0, 2] <= math.pi


def test_config_is_checked():
    from data.errors import UserError

    with pytest.raises(UserError, match="max_samples"):
        DescriptorConfig(max_samples=2)
    with pytest.raises(UserError, match="min_points"):
        DescriptorConfig(min_points=1)
