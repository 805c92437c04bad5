"""The regroup search: a later group of rejected true loops re-decides the early false
loop that contradicts it."""

from __future__ import annotations

import numpy as np
import pytest

from slam.consistency import Admission, incremental_tls, refine_tls, tls_cost
from slam.least_squares import StickySolver
from slam.optimize import initial_guess
from slam.pairwise_consistency import loop_cycles
from slam.pose_graph import PoseGraph, RobustKernel
from slam.regroup import (
    agrees,
    hypotheses,
    lone_loops,
    predicted_cost,
    regroup,
    rejected_groups,
    returns,
)
from tests.test_robust_swap import _wrong_admission


def test_returns_split_where_later_poses_are_far_apart() -> None:
    later = np.array([100, 300, 120, 180, 305, 500])
    runs = returns(later, np.array([0, 1, 2, 3, 4]), gap=50)
    assert [r.tolist() for r in runs] == [[0, 2], [1, 4], [3]]  # gaps 20, 60, 120, 5
    runs = returns(later, np.array([0, 1, 2, 3, 4]), gap=70)
    assert [r.tolist() for r in runs] == [[0, 2, 3], [1, 4]]
    assert [r.tolist() for r in returns(later, np.array([0, 1, 2, 3, 4]), gap=150)] == [
        [0, 2, 3, 1, 4]]
    assert returns(later, np.zeros(0, np.int64)) == []


def test_the_false_loop_is_the_lone_suspect_of_the_group() -> None:
    graph, bad, group, admission = _wrong_admission()
    cycles = loop_cycles(graph)
    members = np.array(group)
    assert agrees(cycles, members)
    # A group made of the false loop and a true one does not agree with itself.
    assert not agrees(cycles, np.array([bad, group[0]]))
    assert lone_loops(graph, admission.weights).tolist() == [bad]
    assert [g.tolist() for g in rejected_groups(graph, admission.weights)] == [group]
    assert rejected_groups(graph, admission.weights, min_size=4) == []
    (run, suspects), = hypotheses(graph, admission.weights, cycles)
    assert sorted(run.tolist()) == group and suspects.tolist() == [bad]
    # With the false loop rejected too there is nothing to suspect; it is within two ids
    # of loop 8-24 on both ends, so in the group, which still agrees (3 of its 6 pairs).
    weights = admission.weights.copy()
    weights[bad] = 0.0
    (run, suspects), = hypotheses(graph, weights, cycles)
    assert sorted(run.tolist()) == sorted([*group, bad]) and suspects.tolist() == []


def test_regroup_swaps_the_false_loop_for_the_group() -> None:
    graph, bad, group, admission = _wrong_admission()
    chain = graph.gtsam_values(initial_guess(graph, "odometry"))
    out = regroup(graph, admission, chain, solver=StickySolver())
    assert len(out.trials) == 1
    tried, against, drop, kept = out.trials[0]
    assert sorted(tried) == group and against == [bad] and kept and drop > 10.0
    assert out.admission.weights[bad] == 0 and out.admission.weights[group].all()
    assert out.admission.tls_cost < admission.tls_cost - 10.0
    assert out.admission.tls_cost == tls_cost(graph, out.admission.values)


def test_regroup_leaves_a_right_admission_alone() -> None:
    graph, bad, _group, _ = _wrong_admission()
    weights = np.ones(len(graph.loops))
    weights[bad] = 0.0
    chain = graph.gtsam_values(initial_guess(graph, "odometry"))
    values, weights = refine_tls(graph, chain, weights, barred=[bad])
    right = Admission(values, weights, tls_cost(graph, values), 0, "stated")
    assert rejected_groups(graph, right.weights) == []
    out = regroup(graph, right, chain)
    assert out.admission is right and out.trials == []


def test_a_hypothesis_that_raises_the_objective_is_not_kept(monkeypatch) -> None:
    graph, _bad, _group, admission = _wrong_admission()
    chain = graph.gtsam_values(initial_guess(graph, "odometry"))
    from slam import regroup as module

    original = module.tls_cost

    def dearer(g, values, *rest):  # every solution but the admission's costs 1e6 more
        return original(g, values, *rest) + (0.0 if values is admission.values else 1e6)

    monkeypatch.setattr(module, "tls_cost", dearer)
    out = regroup(graph, admission, chain, screen=False)
    assert len(out.trials) == 1 and not out.trials[0][3] and out.trials[0][2] < 0
    assert out.admission is admission


def test_incremental_tls_with_regroup_never_ends_dearer() -> None:
    graph, _bad, _group, _ = _wrong_admission()
    chain = graph.gtsam_values(initial_guess(graph, "odometry"))
    off = incremental_tls(graph, chain, regroup=False, tries=0)
    on = incremental_tls(graph, chain, regroup=True, tries=0)
    assert on.tls_cost <= off.tls_cost + 1e-9


def test_optimize_hands_regroup_to_the_incremental_admission(monkeypatch) -> None:
    import slam.optimize as optimize_module

    graph, _bad, _group, _ = _wrong_admission()
    seen: list[object] = []
    real = optimize_module.incremental_tls

    def recording(*args, **kwargs):
        seen.append(kwargs.get("regroup"))
        return real(*args, **kwargs)

    monkeypatch.setattr(optimize_module, "incremental_tls", recording)
    for choice in (True, False, None):
        optimize_module.optimize(graph, method="gnc", gnc_start="incremental", init="odometry",
                                 fast_path=False, regroup=choice)
    assert seen == [True, False, None]


def _right_admission():  # type: ignore[no-untyped-def]
    graph, bad, group, _ = _wrong_admission()
    weights = np.ones(len(graph.loops))
    weights[bad] = 0.0
    chain = graph.gtsam_values(initial_guess(graph, "odometry"))
    values, weights = refine_tls(graph, chain, weights, barred=[bad])
    return graph, bad, group, Admission(values, weights, tls_cost(graph, values), 0, "stated")


def test_predicted_cost_at_the_hypothesis_optimum_is_its_objective() -> None:
    # At the solution of the stated graph of the right decisions the Gauss-Newton step is
    # zero: the model's minimum is the stated error plus c for the one rejected loop, which
    # is the TLS objective (the admitted loops are below c, the false one above it).
    graph, bad, _group, right = _right_admission()
    factors = graph.factor_graph(RobustKernel("none"))
    assert predicted_cost(graph, right.values, right.weights, factors) == pytest.approx(
        right.tls_cost, rel=1e-6)
    # Forcing the false loop in pulls against every true loop: predicted dearer.
    forced = right.weights.copy()
    forced[bad] = 1.0
    assert predicted_cost(graph, right.values, forced, factors) > right.tls_cost + 10.0


def test_predicted_cost_sees_the_drop_of_the_true_hypothesis() -> None:
    graph, bad, group, admission = _wrong_admission()
    factors = graph.factor_graph(RobustKernel("none"))
    weights = admission.weights.copy()
    weights[bad], weights[group] = 0.0, 1.0
    assert predicted_cost(graph, admission.values, weights, factors) < admission.tls_cost - 10.0


def test_a_screened_hypothesis_is_not_solved(monkeypatch) -> None:
    graph, bad, group, admission = _wrong_admission()
    chain = graph.gtsam_values(initial_guess(graph, "odometry"))
    from slam import regroup as module

    monkeypatch.setattr(module, "predicted_cost", lambda *a, **k: admission.tls_cost + 1.0)
    monkeypatch.setattr(module, "refine_tls", None)  # a solve would fail
    out = regroup(graph, admission, chain)
    assert out.trials == [] and out.admission is admission
    (tried, against, drop), = out.screened
    assert sorted(tried) == group and against == [bad] and drop == pytest.approx(-1.0)


def test_a_3d_admission_is_returned_unchanged() -> None:
    # A corridor of 30 poses 1 m apart (4x4 poses) with a rejected group of three loops
    # back to the start and one admitted lone loop: the grouping would find the group,
    # but the pairwise cycle test is planar, so nothing is tested on a 3D graph.
    graph = PoseGraph(dim=3)
    step = np.eye(4)
    step[0, 3] = 1.0
    info = np.eye(6) * 100.0
    for k in range(30):
        pose = np.eye(4)
        pose[0, 3] = float(k)
        graph.add_pose(k, pose)
        if k:
            graph.add_odometry(k - 1, k, step, info)
    for i, j in ((0, 25), (1, 26), (2, 27), (10, 20)):
        back = np.eye(4)
        back[0, 3] = float(j - i)
        graph.add_loop(i, j, back, info)
    weights = np.array([0.0, 0.0, 0.0, 1.0])
    assert [g.tolist() for g in rejected_groups(graph, weights)] == [[0, 1, 2]]
    values = graph.gtsam_values()
    admission = Admission(values, weights, tls_cost(graph, values), 0, "stated")
    out = regroup(graph, admission, values)
    assert out.admission is admission and out.trials == [] and out.screened == []


def test_a_hypothesis_the_calibrated_choice_refuses_is_not_kept(monkeypatch) -> None:
    # The swap lowers the stated objective (the test above); when the calibrated choice
    # between the current admission (index 0) and the hypothesis (1) picks the current
    # one, the admission stays.
    graph, bad, group, admission = _wrong_admission()
    chain = graph.gtsam_values(initial_guess(graph, "odometry"))
    from slam import regroup as module

    seen: list[list[float]] = []

    def choose_current(graph, candidates, **kwargs):  # type: ignore[no-untyped-def]
        seen.append([cost for _, _, cost in candidates])
        return 0

    monkeypatch.setattr(module, "calibrated_choice", choose_current)
    out = regroup(graph, admission, chain)
    assert out.admission is admission
    (tried, against, drop, kept), = out.trials
    assert sorted(tried) == group and against == [bad] and drop > 10.0 and not kept
    (current, hypothesis), = seen
    assert current == admission.tls_cost and hypothesis == pytest.approx(current - drop)
