"""A trajectory reference's disagreement with its own scans (`evaluation.loop_bench_scan_truth`)."""

from __future__ import annotations

import numpy as np

from data import se2
from evaluation.loop_bench_scan_truth import disagreement_sigmas, scan_disagreement
from evaluation.loop_bench_truth import within_reference_uncertainty


def _room(rng: np.random.Generator) -> np.ndarray:
    """Walls of a 10 x 6 m room and a 1 m square pillar, 200 points a wall at random
    places along it (each scan samples its own), 2 mm of noise across."""
    t = rng.uniform(0.0, 1.0, 200)
    walls = []
    for a, b in (((0, 0), (10, 0)), ((10, 0), (10, 6)), ((10, 6), (0, 6)), ((0, 6), (0, 0)),
                 ((4, 2), (5, 2)), ((5, 2), (5, 3)), ((5, 3), (4, 3)), ((4, 3), (4, 2))):
        a, b = np.array(a, float), np.array(b, float)
        walls.append(a + t[:, None] * (b - a))
    return np.vstack(walls) + rng.normal(0.0, 0.002, (len(walls) * len(t), 2))


def _keyframes(n: int = 13):
    """`n` true poses along the room and each one's scan (every wall point, its frame)."""
    rng = np.random.default_rng(0)
    poses = np.column_stack([np.linspace(1.5, 8.5, n), np.full(n, 1.0),
                             np.linspace(0.0, 0.5, n)])
    scans = [se2.transform_points(se2.inverse(p), _room(rng)) for p in poses]
    return poses, scans


def test_true_poses_leave_a_scan_where_it_is():
    poses, scans = _keyframes()
    metres, radians = scan_disagreement(scans, poses, 5)
    assert metres < 5e-3
    assert radians < np.radians(0.05)


def test_a_reference_heading_two_degrees_off_is_measured():
    poses, scans = _keyframes()
    bent = poses.copy()
    bent[6, 2] += np.radians(2.0)
    _, radians = scan_disagreement(scans, bent, 6)
    assert abs(np.degrees(radians) - 2.0) < 0.05
    # a keyframe whose two sides leave the bent one out does not move
    assert scan_disagreement(scans, bent, 0)[1] < np.radians(0.05)


def test_a_kink_shows_on_one_side():
    """Every pose from keyframe 6 on turned by 2 degrees about keyframe 6: its scan sits
    right among the keyframes after it, 2 degrees off those before it."""
    poses, scans = _keyframes()
    kinked = poses.copy()
    turn = np.array([0.0, 0.0, np.radians(2.0)])
    for j in range(6, len(poses)):
        kinked[j] = se2.compose(poses[6], se2.compose(turn, se2.between(poses[6], poses[j])))
    _, radians = scan_disagreement(scans, kinked, 6)
    assert abs(np.degrees(radians) - 2.0) < 0.05


def test_no_pose_or_too_few_neighbours_is_unknown():
    poses, scans = _keyframes(4)
    missing = poses.copy()
    missing[1] = np.nan
    assert np.isnan(scan_disagreement(scans, missing, 1)).all()
    assert np.isfinite(scan_disagreement(scans, missing, 0)).all()  # 2 and 3 after it
    missing[2] = np.nan
    assert np.isnan(scan_disagreement(scans, missing, 0)).all()  # one neighbour a side


def test_sigmas_add_the_two_keyframes_in_quadrature_over_k():
    moves = np.array([[0.3, 0.03], [0.4, 0.04], [np.nan, np.nan]])
    sig = disagreement_sigmas(moves, [[0, 1], [1, 2]])
    assert np.allclose(np.hypot(sig[0, 0], sig[0, 1]), 0.5 / 3)
    assert np.isclose(sig[0, 2], 0.05 / 3)
    assert np.isnan(sig[1]).all()
    # at the benchmark's k = 3 the tolerance widens by the disagreement itself
    edge = 2.0 + np.degrees(0.05)
    wrong_by = np.array([[0.1, edge - 0.01], [0.1, edge + 0.01]])
    out = within_reference_uncertainty(wrong_by, [1.0, 1.0], np.vstack([sig[0], sig[0]]))
    assert out.tolist() == [True, False]


def test_a_slide_along_a_corridor_is_not_counted():
    """Two parallel walls 2 m apart, 30 m long: a reference that puts a keyframe 0.3 m
    further along the corridor cannot be told by the scans; one 0.1 m across it can."""
    rng = np.random.default_rng(1)
    n = 9
    poses = np.column_stack([np.linspace(10.0, 18.0, n), np.zeros(n), np.zeros(n)])
    scans = []
    for p in poses:
        x = rng.uniform(0.0, 30.0, 600)
        walls = np.column_stack([x, np.where(np.arange(600) % 2 == 0, -1.0, 1.0)])
        scans.append(se2.transform_points(se2.inverse(p), walls + rng.normal(0, 0.002, (600, 2))))
    along, across = poses.copy(), poses.copy()
    along[4, 0] += 0.3
    across[4, 1] += 0.1
    assert scan_disagreement(scans, along, 4)[0] < 0.01
    assert abs(scan_disagreement(scans, across, 4)[0] - 0.1) < 0.01
