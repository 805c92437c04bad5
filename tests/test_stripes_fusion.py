"""Stripe resampling, the scale-free option, the fused matcher and the different-pose figures."""

from __future__ import annotations

import numpy as np
import pytest

from data.errors import UserError
from evaluation.stripes_retrieval import cross_pose
from loopclosure.polygon import Polygon
from loopclosure.stripes import (
    DescriptorConfig,
    FusedObjectDatabase,
    describe_many,
    describe_stripes,
    fuse,
    normalised,
    resample_stripes,
)


def _arc(n: int, radius: float) -> np.ndarray:
    t = np.linspace(0.2, np.pi - 0.2, n)
    return np.column_stack([radius * np.cos(t), radius * np.sin(t)])


def _dome(n_stripes: int, radius: float) -> list[np.ndarray]:
    """Stripes of a half sphere seen from above: arcs whose width follows a circle."""
    x = np.linspace(-0.95, 0.95, n_stripes)
    return [_arc(max(int(2 * radius * np.sqrt(1 - xi**2)), 4), radius * np.sqrt(1 - xi**2))
            for xi in x]


def test_resample_keeps_both_ends_and_spaces_evenly():
    s = [np.full((4, 2), float(i)) for i in range(10)]
    kept = resample_stripes(s, 4)
    # linspace(0, 9, 4) = 0, 3, 6, 9.
    assert [int(k[0, 0]) for k in kept] == [0, 3, 6, 9]
    assert resample_stripes(s, 10) == s and resample_stripes(s, None) == s
    with pytest.raises(UserError, match="stripe_count"):
        DescriptorConfig(stripe_count=1)


def test_stripe_count_makes_a_densely_swept_object_match_a_sparse_sweep():
    dense, sparse = _dome(120, 60.0), _dome(40, 60.0)
    paper = DescriptorConfig()
    counted = DescriptorConfig(stripe_count=40)
    a, b = describe_many([dense, sparse], counted)
    assert len(a) == len(b) == 40
    np.testing.assert_allclose(a.l.mean(), 1.0)
    pa, pb = describe_many([dense, sparse], paper)
    # Resampled: the features of the two sweeps agree far better than after trimming.
    from loopclosure.stripes import stripe_distance

    assert stripe_distance(a, b) < 0.2 * stripe_distance(pa, pb)


def test_scale_free_describes_a_scaled_object_identically():
    # Camera stripes hold one point per pixel column: three times the size, three
    # times the points.  Scale free, the pixel size drops out (up to the sampling).
    small, big = _dome(30, 40.0), _dome(30, 120.0)
    cfg = DescriptorConfig(scale_free=True)
    a, b = describe_many([small, big], cfg)
    np.testing.assert_allclose(a.d, b.d, rtol=0.02)
    # Without the option d grows with size (Eq. 1 in the points' unit): about log 3;
    # o (angles) and l do not depend on the unit either way.
    pa, pb = describe_many([small, big])
    np.testing.assert_allclose(a.o, pa.o, atol=1e-6)
    np.testing.assert_allclose(b.l, pb.l)
    assert np.all(pb.d - pa.d > 0.8)
    # One object through describe_stripes gives the batch result.
    np.testing.assert_allclose(describe_stripes(big, cfg).features, b.features)


def test_normalised_by_hand():
    np.testing.assert_allclose(normalised([2.0, 4.0, 6.0]), [0.5, 1.0, 1.5])
    # Median 0 -> divided by the mean (4/3); infinity -> twice the largest finite score.
    np.testing.assert_allclose(normalised([0.0, 0.0, 4.0, np.inf]), [0, 0, 3.0, 6.0])
    np.testing.assert_allclose(normalised([[1.0, 3.0], [0.0, 0.0]]), [[0.5, 1.5], [0, 0]])
    with pytest.raises(UserError, match="non-negative"):
        normalised([-1.0, 1.0])


def test_fuse_is_the_weighted_mean_of_normalised_distances():
    a, b = np.array([1.0, 2.0, 3.0]), np.array([30.0, 20.0, 10.0])
    # normalised: a -> 0.5 1 1.5, b -> 1.5 1 0.5.
    np.testing.assert_allclose(fuse([a, b]), [1.0, 1.0, 1.0])
    np.testing.assert_allclose(fuse([a, b], [3.0, 1.0]), [0.75, 1.0, 1.25])
    with pytest.raises(UserError, match="weights"):
        fuse([a, b], [1.0])
    with pytest.raises(UserError, match="one shape"):
        fuse([a, b[:2]])


def test_fused_database_finds_the_matching_object():
    shapes = [_dome(30, 40.0), [np.column_stack([np.arange(50.0), np.zeros(50)])] * 30,
              _dome(60, 90.0)]
    square = Polygon(np.array([[0, 0], [40, 0], [40, 40], [0, 40]], float))
    t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    circle = Polygon(np.column_stack([20 * np.cos(t), 20 * np.sin(t)]))
    ellipse = Polygon(np.column_stack([40 * np.cos(t), 15 * np.sin(t)]))
    descs = describe_many(shapes)
    db = FusedObjectDatabase(descs, [circle, square, ellipse])
    order, dist = db.query(descs[1], square, k=3)
    assert order[0] == 1 and dist[0] == pytest.approx(0.0, abs=1e-9)
    # Default verifier: shape context on 50 points; stripes + verifier = two parts.
    assert db.verifier_names == ("shape-context-50",)
    assert len(db.method_distances(descs[0], circle)) == 2
    fast = FusedObjectDatabase(descs, [circle, square, ellipse], verifiers=("fft", "ring"))
    assert len(fast.method_distances(descs[0], circle)) == 3
    with pytest.raises(UserError, match="one polygon per object"):
        FusedObjectDatabase(descs, [circle])
    with pytest.raises(UserError, match="weights need 2"):
        FusedObjectDatabase(descs, [circle, square, ellipse], weights=[1.0])


def test_cross_pose_by_hand():
    # Objects 0, 1 (class a), 2 (class b); scans in order 0 0 1 1 2 2.
    objects = np.array([0, 0, 1, 1, 2, 2])
    labels = np.array(["a", "a", "a", "a", "b", "b"])
    d = np.full((6, 6), 9.0)
    # Query rows 0, 2, 4 (first scans) against columns 1, 3, 5 (second scans).
    d[0, [1, 3, 5]] = [1.0, 2.0, 3.0]  # own object nearest; nearest other: 1 (a) -> hit
    d[2, [1, 3, 5]] = [1.0, 2.0, 3.0]  # nearest is object 0, not itself; other: 0 (a) hit
    d[4, [1, 3, 5]] = [2.0, 3.0, 1.0]  # itself; nearest other: object 0 (a) -> miss
    fig = cross_pose(d, labels, objects)
    assert fig["instance"] == pytest.approx(2 / 3)
    assert fig["other_object"] == pytest.approx(2 / 3)
    assert cross_pose(np.zeros((3, 3)), labels[:3], np.arange(3)) == {}
