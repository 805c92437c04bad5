"""FLIRT matcher: detector and beta-grid formulas, RANSAC pose, real and simulated scans.

The contract shared with the shape matchers (distances in [0, 2], rotation about the
sensor origin, retrieval) is tested in test_matcher_contract.py.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from data import se2
from loopclosure.matchers.flirt import FlirtMatcher
from loopclosure.matchers.flirt_features import (
    FlirtFeatureConfig,
    FlirtFeatures,
    beta_grids,
    describe_polygon,
    detect,
    scale_levels,
    smoothed_curves,
)
from loopclosure.polygon import Polygon, polygon_from_scan
from tests.helpers import shared_file
from tests.matcher_shapes import BOX, lobed_star

SQUARE = Polygon(BOX)


def circle_curve(radius: float, n: int) -> np.ndarray:
    a = 2.0 * np.pi * np.arange(n) / n
    return np.column_stack([radius * np.cos(a), radius * np.sin(a)])


# ---------------------------------------------------------------- formulas


def test_gaussian_smoothing_shrinks_a_circle_by_the_closed_form_factor() -> None:
    # Smoothing x = R cos(s / R) along arc length with a Gaussian of width sigma
    # multiplies it by exp(-sigma^2 / (2 R^2)).
    radius, n = 2.0, 256
    step = 2.0 * np.pi * radius / n
    sigmas = np.array([1.0, 4.0, 16.0])  # samples
    smooth, deriv = smoothed_curves(circle_curve(radius, n), sigmas)
    expected = radius * np.exp(-((sigmas * step) ** 2) / (2.0 * radius**2))
    np.testing.assert_allclose(np.linalg.norm(smooth, axis=-1), expected[:, None] * np.ones(n))
    # d/ds of the smoothed curve per sample: speed = factor * step (tangent length).
    speed = (expected * step / radius)[:, None] * np.ones(n)
    np.testing.assert_allclose(np.linalg.norm(deriv, axis=-1), speed)


def test_scale_normalised_displacement_of_a_circle() -> None:
    # delta(sigma) = (R - R exp(-u^2 / 2)) / sigma with u = sigma / R, the same at every point.
    radius, n = 3.0, 256
    cfg = FlirtFeatureConfig(n_samples=n)
    step = 2.0 * np.pi * radius / n
    _, _, delta = detect(circle_curve(radius, n), step, cfg)
    u = scale_levels(cfg) * step / radius
    expected = (1.0 - np.exp(-(u**2) / 2.0)) / u
    np.testing.assert_allclose(delta, expected[:, None] * np.ones(n), rtol=1e-9)


def test_square_corners_are_the_interest_points() -> None:
    # A right-angle corner is displaced by sigma (a + b) / sqrt(2 pi) under smoothing:
    # delta = 2 cos(45 deg) / sqrt(2 pi) = 0.5642, positive (convex).
    feats = describe_polygon(SQUARE, FlirtFeatureConfig())
    assert len(feats) == 4
    np.testing.assert_allclose(np.sort(np.abs(feats.points), axis=0), 2.0)
    np.testing.assert_allclose(feats.responses, np.sqrt(2.0) / np.sqrt(2.0 * np.pi), atol=1e-3)
    # Orientation = outward normal = the diagonal through the corner.
    np.testing.assert_allclose(
        feats.orientations, np.arctan2(feats.points[:, 1], feats.points[:, 0]), atol=1e-9
    )


def test_beta_grid_hand_case() -> None:
    # One grid of radius 1 at the origin, 1 ring x 4 sectors (sector 0 centred on +x).
    # A beam from (-5, 0.1) ends at (0.5, 0.1): it crosses sectors 2 and 1 and ends in 0.
    cfg = FlirtFeatureConfig(rings=1, sectors=4, support_factor=2.0, chord_samples=10)
    ends = np.array([[0.5, 0.1], [-5.0, 3.0]])  # the second beam misses the disc
    occ, evidence = beta_grids(
        np.zeros((1, 2)), np.array([0.5]), np.zeros(1), ends, np.array([-5.0, 0.1]), cfg
    )
    # Beta(1, 1) prior: occ = (hits + 1) / (hits + misses + 2).
    np.testing.assert_allclose(occ[0], [2 / 3, 1 / 3, 1 / 3, 1 / 2])
    np.testing.assert_array_equal(evidence[0], [3, 3, 3, 2])
    var = FlirtFeatures(np.zeros((1, 2)), np.ones(1), np.zeros(1), np.zeros(1), occ, evidence,
                        1.0).variance
    np.testing.assert_allclose(var[0], [1 / 18, 1 / 18, 1 / 18, 1 / 12])


def test_featureless_circle_gets_fallback_points() -> None:
    circle = Polygon(circle_curve(4.0, 256))
    feats = describe_polygon(circle, FlirtFeatureConfig())
    assert len(feats) == FlirtFeatureConfig().min_features + 1
    assert np.all(feats.responses == 0.0)
    m = FlirtMatcher()
    assert m.distance(m.describe(circle), m.describe(circle.rotated(0.4))) < 1e-9
    assert 0.0 <= m.distance(m.describe(circle), m.describe(SQUARE)) <= 2.0


# ---------------------------------------------------------------- matching


def test_identical_shapes_have_distance_zero() -> None:
    m = FlirtMatcher()
    for poly in (SQUARE, lobed_star(3, 0.3), Polygon(np.array([[0, 0], [3, 0], [0.5, 2.0]]))):
        d = m.describe(poly)
        res = m.match(d, d)
        assert res.distance == pytest.approx(0.0, abs=1e-12)
        np.testing.assert_allclose(res.pose, 0.0, atol=1e-9)
        assert len(res.inliers) == len(d)


def test_ransac_recovers_a_rigid_transform() -> None:
    # Centroid viewpoint: the descriptors are then invariant to any rigid motion.
    m = FlirtMatcher(viewpoint="centroid")
    base = lobed_star(4, 0.25, seed=1, noise=0.002)
    pose = np.array([3.0, -2.0, 0.8])  # pose of `base`'s frame in the moved frame
    moved = Polygon(se2.transform_points(pose, base.vertices))
    res = m.match(m.describe(moved), m.describe(base))
    np.testing.assert_allclose(res.pose, pose, atol=1e-9)
    assert len(res.inliers) == len(m.describe(base))
    assert res.distance < 1e-9


def test_distance_is_monotone_in_match_quality() -> None:
    m = FlirtMatcher()
    a = lobed_star(3, 0.3, seed=2)
    da = m.describe(a)
    near = m.distance(da, m.describe(lobed_star(3, 0.3, seed=3, noise=0.002)))
    far = m.distance(da, m.describe(lobed_star(5, 0.3, seed=4)))
    assert 0.0 < near < 1.0 <= far <= 2.0


def test_deterministic_and_seeded() -> None:
    # Enough features that RANSAC samples its hypotheses.
    a, b = lobed_star(5, 0.3, n=400), lobed_star(5, 0.3, n=400, seed=8, noise=0.004)
    m = FlirtMatcher(max_hypotheses=50)
    da, db = m.describe(a), m.describe(b)
    assert m.distance(da, db) == m.distance(da, db)
    np.testing.assert_array_equal(m.match(da, db).inliers, m.match(da, db).inliers)


def test_compiled_kernel_equals_numpy_on_random_shapes() -> None:
    """Property: the numba kernel and the numpy arrays give the same matches."""
    rng = np.random.default_rng(11)
    shapes = [lobed_star(int(rng.integers(3, 7)), 0.3, seed=int(s), noise=0.003, n=300)
              for s in rng.integers(0, 1000, 8)]
    shapes.append(SQUARE)
    fast, slow = FlirtMatcher(), FlirtMatcher(compiled=False)
    descs = [slow.describe(p) for p in shapes]
    for query in descs:
        stacked = slow.stack(descs)
        d_fast, p_fast, pairs_fast, r_fast = fast._run(query, stacked, want_pairs=True)
        d_slow, p_slow, pairs_slow, r_slow = slow._run(query, stacked, want_pairs=True)
        np.testing.assert_allclose(d_fast, d_slow, atol=1e-12)
        np.testing.assert_allclose(p_fast, p_slow, atol=1e-9)
        np.testing.assert_allclose(r_fast, r_slow, atol=1e-12)
        for a, b in zip(pairs_fast, pairs_slow, strict=True):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("compiled", [True, False])
def test_refit_keeps_the_rotation_when_inliers_share_one_point(compiled: bool) -> None:
    """Two inliers on one stacked point fix no rotation: the hypothesis's stays."""
    from loopclosure.matchers import flirt, flirt_kernel

    qp = np.array([[0.0, 0.0], [1.0, 0.0]])
    pts = np.array([[[2.0, 3.0], [5.0, 5.0]]])
    match = np.array([[0, 0]])
    inl = np.array([[True, True]])
    weight = np.ones((1, 2))
    if compiled:
        th, tx, ty = flirt_kernel._procrustes(qp, pts[0], match[0], inl[0], weight[0],
                                              0.7, 0.1, 0.2)
        assert (th, tx, ty) == (0.7, 0.1, 0.2)
        # Two distinct points on both sides: a quarter turn, hand-checked.
        th, tx, ty = flirt_kernel._procrustes(qp, np.array([[0.0, 0.0], [0.0, -1.0]]),
                                              np.array([0, 1]), inl[0], weight[0], 0.7, 0, 0)
    else:
        th, tt = flirt._procrustes(qp, pts, match, inl, weight, np.array([0.7]),
                                   np.array([[0.1, 0.2]]))
        assert th[0] == 0.7 and tuple(tt[0]) == (0.1, 0.2)
        th, tt = flirt._procrustes(qp, np.array([[[0.0, 0.0], [0.0, -1.0]]]),
                                   np.array([[0, 1]]), inl, weight, np.array([0.7]),
                                   np.zeros((1, 2)))
        th, (tx, ty) = th[0], tt[0]
    assert th == pytest.approx(np.pi / 2) and (tx, ty) == pytest.approx((0.0, 0.0))


# ---------------------------------------------------------------- extreme scales


@pytest.mark.parametrize("scale", [1e-6, 1e6])
def test_huge_and_tiny_polygons(scale: float) -> None:
    m = FlirtMatcher()
    p = Polygon(lobed_star(3, 0.3).vertices * scale)
    d = m.describe(p)
    assert np.all(np.isfinite(d.occupancy)) and len(d) >= 3
    assert m.distance(d, d) == pytest.approx(0.0, abs=1e-12)
    assert m.distance(d, m.describe(p.rotated(1.0))) < 1e-9


# ---------------------------------------------------------------- real and simulated data


def test_consecutive_real_scans_match_with_the_corrected_pose() -> None:
    """Intel lab (GMapping-corrected): FLIRT's transform ~ the pose change of the robot."""
    from data.carmen import CarmenLog

    path = shared_file("carmen-corrected/intel-corrected.log.gz")
    scans = list(itertools.islice(CarmenLog(path), 150))
    m = FlirtMatcher()
    errors, same = [], []
    for i in range(0, 148, 4):
        a, b = scans[i], scans[i + 1]
        res = m.match(m.describe(polygon_from_scan(a)), m.describe(polygon_from_scan(b)))
        truth = se2.between(a.odom, b.odom)
        errors.append(
            [np.hypot(*(res.pose[:2] - truth[:2])), abs(se2.wrap_angle(res.pose[2] - truth[2]))]
        )
        same.append(res.distance < 1.0)
    err = np.median(np.array(errors), axis=0)
    # Median motion between the pairs: 1.0 m, 4 degrees; measured median error of
    # FLIRT's transform 0.19 m, 1.2 degrees; 34 of 37 pairs declared the same place.
    assert err[0] < 0.3 and err[1] < 0.05
    assert np.mean(same) >= 0.7


def test_simulated_places_are_recognised() -> None:
    sim = pytest.importorskip("data.sim")
    data = sim.place_dataset("box", places=3, scans_per_place=4, seed=3)
    labels = np.array([label for label, _ in data])
    m = FlirtMatcher()
    d = m.pairwise([m.describe(polygon_from_scan(scan)) for _, scan in data])
    np.fill_diagonal(d, np.inf)
    assert np.mean(labels[np.argmin(d, axis=1)] == labels) >= 0.9


@pytest.mark.parametrize("sectors", [12, 8, 7])
def test_compiled_beta_grids_equal_numpy_on_random_shapes(sectors: int) -> None:
    """The numba beta-grid counts (sector from cross products; arctangent when the
    number of sectors is odd) equal the numpy ones on generic shapes, where no chord
    sample lies on a sector border to within rounding."""
    rng = np.random.default_rng(5)
    fast = FlirtFeatureConfig(sectors=sectors)
    slow = FlirtFeatureConfig(sectors=sectors, compiled=False)
    for seed in rng.integers(0, 1000, 6):
        poly = lobed_star(int(rng.integers(3, 7)), 0.3, seed=int(seed), noise=0.003, n=300)
        a, b = describe_polygon(poly, fast), describe_polygon(poly, slow)
        np.testing.assert_array_equal(a.points, b.points)
        np.testing.assert_array_equal(a.occupancy, b.occupancy)
        np.testing.assert_array_equal(a.evidence, b.evidence)


def test_compiled_beta_grid_sectors_turn_with_the_orientation() -> None:
    """Hand-made case: one feature at the origin, radius 1, 4 rings x 12 sectors; a
    beam ending at angle phi from the feature's axis lands in sector
    round(phi / 30 degrees) mod 12, for axes all round the circle."""
    cfg = FlirtFeatureConfig(compiled=True)
    for orient in np.linspace(-np.pi, np.pi, 13):
        for k in range(12):
            phi = orient + np.radians(30.0 * k + 7.0)  # 7 degrees into sector k
            end = 0.6 * np.array([[np.cos(phi), np.sin(phi)]])  # ring 2 of 4
            occ, _ = beta_grids(np.zeros((1, 2)), np.array([0.5]), np.array([orient]),
                                end, end[0] * 2.0, cfg)  # viewpoint beyond: no chord
            hit = np.flatnonzero(occ[0] > 0.5)
            assert hit.tolist() == [2 * 12 + k]


def test_compiled_sector_of_offsets_equals_the_arctangent_one() -> None:
    """The kernel's bin from cross products equals `_bins`' arctangent bin off the
    borders, and a zero offset takes the sector of ``atan2(0, 0) = 0``."""
    from loopclosure.matchers.flirt_features import _bins
    from loopclosure.matchers.flirt_grid_kernel import _bin

    rng = np.random.default_rng(2)
    border = np.arange(1, 6) * (2.0 * np.pi / 12)
    for orient in rng.uniform(-np.pi, np.pi, 20):
        rot = orient - np.pi / 12
        zero = int((0.0 - orient) * (12 / (2.0 * np.pi)) + 24.5) % 12
        args = (4 / 1.5, orient, 4, 12, np.cos(rot), np.sin(rot), np.cos(border),
                np.sin(border), zero)
        for x, y in rng.uniform(-1.5, 1.5, (50, 2)):
            want = _bins(np.array([x]), np.array([y]), 1.5, orient, 4, 12)[0]
            assert _bin(x, y, *args) == want
        assert _bin(0.0, 0.0, *args) == _bins(np.zeros(1), np.zeros(1), 1.5, orient, 4, 12)[0]


def test_scale_test_without_the_logarithm_agrees_with_it_at_the_bounds() -> None:
    from loopclosure.matchers.flirt_kernel import _compatible

    gate = float(np.log(2.0)) + 1e-12
    hi = float(np.exp(gate))
    lo_in, hi_in = (1.0 + 1e-9) / hi, hi * (1.0 - 1e-9)
    lo_out, hi_out = (1.0 - 1e-9) / hi, hi * (1.0 + 1e-9)
    # Hand-checked: a ratio of exactly 2 (or 1/2) is compatible, 2.001 is not.
    assert _compatible(2.0, gate, lo_in, hi_in, lo_out, hi_out)
    assert _compatible(0.5, gate, lo_in, hi_in, lo_out, hi_out)
    assert not _compatible(2.001, gate, lo_in, hi_in, lo_out, hi_out)
    assert not _compatible(1.0 / 2.001, gate, lo_in, hi_in, lo_out, hi_out)
    # Every ratio around both bounds and the margins' ends: the logarithm's answer.
    xs = []
    for centre in (hi, 1.0 / hi, lo_in, hi_in, lo_out, hi_out, 1.0):
        x = centre
        for _ in range(50):
            x = np.nextafter(x, 0.0)
        for _ in range(100):
            xs.append(x)
            x = np.nextafter(x, np.inf)
    xs += list(np.linspace(0.3, 3.0, 2001)) + list(hi * (1.0 + np.linspace(-3e-9, 3e-9, 601)))
    for x in xs:
        assert _compatible(x, gate, lo_in, hi_in, lo_out, hi_out) == (abs(np.log(x)) <= gate)


def test_compiled_peak_mask_equals_the_numpy_one() -> None:
    """The compiled strict 3 x 3 maxima (circular in position, -inf beyond the scale
    levels) give numpy's mask: ties and plateaus, one position, one level, NaN."""
    from loopclosure.matchers.flirt_features import _local_maxima, _local_maxima_numpy

    rng = np.random.default_rng(5)
    for levels, n in ((1, 1), (1, 2), (3, 1), (2, 3), (7, 64)):
        for a in (rng.normal(size=(levels, n)), np.round(rng.normal(size=(levels, n)), 1)):
            np.testing.assert_array_equal(_local_maxima(a), _local_maxima_numpy(a))
    a = np.abs(rng.normal(size=(4, 40)))
    a[1, 7] = np.nan
    np.testing.assert_array_equal(_local_maxima(a), _local_maxima_numpy(a))
    # hand-checked: one peak; its wrapped neighbour at the other end does not count
    a = np.zeros((2, 5))
    a[1, 0], a[1, 4] = 2.0, 1.0
    assert np.argwhere(_local_maxima(a)).tolist() == [[1, 0]]


def test_compiled_euclidean_descriptor_distances_are_numpys_to_the_bit() -> None:
    """`euclidean_distances` from numpy's norms and products equals the numpy
    broadcast expression of `_descriptor_distances` bit for bit, including the
    clamp of a slightly negative squared distance (a feature compared with itself)
    to 0, and a hand case: occupancies (1, 0) and (0, 1) are sqrt(2) apart."""
    from loopclosure.matchers.flirt_kernel import euclidean_distances

    rng = np.random.default_rng(5)
    matcher = FlirtMatcher()
    bins = matcher.config.rings * matcher.config.sectors
    occ = rng.uniform(0.0, 1.0, (6, 9, bins))
    query = rng.uniform(0.0, 1.0, (7, bins))
    query[0] = occ[2, 4]  # identical descriptors: the expression may round below 0

    class _Query:
        occupancy = query

    ref = matcher._descriptor_distances(_Query, occ)
    got = euclidean_distances(np.einsum("qb,qb->q", query, query),
                              np.einsum("mfb,mfb->mf", occ, occ), np.matmul(occ, query.T))
    assert got.shape == (6, 7, 9)
    assert np.array_equal(got, ref)
    assert got[2, 0, 4] == ref[2, 0, 4] and got[2, 0, 4] < 1e-6
    a, b = np.array([[[1.0, 0.0]]]), np.array([[0.0, 1.0]])
    hand = euclidean_distances(np.einsum("qb,qb->q", b, b), np.einsum("mfb,mfb->mf", a, a),
                               np.matmul(a, b.T))
    assert hand[0, 0, 0] == np.sqrt(2.0)


def test_compiled_responses_equal_the_numpy_ones() -> None:
    """`_responses` (numba) gives `_responses_numpy`'s bits on a random curve and on a
    degenerate one (all samples equal: zero derivative, speed taken as 1, delta 0),
    and on a circle the closed form of the scale-normalised displacement."""
    from loopclosure.matchers.flirt_features import (
        _responses,
        _responses_numpy,
        _smoothed_complex,
    )

    rng = np.random.default_rng(11)
    sigmas = np.array([1.5, 3.0, 6.0, 12.0])
    for curve in (rng.normal(size=(64, 2)), np.ones((32, 2))):
        smooth, deriv = _smoothed_complex(curve, sigmas)
        got = _responses(curve, 0.3, sigmas, smooth, deriv)
        np.testing.assert_array_equal(got, _responses_numpy(curve, 0.3, sigmas, smooth, deriv))
    assert not _responses(curve, 0.3, sigmas, smooth, deriv).any()
    radius, n = 3.0, 256
    step = 2.0 * np.pi * radius / n
    smooth, deriv = _smoothed_complex(circle_curve(radius, n), sigmas)
    delta = _responses(circle_curve(radius, n), step, sigmas, smooth, deriv)
    u = sigmas * step / radius
    expected = radius * (1.0 - np.exp(-(u**2) / 2.0)) / (sigmas * step)
    np.testing.assert_allclose(delta, expected[:, None] * np.ones(n), rtol=1e-9)


def test_batched_smoothing_equals_one_inverse_transform_each() -> None:
    """`smoothed_curves` (one batched inverse FFT, cached filters) is the curve's
    spectrum times each Gaussian inverted alone, and times ``i w`` for the derivative."""
    rng = np.random.default_rng(2)
    curve = rng.normal(size=(48, 2))
    sigmas = np.array([1.0, 2.5, 7.0])
    smooth, deriv = smoothed_curves(curve, sigmas)
    w = 2.0 * np.pi * np.fft.fftfreq(48)
    spec = np.fft.fft(curve[:, 0] + 1j * curve[:, 1])
    for lv, sigma in enumerate(sigmas):
        gauss = np.exp(-0.5 * (sigma * w) ** 2)
        s = np.fft.ifft(spec * gauss)
        d = np.fft.ifft(spec * gauss * (1j * w))
        np.testing.assert_allclose(smooth[lv], np.column_stack([s.real, s.imag]), atol=1e-12)
        np.testing.assert_allclose(deriv[lv], np.column_stack([d.real, d.imag]), atol=1e-12)
    again, _ = smoothed_curves(curve, sigmas)  # the cached filters: the same bits
    np.testing.assert_array_equal(again, smooth)
