"""The regroup search: a later group of rejected true loops re-decides the early false
loop that contradicts it."""

from __future__ import annotations

import numpy as np

from slam.consistency import Admission, incremental_tls, refine_tls, tls_cost
from slam.least_squares import StickySolver
from slam.optimize import initial_guess
from slam.pairwise_consistency import loop_cycles
from slam.regroup import agrees, contradicted, near_pairs, regroup, rejected_groups
from tests.test_robust_swap import _wrong_admission


def test_near_pairs_need_both_ends_close() -> None:
    a = np.array([0, 5, 40, 100])
    b = np.array([200, 210, 205, 300])
    admitted, group = np.array([0, 2, 3]), np.array([1])
    i, j = near_pairs(a, b, group, admitted, near=10)
    assert i.tolist() == [0] and j.tolist() == [1]  # loop 2: first ends 35 apart; 3: 95
    i, j = near_pairs(a, b, group, admitted, near=35)
    assert i.tolist() == [0, 2] and j.tolist() == [1, 1]
    assert near_pairs(a, b, group, np.zeros(0, np.int64), near=35)[0].size == 0


def test_the_false_loop_is_the_one_the_group_contradicts() -> None:
    graph, bad, group, admission = _wrong_admission()
    cycles = loop_cycles(graph)
    members = np.array(group)
    assert agrees(cycles, members)
    admitted = np.flatnonzero(admission.weights > 0.5)
    assert contradicted(cycles, members, admitted) == [bad]
    # Too far apart to be tested together: nothing is contradicted.
    assert contradicted(cycles, members, admitted, near=1) == []
    # A group made of the false loop and two true ones does not agree with itself.
    assert not agrees(cycles, np.array([bad, group[0]]))


def test_regroup_swaps_the_false_loop_for_the_group() -> None:
    graph, bad, group, admission = _wrong_admission()
    chain = graph.gtsam_values(initial_guess(graph, "odometry"))
    out = regroup(graph, admission, chain, solver=StickySolver())
    assert len(out.trials) == 1
    tried, against, drop, kept = out.trials[0]
    assert tried == group and against == [bad] and kept and drop > 10.0
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
    out = regroup(graph, admission, chain)
    assert len(out.trials) == 1 and not out.trials[0][3] and out.trials[0][2] < 0
    assert out.admission is admission


def test_incremental_tls_with_regroup_never_ends_dearer() -> None:
    graph, _bad, _group, _ = _wrong_admission()
    chain = graph.gtsam_values(initial_guess(graph, "odometry"))
    off = incremental_tls(graph, chain, regroup=False, tries=0)
    on = incremental_tls(graph, chain, regroup=True, tries=0)
    assert on.tls_cost <= off.tls_cost + 1e-9
