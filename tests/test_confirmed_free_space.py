"""The confirmed free space (`loopclosure.free_space` (5)): free about the keyframe (1)
and along a scan's own ray (1'), by hand and in the check."""

from __future__ import annotations

import numpy as np
import pytest

from data import se2
from data.errors import UserError
from loopclosure.free_space import (
    SCAN_FREE_SPACE,
    ConfirmedFreeSpace,
    RangeImage,
    ScanFreeSpace,
    Submap,
    SubmapPoints,
    consistency,
)
from loopclosure.geometric_check import GeometricCheckConfig, verify
from loopclosure.registration import RegistrationTarget
from tests.test_scan_free_space import _inner_walls_case


def test_a_point_is_free_only_where_the_keyframe_and_a_scan_both_saw_through_it() -> None:
    # The submap: a return at (5, 0) seen by a scan at the origin facing +x, and a
    # return at (2, 2) seen by a scan at (2, -2) facing +y.
    side = np.array([2.0, -2.0, np.pi / 2])
    points = np.array([[5.0, 0.0], [2.0, 2.0]])
    scans = ScanFreeSpace.of(
        [np.zeros(3), side],
        [points[:1], se2.transform_points(se2.inverse(side), points[1:])])
    image = RangeImage(points)
    both = ConfirmedFreeSpace(image, scans)
    pts = np.array([[3.0, 0.0],    # on the origin scan's ray, before (5, 0): both free
                    [1.0, 1.0],    # before (2, 2) seen from the origin: (1) free, but
                    #                no scan cast that ray
                    [2.0, -1.0],   # on the side scan's ray: (1') free; the origin's
                    #                sector towards it (-45 deg) observed nothing
                    [6.0, 0.0]])   # behind (5, 0): neither
    np.testing.assert_array_equal(image.free(pts, 0.3), [True, True, False, False])
    np.testing.assert_array_equal(scans.free(pts, 0.3), [True, False, True, False])
    np.testing.assert_array_equal(both.free(pts, 0.3), [True, False, False, False])
    assert both.free(np.zeros((0, 2)), 0.3).shape == (0,)


def test_the_submap_of_the_confirmed_model_counts_fewer_conflicts() -> None:
    # The query sees (1, 1), which lies in the candidate's free space about its origin
    # (before its return (2, 2)) but on no ray its scans cast.
    side = np.array([2.0, -2.0, np.pi / 2])
    c_pts = np.array([[5.0, 0.0], [2.0, 2.0]])
    c_scans = ScanFreeSpace.of(
        [np.zeros(3), side], [c_pts[:1], se2.transform_points(se2.inverse(side), c_pts[1:])])
    q_pts = np.array([[5.0, 0.0], [1.0, 1.0]])
    q_scans = ScanFreeSpace.of([np.zeros(3)], [q_pts])
    keyframe = consistency(Submap.of(q_pts), Submap.of(c_pts), np.zeros(3), 0.1, 0.3)
    confirmed = consistency(Submap.of(q_pts, scans=q_scans, confirm=True),
                            Submap.of(c_pts, scans=c_scans, confirm=True), np.zeros(3), 0.1, 0.3)
    # (1, 1) lies before the candidate's (2, 2) seen from its origin: a conflict
    # under (1); no scan of the candidate looked through it.  (2, 2) lies behind the
    # query's (1, 1): no conflict either way.
    assert (keyframe.hits, keyframe.conflicts) == (2, 1)
    assert (confirmed.hits, confirmed.conflicts) == (2, 0)
    assert isinstance(Submap.of(q_pts, scans=q_scans, confirm=True).image, ConfirmedFreeSpace)
    assert isinstance(Submap.of(q_pts, scans=q_scans).image, ScanFreeSpace)
    assert isinstance(Submap.of(q_pts, confirm=True).image, RangeImage)  # no scans: (1)


def test_the_check_confirms_only_with_the_option() -> None:
    cand, query, truth = _inner_walls_case()
    scans = GeometricCheckConfig(free_space_origins="scans")
    confirm = GeometricCheckConfig(free_space_origins="scans", free_space_confirm=True)
    keyframe = GeometricCheckConfig()
    # Scans that observed everything (a huge range in every sector): (1') calls all
    # free, so the confirmed model is (1) itself.
    seeing = RegistrationTarget(cand)
    wide = np.full((1, 720), 1e3)
    seeing.derived[SCAN_FREE_SPACE] = ScanFreeSpace(np.zeros((1, 3)), wide)
    q_seeing = SubmapPoints(query, ScanFreeSpace(np.zeros((1, 3)), wide))
    base = verify(query, RegistrationTarget(cand), headings=[truth[2]], config=keyframe)
    both = verify(q_seeing, seeing, headings=[truth[2]], config=confirm)
    assert both.consistency == pytest.approx(base.consistency)
    assert verify(q_seeing, seeing, headings=[truth[2]], config=scans).consistency < \
        base.consistency
    # Scans that observed nothing: no conflicts, whatever (1) says.
    blind = RegistrationTarget(cand)
    blind.derived[SCAN_FREE_SPACE] = ScanFreeSpace(np.zeros((1, 3)), np.zeros((1, 720)))
    q_blind = SubmapPoints(query, ScanFreeSpace(np.zeros((1, 3)), np.zeros((1, 720))))
    assert verify(q_blind, blind, headings=[truth[2]], config=confirm).consistency == 1.0


def test_either_model_at_its_own_bar_passes_the_free_space_test() -> None:
    cand, query, truth = _inner_walls_case()
    base = verify(query, RegistrationTarget(cand), headings=[truth[2]],
                  config=GeometricCheckConfig())
    assert base.reason.startswith("inconsistent free space")
    # Scans that observed nothing: (5) has no conflicts; at a bar above 1 it refuses.
    blind = RegistrationTarget(cand)
    blind.derived[SCAN_FREE_SPACE] = ScanFreeSpace(np.zeros((1, 3)), np.zeros((1, 720)))
    q_blind = SubmapPoints(query, ScanFreeSpace(np.zeros((1, 3)), np.zeros((1, 720))))

    def check(either: float) -> str:
        cfg = GeometricCheckConfig(free_space_origins="scans", free_space_confirm=True,
                                   min_consistency=1.01, free_space_either=either)
        return verify(q_blind, blind, headings=[truth[2]], config=cfg).reason

    assert check(0.0).startswith("inconsistent free space")  # off
    assert check(base.consistency + 0.01).startswith("inconsistent free space")
    assert not check(base.consistency - 0.01).startswith("inconsistent free space")


def test_an_either_bar_outside_zero_to_one_is_a_user_error() -> None:
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(UserError, match="free_space_either"):
            GeometricCheckConfig(free_space_either=bad)


def test_the_fallback_holds_back_a_fit_only_the_scans_model_passes() -> None:
    cand, query, truth = _inner_walls_case()
    base = verify(query, RegistrationTarget(cand), headings=[truth[2]],
                  config=GeometricCheckConfig())
    # Scans that observed nothing: (5) has no conflicts (consistency 1, above 0.95).
    blind = RegistrationTarget(cand)
    blind.derived[SCAN_FREE_SPACE] = ScanFreeSpace(np.zeros((1, 3)), np.zeros((1, 720)))
    q_blind = SubmapPoints(query, ScanFreeSpace(np.zeros((1, 3)), np.zeros((1, 720))))

    def check(either: float, fallback: bool):
        cfg = GeometricCheckConfig(free_space_origins="scans", free_space_confirm=True,
                                   min_consistency=0.95, free_space_either=either,
                                   free_space_fallback=fallback)
        return verify(q_blind, blind, headings=[truth[2]], config=cfg)

    above = base.consistency + 0.01  # (1) refuses the fit at this bar
    passed = check(above, False)
    assert passed.accepted and not passed.rescuable
    held = check(above, True)
    assert not held.accepted and held.rescuable
    assert held.reason.startswith("inconsistent free space (0.83 <")
    np.testing.assert_array_equal(held.relative, passed.relative)
    # Beyond the revisit radius: refused as (1) refuses it, rescuable from afar.
    far = verify(q_blind, blind, headings=[truth[2]],
                 max_distance=float(np.hypot(*held.relative[:2])) - 0.05,
                 config=GeometricCheckConfig(free_space_origins="scans",
                                             free_space_confirm=True, min_consistency=0.95,
                                             free_space_either=above,
                                             free_space_fallback=True))
    assert far.reason == held.reason.removesuffix("; rescuable")
    assert far.rescuable_far and not far.rescuable and not held.rescuable_far
    # (1) passes it at a lower bar: an acceptance, nothing to rescue.
    both = check(base.consistency - 0.01, True)
    assert both.accepted and not both.rescuable
    # A fit (5) refuses as well is neither accepted nor rescuable.
    refused = verify(query, RegistrationTarget(cand), headings=[truth[2]],
                     config=GeometricCheckConfig(free_space_either=above,
                                                 free_space_fallback=True))
    assert not refused.accepted and not refused.rescuable


def test_a_pair_without_scans_is_judged_by_the_keyframe_model_at_the_either_bar() -> None:
    cand, query, truth = _inner_walls_case()
    base = verify(query, RegistrationTarget(cand), headings=[truth[2]],
                  config=GeometricCheckConfig())
    # No scans' free space on either side: (1) alone, at the either bar (0.99 is the
    # scans' bar and would refuse the fit).
    cfg = GeometricCheckConfig(free_space_origins="scans", free_space_confirm=True,
                               min_consistency=0.99, free_space_either=base.consistency - 0.01)
    assert verify(query, RegistrationTarget(cand), headings=[truth[2]], config=cfg).accepted
    cfg = GeometricCheckConfig(free_space_origins="scans", free_space_confirm=True,
                               min_consistency=0.5, free_space_either=base.consistency + 0.01)
    assert not verify(query, RegistrationTarget(cand), headings=[truth[2]], config=cfg).accepted
