"""The place description's compiled steps: the same bits as the numpy code they replace."""

import numpy as np
import pytest

from loopclosure.matchers import flirt_features as ff
from loopclosure.matchers.flirt_curve_kernel import origin_view_kernel, resample_kernel
from loopclosure.matchers.flirt_grid_kernel import beta_grid_counts, beta_posterior
from loopclosure.matchers.flirt_peak_kernel import peak_candidates_kernel
from loopclosure.matchers.pair_histogram import polygon_samples, surface_samples
from loopclosure.polygon import Polygon

SQUARE = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])


def _star(rng: np.random.Generator, n: int, centre=(0.0, 0.0)) -> Polygon:
    """A random star-shaped polygon of n vertices about `centre` [m]."""
    a = np.sort(rng.uniform(-np.pi, np.pi, n))
    r = rng.uniform(0.5, 15.0, n)
    return Polygon(np.column_stack([r * np.cos(a), r * np.sin(a)]) + centre)


def test_resample_kernel_of_a_square_by_hand() -> None:
    curve, lengths = resample_kernel(SQUARE, 8)
    # Perimeter 8 m, a sample every metre from vertex 0: the corners and the midpoints.
    expected = [[-1, -1], [0, -1], [1, -1], [1, 0], [1, 1], [0, 1], [-1, 1], [-1, 0]]
    assert np.array_equal(curve, np.array(expected, float))
    assert np.array_equal(lengths, [2.0, 2.0, 2.0, 2.0])


def test_resample_kernel_equals_polygon_resample_and_perimeter_to_the_bit() -> None:
    rng = np.random.default_rng(3)
    for n_vertices in (3, 17, 360):
        p = _star(rng, n_vertices)
        for n in (16, 256, 1000):
            curve, lengths = resample_kernel(p.vertices, n)
            assert curve.tobytes() == p.resample(n).tobytes()
            assert float(lengths.sum()) == p.perimeter


def test_origin_view_kernel_by_hand() -> None:
    assert origin_view_kernel(SQUARE)  # the origin inside
    assert not origin_view_kernel(SQUARE + np.array([3.0, 0.5]))  # outside
    assert origin_view_kernel(np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0]]))  # a vertex


def test_origin_view_kernel_agrees_with_contains() -> None:
    rng = np.random.default_rng(4)
    for _ in range(200):
        p = _star(rng, 40, rng.uniform(-12.0, 12.0, 2))
        assert origin_view_kernel(p.vertices) == bool(p.contains(np.zeros((1, 2)))[0])
        numpy_view = ff._viewpoint(p, "auto", 1.0)
        assert ff._viewpoint(p, "auto", 1.0, compiled=True).tobytes() == numpy_view.tobytes()


def test_peak_candidates_kernel_by_hand_and_against_numpy() -> None:
    delta = np.zeros((3, 8))
    delta[1, 2] = -0.5  # a concave peak: |delta| is tested
    delta[0, 6] = 0.1  # a peak below the response threshold
    level, idx, value = peak_candidates_kernel(delta, 0.15, 1.0 + ff._STRICT, 0.0)
    assert level.tolist() == [1] and idx.tolist() == [2] and value.tolist() == [0.5]
    rng = np.random.default_rng(5)
    d = rng.normal(0.0, 0.3, (14, 256))
    level, idx, value = peak_candidates_kernel(d, 0.15, 1.0 + ff._STRICT,
                                               ff._STRICT * np.finfo(float).tiny)
    mag = np.abs(d)
    ref_level, ref_idx = np.nonzero(ff._local_maxima_numpy(mag) & (mag >= 0.15))
    assert np.array_equal(level, ref_level) and np.array_equal(idx, ref_idx)
    assert value.tobytes() == mag[ref_level, ref_idx].tobytes()


def test_beta_posterior_is_the_numpy_posterior_of_the_counts() -> None:
    cfg = ff.FlirtFeatureConfig()
    # No beam near the feature: every bin keeps the prior, occupancy 1/2, evidence 2.
    occ, ev = beta_posterior(*beta_grid_counts(np.array([[50.0, 0.0]]), np.array([1.0]),
                                               np.array([0.0]), SQUARE, np.zeros(2), 4, 12, 8),
                             1.0, 1.0)
    assert np.all(occ == 0.5) and np.all(ev == 2.0) and ev.dtype == np.float32
    rng = np.random.default_rng(6)
    p = _star(rng, 120)
    curve = p.resample(256)
    points, radius = curve[::9].copy(), rng.uniform(0.5, 6.0, len(curve[::9]))
    orient = rng.uniform(-np.pi, np.pi, len(points))
    ends = np.ascontiguousarray(curve[::2])
    counts = beta_grid_counts(points, radius, orient, ends, np.zeros(2), 4, 12, 8)
    occ, ev = beta_posterior(*counts, cfg.prior_hit, cfg.prior_miss)
    ref_occ, ref_ev = ff._posterior(*counts, cfg)
    assert occ.tobytes() == ref_occ.tobytes() and ev.tobytes() == ref_ev.tobytes()


def test_polygon_samples_remember_only_the_same_array_with_the_same_bytes() -> None:
    v = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])
    kw = {"step": 0.5, "max_edge": 3.0, "max_range": 19.5}
    first = polygon_samples(v, **kw)
    for got, ref in zip(first, surface_samples(v, **kw), strict=True):
        assert np.array_equal(got, ref)
        assert not got.flags.writeable  # shared between callers
    assert polygon_samples(v, **kw) is first
    assert polygon_samples(v.copy(), **kw) is not first  # another array
    assert polygon_samples(v, **{**kw, "step": 0.25}) is not first  # other lengths
    v[1, 0] = 4.0  # the same array changed: sampled anew
    moved = polygon_samples(v, **kw)
    assert moved[0].max() == pytest.approx(3.75)


def test_levels_are_the_scale_levels() -> None:
    cfg = ff.FlirtFeatureConfig(n_samples=512)
    assert np.array_equal(ff._levels(cfg), ff.scale_levels(cfg))
    assert ff._levels(cfg) is ff._levels(ff.FlirtFeatureConfig(n_samples=512))
