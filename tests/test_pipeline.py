"""End-to-end runs of the mapper: simulated worlds, the CLI, real logs and bags."""

from __future__ import annotations

import json

import numpy as np
import pytest

from data.sim import MotionConfig, simulate_run
from data.types import Trajectory
from evaluation.loop_metrics import LoopProposal, evaluate_loops
from evaluation.trajectory_error import trajectory_errors
from slam.cli.main import main
from slam.config import PipelineConfig
from slam.outputs import read_loops_csv
from slam.pipeline import Mapper
from tests.helpers import shared_file


@pytest.fixture(scope="module")
def sim_result():
    run = simulate_run(
        "box", seed=3, fov_deg=180.0, beams=181, max_range=12.0, noise_sigma=0.02,
        motion=MotionConfig(laps=1.4),
    )
    shown: list[tuple[int, int, int]] = []
    result = Mapper(PipelineConfig()).run(run.scans, progress=lambda *a: shown.append(a))
    return run, result, shown


def test_progress_counts_every_accepted_loop(sim_result) -> None:
    run, result, shown = sim_result
    assert [n for n, _, _ in shown] == list(range(1, len(run.scans) + 1))
    counts = [c for _, _, c in shown]
    assert counts == sorted(counts)  # one session: a verdict never changes later
    assert counts[-1] == sum(e.candidate.accepted for e in result.loops) >= 10


def test_simulated_loops_are_found_and_none_is_false(sim_result) -> None:
    run, result, _ = sim_result
    accepted = result.accepted_loops
    assert len(accepted) >= 10
    proposals = [
        LoopProposal(e.stamp_match, e.stamp_query, e.candidate.relative, 1.0, True)
        for e in accepted
    ]
    metrics = evaluate_loops(proposals, run.ground_truth, [k.stamp for k in result.keyframes])
    assert metrics.false_positives == 0
    assert metrics.precision == 1.0


def test_loop_closure_does_not_hurt_and_every_scan_gets_a_pose(sim_result) -> None:
    run, result, _ = sim_result
    assert result.scan_poses.shape == (len(run.scans), 3)
    assert np.all(np.isfinite(result.scan_poses))
    gt = run.ground_truth
    after = trajectory_errors(Trajectory.from_xytheta(result.scan_stamps, result.scan_poses), gt)
    before = trajectory_errors(
        Trajectory.from_xytheta(result.scan_stamps, result.odometry_poses), gt
    )
    assert after.ate_rmse <= before.ate_rmse * 1.05
    assert after.ate_rmse < 0.05


def test_wheel_odometry_drift_is_corrected_by_loop_closure() -> None:
    run = simulate_run("box", seed=1, motion=MotionConfig(laps=1.4))
    cfg = PipelineConfig(odometry="wheel")
    result = Mapper(cfg).run(run.scans)
    gt = run.ground_truth
    after = trajectory_errors(Trajectory.from_xytheta(result.scan_stamps, result.scan_poses), gt)
    before = trajectory_errors(
        Trajectory.from_xytheta(result.scan_stamps, result.odometry_poses), gt
    )
    assert len(result.accepted_loops) >= 3
    assert after.ate_rmse < 0.5 * before.ate_rmse


def test_cli_run_writes_every_output(tmp_path) -> None:
    run = simulate_run("box", seed=2, motion=MotionConfig(laps=1.0))
    from data.sim import write_run

    files = write_run(run, tmp_path / "sim")
    out = tmp_path / "out"
    code = main(["run", str(files["log"]), "--out", str(out), "--set", "loops.global_every=2",
                 "--json"])
    assert code == 0
    for name in ("trajectory.tum", "trajectory_kitti.txt", "graph.g2o", "loops.csv", "map.pgm",
                 "map.yaml", "map.png", "map_before.png", "summary.json", "config.yaml",
                 "odometry.tum"):
        assert (out / name).is_file(), name
    summary = json.loads((out / "summary.json").read_text())
    for key in ("scans", "keyframes", "loops_proposed", "loops_accepted", "loops_rejected_by_gnc",
                "wall_s", "peak_rss_mb", "timings_s"):
        assert key in summary
    assert summary["scans"] == len(run.scans)
    # every accepted loop counted once, by the search that proposed it
    rows = read_loops_csv(out / "loops.csv")
    assert {r["search"] for r in rows} <= {"pose", "appearance"}
    assert set(summary["loops_by_stage"]) == {"pose", "appearance"}
    for search, n in summary["loops_by_stage"].items():
        assert n == sum(r["accepted"] for r in rows if r["search"] == search)
    assert sum(summary["loops_by_stage"].values()) == summary["loops_accepted"]
    assert all(r["prior"] for r in rows if r["search"] == "pose")
    # free-space consistency: a fraction, reported by checks without a prior only
    assert all(np.isnan(r["consistency"]) for r in rows if r["prior"])
    assert all(0.0 <= r["consistency"] <= 1.0 for r in rows
               if not r["prior"] and not np.isnan(r["consistency"]))
    assert "global_every: 2" in (out / "config.yaml").read_text()
    traj = np.loadtxt(out / "trajectory.tum")
    assert len(traj) == len(run.scans) and np.all(np.diff(traj[:, 0]) > 0)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["run", "/no/such/log"], "no such file"),
        (["run", "/no/such/log", "--odometry", "lidar"], "unknown odometry"),
        (["run", "--set", "loops.nope=1"], "no key 'nope'"),
    ],
)
def test_cli_run_bad_input(argv, message, tmp_path, capsys) -> None:
    assert main([*argv, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error:") and message in err[-1]


def test_real_ros1_demo_bag_runs_without_odometry(tmp_path) -> None:
    bag = shared_file("rosbag/laser_scan_matcher_demo.bag")
    out = tmp_path / "bag"
    assert main(["run", str(bag), "--out", str(out), "--no-map"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["scans"] == 360 and summary["keyframes"] > 5
    traj = np.loadtxt(out / "trajectory.tum")
    assert len(traj) == 360 and np.all(np.isfinite(traj))


@pytest.mark.slow
def test_real_intel_slice_loops_beat_odometry_on_the_relations() -> None:
    from data.carmen import CarmenLog
    from data.relations import read_relations
    from evaluation.relations_metric import relations_metric

    log = shared_file("carmen/intel.clf.bz2")
    relations = read_relations(shared_file("carmen/intel.relations"))
    scans = []
    for scan in CarmenLog(log):
        scans.append(scan)
        if len(scans) == 2500:
            break
    result = Mapper(PipelineConfig()).run(scans)
    lo, hi = result.scan_stamps.min(), result.scan_stamps.max()
    inside = [r for r in relations if lo <= min(r.t1, r.t2) and max(r.t1, r.t2) <= hi]
    assert len(inside) > 300

    def error(poses: np.ndarray) -> float:
        order = np.argsort(result.scan_stamps, kind="stable")
        traj = Trajectory.from_xytheta(result.scan_stamps[order], poses[order])
        return relations_metric(traj, inside).trans_abs_mean

    assert len(result.accepted_loops) >= 50
    after, before = error(result.scan_poses), error(result.odometry_poses)
    assert after < 0.025
    assert after < 0.8 * before


def test_drift_propagation_matches_a_hand_computed_case() -> None:
    from slam.drift import _propagate_drift

    # Heading uncertainty 0.01 rad^2 before a 2 m step straight ahead (heading 0):
    # the lever arm adds 2^2 * 0.01 = 0.04 m^2 across the motion (y), none along it.
    drift = np.diag([0.0, 0.0, 0.01])
    step = np.diag([0.001, 0.002, 0.0005])
    out = _propagate_drift(drift, np.zeros(3), np.array([2.0, 0.0, 0.0]), step)
    assert out[0, 0] == pytest.approx(0.001)
    assert out[1, 1] == pytest.approx(0.002 + 0.04)
    assert out[2, 2] == pytest.approx(0.0105)
    assert out[1, 2] == pytest.approx(2.0 * 0.01)
    # Facing +y (90 degrees), the body-frame step covariance swaps its x and y.
    out = _propagate_drift(np.zeros((3, 3)), np.array([0.0, 0.0, np.pi / 2]),
                           np.array([1.0, 0.0, 0.0]), step)
    assert out[0, 0] == pytest.approx(0.002)
    assert out[1, 1] == pytest.approx(0.001)


@pytest.mark.slow
def test_real_intel_slice_through_a_ros2_bag_reads_back_identical_and_maps(tmp_path) -> None:
    from data.carmen import CarmenLog, write_log
    from data.sources import open_source

    scans = []
    for scan in CarmenLog(shared_file("carmen/intel.clf.bz2")):
        scans.append(scan)
        if len(scans) == 600:
            break
    log = tmp_path / "intel-slice.log"
    write_log(log, scans)
    bag = tmp_path / "intel-slice-bag"
    assert main(["convert", str(log), str(bag), "--format", "mcap"]) == 0
    back = list(open_source(bag))
    assert len(back) == len(scans)
    for a, b in zip(scans, back, strict=True):
        assert b.stamp == pytest.approx(a.stamp, abs=1e-6)
        np.testing.assert_array_equal(b.ranges, a.ranges.astype(np.float32))
        np.testing.assert_allclose(b.odom, a.odom, atol=1e-6)
    out = tmp_path / "out"
    assert main(["run", str(bag), "--out", str(out), "--no-map"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["scans"] == 600 and summary["keyframes"] > 50
    rows = [r for r in (out / "trajectory.tum").read_text().splitlines() if r[:1].isdigit()]
    assert len(rows) == 600


def test_refine_scans_registers_every_scan_onto_the_optimised_map() -> None:
    run = simulate_run("box", seed=4, fov_deg=180.0, beams=181, max_range=12.0,
                       noise_sigma=0.01, motion=MotionConfig(laps=0.5))
    gt = run.ground_truth
    errors = {}
    for refine in (False, True):
        result = Mapper(PipelineConfig(refine_scans=refine)).run(run.scans)
        assert result.scan_poses.shape == (len(run.scans), 3)
        assert ("refine_scans" in result.timings) == refine
        traj = Trajectory.from_xytheta(result.scan_stamps, result.scan_poses)
        errors[refine] = trajectory_errors(traj, gt).ate_rmse
    assert errors[True] <= errors[False] * 1.05
