"""The free-space margin across each scan's surface (`loopclosure.free_space` (1''), (3)):
the incidence factor by hand, the test it changes, the option that carries it."""

from __future__ import annotations

import numpy as np
import pytest

from data.errors import UserError
from loopclosure.free_space import ScanFreeSpace, surface_secant
from loopclosure.geometric_check import GeometricCheckConfig
from tests.test_scan_free_space import _store

BINS = 720
STEP = 2 * np.pi / BINS  # one sector [rad]


def _wall_y2() -> ScanFreeSpace:
    """One scan at the origin that saw the wall y = 2 m, a beam every 0.25 deg from
    10 to 170 deg bearing."""
    th = np.radians(np.arange(10.0, 170.0, 0.25) + 0.1)
    return ScanFreeSpace.of([np.zeros(3)], [np.c_[2.0 / np.tan(th), np.full_like(th, 2.0)]],
                            bins=BINS, spread=2)


def test_a_constant_range_is_seen_head_on_and_a_ramp_by_its_slope() -> None:
    ring = np.full((1, BINS), 5.0)
    np.testing.assert_array_equal(surface_secant(ring, 10.0), np.ones((1, BINS)))
    # r = 2 + 0.01 b [m]: slope 0.01 m a sector, 0.01 / STEP = 1.146 m/rad; at b = 100,
    # r = 3 m, so 1 / cos(alpha) = sqrt(1 + (1.146 / 3)^2) = sqrt(1.1459) = 1.0705.
    ramp = 2.0 + 0.01 * np.arange(BINS, dtype=float)[None]
    sec = surface_secant(ramp, 10.0)
    assert sec[0, 100] == pytest.approx(np.sqrt(1 + (0.01 / STEP / 3.0) ** 2), rel=1e-6)
    assert sec[0, 100] == pytest.approx(1.0705, abs=1e-3)
    assert surface_secant(ramp, 1.05)[0, 100] == pytest.approx(1.05)  # the cap


def test_a_depth_jump_or_an_unseen_neighbour_is_no_slope() -> None:
    r = np.full((1, BINS), 2.0)
    r[0, 360:] = 6.0  # a door edge: 2 m before sector 360, 6 m from it on
    r[0, 500:504] = 0.0  # nothing seen there
    sec = surface_secant(r, 10.0)
    # Sector 360 (6 m) sees 2 m four sectors before it, 6 m after: the continuous side.
    assert sec[0, 358] == 1.0 and sec[0, 360] == 1.0 and sec[0, 362] == 1.0
    assert sec[0, 502] == 1.0  # itself unseen
    lone = np.zeros((1, BINS))
    lone[0, 10] = 3.0  # a lone return: neither neighbour seen
    assert surface_secant(lone, 10.0)[0, 10] == 1.0


def test_the_wall_seen_obliquely_reads_its_incidence() -> None:
    free = _wall_y2()
    sec = ScanFreeSpace(free.poses, free.ranges, surface_cap=10.0).secant
    at = lambda deg: int((np.radians(deg) + np.pi) / STEP)  # noqa: E731
    # A ray at bearing phi meets y = 2 at incidence 90 - phi from its normal:
    # 1 / cos = 1 / sin(phi): 1 at 90 deg, 2 at 30 deg, 1.41 at 45 deg.  A sector's
    # range is the nearest return within `spread` sectors, up to 1 deg nearer the foot
    # of the wall: (3) reads that bearing's incidence, up to 10% lower at 30 deg.
    assert sec[0, at(90)] == pytest.approx(1.0, abs=0.01)
    assert sec[0, at(45)] == pytest.approx(np.sqrt(2), rel=0.05)
    assert sec[0, at(30)] == pytest.approx(2.0, rel=0.1)
    assert sec[0, at(30)] > sec[0, at(45)] > sec[0, at(60)] > sec[0, at(90)]


def test_a_point_near_the_wall_across_an_oblique_ray_is_not_free() -> None:
    free = _wall_y2()
    surface = ScanFreeSpace(free.poses, free.ranges, surface_cap=4.0)
    phi = np.radians(30.25)  # the wall 4 m along this ray (2 / sin 30 deg)
    ray = np.array([np.cos(phi), np.sin(phi)])
    wall = 2.0 / np.sin(phi)
    pts = np.array([
        (wall - 0.5) * ray,   # 0.5 m before it along the ray, 0.25 m across it
        (wall - 1.0) * ray,   # 1 m along, 0.5 m across
        [0.0, 1.6],           # head on, 0.4 m before it
        [0.0, 1.8],           # head on, 0.2 m before it
    ])
    # Along the ray (1'): the first is free; across the surface (1''): not.
    np.testing.assert_array_equal(free.free(pts, 0.3), [True, True, True, False])
    np.testing.assert_array_equal(surface.free(pts, 0.3), [False, True, True, False])
    # 0.6 m along the ray, 0.3 m across: the sector's range is the nearest return
    # within 1 deg, 3.88 m, so the margin across it (1.83 x 0.3 = 0.55 along) leaves
    # it, a cap of 1.2 (0.36 along) puts it in free space, like the ray's 0.3.
    near = (wall - 0.6) * ray
    assert surface.free(near[None], 0.3).tolist() == [False]
    capped = ScanFreeSpace(free.poses, free.ranges, surface_cap=1.2)
    assert capped.free(near[None], 0.3).tolist() == [True]
    assert free.free(near[None], 0.3).tolist() == [True]


def test_a_cap_of_one_is_the_ray_margin_and_below_one_an_error() -> None:
    free = _wall_y2()
    probe = np.random.default_rng(1).uniform(-5, 5, (400, 2))
    one = ScanFreeSpace(free.poses, free.ranges, surface_cap=1.0)
    np.testing.assert_array_equal(one.free(probe, 0.3), free.free(probe, 0.3))
    with pytest.raises(ValueError, match="surface_cap"):
        ScanFreeSpace(free.poses, free.ranges, surface_cap=0.5)
    with pytest.raises(UserError, match="free_space_surface_cap"):
        GeometricCheckConfig(free_space_surface_cap=0.9)


def test_the_store_hands_its_cap_to_every_submaps_free_space() -> None:
    det, _ = _store()
    assert det.submap_free_space(2).surface_cap == 1.0
    det.config.check.free_space_surface_cap = 3.0
    assert det.submap_free_space(2).surface_cap == 3.0
    assert det.submap_free_space(1, last=1).surface_cap == 3.0


# -- beside the scan's own returns (4) ----------------------------------------------------


def _wall_end() -> ScanFreeSpace:
    """One scan at the origin, a beam every 0.5 deg: the wall x = 4 m up to its end at
    (4, 2) (bearings 0 to 26.5 deg), then a far wall 10 m away (27 to 60 deg)."""
    near = np.radians(np.arange(0.0, 26.6, 0.5))
    far = np.radians(np.arange(27.0, 60.1, 0.5))
    pts = np.r_[np.c_[np.full_like(near, 4.0), 4.0 * np.tan(near)],
                10.0 * np.c_[np.cos(far), np.sin(far)]]
    return ScanFreeSpace.of([np.zeros(3)], [pts])


def test_a_point_beside_the_wall_end_the_ray_passed_is_not_free() -> None:
    plain = _wall_end()
    pts = np.array([[3.9, 2.15],   # 0.19 m past the wall end (4, 1.99), on a 10 m ray
                    [3.0, 2.5],    # 1.1 m from it, on a 10 m ray
                    [2.0, 0.5]])   # 2 m in front of the wall, head on
    np.testing.assert_array_equal(plain.free(pts, 0.3), [True, True, True])
    # Within 4 deg (8 sectors) the scan's own return at the wall end lies 0.15-0.19 m
    # from the first point: not free; the second is 1.1 m from every return near it.
    beside = ScanFreeSpace(plain.poses, plain.ranges, return_window=8)
    np.testing.assert_array_equal(beside.free(pts, 0.3), [False, True, True])
    # One sector either side (28.4-29.4 deg) holds only the far wall's returns.
    narrow = ScanFreeSpace(plain.poses, plain.ranges, return_window=1)
    np.testing.assert_array_equal(narrow.free(pts, 0.3), [True, True, True])
    with pytest.raises(ValueError, match="return_window"):
        ScanFreeSpace(plain.poses, plain.ranges, return_window=-1)
    with pytest.raises(UserError, match="free_space_return_window"):
        GeometricCheckConfig(free_space_return_window=-2)


def test_only_the_returns_of_the_scan_that_saw_through_count() -> None:
    # Scan a (origin) saw only a far wall 10 m away (27 to 60 deg); scan b at (8, 2.15)
    # facing -x saw a return 4 m ahead, at (4, 2.15): 0.1 m from p = (3.9, 2.15), which
    # lies behind that return along b's ray (not b's free space) and 4.5 m along a's.
    far = np.radians(np.arange(27.0, 60.1, 0.5))
    b_pose = np.array([8.0, 2.15, np.pi])
    free = ScanFreeSpace.of([np.zeros(3), b_pose],
                            [10.0 * np.c_[np.cos(far), np.sin(far)], [[4.0, 0.0]]])
    beside = ScanFreeSpace(free.poses, free.ranges, return_window=8)
    p = np.array([[3.9, 2.15]])
    # b's return beside p does not excuse a's ray through it (the all-direction rule
    # about the whole submap would).
    assert free.free(p, 0.3).tolist() == [True]
    assert beside.free(p, 0.3).tolist() == [True]


def test_the_store_hands_its_window_to_every_submaps_free_space() -> None:
    det, _ = _store()
    assert det.submap_free_space(2).return_window == 0
    det.config.check.free_space_return_window = 8
    assert det.submap_free_space(2).return_window == 8
