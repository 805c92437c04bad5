"""The contract every shape matcher keeps, one parametrized test per clause.

The clauses are those of `loopclosure.matchers.base.Matcher` and of DESIGN.md: a matcher
is built by its registry name with config overrides and rejects unknown or bad options
with a `UserError` naming them; degenerate polygons give finite descriptors and finite
distances >= 0; a polygon is at distance ~0 from itself; the batched `distances` equals
a loop of `distance`; rotating a polygon about the sensor origin leaves the distance
unchanged where the matcher claims it (`Matcher.rotation_invariant`); with
``scale_invariant`` a scaled copy matches; nearest neighbours are places of the same
kind.

Each clause has one table, keyed by registry name, saying what each matcher claims and
the tolerances (and the reasons for them) its tests have always used; a matcher missing
from a table makes no such claim.  The equations of each method are checked against
hand-computed cases in its own ``test_matcher_<name>.py``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields
from functools import cache
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data.errors import UserError
from loopclosure.matchers import MATCHER_NAMES, Matcher, get_matcher
from loopclosure.matchers.fft import FFTConfig, FFTMatcher
from loopclosure.matchers.flirt import FlirtConfig, FlirtMatcher
from loopclosure.matchers.integral_invariant import IntegralConfig, IntegralInvariantMatcher
from loopclosure.matchers.mrm import MRMConfig, MRMMatcher
from loopclosure.matchers.pair_histogram import PairHistogramConfig, PairHistogramMatcher
from loopclosure.matchers.ring_projection import RingConfig, RingProjectionMatcher
from loopclosure.matchers.scan_line import ScanLineConfig, ScanLineMatcher
from loopclosure.matchers.shape_context import ShapeContextConfig, ShapeContextMatcher
from loopclosure.matchers.tangent_space import TangentConfig, TangentSpaceMatcher
from loopclosure.polygon import Polygon
from tests.helpers import shared_file
from tests.matcher_shapes import (
    BOX,
    C_SHAPE,
    NOTCHED,
    SQUARE,
    UNIT_SQUARE,
    blob,
    lobed_star,
    random_star,
    regular,
    room,
    smooth_star,
)

# The eight matchers of the paper, in its order, then the surface-pair histogram, with their
# config dataclasses.
MATCHERS: dict[str, tuple[type[Matcher], type]] = {
    "fft": (FFTMatcher, FFTConfig),
    "integral": (IntegralInvariantMatcher, IntegralConfig),
    "ring": (RingProjectionMatcher, RingConfig),
    "shape-context": (ShapeContextMatcher, ShapeContextConfig),
    "scanline": (ScanLineMatcher, ScanLineConfig),
    "mrm": (MRMMatcher, MRMConfig),
    "tangent": (TangentSpaceMatcher, TangentConfig),
    "flirt": (FlirtMatcher, FlirtConfig),
    "pairs": (PairHistogramMatcher, PairHistogramConfig),
}


def _matcher(name: str, **config: Any) -> Matcher:
    return MATCHERS[name][0](**config)


# --- registry and configuration ------------------------------------------------------------------

# get_matcher(name, **overrides) sets the overrides; the descriptor of a square then has
# the shape given (None: the number of features depends on the polygon).
REGISTRY: dict[str, tuple[dict[str, Any], Callable[[Any], Any] | None, tuple[int, ...]]] = {
    "fft": ({"n_harmonics": 8, "scale_invariant": True}, lambda d: d.amplitudes.shape, (8,)),
    "integral": ({"n_points": 32, "alpha": 0.01}, np.shape, (32,)),
    "ring": ({"n_rings": 12}, np.shape, (12,)),
    "shape-context": ({"n_points": 50}, np.shape, (50, 60)),
    "scanline": ({"n_xi": 32}, np.shape, (32,)),
    "mrm": ({"n_points": 50, "n_scales": 5}, lambda d: d.mcc.shape, (50, 5)),
    "tangent": ({"n_points": 32, "norm": "l2"}, lambda d: d.periodic.shape, (32,)),
    "flirt": ({"candidates": 2, "max_hypotheses": 100}, None, ()),
    "pairs": ({"n_distance": 10, "n_angle": 4}, np.shape, (40,)),
}

# cls(config_cls(**example), **override) keeps both.
CONFIG_OBJECTS: dict[str, tuple[dict[str, Any], dict[str, Any]]] = {
    "fft": ({"n_bins": 128}, {"ray_hit": "nearest"}),
    "integral": ({"band": 0.5}, {"n_starts": 2}),
    "ring": ({"max_radius": 5.0}, {"arc_length": False}),
    "shape-context": ({"n_radial": 4}, {"n_angular": 8}),
    "scanline": ({"n_directions": 32}, {"seed": 1}),
    "mrm": ({"n_scales": 5}, {"band": None}),
    "tangent": ({"scale_weight": 0.5}, {"norm": "l2"}),
    "flirt": ({"rings": 3}, {"sectors": 8}),
    "pairs": ({"step": 0.5}, {"n_angle": 4}),
}

# A misspelt option: a UserError matching the pattern, naming every known option too.
UNKNOWN_OPTION: dict[str, tuple[dict[str, Any], str]] = {
    "fft": ({"bins": 3}, "unknown .*bins"),
    "integral": ({"points": 3}, "unknown .*points"),
    "ring": ({"rings": 3}, "unknown .*rings"),
    "shape-context": ({"bogus": 1}, "unknown .*bogus"),
    "scanline": ({"bogus": 1}, "unknown .*bogus"),
    "mrm": ({"bogus": 1}, "unknown .*bogus"),
    "tangent": ({"points": 3}, "unknown .*points"),
    "flirt": ({"not_an_option": 1}, "unknown FLIRT option.*not_an_option"),
    "pairs": ({"bins": 3}, "unknown .*bins"),
}

# Refused option values, and the parameter the message names.
BAD_VALUES: list[tuple[str, dict[str, Any], str]] = [
    ("fft", {"ray_hit": "middle"}, "ray_hit"),
    ("fft", {"n_bins": 64, "n_harmonics": 40}, "n_harmonics"),
    ("integral", {"alpha": -1.0}, "alpha"),
    ("integral", {"band": 0.0}, "band"),
    ("ring", {"max_radius": -1.0}, "max_radius"),
    ("ring", {"norm": "cosine"}, "norm"),
    ("shape-context", {"r_inner": 3.0, "r_outer": 2.0}, "r_inner"),
    ("shape-context", {"mean_distance": 0.0}, "mean_distance"),
    ("scanline", {"n_xi": 0}, "n_xi"),
    ("scanline", {"xi_max": -1.0}, "xi_max"),
    ("mrm", {"n_points": 3}, "n_points"),
    ("mrm", {"band": 0.0}, "band"),
    ("tangent", {"norm": "linf"}, "norm"),
    ("flirt", {"descriptor_distance": "cosine"}, "descriptor_distance"),
    ("flirt", {"viewpoint": "nowhere"}, "viewpoint"),
    ("pairs", {"step": 0.0}, "step"),
    ("pairs", {"max_distance": -1.0}, "max_distance"),
]


# --- descriptors and distances -------------------------------------------------------------------


@dataclass(frozen=True)
class Descriptors:
    """What a matcher's descriptors and distances satisfy.

    Attributes:
        parts: the numeric arrays of a descriptor (all finite).
        self_tol: bound on the distance of a descriptor to itself (0: exactly 0).
        valid: further claims on a descriptor (its shape, its sign).
        max_distance: largest possible distance.
    """

    parts: Callable[[Any], Sequence[Any]]
    self_tol: float = 0.0
    valid: Callable[[Matcher, Any], bool] = lambda m, d: True
    max_distance: float = np.inf


def _itself(d: Any) -> tuple[Any]:
    return (d,)


DESCRIPTORS: dict[str, Descriptors] = {
    "fft": Descriptors(lambda d: (d.amplitudes, d.range_function)),
    "integral": Descriptors(_itself, valid=lambda m, d: d.shape == (m.config.n_points,)),
    "ring": Descriptors(_itself, valid=lambda m, d: bool(np.all(d >= 0))),
    # The chi^2 costs come from a float32 product: a descriptor's cost to itself is zero
    # up to float32 rounding.
    "shape-context": Descriptors(_itself, self_tol=1e-5),
    "scanline": Descriptors(_itself, valid=lambda m, d: d.shape == (m.config.n_xi,)),
    "mrm": Descriptors(lambda d: (d.mcc, d.complexity), 1e-9, lambda m, d: d.complexity > 0),
    "tangent": Descriptors(lambda d: (d.periodic, d.turning, d.log_perimeter)),
    "flirt": Descriptors(
        lambda d: (d.points, d.scales, d.orientations, d.occupancy, d.evidence),
        self_tol=1e-12,
        max_distance=2.0,
    ),
    # Unit-norm square-rooted histograms (or zero): Euclidean distance at most sqrt(2).
    "pairs": Descriptors(_itself, max_distance=float(np.sqrt(2.0)) + 1e-6,
                         valid=lambda m, d: d.shape == (m.config.dim,) and bool(np.all(d >= 0))),
}

# The configs the degenerate-polygon, self-distance and batching tests run with.
VARIANTS: dict[str, tuple[dict[str, Any], ...]] = {
    "fft": ({}, {"scale_invariant": True}),
    "integral": ({}, {"scale_invariant": True}, {"n_starts": 3}),
    "ring": ({}, {"scale_invariant": True}, {"norm": "l1"}),
    "shape-context": ({}, {"scale_invariant": True}),
    "scanline": ({}, {"scale_invariant": True}),
    "mrm": ({}, {"scale_invariant": True}),
    "tangent": ({}, {"norm": "l2"}),
    "flirt": ({},),
    "pairs": ({}, {"scale_invariant": True}),
}


def _random_stars(count: int, n: int = 40) -> Callable[[], list[Polygon]]:
    def make() -> list[Polygon]:
        rng = np.random.default_rng(0)
        return [random_star(rng, n) for _ in range(count)]

    return make


def _blobs(count: int) -> Callable[[], list[Polygon]]:
    return lambda: [blob(s) for s in range(count)]


def _flirt_batch() -> list[Polygon]:
    a, b = lobed_star(3, 0.3), lobed_star(4, 0.2, seed=5)
    return [a, b, Polygon(BOX), lobed_star(3, 0.3, seed=6, noise=0.003)]


@dataclass(frozen=True)
class Batch:
    """The polygons the batching and self-distance tests describe; the first `queries` of
    them are queried against all, batched `distances` must equal a loop of `distance` to
    `rtol`, `atol`, and with `distinct_positive` different polygons are at distance > 0."""

    shapes: Callable[[], list[Polygon]]
    queries: int
    rtol: float
    atol: float
    distinct_positive: bool = False


BATCHES: dict[str, Batch] = {
    # float32 amplitudes / profiles compared by ||q||^2 + ||x||^2 - 2 q.x.
    "fft": Batch(_random_stars(30), 1, rtol=1e-5, atol=1e-6),
    "integral": Batch(_random_stars(12), 1, rtol=1e-12, atol=1e-15, distinct_positive=True),
    "ring": Batch(_random_stars(25), 1, rtol=1e-5, atol=1e-6),
    "shape-context": Batch(_blobs(6), 3, rtol=1e-6, atol=1e-7),
    "scanline": Batch(_blobs(5), 5, rtol=1e-7, atol=0.0),
    "mrm": Batch(_blobs(7), 3, rtol=1e-12, atol=0.0),
    "tangent": Batch(_random_stars(15, n=30), 1, 1e-9, 1e-12, distinct_positive=True),
    "flirt": Batch(_flirt_batch, 1, rtol=1e-7, atol=1e-12),
    "pairs": Batch(_random_stars(20), 1, rtol=1e-5, atol=1e-6),
}

# Polygons that are valid but extreme: every matcher must describe them with finite numbers.
DEGENERATE = {
    "triangle": [[0, 0], [1, 0], [0, 1]],
    "obtuse-triangle": [[0, 0], [3, 0], [0.5, 2.0]],
    "thin-100x0.01": [[0, 0], [100, 0], [100, 0.01], [0, 0.01]],
    "thin-10x0.01": [[0, 0], [10, 0], [10, 0.01], [0, 0.01]],
    "thin-10x0.001": [[0, 0], [10, 0], [10, 0.001], [0, 0.001]],
    "huge-2e6": SQUARE * 1e6,
    "huge-1e6": UNIT_SQUARE * 1e6,
    "huge-1e5": [[0, 0], [1e5, 0], [1e5, 1e5], [0, 1e5]],
    "small-2e-3": SQUARE * 1e-3,
    "small-1e-3": UNIT_SQUARE * 1e-3,
    "tiny-1e-5": [[0, 0], [1e-5, 0], [1e-5, 1e-5], [0, 1e-5]],
    "duplicates-closed": [[0, 0], [1, 0], [1, 0], [1, 1], [0, 1], [0, 0]],
    "duplicates-corners": [[0, 0], [1, 0], [1, 0], [1, 1], [1, 1], [0, 1]],
    "duplicates-box": [[0, 0], [0, 0], [4, 0], [4, 0], [4, 3], [0, 3], [0, 3]],
    "notched": NOTCHED,
    "c-shape": C_SHAPE,
}

# What a degenerate polygon is compared with.
REFERENCES: tuple[Callable[[], Polygon], ...] = (
    lambda: Polygon(SQUARE),
    lambda: Polygon(UNIT_SQUARE),
    lambda: Polygon(BOX),
    lambda: blob(1),
    lambda: lobed_star(3, 0.3),
)


# --- invariances ---------------------------------------------------------------------------------

Bound = Callable[[Matcher, Any, Any], float]
"""``(matcher, descriptor of p, descriptor of the other polygon) -> tolerance``."""


def _const(tol: float) -> Bound:
    return lambda m, da, db: tol


def _rel_distance(fraction: float, floor: float = 0.0) -> Bound:
    """`fraction` of the distance between p and the other polygon (at least `floor`)."""
    return lambda m, da, db: max(fraction * m.distance(da, db), floor)


def _pair_of(star: Callable[[np.random.Generator], Polygon]) -> Callable[[int], Any]:
    """``seed -> (p, (q,))``: two polygons drawn one after the other from one generator."""

    def shapes(seed: int) -> tuple[Polygon, tuple[Polygon, ...]]:
        rng = np.random.default_rng(seed)
        p = star(rng)
        return p, (star(rng),)

    return shapes


def _blob_pair(seed: int) -> tuple[Polygon, tuple[Polygon, ...]]:
    return blob(seed), (blob(seed + 1),)


def _flirt_rooms(draw: tuple[int, float, int]) -> tuple[Polygon, tuple[Polygon, ...]]:
    """A room, then the same place seen again and another place."""
    lobes, amp, seed = draw
    a = lobed_star(lobes, amp, seed=seed, noise=0.003)
    same_place = lobed_star(lobes, amp, seed=seed + 2, noise=0.003)
    return a, (same_place, lobed_star(lobes + 1, amp, seed=seed + 1, noise=0.003))


@dataclass(frozen=True)
class Rotation:
    """Rotation invariance about the sensor origin, as property tests.

    Attributes:
        examples: hypothesis examples per test.
        draws: strategy of the argument of `shapes`.
        shapes: ``draw -> (p, others)``: the polygon and the polygons it is compared with.
        self_bound: strict bound on ``distance(p, p rotated)``.
        pair_bounds: per other polygon q, strict bound on
            ``|distance(p, q rotated) - distance(p, q)|``.
    """

    examples: int
    draws: st.SearchStrategy[Any]
    shapes: Callable[[Any], tuple[Polygon, tuple[Polygon, ...]]]
    self_bound: Bound
    pair_bounds: tuple[Bound, ...]


_SEEDS = st.integers(0, 2**31 - 1)
_SEEDS_10K = st.integers(0, 10_000)
_FLIRT_DRAWS = st.tuples(st.integers(2, 6), st.floats(0.1, 0.4), _SEEDS_10K)

ROTATIONS: dict[str, Rotation] = {
    # A rotation by an angle that is not a multiple of the bin width samples the range
    # function at other angles; for these smooth rooms (radii 2-6 m, 4 harmonics) the
    # difference of the 16 amplitudes stays below 1 % of the descriptor norm.
    "fft": Rotation(
        40,
        _SEEDS,
        _pair_of(smooth_star),
        lambda m, da, db: 0.01 * np.linalg.norm(da.amplitudes),
        (lambda m, da, db: 0.01 * np.linalg.norm(db.amplitudes),),
    ),
    # Rotation is an isometry and keeps vertex 0: only rounding differs.
    "integral": Rotation(30, _SEEDS, _pair_of(random_star), _const(1e-9), (_const(1e-9),)),
    # The profile is exact, so only rounding differs (float32 descriptors).
    "ring": Rotation(40, _SEEDS, _pair_of(random_star), _const(1e-4), (_const(1e-4),)),
    # Tangent-relative angles: rotating a polygon rotates samples and tangents together,
    # so every histogram is unchanged except where an angle falls within rounding of a
    # bin edge (a count moves to the neighbouring bin): at most ~1e-3 of the cost scale.
    "shape-context": Rotation(15, _SEEDS_10K, _blob_pair, _const(2e-3), (_const(2e-3),)),
    # Rotating the polygon turns it against the fixed line family: quadrature noise only.
    # Measured on 20 seeds x 3 angles: median 4 %, max 12 % of the distance between two
    # different random blobs (which are similar shapes); bound 25 %.
    "scanline": Rotation(15, _SEEDS_10K, _blob_pair, _rel_distance(0.25), (_rel_distance(0.25),)),
    # The descriptor only uses displacement lengths and their side: exact up to rounding.
    "mrm": Rotation(20, _SEEDS_10K, _blob_pair, _const(1e-9), (_rel_distance(1e-9, floor=1e-12),)),
    # A rotation adds a constant to every edge angle: only rounding differs.
    "tangent": Rotation(
        30, _SEEDS, _pair_of(lambda rng: random_star(rng, 30)), _const(1e-9), (_const(1e-9),)
    ),
    # A polygon and its rotated copy match exactly (up to rounding).  Pairs that RANSAC
    # rejects can pick another of several near-equal-cost hypotheses after rounding (or a
    # beam chord that grazes a grid flips), which moves their distance, always in [1, 2],
    # by a few hundredths at most (largest seen in 60 random pairs: 0.033; matching pairs:
    # 0.0014).
    "flirt": Rotation(20, _FLIRT_DRAWS, _flirt_rooms, _const(1e-9), (_const(0.01), _const(0.06))),
    # Pair distances and normal angles are unchanged by a rotation; only a pair within
    # rounding of a bin edge can move to the neighbouring bin (float32 descriptor).
    "pairs": Rotation(30, _SEEDS, _pair_of(random_star), _const(2e-3), (_const(2e-3),)),
}


@dataclass(frozen=True)
class Scale:
    """``scale_invariant=True`` matches `shape` scaled by `factor` to within
    `invariant_tol`; the default config puts them farther than `metric_min` apart."""

    shape: Callable[[], Polygon]
    factor: float
    invariant_tol: float
    metric_min: float | None


# Integral invariant and tangent space check their scale handling by formula in their own
# tests (log radius ratio, perimeter term); MRM bounds its metric distance there too.
SCALES: dict[str, Scale] = {
    "fft": Scale(lambda: smooth_star(np.random.default_rng(3)), 7.5, 1e-6, metric_min=1.0),
    "ring": Scale(lambda: random_star(np.random.default_rng(2)), 6.0, 1e-4, metric_min=1.0),
    "shape-context": Scale(lambda: blob(3), 2.0, 1e-5, metric_min=0.05),
    "scanline": Scale(lambda: blob(2), 2.0, 1e-9, metric_min=1.0),
    "mrm": Scale(lambda: blob(5), 2.5, 1e-9, metric_min=None),
    "flirt": Scale(lambda: lobed_star(3, 0.3), 1.5, 1e-9, metric_min=1.0),
    "pairs": Scale(lambda: random_star(np.random.default_rng(2)), 1.7, 2e-3, metric_min=0.3),
}


# --- retrieval -----------------------------------------------------------------------------------

Places = Callable[[], tuple[list[Polygon], np.ndarray]]


def _rooms(noise: float = 0.03, random_start: bool = False) -> Places:
    """Six noisy rooms of each of the three kinds, each at a random pose."""

    def make() -> tuple[list[Polygon], np.ndarray]:
        rng = np.random.default_rng(11)
        kinds = np.repeat(np.arange(3), 6)
        return [room(k, rng, noise, random_start) for k in kinds], kinds

    return make


def _resampled_shapes() -> tuple[list[Polygon], np.ndarray]:
    """A rectangle, an L and a circle, 4 noisy rotated copies each (200 samples)."""
    rng = np.random.default_rng(0)
    kinds = [
        Polygon(np.array([[0, 0], [6, 0], [6, 3], [0, 3]], float)),
        Polygon(np.array([[0, 0], [6, 0], [6, 3], [3, 3], [3, 6], [0, 6]], float)),
        regular(90, 2.5),
    ]

    def noisy(p: Polygon) -> Polygon:
        dense = p.resample(200)
        return Polygon(dense + rng.normal(0, 0.03, dense.shape)).rotated(rng.uniform(-3, 3))

    return [noisy(k) for k in kinds for _ in range(4)], np.repeat(np.arange(3), 4)


def _noisy_blobs() -> tuple[list[Polygon], np.ndarray]:
    """Three blobs, 4 copies each with 5 cm vertex noise at a random heading."""
    rng = np.random.default_rng(0)
    kinds = [blob(100), blob(200), blob(300)]

    def noisy(p: Polygon) -> Polygon:
        v = p.vertices + rng.normal(0, 0.05, p.vertices.shape)
        return Polygon(v).rotated(rng.uniform(-np.pi, np.pi))

    return [noisy(k) for k in kinds for _ in range(4)], np.repeat(np.arange(3), 4)


def _lobed_rooms() -> tuple[list[Polygon], np.ndarray]:
    """Rooms of 3, 4 and 5 lobes, 4 noisy scans each at a random heading."""
    rng = np.random.default_rng(11)
    shapes, kinds = [], []
    for lobes in (3, 4, 5):
        for i in range(4):
            p = lobed_star(lobes, 0.25, seed=100 * lobes + i, noise=0.003)
            shapes.append(p.rotated(float(rng.uniform(-np.pi, np.pi))))
            kinds.append(lobes)
    return shapes, np.array(kinds)


PLACES: dict[str, Places] = {
    "fft": _rooms(),
    "integral": _rooms(random_start=True),
    "ring": _rooms(),
    "shape-context": _noisy_blobs,
    "scanline": _resampled_shapes,
    "mrm": _noisy_blobs,
    "tangent": _rooms(noise=0.02, random_start=True),
    "flirt": _lobed_rooms,
    "pairs": _rooms(),
}

# Smallest nearest-neighbour accuracy on the MPEG-7 subset (apple, bone, key), scale invariant.
MPEG7: dict[str, float] = {"fft": 0.9, "integral": 0.8, "ring": 0.8, "tangent": 0.8}


# --- helpers -------------------------------------------------------------------------------------


def _variant_id(name: str, config: dict[str, Any]) -> str:
    return "-".join([name, *(f"{k}={v}" for k, v in config.items())])


WITH_VARIANTS = [
    pytest.param(name, config, id=_variant_id(name, config))
    for name in MATCHERS
    for config in VARIANTS[name]
]


@cache
def _described(name: str, config: tuple[tuple[str, Any], ...], what: str) -> list[Any]:
    """Descriptors (cached per matcher config) of the references or of the batch."""
    m = _matcher(name, **dict(config))
    shapes = [make() for make in REFERENCES] if what == "references" else BATCHES[name].shapes()
    return [m.describe(p) for p in shapes]


def _assert_self_distance(name: str, value: float) -> None:
    tol = DESCRIPTORS[name].self_tol
    if tol == 0.0:
        assert value == 0.0
    else:
        assert 0.0 <= value < tol


def test_the_tables_cover_every_matcher() -> None:
    names = [n for n in MATCHER_NAMES if n != "cascade"]
    assert list(MATCHERS) == names
    for table in (REGISTRY, CONFIG_OBJECTS, UNKNOWN_OPTION, DESCRIPTORS, VARIANTS, BATCHES, PLACES):
        assert set(table) == set(names)
    # Every matcher that claims rotation invariance is property-tested for it.
    assert set(ROTATIONS) == {n for n in names if MATCHERS[n][0].rotation_invariant}
    assert {name for name, _, _ in BAD_VALUES} == set(names)


# --- registry and configuration ------------------------------------------------------------------


@pytest.mark.parametrize("name", list(REGISTRY))
def test_registry_builds_the_matcher_with_overrides(name: str) -> None:
    overrides, shape_of, shape = REGISTRY[name]
    assert isinstance(get_matcher(name), MATCHERS[name][0])
    m = get_matcher(name, **overrides)
    assert isinstance(m, MATCHERS[name][0]) and m.name == name
    assert m.rotation_invariant
    for key, value in overrides.items():
        assert getattr(m.config, key) == value
    if shape_of is not None:
        assert shape_of(m.describe(Polygon(SQUARE))) == shape


@pytest.mark.parametrize("name", list(CONFIG_OBJECTS))
def test_config_object_and_overrides_combine(name: str) -> None:
    cls, config_cls = MATCHERS[name]
    example, override = CONFIG_OBJECTS[name]
    for key, value in example.items():
        assert getattr(cls(config_cls(**example)).config, key) == value
    m = cls(config_cls(**example), **override)
    for key, value in {**example, **override}.items():
        assert getattr(m.config, key) == value


@pytest.mark.parametrize("name", list(UNKNOWN_OPTION))
def test_unknown_option_is_a_user_error_naming_the_known_ones(name: str) -> None:
    cls, config_cls = MATCHERS[name]
    option, pattern = UNKNOWN_OPTION[name]
    with pytest.raises(UserError, match=pattern) as err:
        cls(**option)
    assert all(f.name in str(err.value) for f in fields(config_cls))


@pytest.mark.parametrize(
    "name, bad, parameter",
    [pytest.param(*row, id=_variant_id(row[0], row[1])) for row in BAD_VALUES],
)
def test_bad_option_value_is_a_user_error_naming_it(
    name: str, bad: dict[str, Any], parameter: str
) -> None:
    cls, config_cls = MATCHERS[name]
    with pytest.raises(UserError, match=parameter):
        config_cls(**bad)
    with pytest.raises(UserError, match=parameter):
        cls(**bad)


# --- degenerate polygons, self-distance, batching ------------------------------------------------


@pytest.mark.parametrize("vertices", list(DEGENERATE.values()), ids=list(DEGENERATE))
@pytest.mark.parametrize("name, config", WITH_VARIANTS)
def test_degenerate_polygons_give_finite_descriptors_and_distances(
    name: str, config: dict[str, Any], vertices: Any
) -> None:
    claims = DESCRIPTORS[name]
    m = _matcher(name, **config)
    d = m.describe(Polygon(np.array(vertices, dtype=float)))
    for part in claims.parts(d):
        assert np.all(np.isfinite(part))
    assert claims.valid(m, d)
    refs = _described(name, tuple(config.items()), "references")
    single = np.array([m.distance(d, r) for r in refs])
    batched = m.distances(d, m.stack([d, *refs]))
    for dist in (single, batched):
        assert np.all(np.isfinite(dist)) and np.all(dist >= 0)
        assert np.all(dist <= claims.max_distance)
    _assert_self_distance(name, m.distance(d, d))
    _assert_self_distance(name, batched[0])


@pytest.mark.parametrize("name, config", WITH_VARIANTS)
def test_distance_to_self_is_zero(name: str, config: dict[str, Any]) -> None:
    m = _matcher(name, **config)
    descs = _described(name, tuple(config.items()), "batch")
    for d in descs:
        _assert_self_distance(name, m.distance(d, d))
    for value in np.diag(m.pairwise(descs)):
        _assert_self_distance(name, value)


@pytest.mark.parametrize("name, config", WITH_VARIANTS)
def test_batched_distances_equal_a_loop_of_distance(name: str, config: dict[str, Any]) -> None:
    batch = BATCHES[name]
    m = _matcher(name, **config)
    descs = _described(name, tuple(config.items()), "batch")
    stacked = m.stack(descs)
    for i, q in enumerate(descs[: batch.queries]):
        batched = m.distances(q, stacked)
        assert batched.shape == (len(descs),)
        single = np.array([m.distance(q, x) for x in descs])
        np.testing.assert_allclose(batched, single, rtol=batch.rtol, atol=batch.atol)
        assert np.all(np.isfinite(batched)) and np.all(batched >= 0)
        assert np.all(batched <= DESCRIPTORS[name].max_distance)
        if batch.distinct_positive:
            assert np.all(np.delete(batched, i) > 0)
    # `distance` is the batched comparison against a one-entry stack, to the last bit.
    for a in descs[:5]:
        for b in descs[:5]:
            assert m.distance(a, b) == m.distances(a, m.stack([b]))[0]


@pytest.mark.parametrize("name, config", WITH_VARIANTS)
def test_empty_stack_gives_no_distances(name: str, config: dict[str, Any]) -> None:
    m = _matcher(name, **config)
    for query in (m.describe(Polygon(SQUARE)), _described(name, tuple(config.items()), "batch")[0]):
        assert m.distances(query, m.stack([])).shape == (0,)


# --- invariances ---------------------------------------------------------------------------------


RotationCheck = Callable[[Matcher, Polygon, Any, tuple[Polygon, ...], float], None]
"""``(matcher, p, descriptor of p, the other polygons, angle)``: asserts a claim."""


def _for_drawn_rotations(name: str, check: RotationCheck) -> None:
    """`check` on ``ROTATIONS[name].examples`` hypothesis draws, angles in [-pi, pi]."""
    rot = ROTATIONS[name]
    m = _matcher(name)

    def run(draw: Any, angle: float) -> None:
        p, others = rot.shapes(draw)
        check(m, p, m.describe(p), others, angle)

    prop = given(draw=rot.draws, angle=st.floats(-np.pi, np.pi))(run)
    settings(max_examples=rot.examples, deadline=None)(prop)()


@pytest.mark.parametrize("name", list(ROTATIONS))
def test_distance_to_rotated_copy_is_near_zero(name: str) -> None:
    bound = ROTATIONS[name].self_bound

    def check(m: Matcher, p: Polygon, da: Any, others: tuple[Polygon, ...], angle: float) -> None:
        tol = bound(m, da, m.describe(others[0]))
        assert m.distance(da, m.describe(p.rotated(angle))) < tol

    _for_drawn_rotations(name, check)


@pytest.mark.parametrize("name", list(ROTATIONS))
def test_distance_unchanged_when_one_polygon_rotates(name: str) -> None:
    bounds = ROTATIONS[name].pair_bounds

    def check(m: Matcher, p: Polygon, da: Any, others: tuple[Polygon, ...], angle: float) -> None:
        for q, bound in zip(others, bounds, strict=True):
            db, db_rot = m.describe(q), m.describe(q.rotated(angle))
            assert abs(m.distance(da, db_rot) - m.distance(da, db)) < bound(m, da, db)

    _for_drawn_rotations(name, check)


@pytest.mark.parametrize("name", list(SCALES))
def test_scale_invariant_option_matches_a_scaled_copy(name: str) -> None:
    sc = SCALES[name]
    p = sc.shape()
    big = Polygon(p.vertices * sc.factor)
    inv = _matcher(name, scale_invariant=True)
    assert inv.distance(inv.describe(p), inv.describe(big)) < sc.invariant_tol
    if sc.metric_min is not None:
        metric = _matcher(name)
        assert metric.distance(metric.describe(p), metric.describe(big)) > sc.metric_min


# --- retrieval -----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(PLACES))
def test_nearest_neighbour_is_the_same_kind_of_place(name: str) -> None:
    shapes, labels = PLACES[name]()
    m = _matcher(name)
    d = m.pairwise([m.describe(s) for s in shapes])
    np.fill_diagonal(d, np.inf)
    assert np.all(labels[d.argmin(axis=1)] == labels)


@pytest.mark.parametrize("name", list(MPEG7))
def test_mpeg7_retrieval_on_real_shapes(name: str) -> None:
    folder = shared_file("mpeg7-subset")
    from data.mpeg7 import load_silhouettes

    shapes = [s for s in load_silhouettes(folder) if s.label in ("apple", "bone", "key")]
    labels = np.array([s.label for s in shapes])
    m = _matcher(name, scale_invariant=True)
    d = m.pairwise([m.describe(Polygon(s.contour)) for s in shapes])
    np.fill_diagonal(d, np.inf)
    assert np.mean(labels[d.argmin(axis=1)] == labels) > MPEG7[name]
