"""Tests of the odometry front ends (`slam.odometry`): icp2d, wheel, kiss-icp."""

from __future__ import annotations

import dataclasses
import itertools

import gtsam
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data import se2
from data.errors import UserError
from data.sim import MotionConfig, OdometryNoise, simulate_run
from data.types import PointCloud, Scan, Trajectory
from evaluation.trajectory_error import trajectory_errors
from slam.odometry import (
    FRONT_ENDS,
    STATUSES,
    MotionNoise,
    OdometryEstimate,
    accumulate,
    adjoint,
    make_odometry,
)
from slam.odometry.icp2d import Icp2dConfig, Icp2dOdometry
from slam.odometry.kiss import KissConfig, KissOdometry
from slam.odometry.wheel import WheelConfig, WheelOdometry
from tests.helpers import shared_file


@pytest.fixture(scope="module")
def run():
    """A short simulated run: ~30 m of a figure-eight, 360-degree laser, drifting odometry."""
    noise = OdometryNoise(scale_bias=0.03, heading_bias=0.01, rot_scale_bias=0.02)
    return simulate_run("box", seed=2, motion=MotionConfig(laps=0.5), odometry_noise=noise)


def ate(estimates: list[OdometryEstimate], truth: Trajectory) -> float:
    poses = np.array([e.pose for e in estimates])
    stamps = np.array([e.stamp for e in estimates])
    return trajectory_errors(Trajectory.from_xytheta(stamps, poses), truth).ate_rmse


def check_estimate(e: OdometryEstimate) -> None:
    assert e.status in STATUSES
    assert e.pose.shape == (3,) and e.delta.shape == (3,) and e.covariance.shape == (3, 3)
    assert np.all(np.isfinite(e.pose)) and np.all(np.isfinite(e.delta))
    assert np.all(np.isfinite(e.covariance))
    np.testing.assert_allclose(e.covariance, e.covariance.T, atol=1e-15)
    assert np.all(np.linalg.eigvalsh(e.covariance) > 0)
    assert 0.0 <= e.fitness <= 1.0 and e.seconds >= 0.0


def chained(estimates: list[OdometryEstimate]) -> np.ndarray:
    """Poses rebuilt from the first pose and the deltas (must equal the poses)."""
    pose = estimates[0].pose
    out = [pose]
    for e in estimates[1:]:
        pose = se2.compose(pose, e.delta)
        out.append(pose)
    return np.array(out)


# ------------------------------------------------------------------ common pieces


def test_factory_names_and_errors() -> None:
    assert isinstance(make_odometry("icp2d"), Icp2dOdometry)
    assert isinstance(make_odometry("wheel"), WheelOdometry)
    assert isinstance(make_odometry("kiss-icp"), KissOdometry)
    assert set(FRONT_ENDS) == {"icp2d", "kiss-icp", "wheel"}
    with pytest.raises(UserError, match="unknown odometry"):
        make_odometry("lidar-magic")
    with pytest.raises(UserError, match="Icp2dConfig"):
        make_odometry("icp2d", WheelConfig())
    with pytest.raises(UserError, match="positive"):
        Icp2dConfig(keyframe_distance=0.0)
    with pytest.raises(UserError, match="point clouds"):
        Icp2dOdometry().process(PointCloud(stamp=0.0, points=np.zeros((10, 3))))


def test_motion_noise_hand_checked() -> None:
    noise = MotionNoise(along_per_m=0.1, along_per_rad=0.0, lateral_per_m=0.05,
                        lateral_per_rad=0.0, rot_per_m=0.02, rot_per_rad=0.1,
                        min_sigma_xy=0.0, min_sigma_theta=0.0)
    cov = noise.covariance([3.0, 4.0, -0.5])  # 5 m, 0.5 rad
    np.testing.assert_allclose(np.diag(cov), [0.01 * 5, 0.0025 * 5, 0.0004 * 5 + 0.01 * 0.5])
    assert np.count_nonzero(cov - np.diag(np.diag(cov))) == 0


def test_adjoint_matches_gtsam() -> None:
    for pose in ([1.0, -2.0, 0.7], [0.3, 0.5, -2.9]):
        np.testing.assert_allclose(adjoint(pose), gtsam.Pose2(*pose).AdjointMap(), atol=1e-12)


@settings(max_examples=8, deadline=None)
@given(
    a=st.tuples(st.floats(-2, 2), st.floats(-2, 2), st.floats(-3, 3)),
    b=st.tuples(st.floats(-2, 2), st.floats(-2, 2), st.floats(-3, 3)),
)
def test_accumulate_matches_monte_carlo(a: tuple, b: tuple) -> None:
    """Right-perturbation covariance propagation agrees with sampling through gtsam."""
    rng = np.random.default_rng(0)
    cov_a = np.diag([0.01, 0.02, 0.003]) ** 2
    cov_b = np.diag([0.015, 0.005, 0.004]) ** 2
    delta, cov = accumulate(a, cov_a, b, cov_b)
    np.testing.assert_allclose(delta, se2.compose(a, b), atol=1e-12)
    pa, pb, pc = gtsam.Pose2(*a), gtsam.Pose2(*b), gtsam.Pose2(*delta)
    n = 3000
    ea = rng.multivariate_normal(np.zeros(3), cov_a, n)
    eb = rng.multivariate_normal(np.zeros(3), cov_b, n)
    samples = np.array([
        gtsam.Pose2.Logmap(pc.between(pa.compose(gtsam.Pose2.Expmap(x))
                                      .compose(pb).compose(gtsam.Pose2.Expmap(y))))
        for x, y in zip(ea, eb, strict=True)
    ])
    emp = np.cov(samples.T)
    scale = np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    assert np.max(np.abs(emp - cov) / scale) < 0.15


# ----------------------------------------------------------------------- wheel


def test_wheel_follows_the_log_and_handles_missing_odometry(run) -> None:
    odo = WheelOdometry()
    est = [odo.process(s) for s in run.scans[:30]]
    for e in est:
        check_estimate(e)
    np.testing.assert_allclose(np.array([e.pose for e in est]),
                               run.odometry.xytheta()[:30], atol=1e-9)
    np.testing.assert_allclose(chained(est), run.odometry.xytheta()[:30], atol=1e-9)
    assert est[0].status == "first" and all(e.status == "ok" for e in est[1:])
    cfg = WheelConfig()
    np.testing.assert_allclose(est[5].covariance, cfg.noise.covariance(est[5].delta))
    blind = dataclasses.replace(run.scans[30], odom=None)
    e = odo.process(blind)
    assert e.status == "no_odometry"
    np.testing.assert_array_equal(e.pose, est[-1].pose)
    assert e.covariance[0, 0] > 5 * est[5].covariance[0, 0]  # a 1 m step vs 0.125 m
    # back on odometry: the increment is measured from the last odometry seen
    e2 = odo.process(run.scans[31])
    np.testing.assert_allclose(
        e2.delta, se2.between(run.scans[29].odom, run.scans[31].odom), atol=1e-12
    )


# ----------------------------------------------------------------------- icp2d


def test_icp2d_reduces_drift_on_the_simulator(run) -> None:
    truth = run.ground_truth
    wheel = [WheelOdometry().process(s) for s in run.scans]
    odo = Icp2dOdometry()
    est = [odo.process(s) for s in run.scans]
    for e in est:
        check_estimate(e)
    ate_wheel, ate_icp = ate(wheel, truth), ate(est, truth)
    assert ate_wheel > 0.15  # the odometry really drifts
    assert ate_icp < 0.03 and ate_icp < ate_wheel / 5
    assert sum(e.status == "ok" for e in est) >= 0.95 * len(est)
    np.testing.assert_allclose(chained(est), np.array([e.pose for e in est]), atol=1e-9)
    assert odo.map_rebuilds < len(est) / 2  # the map is rebuilt at map keyframes only
    assert len(odo.map_points) > 100
    # Without odometry (constant velocity) it still tracks.
    blind = [dataclasses.replace(s, odom=None) for s in run.scans[:120]]
    cv = Icp2dOdometry()
    est_cv = [cv.process(s) for s in blind]
    assert ate(est_cv, truth) < 0.05


def test_icp2d_covariance_reflects_the_match(run) -> None:
    odo = Icp2dOdometry()
    est = [odo.process(s) for s in run.scans[:40]]
    ok = [e for e in est if e.status == "ok"]
    floor = np.square(Icp2dConfig().covariance_floor)
    for e in ok:
        assert np.all(np.diag(e.covariance) >= floor * 0.999)
        assert np.all(np.diag(e.covariance) < floor + 1e-3)  # a good match is tight


def test_icp2d_in_a_featureless_corridor() -> None:
    """Along a corridor the map says nothing: the odometry fills in, ICP fixes the rest."""
    from data.sim import LaserModel, cast

    walls = np.array([[[-50.0, 1.0], [50.0, 1.0]], [[-50.0, -1.0], [50.0, -1.0]]])
    laser = LaserModel(fov_deg=180.0, beams=181, max_range=8.0, noise_sigma=0.005, dropout=0.0)
    k = np.arange(120)
    truth = np.column_stack([0.1 * k, 0.1 * np.sin(k / 20.0), 0.05 * np.cos(k / 20.0)])
    ranges = cast(walls, truth, laser, np.random.default_rng(0))
    # odometry: 5 % long and turning 0.02 rad per metre too much
    inc = se2.between(truth[:-1], truth[1:]) * [1.05, 1.05, 1.0] + [0.0, 0.0, 0.002]
    odom = [truth[0]]
    for d in inc:
        odom.append(se2.compose(odom[-1], d))
    scans = [laser.scan(r, stamp=float(i), odom=o, index=i)
             for i, (r, o) in enumerate(zip(ranges, odom, strict=True))]
    odo = Icp2dOdometry()
    est = [odo.process(s) for s in scans]
    for e in est:
        check_estimate(e)
    assert sum(e.status == "degenerate" for e in est) > 0.8 * len(est)
    final = est[-1].pose
    # across the corridor and in heading ICP is exact; along it the odometry rules
    assert abs(final[1] - truth[-1, 1]) < 0.02
    assert abs(se2.wrap_angle(final[2] - truth[-1, 2])) < np.radians(0.5)
    assert abs(odom[-1][2] - truth[-1, 2]) > np.radians(10)  # odometry heading drifted
    assert abs(final[0] - truth[-1, 0]) < 1.5 * abs(odom[-1][0] - truth[-1, 0]) + 0.05
    cov = est[60].covariance
    assert cov[0, 0] > 25 * cov[1, 1]  # along (x) far less certain than across (y)


def test_icp2d_all_invalid_scans(run) -> None:
    """A stretch of scans without a single return (open space): predict, then recover."""
    scans = list(run.scans[:60])
    for k in range(20, 30):
        s = scans[k]
        scans[k] = dataclasses.replace(s, ranges=np.full_like(s.ranges, s.max_range))
    odo = Icp2dOdometry()
    est = [odo.process(s) for s in scans]
    for e in est:
        check_estimate(e)
    assert [e.status for e in est[20:30]] == ["no_points"] * 10
    for k in range(20, 30):  # pose = previous pose + odometry increment
        u = se2.between(scans[k - 1].odom, scans[k].odom)
        np.testing.assert_allclose(est[k].delta, u, atol=1e-12)
        assert est[k].covariance[0, 0] > est[10].covariance[0, 0]
    assert all(e.status in ("ok", "degenerate") for e in est[31:])
    truth = run.ground_truth.xytheta()[:60]
    err = se2.between(truth[-1], se2.compose(truth[0], se2.between(est[0].pose, est[-1].pose)))
    assert np.hypot(err[0], err[1]) < 0.1
    # Without odometry and without points: the constant-velocity guess, no crash.
    blind = Icp2dOdometry()
    for s in scans[:40]:
        check_estimate(blind.process(dataclasses.replace(s, odom=None)))
    empty = Icp2dOdometry()
    for s in scans[20:25]:  # a log that starts in open space
        e = empty.process(s)
        check_estimate(e)
    check_estimate(empty.process(scans[30]))


def test_icp2d_odometry_glitch_and_kidnap(run) -> None:
    scans = [dataclasses.replace(s) for s in run.scans[:80]]
    # Glitch: from scan 40 on the odometry is offset by 3 m and 90 degrees, the robot
    # did not jump.  ICP must notice and keep the trajectory continuous.
    offset = np.array([3.0, -2.0, np.pi / 2])
    for s in scans[40:]:
        s.odom = se2.compose(offset, s.odom)
    odo = Icp2dOdometry()
    est = [odo.process(s) for s in scans]
    for e in est:
        check_estimate(e)
    assert est[40].status == "odometry_jump" and est[40].extra["kidnap"] is False
    true_step = se2.between(run.ground_truth.xytheta()[39], run.ground_truth.xytheta()[40])
    err = se2.between(true_step, est[40].delta)
    assert np.hypot(err[0], err[1]) < 0.03 and abs(err[2]) < 0.01
    assert all(e.status in ("ok", "degenerate") for e in est[41:])

    # Kidnap: the robot is carried to another part of the world (scans from far later
    # in the run) and the odometry jumps with it: the map restarts, the increment is
    # as good as unknown, and tracking goes on from there.
    far = [dataclasses.replace(s) for s in run.scans[200:240]]
    jump = se2.between(run.scans[39].odom, run.scans[200].odom)
    kid = Icp2dOdometry()
    est = [kid.process(s) for s in list(run.scans[:40]) + far]
    for e in est:
        check_estimate(e)
    assert est[40].status == "odometry_jump" and est[40].extra["kidnap"] is True
    np.testing.assert_allclose(est[40].delta, jump, atol=1e-9)
    assert np.sqrt(est[40].covariance[0, 0]) >= 1.0
    assert all(e.status in ("ok", "degenerate") for e in est[41:])
    rel_true = se2.between(run.ground_truth.xytheta()[200], run.ground_truth.xytheta()[239])
    rel_est = se2.between(est[40].pose, est[-1].pose)
    err = se2.between(rel_true, rel_est)
    assert np.hypot(err[0], err[1]) < 0.05


def test_icp2d_kidnap_noise_odometry(run) -> None:
    """``kidnap_noise="odometry"``: a kidnapped increment keeps the odometry model's
    covariance of that increment times `fallback_inflation` (by hand from the model's
    formula) instead of ``kidnap_sigma``; poses and increments are the fixed rule's."""
    scans = list(run.scans[:40]) + [dataclasses.replace(s) for s in run.scans[200:206]]
    a, b = Icp2dOdometry(), Icp2dOdometry(Icp2dConfig(kidnap_noise="odometry"))
    ea, eb = [a.process(s) for s in scans], [b.process(s) for s in scans]
    assert ea[40].extra["kidnap"] is True and eb[40].extra["kidnap"] is True
    for x, y in zip(ea, eb, strict=True):
        np.testing.assert_array_equal(x.pose, y.pose)
        np.testing.assert_array_equal(x.delta, y.delta)
    np.testing.assert_allclose(np.sqrt(np.diag(ea[40].covariance)), [10.0, 10.0, np.pi])
    u = se2.between(run.scans[39].odom, run.scans[200].odom)
    d, t = np.hypot(u[0], u[1]), abs(se2.wrap_angle(u[2]))
    n = Icp2dConfig().odometry_noise
    want = 10.0 * np.diag([
        n.along_per_m**2 * d + n.along_per_rad**2 * t + n.min_sigma_xy**2,
        n.lateral_per_m**2 * d + n.lateral_per_rad**2 * t + n.min_sigma_xy**2,
        n.rot_per_m**2 * d + n.rot_per_rad**2 * t + n.min_sigma_theta**2])
    np.testing.assert_allclose(eb[40].covariance, want, rtol=1e-12)
    assert d > 1.0 and want[0, 0] < 1.0  # a metres-long jump, far below 10 m sigma
    for k in range(41, len(scans)):  # registered scans: identical covariances
        np.testing.assert_array_equal(ea[k].covariance, eb[k].covariance)
    with pytest.raises(UserError, match="kidnap_noise"):
        Icp2dConfig(kidnap_noise="loose")


def test_icp2d_jump_agreement_gate_by_hand() -> None:
    """``_agrees``: ``e^T C^-1 e <= k^2`` with ``e = between(u, d)``; u = 1 m straight,
    C = diag(0.1^2, 0.05^2, 0.05^2), k = 3: 0.2 m along is 2 sigma (agrees), 0.35 m
    is 3.5 sigma, 0.16 m across 3.2 sigma, 0.16 rad 3.2 sigma (do not); k = 0: never."""
    cov = np.diag([0.01, 0.0025, 0.0025])
    u, prev = np.array([1.0, 0.0, 0.0]), np.array([2.0, -1.0, np.pi / 2])
    odo = Icp2dOdometry(Icp2dConfig(jump_agreement=3.0))

    def agrees(d: list[float], o: Icp2dOdometry = odo) -> bool:
        return o._agrees(prev, se2.compose(prev, np.array(d)), u, cov)

    assert agrees([1.2, 0.0, 0.0]) and agrees([1.0, 0.0, 0.0])
    assert agrees([1.0, 0.14, 0.0]) and agrees([1.0, 0.0, -0.14])
    assert not agrees([1.35, 0.0, 0.0])
    assert not agrees([1.0, 0.16, 0.0]) and not agrees([1.0, 0.0, 0.16])
    assert not agrees([1.0, 0.0, 0.0], Icp2dOdometry())
    with pytest.raises(UserError, match="jump_agreement"):
        Icp2dConfig(jump_agreement=-1.0)


def test_icp2d_jump_agreement_confirms_a_step_both_sensors_agree_on(run) -> None:
    """Twelve scans left out: a 1.7 m odometry jump.  With a fitness test no match
    passes (`jump_fitness_ratio` 2) the default makes it a kidnap (pose from the
    odometry); with ``jump_agreement=3`` the good match, which agrees with the
    odometry, gives the pose (closer to the truth than the odometry).  An odometry
    glitch (3 m, 90 degrees off, the robot did not move so) still does not agree."""
    scans = list(run.scans[:40]) + list(run.scans[52:60])
    truth = se2.between(run.ground_truth.xytheta()[39], run.ground_truth.xytheta()[52])
    fixed = Icp2dOdometry(Icp2dConfig(jump_fitness_ratio=2.0))
    agree = Icp2dOdometry(Icp2dConfig(jump_fitness_ratio=2.0, jump_agreement=3.0))
    ea, eb = [fixed.process(s) for s in scans], [agree.process(s) for s in scans]
    assert ea[40].extra["kidnap"] is True and "agreed" not in ea[40].extra
    assert eb[40].status == "odometry_jump" and eb[40].extra["kidnap"] is False
    assert eb[40].extra["agreed"] is True
    err_a, err_b = se2.between(truth, ea[40].delta), se2.between(truth, eb[40].delta)
    assert np.hypot(err_b[0], err_b[1]) < 0.01 < np.hypot(err_a[0], err_a[1])
    for e in eb:
        check_estimate(e)
    glitch = [dataclasses.replace(s) for s in run.scans[:45]]
    offset = np.array([3.0, -2.0, np.pi / 2])
    for s in glitch[40:]:
        s.odom = se2.compose(offset, s.odom)
    gate = Icp2dOdometry(Icp2dConfig(jump_fitness_ratio=2.0, jump_agreement=3.0))
    eg = [gate.process(s) for s in glitch[:41]]
    assert eg[40].extra["kidnap"] is True and "agreed" not in eg[40].extra
    assert "rejected_fitness" in eg[40].extra  # a good match, off the odometry


def test_icp2d_on_an_intel_slice() -> None:
    """First 600 scans of Intel: the relations inside beat wheel odometry by far."""
    from data.carmen import CarmenLog
    from data.relations import read_relations
    from evaluation.relations_metric import relations_metric

    log = shared_file("carmen/intel.clf.bz2")
    rel_path = shared_file("carmen/intel.relations")
    scans = list(itertools.islice(CarmenLog(log), 600))
    stamps = np.array([s.stamp for s in scans])
    rels = [r for r in read_relations(rel_path)
            if min(r.t1, r.t2) >= stamps.min() and max(r.t1, r.t2) <= stamps.max()]
    assert len(rels) > 30

    def metric(front: str) -> tuple[float, float]:
        odo = make_odometry(front)
        poses = np.array([odo.process(s).pose for s in scans])
        order = np.argsort(stamps, kind="stable")
        uniq, first = np.unique(stamps[order], return_index=True)
        m = relations_metric(Trajectory.from_xytheta(uniq, poses[order][first]), rels)
        assert m.relations_used == len(rels)
        return m.trans_abs_mean, m.rot_abs_mean_deg

    wheel_t, wheel_r = metric("wheel")
    icp_t, icp_r = metric("icp2d")
    print(f"intel slice: wheel {wheel_t:.4f} m {wheel_r:.3f} deg, "
          f"icp2d {icp_t:.4f} m {icp_r:.3f} deg")
    assert icp_t < 0.025 and icp_r < 0.4
    assert icp_t < 0.9 * wheel_t and icp_r < wheel_r / 2


def test_icp2d_outdoors_registers_vegetation() -> None:
    """Freiburg campus (outdoor, mostly trees and bushes), first 150 scans, drifting
    wheel odometry: with clutter matched point to point the front end stays
    registered and ends far closer to the logged (corrected) poses than the
    wheels; point to line alone fails on most scans (the map is ~70% clutter)."""
    from evaluation.robustness import aligned_position_error
    from evaluation.slam_input import load_input
    from loopclosure.registration import IcpConfig

    log = shared_file("carmen-corrected/freiburg-campus-corrected.log.gz")
    data = load_input(log, limit=150, odometry_noise=0)
    ref = dict(enumerate(data.logged_poses))

    def ate(poses: list[np.ndarray]) -> float:
        return aligned_position_error(dict(enumerate(poses)), ref, 2)

    def run_front(point_to_point: bool) -> tuple[float, int]:
        odo = Icp2dOdometry(Icp2dConfig(icp=IcpConfig(point_to_point_clutter=point_to_point)))
        est = [odo.process(s) for s in data.scans]
        return ate([e.pose for e in est]), sum(e.status == "failed" for e in est)

    wheel_ate = ate([s.odom for s in data.scans])
    ate_on, failed_on = run_front(True)
    _, failed_off = run_front(False)
    print(f"campus: wheel {wheel_ate:.3f} m, icp2d {ate_on:.3f} m, failed {failed_on} "
          f"(point to line only: {failed_off})")
    assert Icp2dConfig().icp.point_to_point_clutter  # the default
    assert failed_on <= 5 and failed_off >= 30
    assert ate_on < 0.5 * wheel_ate


# ------------------------------------------------------------------------ kiss


def test_kiss_runs_on_lifted_scans_and_clouds(run) -> None:
    scans = run.scans[:40]
    odo = KissOdometry(KissConfig(voxel_size=0.1))
    est = [odo.process(s) for s in scans]
    for e in est:
        check_estimate(e)
        assert e.matrix is not None and e.matrix.shape == (4, 4)
        np.testing.assert_allclose(se2.from_matrix(e.matrix), e.pose, atol=1e-12)
    assert est[0].status == "first"
    np.testing.assert_allclose(est[0].pose, scans[0].odom, atol=1e-12)
    truth = run.ground_truth
    wheel = [WheelOdometry().process(s) for s in scans]
    assert ate(est, truth) < max(0.05, ate(wheel, truth))
    # The same scans as 3D clouds (z = 0) without odometry.
    clouds = [PointCloud(stamp=s.stamp, index=s.index,
                         points=np.column_stack([s.points(), np.zeros(len(s.points()))]))
              for s in scans]
    cloud_odo = KissOdometry()
    est3 = [cloud_odo.process(c) for c in clouds]
    for e in est3:
        check_estimate(e)
    assert est3[0].status == "first" and np.allclose(est3[0].pose, 0.0)
    # An empty scan: prediction only, no crash.
    empty = Scan(stamp=99.0, ranges=np.zeros(360), angles=scans[0].angles, max_range=25.0,
                 odom=scans[-1].odom, index=40)
    e = odo.process(empty)
    check_estimate(e)
    assert e.status == "no_points"


def test_icp2d_jump_scale_largest_keeps_metre_steps_between_turns_on_the_spot() -> None:
    """A log of one scan per metre where the robot also turns on the spot: after a
    0.5 m step, steps alternate two 0.03 m steps with a 0.5 rad turn and one 1.05 m
    straight.  The median step is 0.03 m, so ``max(1 m, 10 * 0.03 m)`` flags every
    1.05 m step; the largest recent non-jump step (0.5 m, then 1.05 m) gives at
    least ``max(1 m, 5 m)``: none is a jump, while a 12 m step (over ``10 * 1.05``)
    still is, and it does not raise the scale for the next one."""
    def prediction_flags(scale: str, steps: list[np.ndarray]) -> list[bool]:
        odo = Icp2dOdometry(Icp2dConfig(jump_scale=scale))
        pose = np.zeros(3)
        odo._odom = pose.copy()
        flags = []
        for step in steps:
            pose = se2.compose(pose, step)
            flags.append(odo._prediction(pose)[2])
            odo._odom = pose.copy()
        return flags

    walk, turn = np.array([1.05, 0.0, 0.0]), np.array([0.03, 0.0, 0.5])
    steps = [np.array([0.5, 0.0, 0.0])] + [turn, turn, walk] * 4
    median = prediction_flags("median", steps)
    assert median[3] and all(median[6::3])  # every walk after the first turns
    assert not any(prediction_flags("largest", steps))
    kidnap = np.array([12.0, 0.0, 0.0])
    flags = prediction_flags("largest", [*steps, kidnap, kidnap, walk])
    assert flags[-3:] == [True, True, False]
    with pytest.raises(UserError):
        Icp2dConfig(jump_scale="mean")


def test_icp2d_jump_scale_largest_learns_metre_steps_from_the_first_scans(run) -> None:
    """Every ninth scan of the run: steps of about 1.1 m from the very first one, over
    `max_step`.  Against an empty history the first step is a jump; the map confirms
    it, its registered increment becomes the usual step, and no later step is a jump."""
    scans = run.scans[::9][:20]
    steps = [np.hypot(*se2.between(a.odom, b.odom)[:2]) for a, b in itertools.pairwise(scans)]
    assert min(steps[:3]) > 1.0
    odo = Icp2dOdometry(Icp2dConfig(jump_scale="largest"))
    est = [odo.process(s) for s in scans]
    for e in est:
        check_estimate(e)
    assert est[1].status == "odometry_jump" and est[1].extra["kidnap"] is False
    assert all(e.status in ("ok", "degenerate") for e in est[2:])


def test_icp2d_covariance_inflation_by_inlier_ratio() -> None:
    """``covariance_inflation="inliers"``: (ICP + floor) / inlier ratio, hand-checked at a
    zero heading (the body frame is the target frame), the ratio clipped at
    min_inlier_ratio; "none" keeps the sum."""
    from loopclosure.registration import IcpResult

    icp_cov = np.diag([4e-6, 9e-6, 1e-6])
    floor = np.array([0.005, 0.005, 0.002])
    expected_sum = icp_cov + np.diag(floor**2)

    def result(ratio: float) -> IcpResult:
        return IcpResult(pose=np.zeros(3), covariance=icp_cov, hessian=np.eye(3), sigma=0.01,
                         inlier_ratio=ratio, rms=0.01, fitness=ratio, degeneracy=0.3,
                         degenerate_axis=np.array([1.0, 0.0]), iterations=5, converged=True,
                         correspondences=100, ok=True)

    plain = Icp2dOdometry(Icp2dConfig(covariance_floor=tuple(floor)))
    inflated = Icp2dOdometry(Icp2dConfig(covariance_floor=tuple(floor),
                                         covariance_inflation="inliers", min_inlier_ratio=0.25))
    pose = np.zeros(3)
    np.testing.assert_allclose(plain._increment_covariance(result(0.5), pose), expected_sum,
                               atol=1e-11)
    np.testing.assert_allclose(inflated._increment_covariance(result(1.0), pose), expected_sum,
                               atol=1e-11)
    np.testing.assert_allclose(inflated._increment_covariance(result(0.5), pose),
                               2.0 * expected_sum, atol=1e-11)
    np.testing.assert_allclose(inflated._increment_covariance(result(0.1), pose),
                               4.0 * expected_sum, atol=1e-11)
    with pytest.raises(UserError):
        Icp2dConfig(covariance_inflation="fitness")
