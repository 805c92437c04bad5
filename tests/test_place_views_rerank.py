"""The viewpoints' re-ranking of a pool (``viewpoint_order="rerank"``): the
rank-normalised combination of a query's descriptions (loopclosure.place_views) and
the place database's shortlist by it (loopclosure.place_prefilter)."""

from __future__ import annotations

import numpy as np
import pytest

from data.errors import UserError
from loopclosure.place_database import PlaceDatabase
from loopclosure.place_views import VIEWPOINTS, rank_normalised


def test_rank_normalised_rescales_each_description_by_its_kth_smallest() -> None:
    p = np.array([[0.2, 0.3, 0.4, 0.5],
                  [0.1, 0.16, 0.13, 0.6]])
    # rank 2: s_0 = 0.3, s_1 = 0.13, row 1 times 0.3 / 0.13 = [0.231, 0.369, 0.3, 1.385]
    got, which = rank_normalised(p, 2)
    np.testing.assert_allclose(got, [0.2, 0.3, 0.3, 0.5])
    np.testing.assert_array_equal(which, [0, 0, 1, 0])
    # rank 0: the plain minimum
    got, which = rank_normalised(p, 0)
    np.testing.assert_allclose(got, [0.1, 0.16, 0.13, 0.5])
    np.testing.assert_array_equal(which, [1, 1, 1, 0])
    # rank beyond the pool: the largest value, s_0 = 0.5, s_1 = 0.6
    got, _ = rank_normalised(p, 10)
    np.testing.assert_allclose(got, [0.1 * 5 / 6, 0.16 * 5 / 6, 0.13 * 5 / 6, 0.5])
    # a description with no finite distance keeps its scale (and never wins)
    q = np.vstack([p[0], np.full(4, np.inf)])
    got, which = rank_normalised(q, 2)
    np.testing.assert_allclose(got, p[0])
    np.testing.assert_array_equal(which, [0, 0, 0, 0])
    # one description: unchanged
    got, _ = rank_normalised(p[:1], 2)
    np.testing.assert_allclose(got, p[0])


def _vector_db(order: str, pool: int = 128, rank: int = 3) -> PlaceDatabase:
    """Six stored 2-vectors (prefilter ``pairs`` alone, scale fixed at 1): row 0 at
    0.2 from the query's own (0, 0); rows 1-5 around (10, 0), where the query's one
    viewpoint lies, 0.1 or 0.0707 from it."""
    db = PlaceDatabase(prefilter=("pairs",), verifiers=(), fusion="prefilter",
                       grid_headings=0, n_headings=0, top_k=2, fixed_scales=(1.0,),
                       query_viewpoints=True, viewpoint_order=order, viewpoint_pool=pool,
                       viewpoint_rank=rank)
    for key, v in enumerate([(0.2, 0.0), (10.1, 0.0), (10.0, 0.1), (9.9, 0.0),
                             (10.0, -0.1), (10.05, 0.05)]):
        db.add_descriptors(key, {"pairs": np.array(v)})
    return db


def _query() -> dict:
    return {"pairs": np.zeros(2), VIEWPOINTS: {"pairs": np.array([[10.0, 0.0]])}}


def test_rerank_keeps_the_own_nearest_where_a_generic_viewpoint_matches_many() -> None:
    """The plain minimum lets the viewpoint's five look-alikes take both candidates;
    re-ranked with rank 3 the viewpoint's distances are scaled by s_0 / s_1 =
    10.0005 / 0.1 (the own description's 3rd smallest, |(10, 0.1)|, and the
    viewpoint's), so row 0 (0.2) stays first and row 5 (0.0707 x 100 = 7.07) second."""
    assert 0 not in _vector_db("min").candidates(_query()).indices.tolist()
    db = _vector_db("rerank")
    c = db.candidates(_query())
    assert c.indices.tolist() == [0, 5]
    np.testing.assert_allclose(c.prefilter, [0.2, np.hypot(0.05, 0.05) * np.hypot(10.0, 0.1) / 0.1],
                               rtol=1e-5)
    # over fewer rows the scales come from those rows: rows 0, 1, 2, 5 give s_0 =
    # 10.05 (row 5's own), s_1 = 0.1, the same order
    assert db.candidates(_query(), allowed=[0, 1, 2, 5]).indices.tolist() == [0, 5]
    # the own distances of a small mask are exact, of a large one screened: alike
    pre = db._prefilter
    one = np.zeros(6, bool)
    one[5] = True
    exact = pre.own_distances(_query(), one, 6, np.ones(1))
    assert np.isinf(exact[:5]).all()
    np.testing.assert_allclose(exact[5], np.hypot(10.05, 0.05))
    np.testing.assert_allclose(pre.own_distances(_query(), None, 6, np.ones(1))[5],
                               exact[5], rtol=1e-5)
    # the prefilter list ranks the same way
    assert np.argsort(db.prefilter_lists(_query())[0], kind="stable")[:2].tolist() == [0, 5]


def test_rerank_ranks_only_the_pool_again() -> None:
    """Pool of 2 (the own description's two nearest: rows 0 and 3, own 0.2 and 9.9):
    rank 3 is beyond the pool, so s_0 = 9.9 and s_1 = 9.8 (the viewpoint's larger
    distance over the pool, to row 0); row 3 takes 0.1 x 9.9 / 9.8, and the other
    rows keep their own distances, behind the pool."""
    db = _vector_db("rerank", pool=2)
    lists = db.prefilter_lists(_query())
    assert len(lists) == 1
    want = [0.2, 10.1, np.hypot(10.0, 0.1), 0.1 * 9.9 / 9.8, np.hypot(10.0, 0.1),
            np.hypot(10.05, 0.05)]
    np.testing.assert_allclose(lists[0], want, rtol=1e-5)
    assert db.candidates(_query()).indices.tolist() == [3, 0]
    # a stored keyframe asking with its own descriptors: no viewpoints, own order
    assert [m.key for m in db.query_stored(0)] == [0, 3]


def test_rerank_sees_stored_viewpoints_in_the_pool() -> None:
    """A stored viewpoint of row 2 equal to the query's own vector: p = 0 there."""
    db = PlaceDatabase(prefilter=("pairs",), verifiers=(), fusion="prefilter",
                       grid_headings=0, n_headings=0, top_k=2, fixed_scales=(1.0,),
                       viewpoint_order="rerank", viewpoint_rank=0)
    for key, v in enumerate([(0.2, 0.0), (0.5, 0.0), (3.0, 0.0)]):
        desc = {"pairs": np.array(v)}
        if key == 2:
            desc[VIEWPOINTS] = {"pairs": np.zeros((1, 2))}
        db.add_descriptors(key, desc)
    c = db.candidates({"pairs": np.zeros(2)})
    assert c.indices.tolist() == [2, 0]
    np.testing.assert_allclose(c.prefilter, [0.0, 0.2], atol=1e-6)
    with pytest.raises(UserError):
        PlaceDatabase(prefilter=("pairs",), verifiers=(), viewpoint_pool=0)


def test_set_distances_match_the_exact_ones() -> None:
    from loopclosure.matchers.vector_search import VectorStore

    store = VectorStore(2)
    store.extend(np.array([[1.0, 0.0], [4.0, 4.0], [0.0, 3.0]]))
    got = store.set_distances(np.array([[0.0, 0.0], [1.0, 0.0]]), np.array([2, 0]))
    np.testing.assert_allclose(got, [[3.0, 1.0], [np.sqrt(10.0), 0.0]], atol=1e-6)


def test_exact_sets_take_each_rows_nearest_viewpoint_per_query() -> None:
    from loopclosure.place_views import ViewpointRows

    views = ViewpointRows(("pairs",))
    views.append({"pairs": np.array([[0.0, 1.0], [0.0, 5.0]])})  # row 0: two viewpoints
    views.append(None)                                           # row 1: none
    views.append({"pairs": np.array([[3.0, 0.0]])})              # row 2: one
    queries = [{"pairs": np.zeros(2)}, {"pairs": np.array([0.0, 4.0])}]
    p, raw = views.exact_sets(queries, np.array([2, 1, 0]), lambda d: 2.0 * d["pairs"])
    np.testing.assert_allclose(p, [[6.0, np.inf, 2.0], [10.0, np.inf, 2.0]], atol=1e-6)
    np.testing.assert_allclose(raw["pairs"], [[3.0, np.inf, 1.0], [5.0, np.inf, 1.0]],
                               atol=1e-6)
    # the same as `exact`, one query set at a time
    for a, qv in enumerate(queries):
        one, one_raw = views.exact(qv, np.array([2, 1, 0]), lambda d: 2.0 * d["pairs"])
        np.testing.assert_allclose(p[a], one, atol=1e-6)
        np.testing.assert_allclose(raw["pairs"][a], one_raw["pairs"], atol=1e-6)
