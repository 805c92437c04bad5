"""ATE/RPE and the relations metric against hand-checked cases and against evo."""

from __future__ import annotations

import numpy as np
import pytest

from data import se2
from data.relations import read_relations
from data.types import Relation, Trajectory
from evaluation.relations_metric import relations_metric
from evaluation.trajectory_error import associate, rotation_angle_deg, trajectory_errors, umeyama
from tests.helpers import shared_file


def _circle(n: int = 200, radius: float = 5.0) -> Trajectory:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    xyt = np.column_stack([radius * np.cos(t), radius * np.sin(t), se2.wrap_angle(t + np.pi / 2)])
    return Trajectory.from_xytheta(np.arange(n, dtype=float), xyt)


def test_ate_is_zero_after_a_rigid_motion() -> None:
    ref = _circle()
    moved = se2.compose(np.array([3.0, -2.0, 0.7]), ref.xytheta())
    est = Trajectory.from_xytheta(ref.stamps, moved)
    errors = trajectory_errors(est, ref)
    assert errors.ate_rmse < 1e-9
    assert errors.rpe_trans_rmse < 1e-9 and errors.rpe_rot_rmse_deg < 1e-6
    assert errors.matched == len(ref)


def test_ate_of_a_constant_offset_without_alignment() -> None:
    ref = _circle()
    xyt = ref.xytheta().copy()
    xyt[:, 0] += 0.3
    xyt[:, 1] -= 0.4
    errors = trajectory_errors(Trajectory.from_xytheta(ref.stamps, xyt), ref, align=False)
    assert errors.ate_rmse == pytest.approx(0.5)
    assert errors.ate_max == pytest.approx(0.5)
    # A pure translation leaves relative poses unchanged.
    assert errors.rpe_trans_rmse < 1e-9


def test_rpe_of_a_known_step_error() -> None:
    # Reference: 1 m steps along x.  Estimate: 1.1 m steps.  Each RPE pair errs by 0.1 m.
    n = 11
    ref = Trajectory.from_xytheta(np.arange(n, dtype=float), np.column_stack(
        [np.arange(n, dtype=float), np.zeros(n), np.zeros(n)]))
    est = Trajectory.from_xytheta(np.arange(n, dtype=float), np.column_stack(
        [1.1 * np.arange(n), np.zeros(n), np.zeros(n)]))
    errors = trajectory_errors(est, ref, align=False)
    assert errors.rpe_trans_rmse == pytest.approx(0.1)
    assert errors.rpe_pairs == n - 1
    by_metre = trajectory_errors(est, ref, align=False, rpe_delta=2.0, rpe_unit="m")
    assert by_metre.rpe_trans_rmse == pytest.approx(0.2)
    assert by_metre.rpe_pairs == 5


def test_association_tolerance() -> None:
    i_est, i_ref = associate(np.array([0.0, 1.004, 2.02]), np.array([0.0, 1.0, 2.0]), 0.01)
    assert i_est.tolist() == [0, 1] and i_ref.tolist() == [0, 1]


def test_umeyama_recovers_rotation_translation_and_scale() -> None:
    rng = np.random.default_rng(1)
    src = rng.normal(size=(50, 3))
    angle = 0.8
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    dst = 2.5 * src @ rot.T + np.array([1.0, -2.0, 0.5])
    r, t, s = umeyama(src, dst, with_scale=True)
    np.testing.assert_allclose(r, rot, atol=1e-9)
    np.testing.assert_allclose(t, [1.0, -2.0, 0.5], atol=1e-9)
    assert s == pytest.approx(2.5)


def test_rotation_angle_is_accurate_for_tiny_angles() -> None:
    for angle in (1e-9, 1e-5, 0.3, np.pi - 1e-6):
        c, s = np.cos(angle), np.sin(angle)
        rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
        assert rotation_angle_deg(rot) == pytest.approx(np.degrees(angle), rel=1e-6)


def test_relations_metric_hand_checked() -> None:
    # Poses at stamps 0, 1, 2.  The relation 0 -> 2 claims (2, 0, 0); the estimate says
    # delta = (2, 0.1, 0.05).  E = delta * delta*^-1 = (2, 0.1, 0.05) + R(0.05) (-2, 0):
    # translation (2 - 2 cos 0.05, 0.1 - 2 sin 0.05), rotation 0.05 rad.
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.1, 0.05]])
    traj = Trajectory.from_xytheta(np.array([0.0, 1.0, 2.0]), poses)
    rel = [
        Relation(0.0, 2.0, se2.to_se3(np.array([2.0, 0.0, 0.0]))),
        Relation(0.0, 1.0, se2.to_se3(np.array([1.0, 0.0, 0.0]))),
        Relation(0.0, 5.0, se2.to_se3(np.array([1.0, 0.0, 0.0]))),  # stamp 5 not in trajectory
    ]
    m = relations_metric(traj, rel)
    assert (m.relations_used, m.relations_total) == (2, 3)
    e = np.hypot(2 - 2 * np.cos(0.05), 0.1 - 2 * np.sin(0.05))
    np.testing.assert_allclose(m.trans_errors, [e, 0.0], atol=1e-12)
    np.testing.assert_allclose(m.rot_errors_deg, [np.degrees(0.05), 0.0], atol=1e-9)
    assert m.trans_abs_mean == pytest.approx(e / 2)
    assert m.trans_abs_std == pytest.approx(np.std([e, 0.0], ddof=1))
    assert m.trans_sq_mean == pytest.approx(e**2 / 2)
    assert m.rot_sq_mean_deg2 == pytest.approx(np.degrees(0.05) ** 2 / 2)


def test_relations_metric_of_raw_intel_odometry() -> None:
    """Relations error of the FLASER pose fields, recomputed independently with gtsam Pose2."""
    gtsam = pytest.importorskip("gtsam")
    from data.carmen import CarmenLog

    log = shared_file("carmen/intel.clf.bz2")
    rel_path = shared_file("carmen/intel.relations")
    stamps, poses = [], []
    for scan in CarmenLog(log):
        stamps.append(scan.stamp)
        poses.append(scan.odom)
    stamps_arr, poses_arr = np.array(stamps), np.array(poses)
    order = np.argsort(stamps_arr)
    traj = Trajectory.from_xytheta(stamps_arr[order], poses_arr[order])
    relations = read_relations(rel_path)
    metric = relations_metric(traj, relations)

    by_stamp = {round(t, 6): p for t, p in zip(stamps, poses, strict=True)}
    trans, rot = [], []
    for r in relations:
        a = gtsam.Pose2(*by_stamp[round(r.t1, 6)])
        b = gtsam.Pose2(*by_stamp[round(r.t2, 6)])
        yaw = np.arctan2(r.delta[1, 0], r.delta[0, 0])
        expected = gtsam.Pose2(r.delta[0, 3], r.delta[1, 3], yaw)
        err = a.between(b).compose(expected.inverse())
        trans.append(np.hypot(err.x(), err.y()))
        rot.append(abs(np.degrees(err.theta())))
    assert metric.relations_used == len(relations) == 2984
    assert metric.trans_abs_mean == pytest.approx(np.mean(trans), rel=1e-9)
    assert metric.trans_abs_std == pytest.approx(np.std(trans, ddof=1), rel=1e-9)
    assert metric.rot_abs_mean_deg == pytest.approx(np.mean(rot), rel=1e-9)
    # The raw odometry of the Intel lab drifts by metres over its loops.
    assert 5.0 < metric.trans_abs_mean < 10.0


def test_against_evo() -> None:
    """Our ATE and RPE equal evo's APE and RPE (translation part) on the same trajectories."""
    pytest.importorskip("evo")
    from evo.core import metrics, sync
    from evo.core.trajectory import PoseTrajectory3D

    rng = np.random.default_rng(3)
    ref = _circle(300)
    xyt = ref.xytheta() + np.column_stack(
        [np.cumsum(rng.normal(0, 0.01, 300)), np.cumsum(rng.normal(0, 0.01, 300)),
         np.cumsum(rng.normal(0, 0.002, 300))])
    xyt = se2.compose(np.array([1.0, 2.0, 0.3]), xyt)
    est = Trajectory.from_xytheta(ref.stamps + 0.003, xyt)

    evo_ref = PoseTrajectory3D(poses_se3=list(ref.poses), timestamps=ref.stamps)
    evo_est = PoseTrajectory3D(poses_se3=list(est.poses), timestamps=est.stamps)
    evo_ref, evo_est = sync.associate_trajectories(evo_ref, evo_est, max_diff=0.01)
    evo_est.align(evo_ref, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((evo_ref, evo_est))
    rpe_t = metrics.RPE(metrics.PoseRelation.translation_part, 1.0, metrics.Unit.frames)
    rpe_t.process_data((evo_ref, evo_est))
    rpe_r = metrics.RPE(metrics.PoseRelation.rotation_angle_deg, 1.0, metrics.Unit.frames)
    rpe_r.process_data((evo_ref, evo_est))

    ours = trajectory_errors(est, ref)
    assert ours.matched == 300
    assert ours.ate_rmse == pytest.approx(ape.get_statistic(metrics.StatisticsType.rmse), rel=1e-9)
    assert ours.ate_max == pytest.approx(ape.get_statistic(metrics.StatisticsType.max), rel=1e-9)
    assert ours.rpe_trans_rmse == pytest.approx(
        rpe_t.get_statistic(metrics.StatisticsType.rmse), rel=1e-7)
    assert ours.rpe_rot_rmse_deg == pytest.approx(
        rpe_r.get_statistic(metrics.StatisticsType.rmse), rel=1e-6)
