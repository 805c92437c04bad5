"""Tests of the keypoint-pair vote (`loopclosure.place_vote`), hand-checked cases."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from data.errors import UserError
from loopclosure.place_vote import PairVoteConfig, PairVoteIndex, pair_keys

# Four keypoints whose six pair lengths differ by more than a length bin (0.25 m)
# from each other: 2.0, 3.0, 4.6, 3.61, 5.0, 2.83 [m] (only one stored pair per key).
PLACE = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 3.0], [-2.0, -2.0]])
NORMALS = np.array([0.4, 1.9, 3.3, 5.0])


def moved(points, normals, theta, t):
    """The place seen from a frame rotated by -theta: p -> R(theta) p + t."""
    c, s = np.cos(theta), np.sin(theta)
    return points @ np.array([[c, s], [-s, c]]) + np.asarray(t), normals + theta


def test_pair_key_of_two_points_by_hand():
    cfg = PairVoteConfig(n_labels=1)
    pts = np.array([[0.0, 0.0], [2.0, 0.0]])
    o = np.array([np.pi / 2 + 0.1, np.pi / 2 + 0.1])
    keys, a, phi = pair_keys(pts, o, cfg, both_directions=False)
    # length 2 m -> bin 8; phi = 0; both normals at 1.67 rad -> angle bin 3 (30 deg bins)
    assert keys.tolist() == [(8 * 12 + 3) * 12 + 3]
    assert a.tolist() == [0] and phi.tolist() == [0.0]
    keys, a, phi = pair_keys(pts, o, cfg, both_directions=True)
    # the reverse pair: phi = pi, normals at 1.67 - pi + 2 pi = 4.81 rad -> bin 9
    assert sorted(keys.tolist()) == sorted([(8 * 12 + 3) * 12 + 3, (8 * 12 + 9) * 12 + 9])


def test_pair_keys_drop_short_and_long_pairs_and_keep_labels():
    cfg = PairVoteConfig(min_length=0.5, max_length=10.0, n_labels=2)
    pts = np.array([[0.0, 0.0], [0.3, 0.0], [20.0, 0.0]])
    keys, _, _ = pair_keys(pts, np.zeros(3), cfg, both_directions=False)
    assert len(keys) == 0  # 0.3 m, 20 m and 19.7 m are all out of range
    two = np.array([[0.0, 0.0], [2.0, 0.0]])
    k0, _, _ = pair_keys(two, np.full(2, 1.67), cfg, False, labels=np.array([0, 0]))
    k1, _, _ = pair_keys(two, np.full(2, 1.67), cfg, False, labels=np.array([1, 0]))
    assert k1[0] - k0[0] == 2  # label of the first point times n_labels


def test_neighbours_limit_the_pairs():
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [9.0, 0.0]])
    all_pairs, _, _ = pair_keys(pts, np.zeros(4), PairVoteConfig(), both_directions=False)
    near, _, _ = pair_keys(pts, np.zeros(4), PairVoteConfig(neighbours=1), both_directions=False)
    assert len(all_pairs) == 6
    # nearest neighbours: 0-1, 1-0 (or 1-2), 2-1, 3-2 -> pairs {0,1}, {1,2}, {2,3}
    assert len(near) == 3


def test_the_same_place_moved_collects_every_pair_in_one_cell():
    cfg = PairVoteConfig(normalise=False, n_labels=1)
    index = PairVoteIndex(cfg)
    index.add(*moved(PLACE, NORMALS, 0.3, (1.1, 0.4)))  # same place, 1.2 m away
    index.add(*moved(PLACE, NORMALS, 0.3, (5.0, 0.0)))  # same shape, 5 m away
    index.add(np.array([[0.0, 0.0], [7.0, 0.0], [0.0, 7.0]]), np.zeros(3))
    score = index.scores(PLACE, NORMALS)
    # six query pairs, each matching its one stored pair with the same transform
    assert score.tolist() == [6.0, 0.0, 0.0]
    index_n = PairVoteIndex(PairVoteConfig(n_labels=1))
    index_n.add(*moved(PLACE, NORMALS, 0.3, (1.1, 0.4)))
    assert index_n.scores(PLACE, NORMALS)[0] == pytest.approx(6.0 / np.sqrt(12.0))


def test_a_partial_view_still_votes_for_its_place():
    index = PairVoteIndex(PairVoteConfig(normalise=False, n_labels=1))
    index.add(*moved(PLACE, NORMALS, -0.5, (0.3, -1.0)))
    # the query sees three of the four keypoints: its three pairs all vote
    assert index.scores(PLACE[:3], NORMALS[:3]).tolist() == [3.0]


def test_labels_must_agree():
    index = PairVoteIndex(PairVoteConfig(normalise=False, n_labels=2))
    index.add(PLACE, NORMALS, np.array([0, 0, 1, 1]))
    assert index.scores(PLACE, NORMALS, np.array([0, 0, 1, 1]))[0] == 6.0
    index.add(PLACE, NORMALS, np.zeros(4, int))
    # every query point of class 1 against a place of class 0 only: no key can match
    assert index.scores(PLACE, NORMALS, np.ones(4, int))[1] == 0.0


def test_empty_index_and_single_keypoint_give_zero():
    index = PairVoteIndex()
    assert index.scores(PLACE, NORMALS).shape == (0,)
    index.add(PLACE, NORMALS)
    assert index.scores(PLACE[:1], NORMALS[:1]).tolist() == [0.0]
    index.add(np.zeros((0, 2)), np.zeros(0))
    assert index.scores(PLACE, NORMALS)[1] == 0.0


def test_bad_config_is_refused():
    with pytest.raises(UserError):
        PairVoteConfig(length_step=0.0)
    with pytest.raises(UserError):
        PairVoteConfig(min_length=5.0, max_length=2.0)
    with pytest.raises(UserError):
        PairVoteConfig(neighbours=-1)


def test_length_slack_finds_a_pair_across_a_bin_edge():
    # stored pair 2.24 m long (bin 8), query pair 2.26 m (bin 9): found with the
    # neighbouring bins only
    o = np.array([1.0, 2.0])
    stored = (np.array([[0.0, 0.0], [2.24, 0.0]]), o)
    query = (np.array([[0.0, 0.0], [2.26, 0.0]]), o)
    for slack, expected in ((0, 0.0), (1, 1.0)):
        index = PairVoteIndex(PairVoteConfig(normalise=False, n_labels=1, length_slack=slack))
        index.add(*stored)
        assert index.scores(*query).tolist() == [expected]


def brute_force_scores(places, query, cfg):
    """Every query pair against every stored directed pair, cells counted in a dict
    (the module docstring's vote, written out pair by pair)."""
    qk, qa, qphi = pair_keys(query[0], query[1], cfg, False, query[2])
    na2 = cfg.n_angle ** 2 * cfg.n_labels ** 2
    out = []
    for place in places:
        sk, sa, sphi = pair_keys(place[0], place[1], cfg, True, place[2])
        cells = {}
        for i in range(len(qk)):
            for j in range(len(sk)):
                if abs(int(qk[i]) - int(sk[j])) % na2 or abs(int(qk[i]) - int(sk[j])) > \
                        cfg.length_slack * na2:
                    continue
                theta = np.mod(qphi[i] - sphi[j], 2 * np.pi)
                c, s = np.cos(theta), np.sin(theta)
                p = place[0][sa[j]]
                t = query[0][qa[i]] - np.array([c * p[0] - s * p[1], s * p[0] + c * p[1]])
                if np.hypot(*t) > cfg.max_translation:
                    continue
                half = cfg.n_translation // 2
                cell = (int(theta // cfg.theta_step) % cfg.n_theta,
                        min(max(int(np.floor(t[0] / cfg.translation_step)) + half, 0),
                            cfg.n_translation - 1),
                        min(max(int(np.floor(t[1] / cfg.translation_step)) + half, 0),
                            cfg.n_translation - 1))
                cells[cell] = cells.get(cell, 0) + 1
        out.append(max(cells.values(), default=0))
    return np.array(out, float)


def random_places(n, seed=0):
    """`n` noisy partial views of one random set of 14 keypoints (labels 0..1)."""
    rng = np.random.default_rng(seed)
    base = rng.uniform(-5, 5, (14, 2))
    normals = rng.uniform(0, 2 * np.pi, 14)
    labels = rng.integers(0, 2, 14)
    out = []
    for _ in range(n):
        keep = rng.random(14) < 0.8
        p, o = moved(base[keep], normals[keep], rng.uniform(-np.pi, np.pi),
                     rng.normal(0, 1.0, 2))
        out.append((p + rng.normal(0, 0.04, p.shape), o + rng.normal(0, 0.05, len(o)),
                    labels[keep]))
    return out


def test_incremental_index_votes_as_the_brute_force_while_it_grows():
    cfg = PairVoteConfig(normalise=False, n_labels=2)
    places = random_places(9, seed=1)
    query = random_places(1, seed=2)[0]
    index = PairVoteIndex(cfg)
    for n, place in enumerate(places, 1):
        index.add(*place)
        # a query between insertions sees every place stored so far
        assert index.scores(*query).tolist() == brute_force_scores(places[:n], query,
                                                                   cfg).tolist()
    # blocks of 8 and 1 places (a binary counter over the 9 insertions)
    assert [b[0] for b in index._blocks] == [8, 1]
    assert index.postings == sum(len(pair_keys(p[0], p[1], cfg, True, p[2])[0]) for p in places)


def test_key_start_table_of_a_large_block_finds_the_same_postings():
    from loopclosure.place_vote import TABLE_PLACES

    cfg = PairVoteConfig(normalise=False, n_labels=2)
    places = random_places(TABLE_PLACES, seed=3)
    query = random_places(1, seed=4)[0]
    index = PairVoteIndex(cfg)
    for place in places:
        index.add(*place)
    assert index._blocks[0][0] == TABLE_PLACES and index._blocks[0][6] is not None
    assert index.scores(*query).tolist() == brute_force_scores(places, query, cfg).tolist()


def test_stop_list_skips_a_key_most_places_hold():
    # a 2-point place stored 3 times and a 4-point place once: the 2-point pair's key
    # has 3 postings (per direction) of 4 places
    two = (np.array([[0.0, 0.0], [2.0, 0.0]]), np.array([1.0, 2.0]))
    cfg = PairVoteConfig(normalise=False, n_labels=1)
    for share, expected in ((0.0, [1.0, 1.0, 1.0, 0.0]), (0.5, [0.0, 0.0, 0.0, 0.0])):
        index = PairVoteIndex(replace(cfg, stop_share=share))
        for _ in range(3):
            index.add(*two)
        index.add(PLACE, NORMALS)
        assert index.scores(*two).tolist() == expected
    # the 4-point place's keys have 1 posting each: kept at share 0.5
    index = PairVoteIndex(replace(cfg, stop_share=0.5))
    for _ in range(3):
        index.add(*two)
    index.add(PLACE, NORMALS)
    assert index.scores(PLACE, NORMALS).tolist() == [0.0, 0.0, 0.0, 6.0]
    with pytest.raises(UserError):
        PairVoteConfig(stop_share=-0.1)


def test_vote_keypoints_of_a_room_are_near_the_sensor_and_labelled():
    from loopclosure.place_vote import vote_keypoints
    from loopclosure.polygon import Polygon

    # an L-shaped room, 12 m x 8 m, sensor at the origin
    room = np.array([[-2.0, -2.0], [10.0, -2.0], [10.0, 2.0], [3.0, 2.0], [3.0, 6.0],
                     [-2.0, 6.0]])
    p, o, lab = vote_keypoints(Polygon(room), step=0.2, max_range=15.0)
    assert len(p) >= 4 and len(p) == len(o) == len(lab)
    assert set(lab.tolist()) <= set(range(6))
    near, _, _ = vote_keypoints(Polygon(room), step=0.2, max_range=5.0)
    assert len(near) < len(p) and np.hypot(*near.T).max() <= 5.0
