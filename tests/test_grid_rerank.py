"""The grids' ranking of the prefilter's shortlist (`loopclosure.grid_rerank`) and its
use by the place database."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from data.errors import UserError
from loopclosure import PlaceDatabase, PlaceDatabaseConfig
from loopclosure.grid_rerank import (
    dilate_polar,
    dilated_similarity,
    grid_similarity,
    union_of_rankings,
)
from loopclosure.polygon import Polygon


def test_dilation_is_a_plus_circular_in_sectors_only() -> None:
    g = np.zeros((4, 6), bool)
    g[0, 0] = True
    d = dilate_polar(g)
    want = np.zeros((4, 6), bool)
    want[0, [5, 0, 1]] = True  # the sector neighbours wrap around
    want[1, 0] = True  # the ring below; no ring above ring 0 (rings do not wrap)
    np.testing.assert_array_equal(d, want)
    assert dilate_polar(g[None]).shape == (1, 4, 6)


def test_similarity_of_a_grid_with_itself_turned_is_one() -> None:
    rng = np.random.default_rng(3)
    g = rng.random((5, 24)) < 0.2
    turned = np.stack([np.roll(g, s, axis=1) for s in (0, 1, 7, 23)])
    np.testing.assert_allclose(grid_similarity(g, turned), 1.0, atol=1e-12)


def test_similarity_hand_checked_and_empty_grids() -> None:
    q = np.zeros((3, 8), bool)
    q[0, 0] = True  # dilated: 4 cells (3 in ring 0, 1 in ring 1)
    other = np.zeros((3, 8), bool)
    other[2, 4] = True  # dilated: 4 cells (3 in ring 2, 1 in ring 1), best turn: 1 shared
    c = grid_similarity(q, np.stack([other, np.zeros((3, 8), bool)]))
    np.testing.assert_allclose(c, [1 / np.sqrt(4 * 4), 0.0])


def test_similarity_refuses_grids_of_another_shape() -> None:
    with pytest.raises(UserError, match="disagree"):
        grid_similarity(np.zeros((3, 8), bool), np.zeros((2, 3, 9), bool))


def test_union_takes_k_by_distance_and_extras_by_the_combined_score() -> None:
    p = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    c = np.array([0.0, 0.0, 0.0, 0.0, 0.9, 0.1])
    # K = 2: positions 0, 1; of the rest, p - c: 0.3, 0.4, -0.4, 0.5 -> position 4 first.
    np.testing.assert_array_equal(union_of_rankings(p, c, 2, 1, 1.0), [0, 1, 4])
    np.testing.assert_array_equal(union_of_rankings(p, c, 2, 2, 1.0), [0, 1, 2, 4])
    np.testing.assert_array_equal(union_of_rankings(p, c, 2, 0, 1.0), [0, 1])
    np.testing.assert_array_equal(union_of_rankings(p, c, 2, 2, 0.0), [0, 1, 2, 3])
    with pytest.raises(UserError):
        union_of_rankings(p, c[:3], 2, 1, 1.0)


def _room(rng: np.random.Generator, n: int = 180) -> Polygon:
    """A closed room-like polygon with random bumps [m], about the origin."""
    a = np.linspace(-np.pi, np.pi, n, endpoint=False)
    r = 3.0 + rng.uniform(0, 2.0) * (np.cos(2 * a) > rng.uniform(-1, 1)) + 0.2 * rng.random(n)
    return Polygon(np.c_[r * np.cos(a), r * np.sin(a)])


def test_database_candidates_are_the_k_best_and_the_grids_extras() -> None:
    """Brute force: p of every row, the shortlist, c of its rows, then the union."""
    rng = np.random.default_rng(0)
    polys = [_room(rng) for _ in range(40)]
    stages = PlaceDatabaseConfig().stages
    db = PlaceDatabase(top_k=4, grid_extra=3, grid_shortlist=12,
                       fixed_scales=(1.0,) * len(stages))
    for i, poly in enumerate(polys):
        db.add(i, poly)
    q = db.describe(_room(rng))
    p, _ = db.prefilter_distances(q)
    short = np.lexsort((np.arange(len(p)), p))[:12]
    n_cells = db.config.grid_rings * db.config.grid_sectors
    unpack = lambda b: np.unpackbits(b, count=n_cells).reshape(  # noqa: E731
        db.config.grid_rings, db.config.grid_sectors)
    c = grid_similarity(unpack(q["grid"]), np.stack([unpack(db.descriptors(int(i))["grid"])
                                                     for i in short]))
    want = short[union_of_rankings(p[short], c, 4, 3, 1.0)]
    got = db.candidates(q)
    np.testing.assert_array_equal(got.indices, want)
    assert len(got.indices) == 7
    np.testing.assert_allclose(got.prefilter, p[want], rtol=1e-9)
    none = PlaceDatabase(replace(db.config, grid_extra=0))
    for i, poly in enumerate(polys):
        none.add(i, poly)
    np.testing.assert_array_equal(none.candidates(q).indices, short[:4])



def test_dilated_similarity_equals_grid_similarity_on_grids_dilated_once() -> None:
    rng = np.random.default_rng(3)
    query = rng.random((6, 24)) < 0.15
    stored = rng.random((5, 6, 24)) < 0.15
    stored[4] = False  # an empty grid: similarity 0
    dilated = dilate_polar(stored)
    counts = np.count_nonzero(dilated, axis=(1, 2))
    got = dilated_similarity(dilate_polar(query), dilated, counts)
    np.testing.assert_array_equal(got, grid_similarity(query, stored))
    assert got[4] == 0.0


def test_similarity_skips_the_rings_the_query_leaves_empty() -> None:
    """The correlation over the query's occupied rings only is the brute-force
    circular correlation of the whole grids (the empty rings add only zeros), also
    when the stored grids are occupied there, and 0 for an empty query."""
    rng = np.random.default_rng(7)
    query = dilate_polar(rng.random((8, 30)) < 0.2)
    query[[0, 4, 5, 7]] = False
    stored = dilate_polar(rng.random((6, 8, 30)) < 0.2)
    counts = np.count_nonzero(stored, axis=(1, 2))
    brute = np.array([max(np.sum(g * np.roll(query, -k, axis=1)) for k in range(30))
                      for g in stored.astype(int)])
    expected = brute / np.sqrt(query.sum() * counts)
    np.testing.assert_allclose(dilated_similarity(query, stored, counts), expected,
                               atol=1e-5)
    empty = np.zeros_like(query)
    np.testing.assert_array_equal(dilated_similarity(empty, stored, counts), 0.0)


def test_union_of_rankings_in_the_shortlists_own_order() -> None:
    p = np.array([0.5, 0.1, 0.3, 0.2])
    c = np.array([0.0, 0.0, 0.0, 1.0])
    # ordered: the first two positions, then the best of the rest by p - c (position 3)
    np.testing.assert_array_equal(union_of_rankings(p, c, 2, 1, 1.0, ordered=True), [0, 1, 3])
    # by p: positions 1 and 3, then position 2 (0.3 < 0.5), in increasing p
    np.testing.assert_array_equal(union_of_rankings(p, c, 2, 1, 1.0), [1, 3, 2])
