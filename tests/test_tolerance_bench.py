"""The diagnoses of bench-loops tolerance cases and of the final ranking
(``benchmarks/tolerance_cases.py``, ``benchmarks/final_ranking.py``) on hand-checked cases."""

from __future__ import annotations

from itertools import pairwise
from types import SimpleNamespace

import numpy as np

from data import se2
from loopclosure.registration import RegistrationTarget
from tests.helpers import load_benchmark


def _room() -> np.ndarray:
    """Walls of a 6 x 4 m room with a 1 m notch, a point every 2 cm [m]."""
    corners = np.array([[-3, -2], [3, -2], [3, 2], [0.5, 2], [0.5, 1], [-0.5, 1], [-0.5, 2],
                        [-3, 2], [-3, -2]], float)
    parts = []
    for a, b in pairwise(corners):
        n = max(int(np.hypot(*(b - a)) / 0.02), 2)
        s = np.linspace(0.0, 1.0, n, endpoint=False)[:, None]
        parts.append(a + s * (b - a))
    return np.vstack(parts)


def test_line_distances_of_points_off_a_wall() -> None:
    """Points 3 cm off a straight wall are 3 cm from its line; moved 1 cm further, 4 cm."""
    bench = load_benchmark("tolerance_cases")
    wall = np.column_stack([np.arange(-2.0, 2.0, 0.02), np.zeros(200)])
    target = RegistrationTarget(wall, bench.FINE)
    src = np.array([[0.0, 0.03], [0.51, -0.03]])
    np.testing.assert_allclose(bench.line_distances(src, target, np.zeros(3)), 0.03, atol=1e-9)
    np.testing.assert_allclose(bench.line_distances(src[:1], target, np.array([0, 0.01, 0])),
                               0.04, atol=1e-9)


def test_fixed_heading_fit_recovers_the_translation() -> None:
    """The room moved by (0.05, -0.03) m at the right heading: the fit undoes the move and
    its truncated cost is zero; at a heading 3 degrees off the cost is higher."""
    bench = load_benchmark("tolerance_cases")
    room = _room()
    target = RegistrationTarget(room, bench.FINE)
    shifted = room + np.array([0.05, -0.03])
    pose, cost = bench.fixed_heading_fit(shifted, target, np.zeros(3))
    np.testing.assert_allclose(pose, [-0.05, 0.03, 0.0], atol=2e-3)
    assert cost < 1e-3
    _, turned = bench.fixed_heading_fit(shifted, target, np.array([0, 0, np.radians(3.0)]))
    assert turned > 10 * max(cost, 1e-4)


def test_keyframe_consistency_finds_a_turned_pose() -> None:
    """Three scans of one room from three poses: exact poses hold them together (ICP turns
    none); the middle pose turned by 2 degrees, ICP turns its scan back by about 2."""
    bench = load_benchmark("tolerance_cases")
    room = _room()
    poses = np.array([[0.0, 0.0, 0.0], [0.3, 0.1, 0.05], [0.6, -0.1, 0.1]])
    kfs = [SimpleNamespace(points=se2.transform_points(se2.inverse(p), room)) for p in poses]
    mapper = SimpleNamespace(keyframes=SimpleNamespace(keyframes=kfs))
    exact = bench.keyframe_consistency(mapper, poses, half=2)
    assert np.all(exact < 0.05)
    bent = poses.copy()
    bent[1, 2] += np.radians(2.0)
    turns = bench.keyframe_consistency(mapper, bent, half=2)
    assert abs(turns[1] - 2.0) < 0.2


def test_final_ranking_figures_by_hand() -> None:
    """Scores 3, 2, 1 for correct, wrong, correct among 4 revisits: recall at 100%
    precision 1/4; average precision 1/4 * 1 + 1/4 * 2/3 (the second correct one is
    the third proposal)."""
    bench = load_benchmark("final_ranking")
    r100, r99, ap = bench.figures(np.array([3.0, 2.0, 1.0]), np.array([True, False, True]), 4)
    assert r100 == 0.25 and r99 == 0.25
    np.testing.assert_allclose(ap, 0.25 + 0.25 * 2 / 3)


def test_logistic_ranks_a_separable_feature() -> None:
    """Truth decided by the first feature alone: the fitted logistic weighs it far
    above the two noise features and ranks nearly every true detection first."""
    bench = load_benchmark("final_ranking")
    rng = np.random.default_rng(1)
    x = rng.normal(size=(200, 3))
    y = x[:, 0] > 0.2
    model = bench.fit_logistic(x, y)
    w = model[2]
    assert w[1] > 5 * np.abs(w[2:]).max()
    s = bench.logistic_score(model, x)
    auc = np.mean(s[y][:, None] > s[~y][None, :])
    assert auc > 0.99
