"""Tests of the keypoint-pair vote (`loopclosure.place_vote`), hand-checked cases."""

from __future__ import annotations

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
