"""Multi-session mapping: the saved map's round trip, the join rule, two sessions of
one simulated world joined with the right transform, two worlds never joined."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from data import se2
from data.errors import DataError
from data.sim import MotionConfig, simulate_run
from data.types import Trajectory
from evaluation.trajectory_error import trajectory_errors
from slam.cli.main import main
from slam.config import PipelineConfig
from slam.pipeline import Mapper
from slam.session_file import read_saved_map, write_saved_map
from slam.sessions import PendingLoop, SessionsConfig, consistent_group

SENSOR = {"fov_deg": 180.0, "beams": 181, "max_range": 12.0, "noise_sigma": 0.02}
MOVE = np.array([30.0, -20.0, 2.0])  # the second session's odometry frame, unknown to it


def _moved(scans: list, move: np.ndarray) -> list:
    """The scans with their odometry in another frame (an unknown start pose)."""
    return [dataclasses.replace(s, odom=se2.compose(move, s.odom)) for s in scans]


@pytest.fixture(scope="module")
def box_run():
    return simulate_run("box", seed=0, motion=MotionConfig(laps=1.5), **SENSOR)


@pytest.fixture(scope="module")
def two_sessions(box_run, tmp_path_factory):
    """The run split at its middle: the first half mapped and saved, the second mapped
    into it from a moved odometry frame."""
    scans = box_run.scans
    half = len(scans) // 2
    cfg = PipelineConfig(odometry="icp2d")
    first = Mapper(cfg, name="first").run(scans[:half])
    path = write_saved_map(tmp_path_factory.mktemp("map") / "session.npz", first.saved_map)
    mapper = Mapper(cfg, saved=read_saved_map(path), name="second")
    second = mapper.run(_moved(scans[half:], MOVE))
    return first, mapper, second, path


def test_saved_map_round_trip(two_sessions, tmp_path) -> None:
    first, _, _, path = two_sessions
    back = read_saved_map(path)
    saved = first.saved_map
    assert back.config == json.loads(json.dumps(saved.config))
    assert back.sessions == saved.sessions
    for name, values in saved.arrays.items():
        np.testing.assert_array_equal(back[name], values, err_msg=name)
    # Written again, it reads back identical.
    again = read_saved_map(write_saved_map(tmp_path / "again.npz", back))
    for name, values in back.arrays.items():
        np.testing.assert_array_equal(again[name], values, err_msg=name)
    assert back.n_keyframes == len(first.keyframes)
    assert back.n_scans == len(first.scan_stamps)
    np.testing.assert_array_equal(back.keyframe_scan(3).ranges, first.keyframes[3].scan.ranges)


def test_second_session_joins_with_the_right_transform(box_run, two_sessions) -> None:
    _first, mapper, joint, _ = two_sessions
    assert mapper.joined
    s = joint.sessions
    assert [x.name for x in s] == ["first", "second"] and all(x.joined for x in s)
    assert s[1].loops >= 3 and s[1].joined_at_keyframe is not None
    assert s[1].joined_after_m < 20.0
    # Both sessions' scans, in the first session's frame, as good as one run.
    assert len(joint.scan_stamps) == len(box_run.scans)
    errors = trajectory_errors(
        Trajectory.from_xytheta(joint.scan_stamps, joint.scan_poses), box_run.ground_truth)
    assert errors.ate_rmse < 0.05
    # The transform: the second session's frame in the map frame, from ground truth.
    half = len(box_run.scans) // 2
    own_first = mapper.odometry_poses[0]
    truth_first = se2.compose(
        joint.scan_poses[0], se2.between(
            _pose(box_run.ground_truth, 0), _pose(box_run.ground_truth, half)))
    truth = se2.compose(truth_first, se2.inverse(own_first))
    t = np.asarray(s[1].transform)
    assert np.hypot(*(t[:2] - truth[:2])) < 0.1
    assert abs(se2.wrap_angle(t[2] - truth[2])) < np.radians(1.0)
    # The saved map of the joint run holds both sessions.
    assert joint.saved_map.n_keyframes == len(joint.keyframes)
    assert set(joint.saved_map["kf_session"].tolist()) == {0, 1}


def _pose(trajectory: Trajectory, i: int) -> np.ndarray:
    m = trajectory.poses[i]
    return np.array([m[0, 3], m[1, 3], np.arctan2(m[1, 0], m[0, 0])])


def test_another_world_is_never_joined(two_sessions) -> None:
    _, _, _, path = two_sessions
    other = simulate_run("surface", seed=3, motion=MotionConfig(laps=0.7), **SENSOR)
    mapper = Mapper(PipelineConfig(odometry="icp2d"), saved=read_saved_map(path), name="other")
    with pytest.warns(UserWarning, match="never revisited the saved map"):
        result = mapper.run(_moved(other.scans, MOVE))
    assert not mapper.joined
    assert result.sessions[-1].joined is False and result.sessions[-1].transform is None
    # Written alone, in its own frame, keys from 0.
    assert len(result.keyframes) == result.saved_map.n_keyframes
    assert all(0 <= e.candidate.match < len(result.keyframes) for e in result.loops)


def test_join_needs_several_consistent_loops() -> None:
    poses = np.zeros((20, 3))
    poses[:10, 0] = np.arange(10.0)  # saved keyframes along x (map frame)
    t = np.array([5.0, 2.0, 0.5])  # the session frame in the map frame
    poses[10:] = se2.compose(se2.inverse(t), poses[:10])  # the same places, session frame

    def loop(a: int, b: int, error: tuple = (0, 0, 0)) -> PendingLoop:
        z = se2.between(poses[a], se2.compose(t, poses[b])) + np.asarray(error, float)
        return PendingLoop(None, a, b, z)

    cfg = SessionsConfig(join_loops=3)
    good = [loop(1, 11), loop(3, 13), loop(6, 16, (0.1, 0.0, 0.01))]
    wrong = loop(8, 12, (0.0, 3.0, 0.3))  # a look-alike place: consistent with nothing
    assert consistent_group([*good[:2], wrong], poses, cfg) == []
    assert consistent_group([wrong, *good], poses, cfg) == [1, 2, 3]
    # Three loops from only two keyframes of the new session are not enough.
    assert consistent_group([loop(1, 11), loop(2, 11), loop(3, 13)], poses, cfg) == []
    assert consistent_group([loop(1, 11), loop(2, 11), loop(3, 13)], poses,
                            SessionsConfig(join_loops=2)) == [0, 1, 2]
    # Beyond the tolerance, two loops disagree.
    off = loop(6, 16, (0.0, 0.8, 0.0))
    assert consistent_group([*good[:2], off], poses, cfg) == []


def test_truncated_or_foreign_saved_map_is_refused(two_sessions, tmp_path, capsys) -> None:
    _, _, _, path = two_sessions
    data = Path(path).read_bytes()
    cut = tmp_path / "cut"
    cut.mkdir()
    (cut / "session.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match="truncated or damaged"):
        read_saved_map(cut)
    assert main(["run", "--map", str(cut), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "truncated" in err[0]
    other = tmp_path / "other.npz"
    np.savez(other, meta=np.frombuffer(json.dumps({"format": "x"}).encode(), np.uint8))
    with pytest.raises(DataError, match="not a loopclosure saved map"):
        read_saved_map(other)
    newer = tmp_path / "newer.npz"
    meta = {"format": "loopclosure-session", "version": 99}
    np.savez(newer, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8))
    with pytest.raises(DataError, match="version 99 is not supported"):
        read_saved_map(newer)
    with pytest.raises(DataError, match="no saved map here"):
        read_saved_map(tmp_path / "nowhere")


def test_cli_continues_a_saved_map(box_run, tmp_path, capsys) -> None:
    from data.carmen.writer import write_log

    scans = box_run.scans
    half = len(scans) // 2
    write_log(tmp_path / "first.log", scans[:half])
    write_log(tmp_path / "second.log", _moved(scans[half:], MOVE))
    one, two = tmp_path / "one", tmp_path / "two"
    assert main(["run", str(tmp_path / "first.log"), "--out", str(one), "--no-map",
                 "--odometry", "icp2d"]) == 0
    assert (one / "session.npz").is_file()
    before = (one / "session.npz").read_bytes()
    capsys.readouterr()
    assert main(["run", str(tmp_path / "second.log"), "--map", str(one), "--out", str(two),
                 "--no-map"]) == 0
    assert "session 2 joined the saved map at its keyframe" in capsys.readouterr().out
    sessions = json.loads((two / "sessions.json").read_text())["sessions"]
    assert [s["joined"] for s in sessions] == [True, True]
    assert sessions[1]["loops"] >= 3 and len(sessions[1]["transform"]) == 3
    traj = np.loadtxt(two / "trajectory.tum")
    assert len(traj) == len(scans) and np.all(np.diff(traj[:, 0]) > 0)
    assert (one / "session.npz").read_bytes() == before  # the saved map is not altered
    # The saved map's parameters carry over (the first run chose icp2d).
    assert "odometry: icp2d" in (two / "config.yaml").read_text()


def test_a_third_session_joins_the_two(box_run, two_sessions, tmp_path) -> None:
    _, _, joint, _ = two_sessions
    path = write_saved_map(tmp_path / "session.npz", joint.saved_map)
    scans = box_run.scans[: len(box_run.scans) // 3]
    mapper = Mapper(PipelineConfig(odometry="icp2d"), saved=read_saved_map(path), name="third")
    result = mapper.run(_moved(scans, np.array([-12.0, 40.0, -1.0])))
    assert [s.name for s in result.sessions] == ["first", "second", "third"]
    assert all(s.joined for s in result.sessions)
    assert len(result.scan_stamps) == len(box_run.scans) + len(scans)
    assert set(result.saved_map["kf_session"].tolist()) == {0, 1, 2}
    # The third session lies where the first one does (same scans, same place).
    n = len(scans)
    first_poses = result.scan_poses[:n]
    third_poses = result.scan_poses[-n:]
    assert np.median(np.hypot(*(first_poses[:, :2] - third_poses[:, :2]).T)) < 0.05
