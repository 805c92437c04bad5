"""TUM and KITTI trajectory files: hand-written snippets, errors, round trips, evo interop."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from data.atomic_write import write_text_atomic
from data.errors import DataError, DataWarning, UserError
from data.text_table import format_stamps
from data.trajectory_io import read_kitti, read_tum, write_kitti, write_tum
from data.types import Trajectory

H = math.sqrt(0.5)
TUM = f"""\
# timestamp tx ty tz qx qy qz qw
976052905.167303 1 2 3 0 0 0 1

976052905.267303 4 5 6 0 0 {H!r} {H!r}
"""
ROT_Z90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])

KITTI = """\
1 0 0 0.5 0 1 0 0.25 0 0 1 -1
0 -1 0 2 1 0 0 3 0 0 1 4
"""


def _write(tmp_path: Path, text: str, name: str = "t.txt") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _random_traj(n: int, seed: int, stamp0: float = 976052905.167303) -> Trajectory:
    rng = np.random.default_rng(seed)
    stamps = stamp0 + np.cumsum(rng.uniform(1e-3, 1.0, n))
    poses = np.zeros((n, 4, 4))
    poses[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    poses[:, :3, 3] = rng.normal(0.0, 100.0, (n, 3))
    poses[:, 3, 3] = 1.0
    return Trajectory(stamps, poses)


# --------------------------------------------------------------------------- TUM


def test_tum_snippet_by_hand(tmp_path: Path) -> None:
    t = read_tum(_write(tmp_path, TUM))
    assert len(t) == 2
    assert t.stamps[0] == 976052905.167303 and t.stamps[1] == 976052905.267303
    np.testing.assert_array_equal(t.poses[0], [[1, 0, 0, 1], [0, 1, 0, 2], [0, 0, 1, 3],
                                               [0, 0, 0, 1]])
    np.testing.assert_allclose(t.poses[1][:3, :3], ROT_Z90, atol=1e-15)
    np.testing.assert_array_equal(t.poses[1][:3, 3], [4, 5, 6])
    np.testing.assert_allclose(t.xytheta()[1], [4, 5, math.pi / 2], atol=1e-15)


def test_tum_non_unit_quaternion_warns_once(tmp_path: Path) -> None:
    text = "0 0 0 0 0 0 0 2\n1 0 0 0 0 0 5 5\n2 0 0 0 0 0 0 1\n"
    with pytest.warns(DataWarning, match="2 TUM quaternions are not unit length") as rec:
        t = read_tum(_write(tmp_path, text))
    assert len(rec) == 1
    np.testing.assert_array_equal(t.poses[0], np.eye(4))
    np.testing.assert_allclose(t.poses[1][:3, :3], ROT_Z90, atol=1e-15)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("", "empty file"),
        ("# header only\n", "empty file"),
        ("0 1 2 3 0 0 0\n", "line 1: TUM pose .* needs 8 values, found 7"),
        ("0 0 0 0 0 0 0 1\n1 x 0 0 0 0 0 1\n", "line 2: 'x' is not a number"),
        ("0 0 0 0 0 0 0 1\n1 nan 0 0 0 0 0 1\n", "line 2: non-finite"),
        ("0 0 0 0 0 0 0 1\n# c\n0 0 0 0 0 0 0 1\n", "line 3: .*strictly increasing stamps"),
        ("1 0 0 0 0 0 0 1\n0.5 0 0 0 0 0 0 1\n", "line 2: stamp 0.5 does not increase"),
        ("0 0 0 0 0 0 0 0\n", "line 1: zero quaternion"),
    ],
)
def test_tum_bad_input(tmp_path: Path, text: str, match: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(DataError, match=match) as err:
        read_tum(path)
    assert str(path) in str(err.value)


def test_missing_file_is_data_error(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="no such file"):
        read_tum(tmp_path / "none.tum")
    with pytest.raises(DataError, match="no such file"):
        read_kitti(tmp_path / "none.txt")


def test_tum_round_trip(tmp_path: Path) -> None:
    traj = _random_traj(50, seed=1)
    write_tum(tmp_path / "a.tum", traj)
    back = read_tum(tmp_path / "a.tum")
    np.testing.assert_array_equal(back.stamps, traj.stamps)
    np.testing.assert_array_equal(back.poses[:, :3, 3], traj.poses[:, :3, 3])
    np.testing.assert_allclose(back.poses, traj.poses, rtol=0, atol=1e-15)
    # Reading what was written and writing it again changes nothing in the text.
    write_tum(tmp_path / "b.tum", back)
    assert read_tum(tmp_path / "b.tum").stamps.tolist() == traj.stamps.tolist()


def test_tum_ipc_stamps_written_with_microseconds(tmp_path: Path) -> None:
    traj = Trajectory.from_xytheta([976052905.167303, 976052905.5, 976052906.1 + 1e-7],
                                   np.zeros((3, 3)))
    write_tum(tmp_path / "s.tum", traj)
    stamps = [ln.split()[0] for ln in (tmp_path / "s.tum").read_text().splitlines()[1:]]
    assert stamps[:2] == ["976052905.167303", "976052905.500000"]
    assert float(stamps[2]) == traj.stamps[2]  # sub-microsecond: full repr, still exact
    assert format_stamps([0.1, 2.0]) == ["0.100000", "2.000000"]


settings_ = settings(max_examples=30, deadline=None,
                     suppress_health_check=[HealthCheck.function_scoped_fixture])


@settings_
@given(
    xyz=st.lists(st.tuples(*[st.floats(-1e7, 1e7, allow_nan=False)] * 3), min_size=1,
                 max_size=6),
    seed=st.integers(0, 2**31),
)
def test_tum_round_trip_property(tmp_path: Path, xyz: list, seed: int) -> None:
    n = len(xyz)
    traj = _random_traj(n, seed)
    traj.poses[:, :3, 3] = np.array(xyz)
    write_tum(tmp_path / "p.tum", traj)
    back = read_tum(tmp_path / "p.tum")
    np.testing.assert_array_equal(back.stamps, traj.stamps)
    np.testing.assert_array_equal(back.poses[:, :3, 3], traj.poses[:, :3, 3])
    np.testing.assert_allclose(back.poses[:, :3, :3], traj.poses[:, :3, :3], rtol=0, atol=2e-15)


def test_writers_refuse_bad_trajectories(tmp_path: Path) -> None:
    out = _write(tmp_path, TUM, "keep.tum")
    bad = _random_traj(3, seed=2)
    bad.poses[1, 0, 3] = np.nan
    with pytest.raises(UserError, match="non-finite"):
        write_tum(out, bad)
    with pytest.raises(UserError, match="non-finite"):
        write_kitti(out, bad)
    backwards = _random_traj(3, seed=3)
    backwards.stamps[2] = backwards.stamps[0]
    with pytest.raises(UserError, match="strictly increasing"):
        write_tum(out, backwards)
    with pytest.raises(UserError, match="empty"):
        write_tum(out, Trajectory(np.zeros(0), np.zeros((0, 4, 4))))
    assert out.read_text() == TUM
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.tum"]


def test_atomic_write_compression_and_missing_dir(tmp_path: Path) -> None:
    traj = _random_traj(4, seed=4)
    for name in ("c.tum.gz", "c.tum.bz2"):
        write_tum(tmp_path / name, traj)
        assert (tmp_path / name).read_bytes()[:2] in (b"\x1f\x8b", b"BZ")
        np.testing.assert_array_equal(read_tum(tmp_path / name).stamps, traj.stamps)
    with pytest.raises(DataError, match="does not exist"):
        write_text_atomic(tmp_path / "missing" / "x.txt", "x")


# --------------------------------------------------------------------------- KITTI


def test_kitti_snippet_by_hand(tmp_path: Path) -> None:
    t = read_kitti(_write(tmp_path, KITTI))
    np.testing.assert_array_equal(t.stamps, [0.0, 1.0])
    np.testing.assert_array_equal(t.poses[0][:3, 3], [0.5, 0.25, -1])
    np.testing.assert_array_equal(t.poses[1][:3, :3], ROT_Z90)
    np.testing.assert_array_equal(t.poses[1][:3, 3], [2, 3, 4])
    np.testing.assert_array_equal(t.poses[:, 3], [[0, 0, 0, 1]] * 2)


def test_kitti_stamps_array_and_times_file(tmp_path: Path) -> None:
    path = _write(tmp_path, KITTI)
    np.testing.assert_array_equal(read_kitti(path, stamps=[10.0, 10.1]).stamps, [10.0, 10.1])
    times = _write(tmp_path, "0.000000e+00\n1.036231e-01\n", "times.txt")
    np.testing.assert_array_equal(read_kitti(path, stamps=times).stamps, [0.0, 0.1036231])
    with pytest.raises(DataError, match="2 poses but 3 stamps"):
        read_kitti(path, stamps=[1.0, 2.0, 3.0])
    with pytest.raises(DataError, match="strictly increasing"):
        read_kitti(path, stamps=[2.0, 2.0])
    with pytest.raises(DataError, match="NaN"):
        read_kitti(path, stamps=[1.0, np.nan])


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("", "empty file"),
        ("1 0 0 0 0 1 0 0 0 0 1\n", "line 1: KITTI pose .* needs 12 values, found 11"),
        ("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 inf\n", "line 2: non-finite"),
        ("1 0 0 0 0 1 0 0 0 0 one 0\n", "line 1: 'one' is not a number"),
        ("2 0 0 0 0 1 0 0 0 0 1 0\n", "line 1: the 3x3 block is not a rotation"),
        ("-1 0 0 0 0 1 0 0 0 0 1 0\n", "line 1: the 3x3 block is not a rotation"),
    ],
)
def test_kitti_bad_input(tmp_path: Path, text: str, match: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(DataError, match=match) as err:
        read_kitti(path)
    assert str(path) in str(err.value)


def test_kitti_round_trip_exact(tmp_path: Path) -> None:
    traj = _random_traj(30, seed=5, stamp0=0.0)
    write_kitti(tmp_path / "k.txt", traj)
    back = read_kitti(tmp_path / "k.txt", stamps=traj.stamps)
    np.testing.assert_array_equal(back.poses, traj.poses)
    np.testing.assert_array_equal(back.stamps, traj.stamps)


# --------------------------------------------------------------------------- interop with evo


def test_evo_reads_what_we_write(tmp_path: Path) -> None:
    file_interface = pytest.importorskip("evo.tools.file_interface")
    traj = _random_traj(20, seed=6)
    write_tum(tmp_path / "e.tum", traj)
    write_kitti(tmp_path / "e.kitti", traj)
    evo_tum = file_interface.read_tum_trajectory_file(str(tmp_path / "e.tum"))
    np.testing.assert_array_equal(evo_tum.timestamps, traj.stamps)
    np.testing.assert_allclose(np.stack(evo_tum.poses_se3), traj.poses, atol=1e-12)
    evo_kitti = file_interface.read_kitti_poses_file(str(tmp_path / "e.kitti"))
    np.testing.assert_allclose(np.stack(evo_kitti.poses_se3), traj.poses, atol=1e-12)


def test_interrupted_write_leaves_old_file_and_no_temp(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = _write(tmp_path, TUM, "keep.tum")

    def fail(*_args: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("data.atomic_write.os.replace", fail)
    with pytest.raises(DataError, match="cannot write: No space left"):
        write_tum(out, _random_traj(3, seed=7))
    assert out.read_text() == TUM
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.tum"]
