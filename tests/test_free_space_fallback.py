"""The loop detector's rescue of fits only the scans' free space passes
(`GeometricCheckConfig.free_space_fallback`): accepted only for a query none of whose
places passes the keyframe model, never in place of one."""

from __future__ import annotations

import dataclasses

import numpy as np

from loopclosure.candidate_checks import RESCUED
from loopclosure.loop_candidate import LoopCandidate
from tests.test_circle_fallback import _apart, _calls, _match, _three, _verdict


def _rescuable():
    return dataclasses.replace(_verdict(False, "inconsistent free space (0.90 < 0.92); "
                                               "rescuable"), rescuable=True)


def test_a_rescuable_fit_is_accepted_only_when_no_place_passes(monkeypatch) -> None:
    fail = _verdict(False, "registration failed")
    ok = _verdict(True, "accepted")
    # Place 0 only the scans' model passes, place 1 the keyframe model: place 1 alone.
    _calls(monkeypatch, {(0, False): _rescuable(), (1, False): ok, (2, False): fail})
    out = _three(0).verify_places(3, [_match(k, 0.0) for k in range(3)], _apart())
    assert [c.accepted for c in out] == [False, True, False]
    assert out[0].reason.endswith("rescuable")
    # No place passes the keyframe model: the rescuable one is accepted.
    _calls(monkeypatch, {(0, False): fail, (1, False): _rescuable(), (2, False): fail})
    out = _three(0).verify_places(3, [_match(k, 0.0) for k in range(3)], _apart())
    assert [c.accepted for c in out] == [False, True, False]
    assert out[1].reason == out[1].verification.reason == RESCUED
    assert out[1].verification.accepted


def test_rescues_stop_at_the_budget_and_follow_the_check_order(monkeypatch) -> None:
    calls = _calls(monkeypatch, {(k, False): _rescuable() for k in range(3)})
    out = _three(0).verify_places(3, [_match(k, 0.0) for k in range(3)], _apart())
    # Every place checked (none accepted on the way), the first max_loops = 2 rescued;
    # they put the query 10 m apart, so the agreement test then refuses both.
    assert calls == [(0, False), (1, False), (2, False)]
    assert [c.reason.split(" (")[0] for c in out] == [
        "ambiguous places", "ambiguous places", "inconsistent free space"]


def test_the_whole_circle_comes_first_and_its_rescuable_fit_counts(monkeypatch) -> None:
    fail = _verdict(False, "inconsistent free space (0.50 < 0.92)")
    ok = _verdict(True, "accepted")
    # The circle's re-check of place 0 passes the keyframe model: it wins over the
    # rescuable place 1.
    _calls(monkeypatch, {(0, False): fail, (1, False): _rescuable(), (0, True): ok,
                         (1, True): fail})
    out = _three(2).verify_places(3, [_match(k, 0.0) for k in range(2)], _apart())
    assert [c.accepted for c in out] == [True, False]
    # The circle's re-check is only rescuable: it replaces the refusal, and is rescued.
    _calls(monkeypatch, {(0, False): fail, (1, False): fail, (0, True): _rescuable(),
                         (1, True): fail})
    out = _three(2).verify_places(3, [_match(k, 0.0) for k in range(2)], _apart())
    assert [c.accepted for c in out] == [True, False]


def test_rescues_skip_non_rescuable_checks_and_stop_at_the_budget() -> None:
    det = _three(0)
    c = LoopCandidate.checked(3, 1, "appearance", _rescuable())
    d = LoopCandidate.checked(3, 2, "appearance", _rescuable())
    other = LoopCandidate.checked(3, 0, "appearance", _verdict(False, "registration failed"))
    assert [x.accepted for x in det._rescued(3, [other, c], 1, _apart())] == [False, True]
    assert [x.accepted for x in det._rescued(3, [c, d], 0, _apart())] == [False, False]
    assert [x.accepted for x in det._rescued(3, [c, other, d], 1, _apart())] == [True, False,
                                                                                  False]
    # Two rescues at one place (keyframes 1 and 2 within place_separation): one.
    near = _apart()
    near[2] = near[1] + [0.2, 0.0, 0.0]
    assert [x.accepted for x in det._rescued(3, [c, d], 2, near)] == [True, False]
    assert not c.accepted  # the input is not changed


def _far(relative) -> object:
    v = _verdict(False, "not a revisit (10.0 m apart)")
    return dataclasses.replace(v, relative=np.asarray(relative, float))


def test_a_nearer_place_only_the_scans_model_passes_is_kept_aside(monkeypatch) -> None:
    fail = _verdict(False, "registration failed")
    # Place 0's fit puts the query 10 m away, at keyframe 1: its check there is
    # rescuable.  The query's verdict at 0 stays the default's; the rescue takes 1.
    _calls(monkeypatch, {(0, False): _far([10.0, 0.0, 0.0]), (1, False): _rescuable(),
                         (2, False): fail})
    out = _three(0).verify_places(3, [_match(0, 0.0), _match(2, 0.0)], _apart())
    assert [(c.match, c.accepted, c.reason) for c in out] == [(1, True, RESCUED),
                                                             (2, False, fail.reason)]
    assert out[0].predicted_distance == 20.0 and out[0].fused_score == 0.9
    # Place 2 passes the keyframe model: place 0 keeps its default verdict.
    _calls(monkeypatch, {(0, False): _far([10.0, 0.0, 0.0]), (1, False): _rescuable(),
                         (2, False): _verdict(True, "accepted")})
    out = _three(0).verify_places(3, [_match(0, 0.0), _match(2, 0.0)], _apart())
    assert [(c.match, c.accepted) for c in out] == [(0, False), (2, True)]
    assert out[0].reason.startswith("not a revisit")


def test_a_move_only_the_scans_model_allows_is_a_rescue(monkeypatch) -> None:
    # Place 0's fit fails (1) but passes the scans' model, 10 m away at keyframe 1:
    # the default refuses it for its free space and never moves; the move's check at
    # 1 passes (1), and counts only as a rescue.
    held = dataclasses.replace(_verdict(False, "inconsistent free space (0.91 < 0.92)"),
                               relative=np.array([10.0, 0.0, 0.0]), rescuable_far=True)
    fail = _verdict(False, "registration failed")
    calls = _calls(monkeypatch, {(0, False): held, (1, False): _verdict(True, "accepted"),
                                 (2, False): fail})
    out = _three(0).verify_places(3, [_match(0, 0.0), _match(2, 0.0)], _apart())
    assert calls == [(0, False), (1, False), (2, False)]
    assert [(c.match, c.accepted, c.reason) for c in out] == [(1, True, RESCUED),
                                                             (2, False, fail.reason)]
    _calls(monkeypatch, {(0, False): held, (1, False): _verdict(True, "accepted"),
                         (2, False): _verdict(True, "accepted")})
    out = _three(0).verify_places(3, [_match(0, 0.0), _match(2, 0.0)], _apart())
    assert [(c.match, c.accepted, c.reason) for c in out] == [(0, False, held.reason),
                                                             (2, True, "accepted")]
