"""The swap search: a group of rejected true loops pushes out an admitted false one."""

from __future__ import annotations

import numpy as np

from data import se2
from slam.consistency import Admission, refine_tls, tls_cost
from slam.least_squares import StickySolver
from slam.optimize import initial_guess
from slam.swap import rejected_groups, swap_search
from tests.test_backend import INFO, _square_graph


def _wrong_admission():
    """The noisy square (3 laps) plus a false loop 10-22; an admission that took the false
    loop and rejected the three true loops at poses 22-24 (a group), solved so."""
    graph, truth = _square_graph(noise=0.02, laps=3)
    wrong = se2.compose(se2.between(truth[10], truth[22]), np.array([1.5, -1.0, 0.4]))
    bad = graph.add_loop(10, 22, wrong, INFO)
    group = [k for k, c in enumerate(graph.loops) if k != bad and 22 <= c.j <= 24]
    weights = np.ones(len(graph.loops))
    weights[group] = 0.0
    start = graph.gtsam_values(initial_guess(graph, "odometry"))
    values, _ = refine_tls(graph, start, weights, barred=group, max_rounds=1)
    return graph, bad, group, Admission(values, weights, tls_cost(graph, values), 0, "stated")


def test_groups_of_rejected_loops() -> None:
    graph, _bad, group, admission = _wrong_admission()
    assert rejected_groups(graph, admission.weights) == [group]
    assert rejected_groups(graph, admission.weights, min_size=4) == []


def test_a_rejected_group_pushes_out_the_false_loop() -> None:
    graph, bad, group, admission = _wrong_admission()
    start = graph.gtsam_values(initial_guess(graph, "odometry"))
    out = swap_search(graph, admission, start, solver=StickySolver())
    assert out.kept == [group] and out.pushed == [bad]
    assert out.admission.weights[bad] == 0 and out.admission.weights[group].all()
    assert out.admission.tls_cost < admission.tls_cost - 10.0
    # The same swap is refused when it has to gain more per loop pushed out than it does.
    gain = admission.tls_cost - out.admission.tls_cost
    refused = swap_search(graph, admission, start, gain_per_loop=gain + 1.0)
    assert refused.kept == [] and refused.admission is admission
