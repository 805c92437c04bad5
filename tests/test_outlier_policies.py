"""False-loop policies (random, local, grouped, local-grouped) and the robustness rows."""

from __future__ import annotations

import numpy as np
import pytest

from data import se2
from data.errors import UserError
from evaluation.outlier_policies import inject_false_loops, parse_policies
from evaluation.robustness import run_robustness
from slam.optimize import default_outlier_residual
from slam.pose_graph import PoseGraph, whitened_residual

INFO = np.diag([100.0, 100.0, 400.0])


def _line(n: int = 120, turn: float = 0.0) -> PoseGraph:
    """`n` poses 1 m apart along x (each step turning by `turn` rad), loops every 25 ids."""
    graph = PoseGraph(dim=2)
    pose = np.zeros(3)
    step = np.array([1.0, 0.0, turn])
    for k in range(n):
        if k:
            pose = se2.compose(pose, step)
            graph.add_odometry(k - 1, k, step, INFO)
        graph.add_pose(k, pose)
    for k in range(30, n, 25):
        graph.add_loop(k - 30, k, se2.between(graph.initial[k - 30], graph.initial[k]), INFO)
    return graph


def _false(graph: PoseGraph, policy: str, ratio: float = 0.5, **kw):
    corrupted, idx = inject_false_loops(graph, ratio, np.random.default_rng(3), policy, **kw)
    return corrupted, [corrupted.loops[k] for k in idx]


@pytest.mark.parametrize("policy", ["random", "local", "grouped", "local-grouped"])
def test_every_policy_reaches_the_ratio_on_new_pairs(policy: str) -> None:
    graph = _line()
    corrupted, false = _false(graph, policy, ratio=0.6, group_size=3)
    n_true = len(graph.loops)
    assert len(false) == round(n_true * 0.6 / 0.4)
    assert len(corrupted.loops) == n_true + len(false)
    pairs = {(min(c.i, c.j), max(c.i, c.j)) for c in graph.odometry + graph.loops}
    for c in false:
        assert abs(c.i - c.j) > 10
        assert (min(c.i, c.j), max(c.i, c.j)) not in pairs
        pairs.add((min(c.i, c.j), max(c.i, c.j)))
        assert any(np.array_equal(c.information, t.information) for t in graph.loops)


def test_local_false_loops_stay_within_the_window() -> None:
    _, false = _false(_line(), "local", local_window=20)
    assert all(10 < abs(c.i - c.j) <= 20 for c in false)


def test_random_false_loops_copy_a_true_measurement() -> None:
    graph = _line()
    _, false = _false(graph, "random")
    for c in false:
        assert any(np.allclose(c.measurement, t.measurement) for t in graph.loops)


def test_a_group_shares_one_wrong_transform() -> None:
    # Straight line, no turn: T_k = (-k, 0, 0) + T + (k, 0, 0) rotated by T's heading:
    # with T = (x, y, phi), T_k = (x - k + k cos phi, y + k sin phi, phi).
    graph = _line(turn=0.0)
    graph.loops = [graph.loops[0]]
    graph.loops[0].measurement = np.array([2.0, 1.0, np.pi / 2])
    _, false = _false(graph, "grouped", ratio=0.8, group_size=4)
    assert len(false) == 4
    first = min(false, key=lambda c: c.i)
    for c in false:
        k = c.i - first.i
        assert c.j - first.j == k  # consecutive pairs (i + k, j + k)
        assert np.allclose(c.measurement, [2.0 - k, 1.0 + k, np.pi / 2], atol=1e-9)


def test_a_group_is_consistent_along_a_curved_chain() -> None:
    graph = _line(turn=0.05)
    _, false = _false(graph, "grouped", ratio=0.5, group_size=5)
    x = graph.initial
    groups: dict[tuple[int, int], list] = {}
    for c in false:
        groups.setdefault((c.i - c.j, 0), []).append(c)
    for members in groups.values():
        members.sort(key=lambda c: c.i)
        base = members[0]
        wrong = se2.compose(x[base.i], base.measurement)  # where the group puts pose base.j
        for c in members[1:]:  # each member implies the same placement of base.j
            implied_j = se2.compose(x[c.i], c.measurement)
            back = se2.compose(implied_j, se2.between(x[c.j], x[base.j]))
            assert np.allclose(back, wrong, atol=1e-9)


def test_policy_names_are_checked() -> None:
    assert parse_policies("random, grouped") == ["random", "grouped"]
    with pytest.raises(UserError, match="--policy"):
        parse_policies("random,sideways")
    with pytest.raises(UserError, match="policy"):
        inject_false_loops(_line(), 0.5, np.random.default_rng(0), "sideways")
    with pytest.raises(UserError, match="group_size"):
        inject_false_loops(_line(), 0.5, np.random.default_rng(0), "grouped", group_size=0)


def test_rows_carry_policy_seed_and_odometry_scale() -> None:
    rows = run_robustness(_line(60), [0.0, 0.3], ["none"], seed=2,
                          policies=["local", "grouped"], odometry_scale=0.1)
    assert [(r.policy, r.outlier_ratio) for r in rows] == [
        ("local", 0.0), ("local", 0.3), ("grouped", 0.0), ("grouped", 0.3)]
    assert all(r.to_json()["odometry_scale"] == 0.1 and r.seed == 2 for r in rows)
    assert rows[0].ate_vs_clean_m < 1e-6
    with pytest.raises(UserError, match="odometry_scale"):
        run_robustness(_line(60), [0.0], ["none"], odometry_scale=0.0)


@pytest.mark.parametrize("policy", ["random", "local", "grouped"])
def test_no_false_loop_is_true_by_chance(policy: str) -> None:
    graph = _line()  # every true loop measures (30, 0, 0): many random pairs 30 apart agree
    exact = dict(graph.initial)
    corrupted, idx = inject_false_loops(graph, 0.7, np.random.default_rng(0), policy,
                                        group_size=3, reference=exact)
    threshold = default_outlier_residual(2)
    assert all(whitened_residual(corrupted.loops[k], exact, 2) > threshold for k in idx)
