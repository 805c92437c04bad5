"""The prior-free check's figures of its weakest direction: surface facing it, slide profile."""

from __future__ import annotations

import numpy as np
import pytest

from loopclosure.free_space import Submap, consistency
from loopclosure.geometric_check import axis_length, pinned_length
from loopclosure.prior_free import axis_profile


def test_axis_length_is_the_weighted_count_of_points_facing_the_weak_axis() -> None:
    # Rows J = [n_x, n_y, 0] (no rotation coupling): 40 points facing y (a corridor's
    # walls) and 6 facing x (a door jamb), unit weights -> lambda_min = 6 along x.
    h = np.zeros((3, 3))
    h[0, 0], h[1, 1], h[2, 2] = 6.0, 40.0, 1.0
    assert axis_length(h, 0.1) == pytest.approx(0.6)
    # A rotation coupled to x is marginalised: h_xx - h_xt^2 / h_tt = 6 - 2^2 / 2 = 4.
    h[0, 2] = h[2, 0] = 2.0
    h[2, 2] = 2.0
    assert axis_length(h, 0.1) == pytest.approx(0.4)


def _corridor(end_wall: bool) -> np.ndarray:
    x = np.arange(-6.0, 6.0, 0.1)
    pts = [np.c_[x, np.full_like(x, 1.0)], np.c_[x, np.full_like(x, -1.0)]]
    if end_wall:
        y = np.arange(-0.9, 0.95, 0.1)  # clear of the side walls
        pts.append(np.c_[np.full_like(y, 3.0), y])
    return np.vstack(pts)


def test_axis_profile_holds_in_a_plain_corridor_and_drops_at_an_end_wall() -> None:
    plain = Submap.of(_corridor(False))
    # Slid 0.5 m along x: the walls of a 12 m corridor still match but for their 0.5 m
    # ends: 115 of 120 points per wall, both directions.
    held = axis_profile(plain, plain, [0, 0, 0], [1.0, 0.0], 0.5, 0.04, 0.3)
    np.testing.assert_array_equal(held, [460, 460])
    assert consistency(plain, plain, [0, 0, 0], 0.04, 0.3).hits == 480
    # 20 hits lost of 0.1 m points, halved: 1 m (two walls' 0.5 m ends).
    assert pinned_length(480, held, 0.1) == pytest.approx(1.0)
    ended = Submap.of(_corridor(True))
    # The end wall (19 points each way) matches nowhere once slid: 518 -> 460 hits,
    # 2.9 m pinned (1 m of wall ends and the 1.9 m end wall).
    dropped = axis_profile(ended, ended, [0, 0, 0], [1.0, 0.0], 0.5, 0.04, 0.3)
    np.testing.assert_array_equal(dropped, [460, 460])
    assert pinned_length(518, dropped, 0.1) == pytest.approx(2.9)
    assert np.isnan(pinned_length(518, [], 0.1))


def _dead_end(closed: bool) -> np.ndarray:
    """A corridor 2 m wide from x = -6 to 3 m, closed at x = 3 when `closed`."""
    x = np.arange(-6.0, 3.0, 0.1)
    pts = [np.c_[x, np.full_like(x, 1.0)], np.c_[x, np.full_like(x, -1.0)]]
    if closed:
        y = np.arange(-0.9, 0.95, 0.1)
        pts.append(np.c_[np.full_like(y, 3.0), y])
    return np.vstack(pts)


def test_pinned_degenerate_accepts_a_corridor_held_by_its_end_wall() -> None:
    from loopclosure.geometric_check import GeometricCheckConfig, verify
    from loopclosure.prior_free import PriorFreeConfig
    from loopclosure.registration import RegistrationTarget

    # The candidate sees the dead end whole, the query its last 3 m from a sensor 0.3 m
    # further on: the end wall's 19 points are the only information along x.  A
    # degeneracy bar of 0.3 rejects the fit; slid 0.5 m the end wall un-matches
    # (19 points each way: 1.9 m pinned, less what the walls' ends gain or lose).
    search = PriorFreeConfig(opposite_headings=False)  # no corridor turned round
    off = GeometricCheckConfig(min_degeneracy=0.3, min_matched_length=1.5, search=search)
    on = GeometricCheckConfig(min_degeneracy=0.3, min_matched_length=1.5, search=search,
                              pinned_degenerate=True)
    full = _dead_end(True)
    query = full[full[:, 0] > 0.0] - [0.3, 0.0]
    plain = verify(query, RegistrationTarget(full), headings=[0.0], max_distance=2.0,
                   config=off)
    assert plain.reason.startswith("degenerate"), plain.reason
    assert 1.5 <= plain.pinned_length <= 2.4
    held = verify(query, RegistrationTarget(full), headings=[0.0], max_distance=2.0,
                  config=on)
    assert held.accepted, held.reason
    np.testing.assert_allclose(held.relative, [0.3, 0.0, 0.0], atol=0.03)
    # Without the end wall nothing pins it: the slide loses only the walls' ends.
    bare = _dead_end(False)
    lost = verify(bare[bare[:, 0] > 0.0] - [0.3, 0.0], RegistrationTarget(bare),
                  headings=[0.0], max_distance=2.0, config=on)
    assert not lost.accepted and lost.pinned_length < 1.5


def _door_jambs(jamb: float) -> np.ndarray:
    """A corridor 2 m wide along x, narrowed at x = 1.5 by two jambs `jamb` [m] long."""
    x = np.arange(-6.0, 6.0, 0.1)
    y = np.arange(1.0 - jamb + 0.05, 1.0, 0.1)
    return np.vstack([np.c_[x, np.full_like(x, 1.0)], np.c_[x, np.full_like(x, -1.0)],
                      np.c_[np.full_like(y, 1.5), y], np.c_[np.full_like(y, 1.5), -y]])


def test_pinned_required_rejects_a_full_overlap_pinned_by_too_little() -> None:
    from loopclosure.geometric_check import GeometricCheckConfig, verify
    from loopclosure.prior_free import PriorFreeConfig
    from loopclosure.registration import RegistrationTarget

    search = PriorFreeConfig(opposite_headings=False)
    required = GeometricCheckConfig(search=search, pinned_required=True)
    # 0.5 m jambs seen by a query 4 m long: a full overlap (fitness 0.9) with degeneracy
    # 0.08, between the two bars, whose slide un-matches only the jambs' 10 points each
    # way less what the walls' ends give back: under 1 m pinned.
    corridor = _door_jambs(0.5)
    query = corridor[np.abs(corridor[:, 0] - 0.3) < 2.0] - [0.3, 0.0]
    v = verify(query, RegistrationTarget(corridor), headings=[0.0], max_distance=2.0,
               config=required)
    assert 0.04 <= v.degeneracy < 0.1 and v.fitness > 0.55
    assert v.pinned_length < 2.0
    assert v.reason.startswith("degenerate and not pinned"), v.reason
    # Jambs of 0.9 m on a 3 m query: degeneracy above 0.1, the rule is not asked.
    wide = _door_jambs(0.9)
    short = wide[np.abs(wide[:, 0] - 0.3) < 1.5] - [0.3, 0.0]
    w = verify(short, RegistrationTarget(wide), headings=[0.0], max_distance=2.0,
               config=required)
    assert w.degeneracy >= 0.1 and w.accepted, w.reason


def test_slide_anisotropy_is_the_axis_slide_over_the_cross_slide() -> None:
    from loopclosure.geometric_check import slide_anisotropy

    ended = Submap.of(_corridor(True))
    along = axis_profile(ended, ended, [0, 0, 0], [1.0, 0.0], 0.5, 0.04, 0.3)
    across = axis_profile(ended, ended, [0, 0, 0], [0.0, 1.0], 0.5, 0.04, 0.3)
    # Slid 0.5 m up: of the end wall's 19 points (y = -0.9..0.9) 14 still land on it
    # and one (y = 0.5 -> 1.0) on the upper side wall; of the side walls only the
    # lower one's point at x = 3 (y = -1 -> -0.5) lands on the end wall: 16 hits,
    # both directions 32 (the same slid down).
    np.testing.assert_array_equal(across, [32, 32])
    assert slide_anisotropy(along, across) == pytest.approx(460 / 32)
    assert slide_anisotropy([3, 5], [0, 10]) == pytest.approx(0.5)
    assert slide_anisotropy([3, 5], [0, 0]) == np.inf
    assert np.isnan(slide_anisotropy([0, 0], [0, 0]))
    assert np.isnan(slide_anisotropy([], [1, 2]))



def test_held_by_pin_asks_the_cross_slide_only_with_pinned_cross() -> None:
    from loopclosure.geometric_check import GeometricCheckConfig, held_by_pin

    on = GeometricCheckConfig(pinned_degenerate=True)
    blind = GeometricCheckConfig(pinned_degenerate=True, pinned_cross=False)
    # A corridor held by its end wall: 460 hits kept along it, 32 across.
    assert held_by_pin(2.9, [460, 460], [32, 32], on)
    # Scattered points lost whichever way: 30 / 46 kept along, 60 / 67 across (the
    # pin of 9 m says nothing of the weak axis).
    assert not held_by_pin(9.0, [30, 46], [60, 67], on)
    assert held_by_pin(9.0, [30, 46], [60, 67], blind)
    # Under the floor of matched surface, or with the rule off: never.
    assert not held_by_pin(1.9, [460, 460], [32, 32], on)
    assert not held_by_pin(9.0, [460, 460], [32, 32], GeometricCheckConfig())
    assert not held_by_pin(float("nan"), [], [], on)
