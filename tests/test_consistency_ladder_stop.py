"""The odometry ladder's stop (`slam.consistency.LADDER_STOP`): a rung that changes no
refined decision ends the climb; the bar search's skip (`slam.consistency.BAR_AGREE`)
when another rung's candidate keeps the winner's loops."""

from __future__ import annotations

import numpy as np
import pytest

import slam.admission as admission
import slam.consistency as consistency
from slam.consistency import Admission, _other_rung_agrees, _rung_agrees, incremental_tls
from slam.optimize import initial_guess
from slam.pose_graph import poses_from_values
from tests.test_backend import _square_graph


def _refined_by(weights: dict[str, list[float]]):
    def refined(decide, run):  # type: ignore[no-untyped-def]
        return None, np.array(weights[run]), 0.0
    return refined


def test_a_rung_agrees_only_when_some_pass_keeps_the_same_loops() -> None:
    refined = _refined_by({"x1-stated": [1, 0, 1], "x1-calibrated": [1, 0, 0],
                           "x10": [1, 0, 0], "x10-other": [0.9, 0.2, 0.4]})
    # the same loops as the calibrated pass below (0.9 and 0.2 read as kept / rejected)
    assert _rung_agrees([(None, "x10")], [(None, "x1-stated"), (None, "x1-calibrated")],
                        refined)
    assert _rung_agrees([(None, "x10-other")], [(None, "x1-calibrated")], refined)
    assert not _rung_agrees([(None, "x10")], [(None, "x1-stated")], refined)
    assert not _rung_agrees([], [(None, "x1-stated")], refined)  # nothing finished


@pytest.mark.parametrize("stop", [False, True])
def test_the_ladder_stops_after_a_rung_that_changes_nothing(monkeypatch, stop) -> None:
    graph, _ = _square_graph(noise=0.02, laps=3)
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    made: list[float] = []
    init = admission.AdmissionPass.__init__

    def counted(self, g, *a, **kw):  # type: ignore[no-untyped-def]
        made.append(float(g.odometry[0].information[0, 0]))
        init(self, g, *a, **kw)

    monkeypatch.setattr(admission.AdmissionPass, "__init__", counted)
    monkeypatch.setattr(consistency, "LADDER_STOP", stop)
    result = incremental_tls(graph, values, block=10, tries=0)
    first = graph.odometry[0].information[0, 0]
    # without outliers every rung keeps every loop: x10 agrees with x1 and x100 is not run
    assert [m / first for m in made] == ([1.0, 10.0] if stop else [1.0, 10.0, 100.0])
    assert result.weights.all()
    plain = incremental_tls(graph, values, block=10, tries=0, ladder=(1.0,))
    a, b = poses_from_values(result.values, 2), poses_from_values(plain.values, 2)
    assert max(np.abs(a[k] - b[k]).max() for k in a) < 1e-6  # both at the plain optimum


def test_another_rung_agrees_only_on_another_graph_with_the_same_loops() -> None:
    x1, x10 = object(), object()

    def candidate(weights):  # type: ignore[no-untyped-def]
        return Admission(None, np.array(weights, dtype=float), 0.0, 0, "stated")

    best = candidate([1, 0, 1])
    same_graph = [(best, x1, None), (candidate([1, 0, 1]), x1, None)]
    assert not _other_rung_agrees(best, x1, same_graph)
    assert _other_rung_agrees(best, x1, [*same_graph, (candidate([0.8, 0.1, 0.6]), x10, None)])
    assert not _other_rung_agrees(best, x1, [*same_graph, (candidate([1, 1, 1]), x10, None)])


@pytest.mark.parametrize("agree", [False, True])
def test_the_bar_search_is_skipped_when_another_rung_agrees(monkeypatch, agree) -> None:
    graph, _ = _square_graph(noise=0.02, laps=3)
    values = graph.gtsam_values(initial_guess(graph, "odometry"))
    searched: list[int] = []
    bar = consistency.bar_search

    def counted(*a, **kw):  # type: ignore[no-untyped-def]
        searched.append(1)
        return bar(*a, **kw)

    monkeypatch.setattr(consistency, "bar_search", counted)
    monkeypatch.setattr(consistency, "BAR_AGREE", agree)
    result = incremental_tls(graph, values, block=10)
    # without outliers every rung keeps every loop, so another rung always agrees
    assert searched == ([] if agree else [1])
    assert result.weights.all()
