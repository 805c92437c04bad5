"""Place database (loopclosure.place_database), its headings and recall@k, and the
shared vector search."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data.errors import UserError
from data.sim import place_dataset
from loopclosure.headings import headings_from_range_functions
from loopclosure.matchers.fft import FFTMatcher, heading_from_range_functions
from loopclosure.matchers.vector_search import (
    VectorStore,
    euclidean_distances,
    smallest_k,
    stack_vectors,
)
from loopclosure.place_config import PlaceDatabaseConfig
from loopclosure.place_database import PlaceDatabase
from loopclosure.polygon import Polygon, polygon_from_scan
from loopclosure.recall import prefilter_recall_at_k


def star_polygon(rng: np.random.Generator, n: int = 90, size: float = 5.0) -> Polygon:
    """A random star-shaped room-sized polygon [m] (counter-clockwise)."""
    theta = np.sort(rng.uniform(0, 2 * np.pi, n))
    harmonics = rng.normal(size=(4, 2)) * 0.15
    k = np.arange(1, 5)[:, None]
    r = size * (1 + (harmonics[:, :1] * np.cos(k * theta) + harmonics[:, 1:] * np.sin(k * theta))
                .sum(axis=0))
    r *= rng.uniform(0.97, 1.03, n)
    return Polygon(np.c_[r * np.cos(theta), r * np.sin(theta)])


@pytest.fixture(scope="module")
def polygons() -> list[Polygon]:
    rng = np.random.default_rng(11)
    return [star_polygon(rng, size=rng.uniform(3, 8)) for _ in range(60)]


@pytest.fixture(scope="module")
def places() -> tuple[list[Polygon], np.ndarray, np.ndarray]:
    """A small simulated Box set: 5 places x 8 scans, with the true poses."""
    ds = place_dataset("box", places=5, scans_per_place=8, seed=3)
    return (
        [polygon_from_scan(s) for _, s in ds],
        np.array([label for label, _ in ds]),
        np.array([s.odom for _, s in ds]),
    )


def quick_db(**overrides: object) -> PlaceDatabase:
    """FFT + ring prefilter, integral-invariant verifier (fast), rank fusion; the K
    candidates are the K smallest prefilter distances (no grid candidates)."""
    cfg = dict(prefilter=("fft", "ring"), verifiers=("integral",), fusion="rank", top_k=5,
               grid_extra=0)
    cfg.update(overrides)
    return PlaceDatabase(PlaceDatabaseConfig(**cfg))  # type: ignore[arg-type]


# -- vector search --------------------------------------------------------------------


def test_euclidean_distances_match_float64_and_identical_is_zero() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(5.0, 1.0, size=(500, 16))
    st_ = stack_vectors(list(x), 16)
    q = x[17].copy()
    d = euclidean_distances(q, st_.matrix, st_.sqnorms)
    ref = np.linalg.norm(x.astype(np.float32).astype(float) - q.astype(np.float32), axis=1)
    np.testing.assert_allclose(d, ref, rtol=2e-5, atol=1e-4)
    assert d[17] == 0.0 and d.dtype == np.float64 and (d >= 0).all()


def test_smallest_k_is_the_sorted_prefix() -> None:
    rng = np.random.default_rng(1)
    v = rng.integers(0, 50, size=400).astype(float)  # many ties
    for k in (1, 7, 400, 1000):
        idx = smallest_k(v, k)
        want = np.argsort(v, kind="stable")[: min(k, 400)]
        np.testing.assert_array_equal(v[idx], v[want])
        assert list(idx) == sorted(idx, key=lambda i: (v[i], i))
    assert len(smallest_k(v, 0)) == 0


def test_vector_store_grows_by_doubling_and_keeps_rows() -> None:
    rng = np.random.default_rng(2)
    x = rng.normal(100.0, 1.0, size=(300, 8))  # large offset: the reference row matters
    store = VectorStore(8, capacity=4)
    caps = []
    for row in x:
        store.append(row)
        caps.append(store.capacity)
    assert len(store) == 300
    assert set(caps) == {4 * 2**i for i in range(8)}  # 4, 8, ..., 256, 512
    np.testing.assert_allclose(store.row(123), x[123], atol=1e-4)
    d = store.distances(x[5])
    np.testing.assert_allclose(d, np.linalg.norm(x - x[5], axis=1), rtol=1e-4, atol=1e-4)
    assert d[5] == 0.0
    rows = np.array([3, 5, 299])
    np.testing.assert_allclose(store.distances(x[5], rows), d[rows])
    with pytest.raises(ValueError):
        store.append(np.full(8, np.nan))


# -- database consistency with brute force --------------------------------------------


def test_query_matches_brute_force(polygons: list[Polygon]) -> None:
    db = quick_db(top_k=7)
    for i, p in enumerate(polygons):
        db.add(i, p, stamp=float(i), pose=(float(i), 0.0, 0.0))
    fft, ring, integral = db.matchers["fft"], db.matchers["ring"], db.matchers["integral"]
    fd = [fft.describe(p) for p in polygons]
    rd = [ring.describe(p) for p in polygons]
    idd = [integral.describe(p) for p in polygons]
    scales = db.scales
    q = star_polygon(np.random.default_rng(99))
    qf, qr, qi = fft.describe(q), ring.describe(q), integral.describe(q)
    d_fft = np.array([fft.distance(qf, d) for d in fd])
    d_ring = np.array([ring.distance(qr, d) for d in rd])
    combined = d_fft / scales["fft"] + d_ring / scales["ring"]
    got, raw = db.prefilter_distances(q)
    np.testing.assert_allclose(raw["fft"], d_fft, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(raw["ring"], d_ring, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(got, combined, rtol=1e-4, atol=1e-5)
    want = set(np.argsort(combined)[:7].tolist())
    matches = db.query(q)
    assert {m.key for m in matches} == want
    assert sorted(m.prefilter_rank for m in matches) == list(range(7))
    for m in matches:
        assert m.distances["integral"] == pytest.approx(integral.distance(qi, idd[m.key]))
        assert m.prefilter_distance == pytest.approx(combined[m.key], rel=1e-4)
        assert 0.0 <= m.score <= 1.0
        assert m.stamp == float(m.key) and m.pose == (float(m.key), 0.0, 0.0)
        assert m.verifier_distances == {"integral": m.distances["integral"]}
    scores = [m.score for m in matches]
    assert scores == sorted(scores, reverse=True)


def test_query_of_a_stored_polygon_finds_itself_first(polygons: list[Polygon]) -> None:
    db = PlaceDatabase(top_k=5)  # defaults: surface pairs, FLIRT, logistic fusion
    for i, p in enumerate(polygons[:20]):
        db.add(i, p)
    m = db.query(polygons[4])
    assert m[0].key == 4
    assert m[0].distances["pairs"] == 0.0 and m[0].distances["flirt"] == 0.0
    assert m[0].score > 0.99


def test_storage_grows_without_restacking(polygons: list[Polygon]) -> None:
    db = quick_db()
    ids = []
    for i, p in enumerate(polygons):
        db.add(f"kf{i}", p)  # string keys work too
        ids.append(id(db._stores["fft"]._rows))
    # 60 keyframes fit the initial 64 rows: the buffer is never replaced or re-stacked.
    assert len(set(ids)) == 1
    assert len(db) == 60 and "kf3" in db and db.keys[3] == "kf3"
    with pytest.raises(UserError, match="already"):
        db.add("kf3", polygons[0])


def test_storage_capacity_doubles_over_many_insertions() -> None:
    db = PlaceDatabase(prefilter=("fft", "ring"), verifiers=(), fusion="prefilter", n_headings=0)
    fft, ring = db.matchers["fft"], db.matchers["ring"]
    p = star_polygon(np.random.default_rng(0))
    desc = {"fft": fft.describe(p), "ring": ring.describe(p)}
    caps = set()
    for i in range(1000):
        db.add_descriptors(i, desc)
        caps.add(db._stores["ring"].capacity)
    assert caps == {64 * 2**i for i in range(5)}  # 64 .. 1024


# -- gating ---------------------------------------------------------------------------


def test_allowed_keys_mask_and_exclusions(polygons: list[Polygon]) -> None:
    db = quick_db(top_k=5)
    for i, p in enumerate(polygons):
        db.add(i, p)
    q = polygons[10]
    full, _ = db.prefilter_distances(q)
    for allowed in (np.array([3, 10, 40, 41, 42, 59]), np.arange(0, 60, 2)):
        got = db.query(q, allowed=allowed)
        want = allowed[np.argsort(full[allowed])[:5]]
        assert {m.key for m in got} == set(want.tolist())
        mask = np.zeros(60, bool)
        mask[allowed] = True
        assert {m.key for m in db.query(q, allowed=mask)} == set(want.tolist())
    got = db.query(q, exclude_keys=[10, 11])
    assert all(m.key not in (10, 11) for m in got) and len(got) == 5
    assert db.query(q, allowed=np.zeros(60, bool)) == []
    assert [m.key for m in db.query(q, allowed=[7])] == [7]
    with pytest.raises(UserError, match="not in the place database"):
        db.query(q, allowed=[1000])
    with pytest.raises(UserError, match="shape"):
        db.query(q, allowed=np.ones(3, bool))


# -- what the prefilter keeps; headings -----------------------------------------------


def test_prefilter_recall_on_simulated_places(places) -> None:
    polys, labels, _ = places
    db = PlaceDatabase(verifiers=(), fusion="prefilter")
    for i, p in enumerate(polys):
        db.add(i, p)
    rec = {r.k: r for r in prefilter_recall_at_k(db, labels, ks=(1, 5, 7, 20))}
    assert rec[1].hit_rate >= 0.95 and rec[1].queries == 40
    assert rec[7].recall >= 0.85  # 7 other scans of the same place exist
    assert rec[20].recall == 1.0 or rec[20].recall >= rec[7].recall
    # Explicit queries give the same figures as the leave-one-out default when a
    # database without the query is used.
    sub = PlaceDatabase(verifiers=(), fusion="prefilter")
    for i, p in enumerate(polys[1:]):
        sub.add(i, p)
    r = prefilter_recall_at_k(sub, labels[1:], ks=(1,), queries=[(labels[0], polys[0])])
    assert r[0].queries == 1 and r[0].hit_rate == 1.0


def test_heading_hypotheses_first_equals_scalar_version() -> None:
    rng = np.random.default_rng(4)
    fft = FFTMatcher()
    q = fft.describe(star_polygon(rng))
    stored = [fft.describe(star_polygon(rng)) for _ in range(6)]
    angles, scores = headings_from_range_functions(
        q.range_function, np.stack([d.range_function for d in stored]), 3
    )
    for j, d in enumerate(stored):
        # heading(stored) - heading(query), negated: the query's heading in the stored frame.
        a, s = heading_from_range_functions(d.range_function, q.range_function)
        assert -angles[j, 0] == pytest.approx(a, abs=1e-9)
        assert scores[j, 0] == pytest.approx(s, abs=1e-9)
        assert np.all(np.diff(scores[j][np.isfinite(scores[j])]) <= 1e-12)


@settings(max_examples=25, deadline=None)
@given(st.floats(-3.1, 3.1), st.integers(0, 10_000))
def test_heading_recovers_rotation(angle: float, seed: int) -> None:
    p = star_polygon(np.random.default_rng(seed), n=200)
    db = PlaceDatabase(prefilter=("fft", "ring"), verifiers=(), fusion="prefilter", n_headings=2,
                       grid_headings=0)  # the range-function hypotheses alone
    db.add("a", p)
    m = db.query(p.rotated(angle))[0]
    err = (m.headings[0][0] + angle + np.pi) % (2 * np.pi) - np.pi
    # query = R(angle) stored, so the query's heading in the stored frame,
    # heading(query) - heading(stored), is -angle; 1.4-degree bins, sub-bin refined by
    # the parabola.
    assert abs(err) < np.radians(1.5)
    assert m.headings[0][1] > 0.95


def test_headings_match_true_poses_of_simulated_scans(places) -> None:
    polys, labels, poses = places
    db = PlaceDatabase(verifiers=(), fusion="prefilter", top_k=3)
    for i, (p, pose) in enumerate(zip(polys, poses, strict=True)):
        db.add(i, p, pose=pose)
    errors = []
    for j, p in enumerate(polys):
        for m in db.query(p, exclude_keys=[j]):
            if labels[m.key] == labels[j]:
                want = poses[j][2] - m.pose[2]  # the query's heading in the stored frame
                errors.append(abs((m.headings[0][0] - want + np.pi) % (2 * np.pi) - np.pi))
    assert len(errors) > 60
    assert np.degrees(np.median(errors)) < 3.0


# -- config and scales ----------------------------------------------------------------


def test_scales_are_positive_and_fixed_scales_are_used(polygons: list[Polygon]) -> None:
    db = quick_db()
    for i, p in enumerate(polygons[:10]):
        db.add(i, p)
    s = db.scales
    assert set(s) == {"fft", "ring", "integral"}
    assert all(np.isfinite(v) and v > 0 for v in s.values())
    fixed = quick_db(fixed_scales=(1.0, 2.0, 3.0))
    for i, p in enumerate(polygons[:10]):
        fixed.add(i, p)
    assert fixed.scales == {"fft": 1.0, "ring": 2.0, "integral": 3.0}


def test_bad_configs_are_user_errors() -> None:
    with pytest.raises(UserError, match="vector"):
        PlaceDatabaseConfig(prefilter=("mrm",))
    with pytest.raises(UserError, match="unknown verifier"):
        PlaceDatabaseConfig(verifiers=("nope",))
    with pytest.raises(UserError, match="refit"):
        PlaceDatabaseConfig(verifiers=("integral",), fusion="logistic")
    with pytest.raises(UserError, match="fusion"):
        PlaceDatabaseConfig(fusion="vote")
    with pytest.raises(UserError, match="top_k"):
        PlaceDatabaseConfig(top_k=0)
    with pytest.raises(UserError, match="nonsense"):
        PlaceDatabase(nonsense=1)


def test_empty_database_and_descriptor_queries(polygons: list[Polygon]) -> None:
    db = quick_db()
    assert db.query(polygons[0]) == []
    for i, p in enumerate(polygons[:8]):
        db.add(i, p)
    desc = db.describe(polygons[3])
    a = db.query(desc)
    b = db.query(polygons[3])
    assert [m.key for m in a] == [m.key for m in b]
    assert all(np.isfinite(list(m.distances.values())).all() for m in a)


def test_headings_without_an_fft_stage(polygons: list[Polygon]) -> None:
    db = PlaceDatabase(prefilter=("ring",), verifiers=(), fusion="prefilter", n_headings=2,
                       grid_headings=0)
    for i, p in enumerate(polygons[:5]):
        db.add(i, p)
    m = db.query(polygons[2].rotated(0.5))[0]
    assert m.key == 2 and "fft" not in m.distances
    assert abs((m.headings[0][0] + 0.5 + np.pi) % (2 * np.pi) - np.pi) < np.radians(1.5)
    no = PlaceDatabase(prefilter=("ring",), verifiers=(), fusion="prefilter", n_headings=0,
                       grid_headings=0)
    no.add(0, polygons[0])
    assert no.query(polygons[0])[0].headings == ()


def test_headings_on_demand_equal_the_query_s(polygons: list[Polygon]) -> None:
    """query(headings=False) leaves them empty; with_headings gives what query gives."""
    db = PlaceDatabase(top_k=5)
    for i, p in enumerate(polygons[:12]):
        db.add(i, p)
    q = polygons[4].rotated(1.0)
    full = db.query(q)
    bare = db.query(q, headings=False)
    assert [m.key for m in bare] == [m.key for m in full]
    assert all(m.headings == () for m in bare)
    assert any(m.headings for m in full)
    late = db.with_headings(q, bare[::-1])
    assert [m.headings for m in late] == [m.headings for m in full[::-1]]
    assert db.with_headings(q, []) == []


def test_stored_descriptors_query_like_the_polygon(polygons: list[Polygon]) -> None:
    db = PlaceDatabase(top_k=5)  # defaults: headings on, FLIRT + MRM verifiers
    for i, p in enumerate(polygons[:12]):
        db.add(i, p)
    stored = db.query(db.descriptors(7), exclude_keys=[7])
    fresh = db.query(polygons[7], exclude_keys=[7])
    assert stored == fresh  # every key, distance, score and heading bit for bit
    with pytest.raises(UserError, match="not in the place database"):
        db.descriptors(99)


@pytest.mark.parametrize("shortlist", [8, 50])
def test_a_stored_key_asked_again_queries_only_the_new_keys(
    polygons, monkeypatch, shortlist
) -> None:
    """`query_stored` over a growing allowed set (keys added between the calls) gives
    `query`'s answer over all allowed keys, and on a repeat screens only the new ones;
    with a grid shortlist shorter than the allowed set too (rows drop out of it)."""
    stages = PlaceDatabaseConfig().stages
    db = PlaceDatabase(top_k=5, fixed_scales=(1.0,) * len(stages),  # no re-estimates
                       grid_shortlist=shortlist)
    for i, p in enumerate(polygons[:30]):
        db.add(i, p)
    asked: list[int] = []
    real_shortlist = PlaceDatabase._shortlist

    def counting(self, q, mask, k, keep):
        asked.append(int(np.count_nonzero(mask)) if mask is not None else len(self))
        return real_shortlist(self, q, mask, k, keep)

    monkeypatch.setattr(PlaceDatabase, "_shortlist", counting)
    for n in (12, 13, 13, 20):  # the keys 0..n-1 are allowed; 30.. are added as it grows
        got = db.query_stored(25, allowed=np.arange(n))
        want = db.query(db.descriptors(25), allowed=np.arange(n), headings=False)
        asked.pop()  # the reference query's own screening
        assert len(want) == min(n, 5 + min(5, shortlist - 5))  # K and the grids' extras
        assert [m.key for m in got] == [m.key for m in want]
        assert [m.score for m in got] == pytest.approx([m.score for m in want], rel=1e-12)
        assert sorted(m.prefilter_rank for m in got) == list(range(len(want)))
        db.add(len(db), polygons[len(db)])
    # 12 keys first; then 1 new key, none, 7 new keys.
    assert asked == [12, 1, 7]
    # Another stored key, or an allowed set that lost keys, asks in full.
    db.query_stored(26, allowed=np.arange(20))
    db.query_stored(26, allowed=np.arange(1, 20))
    assert asked[-2:] == [20, 19]


def test_vote_fused_order_by_hand() -> None:
    from loopclosure.place_shortlist import vote_fused_order

    order = np.array([3, 1, 0, 2, 4])
    votes = np.array([0.0, 5.0, 2.0, 9.0, 2.0])
    # head 3, 1; then the voted others by score, ties by position: 2, 4; then 0
    assert vote_fused_order(order, votes, 2, 4).tolist() == [3, 1, 2, 4, 0]
    assert vote_fused_order(order, votes, 2, 3).tolist() == [3, 1, 2, 0, 4]
    assert vote_fused_order(order, votes, 5, 5).tolist() == order.tolist()
    assert vote_fused_order(order, np.zeros(5), 1, 4).tolist() == order.tolist()


def moved_polygon(polygon: Polygon, theta: float, t: tuple[float, float]) -> Polygon:
    c, s = np.cos(theta), np.sin(theta)
    return Polygon(np.asarray(polygon.vertices) @ np.array([[c, s], [-s, c]]) + np.asarray(t))


def test_the_vote_brings_a_moved_copy_into_the_candidates(polygons: list[Polygon]) -> None:
    query = polygons[0]
    stored = [*polygons[1:13], moved_polygon(query, 0.4, (0.6, -0.3)), *polygons[13:20]]
    off = quick_db()
    on = quick_db(vote="fuse", vote_split=0)
    for i, p in enumerate(stored):
        off.add(i, p)
        on.add(i, p)
    assert "vote" not in off.describe(query) and "vote" in on.describe(query)
    votes = on.vote_scores(query)
    assert int(np.argmax(votes)) == 12 and votes[12] > 2 * np.sort(votes)[-2]
    c_on = on.candidates(query)
    assert int(c_on.indices[0]) == 12  # vote_split 0: the vote's best comes first
    assert len(c_on.indices) == 5 and len(set(c_on.indices.tolist())) == 5
    # prefilter distances of the vote's rows are the exact ones of those rows
    p_all, _ = on.prefilter_distances(query)
    assert np.allclose(c_on.prefilter, p_all[c_on.indices])
    # all K from the prefilter: the candidates of the database without the vote
    all_pre = quick_db(vote="fuse", vote_split=5)
    for i, p in enumerate(stored):
        all_pre.add(i, p)
    c_off, c_all = off.candidates(query), all_pre.candidates(query)
    assert c_all.indices.tolist() == c_off.indices.tolist()
    assert np.array_equal(c_all.scores, c_off.scores)
    # a gated-out row never enters through the vote
    mask = np.ones(len(stored), bool)
    mask[12] = False
    assert 12 not in on.candidates(query, allowed=mask).indices.tolist()
    with pytest.raises(UserError):
        off.vote_scores(query)
    with pytest.raises(UserError):
        PlaceDatabaseConfig(vote="on")
