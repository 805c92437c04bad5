"""Offset viewpoints of a stored keyframe (loopclosure.viewpoints) and the place
database's smallest distance over them (loopclosure.place_views)."""

from __future__ import annotations

import numpy as np
import pytest

from data.errors import UserError
from loopclosure.place_database import PlaceDatabase
from loopclosure.place_shortlist import rank_interleave
from loopclosure.place_views import VIEWPOINTS, ViewpointRows
from loopclosure.polygon import Polygon
from loopclosure.viewpoints import (
    ViewpointConfig,
    free_offsets,
    ring_offsets,
    viewpoint_scans,
    viewpoint_vectors,
)
from loopclosure.virtual_scan import virtual_scan


def _corridor(half_width: float = 1.2, length: float = 8.0, step: float = 0.05) -> np.ndarray:
    """Two parallel walls at y = +-half_width, x in [-length, length] [m]."""
    x = np.arange(-length, length + step / 2, step)
    return np.concatenate([np.c_[x, np.full_like(x, half_width)],
                           np.c_[x, np.full_like(x, -half_width)]])


def test_ring_offsets_start_beside_the_path() -> None:
    o = ring_offsets(ViewpointConfig(radii=(1.0, 2.0), count=4))
    np.testing.assert_allclose(o, [[0, 1], [-1, 0], [0, -1], [1, 0],
                                   [0, 2], [-2, 0], [0, -2], [2, 0]], atol=1e-12)
    assert ring_offsets(ViewpointConfig()).shape == (0, 2)


def test_free_offsets_keep_viewpoints_clear_of_walls() -> None:
    pts = _corridor(1.2)
    own = virtual_scan(pts, 360, 20.0)
    # Beside the path (y = +-1) lies 0.2 m from a wall: out; along the corridor: in.
    free = free_offsets(pts, own, ViewpointConfig(radii=(1.0,), count=4, clearance=0.3))
    np.testing.assert_allclose(free, [[-1, 0], [1, 0]], atol=1e-12)
    # Beyond the wall (y = +-2): the keyframe's beam stops at the wall: out.
    free = free_offsets(pts, own, ViewpointConfig(radii=(2.0,), count=4, clearance=0.3))
    np.testing.assert_allclose(free, [[-2, 0], [2, 0]], atol=1e-12)
    # Wider corridor: all four in; the scans come from each viewpoint.
    pts = _corridor(3.0)
    cfg = ViewpointConfig(radii=(1.0,), count=4, clearance=0.3)
    scans = viewpoint_scans(pts, virtual_scan(pts, 360, 20.0), cfg, 360, 20.0)
    assert len(scans) == 4
    left = scans[0]  # at (0, 1): the left wall 2 m away straight up (bearing pi / 2)
    assert left.ranges[270] == pytest.approx(2.0, abs=0.02)
    assert left.ranges[90] == pytest.approx(4.0, abs=0.02)


def test_viewpoint_config_rejects_bad_values() -> None:
    with pytest.raises(UserError):
        ViewpointConfig(radii=(-1.0,))
    with pytest.raises(UserError):
        ViewpointConfig(radii=(1.0,), count=0)


def test_viewpoint_rows_take_the_smallest_distance_per_keyframe() -> None:
    rng = np.random.default_rng(0)
    rows = ViewpointRows(("a", "b"))
    per_row = [rng.normal(size=(n, 2, 3)) if n else None for n in (2, 0, 3, 1)]
    for v in per_row:
        rows.append(None if v is None else {"a": v[:, 0], "b": v[:, 1]})
    assert len(rows) == 6
    q = {"a": rng.normal(size=3), "b": rng.normal(size=3)}
    factors = {"a": 0.5, "b": 2.0}
    expected = np.full(4, np.inf)
    for r, v in enumerate(per_row):
        if v is not None:
            d = (0.5 * np.linalg.norm(v[:, 0] - q["a"], axis=1)
                 + 2.0 * np.linalg.norm(v[:, 1] - q["b"], axis=1))
            expected[r] = d.min()
    np.testing.assert_allclose(rows.screen([q], factors, 4), expected, rtol=1e-4)
    # two query sets: the smaller of the two per keyframe, from one pass
    q2 = {"a": rng.normal(size=3), "b": rng.normal(size=3)}
    both = np.minimum(expected, rows.screen([q2], factors, 4))
    np.testing.assert_allclose(rows.screen([q2, q], factors, 4), both, rtol=1e-4)
    p, raw = rows.exact(q, np.array([3, 1, 0, 2]),
                        lambda d: 0.5 * d["a"] + 2.0 * d["b"])
    np.testing.assert_allclose(p, expected[[3, 1, 0, 2]], rtol=1e-6)
    assert np.isinf(raw["a"][1]) and np.isfinite(raw["b"][0])
    np.testing.assert_allclose(rows.vectors(2)["a"], per_row[2][:, 0], atol=1e-6)
    assert rows.vectors(1) is None


def _square(half: float, centre: tuple[float, float] = (0.0, 0.0)) -> Polygon:
    t = np.linspace(-half, half, 40, endpoint=False)
    cx, cy = centre
    v = np.concatenate([np.c_[t, np.full_like(t, -half)], np.c_[np.full_like(t, half), t],
                        np.c_[-t, np.full_like(t, half)], np.c_[np.full_like(t, -half), -t]])
    return Polygon(v + np.array([cx, cy]))


def test_database_distance_is_the_smallest_over_viewpoints() -> None:
    db = PlaceDatabase(prefilter=("pairs",), verifiers=(), fusion="prefilter",
                       grid_headings=0, n_headings=0, top_k=2)
    rooms = [_square(s) for s in (2.0, 3.0, 4.0, 5.0)]
    query = db.describe(_square(6.0))
    for key, room in enumerate(rooms):
        desc = db.describe(room)
        if key == 1:  # keyframe 1 seen from a viewpoint holding the query's place
            desc[VIEWPOINTS] = {"pairs": np.stack([np.asarray(db.describe(rooms[0])["pairs"]),
                                                   np.asarray(query["pairs"])])}
        db.add_descriptors(key, desc)
    p, raw = db.prefilter_distances(query)
    assert p[1] == pytest.approx(0.0, abs=1e-9) and raw["pairs"][1] == pytest.approx(0.0)
    assert np.all(p[[0, 2, 3]] > 0.01)
    assert next(m.key for m in db.query(query)) == 1
    assert db.candidates(query).prefilter[0] == pytest.approx(0.0, abs=1e-9)
    # the stored viewpoints travel with the keyframe's descriptors; queries ignore them
    again = PlaceDatabase(db.config)
    for key in db.keys:
        again.add_descriptors(key, db.descriptors(key))
    np.testing.assert_allclose(again.prefilter_distances(query)[0], p)
    np.testing.assert_allclose(db.prefilter_distances(db.descriptors(1))[0][1], 0.0)


def test_viewpoint_vectors_describe_each_free_viewpoint() -> None:
    db = PlaceDatabase(prefilter=("pairs",), verifiers=(), fusion="prefilter",
                       grid_headings=0, n_headings=0)
    pts = _corridor(3.0)
    own = virtual_scan(pts, 360, 20.0)
    views = viewpoint_vectors(pts, own, ViewpointConfig(radii=(1.0,), count=2), db)
    assert views is not None and views["pairs"].shape == (2, len(db.describe(
        Polygon(np.array([[0, 0], [1, 0], [0, 1.0]])))["pairs"]))
    assert viewpoint_vectors(pts, own, ViewpointConfig(), db) is None


def test_query_viewpoints_are_compared_only_when_asked() -> None:
    rooms = [_square(s) for s in (2.0, 3.0, 4.0, 5.0)]
    for asked in (False, True):
        db = PlaceDatabase(prefilter=("pairs",), verifiers=(), fusion="prefilter",
                           grid_headings=0, n_headings=0, top_k=2, query_viewpoints=asked)
        for key, room in enumerate(rooms):
            db.add(key, room)
        query = db.describe(_square(6.0))
        query[VIEWPOINTS] = {"pairs": np.asarray(db.describe(rooms[2])["pairs"])[None]}
        p, _ = db.prefilter_distances(query)
        assert (p[2] == pytest.approx(0.0, abs=1e-9)) == asked
        if asked:
            assert db.candidates(query).indices[0] == 2


def test_fused_score_sees_own_distances_unless_asked() -> None:
    rooms = [_square(s) for s in (2.0, 3.0, 4.0, 5.0)]
    for scores in (False, True):
        db = PlaceDatabase(prefilter=("pairs",), verifiers=(), fusion="prefilter",
                           grid_headings=0, n_headings=0, top_k=2, viewpoint_scores=scores)
        query = db.describe(_square(6.0))
        for key, room in enumerate(rooms):
            desc = db.describe(room)
            if key == 1:
                desc[VIEWPOINTS] = {"pairs": np.asarray(query["pairs"])[None]}
            db.add_descriptors(key, desc)
        c = db.candidates(query)
        assert c.indices[0] == 1 and c.prefilter[0] == pytest.approx(0.0, abs=1e-9)
        own = np.linalg.norm(np.asarray(query["pairs"]) - db.describe(rooms[1])["pairs"])
        assert c.distances[0, 0] == pytest.approx(0.0 if scores else own, abs=1e-6)


def test_viewpoints_on_the_query_side_only() -> None:
    """stored_viewpoints=False: a stored keyframe's viewpoints are kept with its
    descriptors but not screened; the query's own viewpoints still are."""
    rooms = [_square(s) for s in (2.0, 3.0, 4.0, 5.0)]
    db = PlaceDatabase(prefilter=("pairs",), verifiers=(), fusion="prefilter",
                       grid_headings=0, n_headings=0, top_k=2, query_viewpoints=True,
                       stored_viewpoints=False)
    query = db.describe(_square(6.0))
    for key, room in enumerate(rooms):
        desc = db.describe(room)
        if key == 1:  # a stored viewpoint identical to the query: not screened
            desc[VIEWPOINTS] = {"pairs": np.asarray(query["pairs"])[None]}
        db.add_descriptors(key, desc)
    assert VIEWPOINTS in db.descriptors(1)
    p, _ = db.prefilter_distances(query)
    assert p[1] > 0.1
    query[VIEWPOINTS] = {"pairs": np.asarray(db.describe(rooms[2])["pairs"])[None]}
    p, _ = db.prefilter_distances(query)
    assert p[2] == pytest.approx(0.0, abs=1e-9) and p[1] > 0.1
    assert db.candidates(query).indices[0] == 2


def test_rank_interleave_orders_by_best_rank_then_distance() -> None:
    a = np.array([0.1, 0.5, 0.3, np.inf])
    b = np.array([0.9, 0.2, 0.8, 0.05])
    # ranks in a: rows 0, 2, 1; in b: rows 3, 1, 2, 0 -> best ranks 0, 1, 1, 0
    np.testing.assert_array_equal(rank_interleave([a, b]), [3, 0, 1, 2])
    np.testing.assert_array_equal(rank_interleave([a]), [0, 2, 1, 3])


def test_interleaved_viewpoint_order_keeps_the_own_descriptions_best() -> None:
    """Two query viewpoints identical to rooms 3 and 4 take the first two places by the
    smallest distance; interleaved, the own description's nearest (room 0) keeps one."""
    rooms = [_square(s) for s in (2.0, 3.0, 4.0, 5.0, 6.0, 7.0)]
    found = {}
    for order in ("min", "interleave"):
        db = PlaceDatabase(prefilter=("pairs",), verifiers=(), fusion="prefilter",
                           grid_headings=0, n_headings=0, top_k=2, query_viewpoints=True,
                           viewpoint_order=order)
        for key, room in enumerate(rooms):
            db.add(key, room)
        query = db.describe(_square(2.1))
        query[VIEWPOINTS] = {"pairs": np.stack([np.asarray(db.describe(rooms[i])["pairs"])
                                                for i in (3, 4)])}
        lists = db.prefilter_lists(query)
        assert len(lists) == (2 if order == "interleave" else 1)
        assert int(np.argmin(lists[0])) == (0 if order == "interleave" else 3)
        found[order] = sorted(int(i) for i in db.candidates(query).indices)
        # a masked query (few rows allowed: exact distances, no screening) agrees
        few = db.candidates(query, allowed=[0, 3, 4, 5]).indices
        assert sorted(int(i) for i in few) == found[order]
    assert found == {"min": [3, 4], "interleave": [0, 3]}
    with pytest.raises(UserError):
        PlaceDatabase(prefilter=("pairs",), verifiers=(), viewpoint_order="mean")


def test_interleave_ranks_stored_viewpoints_as_their_own_list() -> None:
    """Stored viewpoints of rooms 4 and 5 identical to the query take the first two
    places by the smallest distance; interleaved, the own descriptions' nearest
    (room 0) keeps one of the two."""
    rooms = [_square(s) for s in (2.0, 3.0, 4.0, 5.0, 6.0, 7.0)]
    found = {}
    for order in ("min", "interleave"):
        db = PlaceDatabase(prefilter=("pairs",), verifiers=(), fusion="prefilter",
                           grid_headings=0, n_headings=0, top_k=2, viewpoint_order=order)
        query = db.describe(_square(2.1))
        for key, room in enumerate(rooms):
            desc = db.describe(room)
            if key in (4, 5):
                desc[VIEWPOINTS] = {"pairs": np.asarray(query["pairs"])[None]}
            db.add_descriptors(key, desc)
        lists = db.prefilter_lists(query)
        assert len(lists) == (2 if order == "interleave" else 1)
        found[order] = sorted(int(i) for i in db.candidates(query).indices)
    assert found == {"min": [4, 5], "interleave": [0, 4]}
