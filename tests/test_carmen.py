"""Tests of data.carmen: every message type by hand, bad input, round trips, real logs."""

from __future__ import annotations

import bz2
import gzip
import math
import threading
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from data.carmen import (
    DEFAULT_MAX_RANGE,
    CarmenLog,
    choose_max_range,
    field_of_view_deg,
    is_carmen,
    old_laser_geometry,
    write_log,
)
from data.errors import DataError, DataWarning, UserError
from data.sources import ScanSource
from data.types import Scan
from tests.helpers import shared_file

DEG = math.pi / 180.0


def write(tmp_path: Path, text: str, name: str = "log.clf") -> Path:
    path = tmp_path / name
    data = text.encode("latin-1")
    if name.endswith(".gz"):
        data = gzip.compress(data)
    elif name.endswith(".bz2"):
        data = bz2.compress(data)
    path.write_bytes(data)
    return path


def read(path: Path, **kwargs) -> tuple[list[Scan], list[str]]:
    """All scans and the texts of the DataWarnings emitted while reading."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scans = list(CarmenLog(path, **kwargs))
    texts = [str(w.message) for w in caught if issubclass(w.category, DataWarning)]
    return scans, texts


def flaser(ranges: list[float], pose=(1.0, 2.0, 0.5), stamp=100.0, name="FLASER") -> str:
    body = " ".join(f"{r:.2f}" for r in ranges)
    x, y, t = pose
    return f"{name} {len(ranges)} {body} {x} {y} {t} 9.0 9.0 9.0 {stamp:.6f} nohost 0.5\n"


# --------------------------------------------------------------------------- message types


def test_flaser_by_hand(tmp_path: Path) -> None:
    text = (
        "# message_name [message contents] ipc_timestamp ipc_hostname logger_timestamp\n"
        "## another comment\n"
        "PARAM robot_frontlaser_offset 0.0 nohost 0\n"
        "ODOM 0.0 0.0 0.1 0 0 0 99.5 nohost 0.0\n"
        "FLASER 3 1.50 81.83 2.25 1.0 2.0 0.5 9.0 9.0 9.0 100.000001 nohost 0.5\n"
        "NEFF 12.5 100.1 nohost 0.6\n"
        "FLASER 3 1.00 0.00 nan 1.5 2.5 -0.25 9.0 9.0 9.0 100.2 nohost 0.7\n"
    )
    scans, warned = read(write(tmp_path, text))
    assert warned == []
    assert len(scans) == 2
    a, b = scans
    assert a.index == 0 and b.index == 1
    assert a.stamp == pytest.approx(100.000001, abs=1e-9)
    np.testing.assert_allclose(a.ranges, [1.5, 81.83, 2.25])
    # 3 beams over 180 degrees: -90, 0, +90 (steps of pi / (n - 1))
    np.testing.assert_allclose(a.angles, [-math.pi / 2, 0.0, math.pi / 2], atol=1e-12)
    np.testing.assert_allclose(a.odom, [1.0, 2.0, 0.5])  # laser pose, not odom_x..
    assert a.max_range == DEFAULT_MAX_RANGE == 80.0
    assert a.valid.tolist() == [True, False, True]  # 81.83 is the no-return value
    assert b.valid.tolist() == [True, False, False]  # zero and NaN are invalid
    np.testing.assert_allclose(b.odom, [1.5, 2.5, -0.25])


def test_rlaser_selection_and_auto(tmp_path: Path) -> None:
    text = (
        flaser([1.0, 2.0], stamp=1.0, name="RLASER")
        + flaser([3.0, 4.0, 5.0], stamp=2.0, name="FLASER")
        + flaser([6.0, 7.0], stamp=3.0, name="RLASER")
    )
    path = write(tmp_path, text)
    auto, _ = read(path)  # the first laser message is an RLASER
    assert [s.stamp for s in auto] == [1.0, 3.0]
    front, _ = read(path, laser="flaser")
    assert [len(s.ranges) for s in front] == [3]
    info = CarmenLog(path, laser="FLASER").info()
    assert info.extra["laser"] == "FLASER"
    assert info.extra["messages"] == {"FLASER": 1, "RLASER": 2}
    with pytest.raises(UserError, match="unknown CARMEN laser"):
        CarmenLog(path, laser="LIDAR")
    with pytest.raises(DataError, match=r"no ROBOTLASER1 messages.*FLASER, RLASER"):
        list(CarmenLog(path, laser="ROBOTLASER1"))


def robotlaser(
    ranges: list[float],
    *,
    start=-1.0,
    fov=2.0,
    res=1.0,
    max_range=30.0,
    remissions=(0.5, 0.25, 0.125),
    laser=(1.0, 2.0, 0.3),
    robot=(0.9, 1.9, 0.3),
    stamp=50.0,
    mode=True,
    name="ROBOTLASER1",
) -> str:
    cfg = f"0 {start} {fov} {res} {max_range} 0.01" + (" 0" if mode else "")
    rng = " ".join(str(r) for r in ranges)
    rem = " ".join(str(r) for r in remissions)
    pose = " ".join(str(v) for v in (*laser, *robot))
    return (
        f"{name} {cfg} {len(ranges)} {rng} {len(remissions)} {rem} {pose} "
        f"0.1 0.2 0.3 0.4 0.5 {stamp} host 7.0\n"
    )


def test_robotlaser_by_hand(tmp_path: Path) -> None:
    text = robotlaser([1.0, 2.0, 30.0]) + robotlaser([4.0, 5.0], mode=False, stamp=51.0, res=0.5)
    scans, warned = read(write(tmp_path, text))
    assert warned == []
    a, b = scans
    np.testing.assert_allclose(a.angles, [-1.0, 0.0, 1.0])  # start + i * resolution
    np.testing.assert_allclose(a.ranges, [1.0, 2.0, 30.0])
    assert a.max_range == 30.0 and a.valid.tolist() == [True, True, False]
    np.testing.assert_allclose(a.odom, [1.0, 2.0, 0.3])  # the laser pose, not the robot's
    assert a.stamp == 50.0
    # an old-CARMEN line without remission_mode
    np.testing.assert_allclose(b.angles, [-1.0, -0.5])
    assert b.stamp == 51.0


def test_robotlaser_resolution_from_fov(tmp_path: Path) -> None:
    text = robotlaser([1.0, 1.0, 1.0, 1.0, 1.0], start=-math.pi, fov=math.pi, res=0.0)
    (scan,), _ = read(write(tmp_path, text))
    np.testing.assert_allclose(np.diff(scan.angles), math.pi / 4)


def rawlaser(ranges: list[float], stamp: float, name: str = "RAWLASER1") -> str:
    rng = " ".join(str(r) for r in ranges)
    return f"{name} 0 -1.5708 3.1416 1.5708 8.0 0.01 0 {len(ranges)} {rng} 0 {stamp} host 1.0\n"


def test_rawlaser_odometry_interpolation(tmp_path: Path) -> None:
    text = (
        "PARAM robot_frontlaser_offset 0.5 nohost 0\n"
        + rawlaser([1.0, 2.0, 3.0], 9.0)  # before the first ODOM: takes it
        + "ODOM 0.0 0.0 0.0 0 0 0 10.0 host 0\n"
        + rawlaser([1.0, 2.0, 3.0], 10.5)  # halfway between the two ODOMs
        + rawlaser([1.0, 2.0, 3.0], 10.75)
        + "ODOM 2.0 0.0 1.0 0 0 0 11.0 host 0\n"
        + rawlaser([1.0, 2.0, 3.0], 12.0)  # after the last ODOM: takes it
    )
    scans, warned = read(write(tmp_path, text))
    assert warned == []
    assert [s.stamp for s in scans] == [9.0, 10.5, 10.75, 12.0]
    np.testing.assert_allclose(scans[0].odom, [0.5, 0.0, 0.0])
    # robot at (1, 0, 0.5); laser 0.5 m ahead along the heading
    np.testing.assert_allclose(scans[1].odom, [1 + 0.5 * math.cos(0.5), 0.5 * math.sin(0.5), 0.5])
    np.testing.assert_allclose(
        scans[2].odom, [1.5 + 0.5 * math.cos(0.75), 0.5 * math.sin(0.75), 0.75]
    )
    np.testing.assert_allclose(scans[3].odom, [2 + 0.5 * math.cos(1.0), 0.5 * math.sin(1.0), 1.0])
    np.testing.assert_allclose(scans[1].angles, [-1.5708, 0.0, 1.5708])
    assert scans[1].max_range == 8.0


def test_rawlaser_full_front_mount(tmp_path: Path) -> None:
    text = (
        "PARAM robot_frontlaser_offset 0.3 nohost 0\n"
        "PARAM robot_frontlaser_side_offset 0.1 nohost 0\n"
        "PARAM robot_frontlaser_angular_offset 0.2 nohost 0\n"
        "ODOM 1.0 1.0 1.5707963267948966 0 0 0 5.0 host 0\n" + rawlaser([1.0, 2.0], 5.0)
    )
    (scan,), _ = read(write(tmp_path, text))
    # robot facing +y: forward 0.3 is +y, left 0.1 is -x
    np.testing.assert_allclose(scan.odom, [1.0 - 0.1, 1.0 + 0.3, math.pi / 2 + 0.2])


def test_rawlaser_backwards_stamps_and_rear_mount(tmp_path: Path) -> None:
    text = (
        "PARAM robot_rearlaser_offset 0.2 nohost 0\n"
        "ODOM 1.0 0.0 0.0 0 0 0 20.0 host 0\n"
        + rawlaser([1.0, 1.0], 19.1, "RAWLASER2")  # nearer in time to the second ODOM
        + "ODOM 3.0 0.0 0.0 0 0 0 19.0 host 0\n"  # ipc stamp goes backwards
    )
    (scan,), _ = read(write(tmp_path, text))
    np.testing.assert_allclose(scan.odom, [3.0 - 0.2, 0.0, -math.pi])  # behind, looking back


def test_rawlaser_without_odometry(tmp_path: Path) -> None:
    scans, _ = read(write(tmp_path, rawlaser([1.0, 2.0], 1.0) + rawlaser([1.0, 2.0], 2.0)))
    assert [s.odom for s in scans] == [None, None]


def test_param_laser_geometry_and_max(tmp_path: Path) -> None:
    text = (
        "PARAM laser_front_laser_resolution 0.5 nohost 0\n"
        "PARAM robot_front_laser_max 80.99 1089804841.8 lion 1089804841.8\n"
        + flaser([5.0] * 359 + [81.91])
    )
    (scan,), _ = read(write(tmp_path, text))
    assert scan.angles[0] == pytest.approx(-90 * DEG)
    assert scan.angles[-1] == pytest.approx(89.5 * DEG)  # 360 beams of 0.5 deg
    assert scan.max_range == 80.99 and not scan.valid[-1]


def test_old_laser_geometry_rules() -> None:
    start, step = old_laser_geometry(181, {"laser_front_laser_resolution": "1.0"})
    assert (start, step) == pytest.approx((-math.pi / 2, DEG))
    # fov alone: beams evenly over it
    start, step = old_laser_geometry(101, {"laser_front_laser_fov": "100"})
    assert (start, step) == pytest.approx((-50 * DEG, DEG))
    # a resolution that does not fit the beam count is ignored
    start, step = old_laser_geometry(181, {"laser_front_laser_resolution": "0.5"})
    assert (start, step) == pytest.approx((-math.pi / 2, math.pi / 180))
    # rear laser reads its own parameters
    start, step = old_laser_geometry(
        361, {"laser_rear_laser_resolution": "0.5", "laser_front_laser_resolution": "1"}, "RLASER"
    )
    assert step == pytest.approx(0.5 * DEG)
    # documented default: 180 degrees in steps of pi / (n - 1)
    # CARMEN's readlog convention: 1-degree steps for 180 and 181 beams.
    assert old_laser_geometry(180, {}) == pytest.approx((-math.pi / 2, math.pi / 180))
    assert old_laser_geometry(181, {}) == pytest.approx((-math.pi / 2, math.pi / 180))


def test_no_return_band_rule(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    # a SICK in 32 m mode (Orebro): nothing above 32.77, many no-returns at 32.76/32.77
    lines = [flaser([*rng.uniform(0.5, 30.0, 8), 32.76, 32.77], stamp=float(i)) for i in range(20)]
    scans, _ = read(write(tmp_path, "".join(lines)))
    assert {s.max_range for s in scans} == {32.7545}
    assert not scans[0].valid[-2:].any() and scans[0].valid[:8].all()
    # one reading beyond every band: cm mode, the default
    lines.insert(5, flaser([1.0] * 9 + [81.83], stamp=99.0))
    scans, _ = read(write(tmp_path, "".join(lines)))
    assert {s.max_range for s in scans} == {DEFAULT_MAX_RANGE}
    assert len(scans) == 21
    # explicit override wins
    scans, _ = read(write(tmp_path, "".join(lines)), max_range=12.0)
    assert {s.max_range for s in scans} == {12.0}


def test_choose_max_range_cases() -> None:
    indoor = [np.array([1.0, 2.0, 7.5])] * 10  # no evidence of a no-return value
    assert choose_max_range(indoor) == DEFAULT_MAX_RANGE
    clipped = [np.array([1.0, 2.0, 50.0, 49.0])] * 10
    assert choose_max_range(clipped) == 49.995
    mm8 = [np.array([1.0, 8.19, 8.18, 4.0])] * 10
    assert choose_max_range(mm8) == 8.1785
    assert choose_max_range([]) == DEFAULT_MAX_RANGE


def test_field_of_view_convention() -> None:
    sick = Scan(0.0, np.ones(181), np.linspace(-math.pi / 2, math.pi / 2, 181), 80.0)
    assert field_of_view_deg(sick) == pytest.approx(180.0)
    full = Scan(0.0, np.ones(360), -math.pi + np.arange(360) * DEG, 80.0)
    assert field_of_view_deg(full) == 360.0


def test_info_by_hand(tmp_path: Path) -> None:
    text = (
        "PARAM robot_front_laser_max 50.0 nohost 0\n"
        "ODOM 0 0 0 0 0 0 10.0 h 0\n"
        + flaser([1.0, 2.0, 3.0], stamp=10.0)
        + "ODOM 0 0 0 0 0 0 10.5 h 0\n"
        + flaser([1.0, 2.0, 3.0], stamp=12.5)
        + flaser([1.0, 2.0, 3.0], stamp=11.0)  # backwards
        + "SYNC tag 12.0 h 0\n"
    )
    info = CarmenLog(write(tmp_path, text)).info()
    assert (info.format, info.scans, info.beams, info.odometry) == ("carmen", 3, 3, 2)
    assert info.fov_deg == pytest.approx(180.0)
    assert info.max_range == 50.0
    assert info.duration_s == pytest.approx(2.5)
    assert info.extra["messages"] == {"FLASER": 3, "ODOM": 2, "PARAM": 1, "SYNC": 1}
    assert info.extra["stamps_backwards"] == 1
    assert info.extra["bad_lines"] == 0
    assert isinstance(CarmenLog(write(tmp_path, text)), ScanSource)


def test_compressed_inputs(tmp_path: Path) -> None:
    text = "".join(flaser([1.0, 2.0], stamp=float(i)) for i in range(5))
    for name in ("log.gz", "log.bz2", "log.clf"):
        scans, warned = read(write(tmp_path, text, name))
        assert [s.stamp for s in scans] == [0.0, 1.0, 2.0, 3.0, 4.0] and warned == []


def test_stops_early_without_leaking(tmp_path: Path) -> None:
    text = "".join(flaser([1.0, 2.0], stamp=float(i)) for i in range(30000))
    log = CarmenLog(write(tmp_path, text, "log.gz"))
    before = threading.active_count()
    it = iter(log)
    assert next(it).stamp == 0.0
    assert threading.active_count() == before + 1  # the decompressing thread
    it.close()  # stops it
    assert threading.active_count() == before


# --------------------------------------------------------------------------- bad input


def test_truncated_last_line(tmp_path: Path) -> None:
    text = "".join(flaser([1.0, 2.0, 3.0], stamp=float(i)) for i in range(4))
    path = write(tmp_path, text[:-25])  # cut inside the last line's numbers
    scans, warned = read(path)
    assert [s.stamp for s in scans] == [0.0, 1.0, 2.0]
    assert len(warned) == 1
    assert "skipped 1 malformed line(s), first at line 4" in warned[0]
    assert str(path) in warned[0]
    with pytest.raises(DataError, match="line 4: FLASER"):
        list(CarmenLog(path, strict=True))


@pytest.mark.parametrize(
    ("bad", "why"),
    [
        ("FLASER 3 1.0 0 0 0 0 0 0 5.0 h 0\n", "expected 14 fields"),  # ranges missing
        ("FLASER 3 1.0 2.x 3.0 0 0 0 0 0 0 5.0 h 0\n", "not a number"),
        ("FLASER 3 1.0 2.0 3.0 nan 0 0 0 0 0 5.0 h 0\n", "non-finite pose"),
        ("FLASER three 1.0\n", "not an integer"),
        ("ODOM 1 2\n", "expected 10 fields"),
        ("ODOM 1 2 3 0 0 0 inf h 0\n", "non-finite"),
        ("fl@ser 1 2\n", "not a CARMEN message"),
        ("PARAM lonely\n", "without a value"),
    ],
)
def test_malformed_middle_line(tmp_path: Path, bad: str, why: str) -> None:
    good = [flaser([1.0, 2.0, 3.0], stamp=float(i)) for i in range(4)]
    path = write(tmp_path, "".join(good[:2]) + bad + bad + "".join(good[2:]))
    scans, warned = read(path)
    assert [s.stamp for s in scans] == [0.0, 1.0, 2.0, 3.0]
    assert len(warned) == 1
    assert "skipped 2 malformed line(s), first at line 3" in warned[0] and why in warned[0]
    with pytest.raises(DataError, match=f"line 3: .*{why}"):
        list(CarmenLog(path, strict=True))


def test_malformed_robotlaser_and_rawlaser(tmp_path: Path) -> None:
    good = robotlaser([1.0, 2.0], stamp=1.0)
    short = robotlaser([1.0, 2.0], stamp=2.0).replace(" 2 1.0 2.0 ", " 3 1.0 2.0 ", 1)
    nonfinite = robotlaser([1.0, 2.0], stamp=3.0, laser=(1.0, "nan", 0.0))
    path = write(tmp_path, good + short + nonfinite + good.replace(" 1.0 host", " 4.0 host"))
    scans, warned = read(path)
    assert [s.stamp for s in scans] == [1.0, 4.0]
    assert "skipped 2 malformed line(s), first at line 2 (ROBOTLASER1: " in warned[0]
    raw = rawlaser([1.0, 2.0], 1.0) + rawlaser([1.0, 2.0], 2.0).replace(" 2 1.0 2.0", " 2 1.0", 1)
    scans, warned = read(write(tmp_path, raw))
    assert [s.stamp for s in scans] == [1.0]
    assert "first at line 2 (RAWLASER1: " in warned[0]


def test_missing_empty_directory_garbage(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="no such file"):
        CarmenLog(tmp_path / "nope.clf")
    with pytest.raises(DataError, match="directory"):
        CarmenLog(tmp_path)
    empty = write(tmp_path, "", "empty.clf")
    with pytest.raises(DataError, match="not a CARMEN log: file is empty"):
        CarmenLog(empty)
    with pytest.raises(DataError, match="not a CARMEN log: file is empty"):
        CarmenLog(write(tmp_path, "", "empty.gz"))
    garbage = tmp_path / "garbage.bin"
    garbage.write_bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    with pytest.raises(DataError, match=r"garbage.bin: not a CARMEN log"):
        CarmenLog(garbage)
    prose = write(tmp_path, "VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n", "g.g2o")
    with pytest.raises(DataError, match="not a CARMEN log: 2 of the first 2 lines"):
        CarmenLog(prose)
    comments = write(tmp_path, "# just a comment\n", "c.clf")
    with pytest.raises(DataError, match="only comments"):
        CarmenLog(comments)
    for path in (tmp_path / "nope.clf", tmp_path, empty, garbage, prose, comments):
        assert not is_carmen(path)
    assert is_carmen(write(tmp_path, flaser([1.0]), "ok.clf"))


def test_log_without_lasers_warns(tmp_path: Path) -> None:
    scans, warned = read(write(tmp_path, "ODOM 0 0 0 0 0 0 1.0 h 0\n"))
    assert scans == [] and len(warned) == 1 and "no laser messages" in warned[0]


def test_corrupt_gzip_stream(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    text = "".join(flaser(list(rng.uniform(1, 9, 90)), stamp=float(i)) for i in range(1500))
    blob = bytearray(gzip.compress(text.encode()))
    blob[len(blob) // 2 : len(blob) // 2 + 40] = bytes(40)  # wipe a stretch mid-stream
    path = tmp_path / "broken.gz"
    path.write_bytes(bytes(blob))
    scans, warned = read(path)
    assert 0 < len(scans) < 1500
    assert [s.stamp for s in scans[:200]] == [float(i) for i in range(200)]
    assert len(warned) == 1 and ("corrupt" in warned[0] or "malformed" in warned[0])
    with pytest.raises(DataError):
        list(CarmenLog(path, strict=True))


def test_truncated_bzip2(tmp_path: Path) -> None:
    text = "".join(flaser([1.0, 2.0, 3.0], stamp=float(i)) for i in range(20000))
    blob = bz2.compress(text.encode(), compresslevel=1)  # 100 kB blocks
    path = tmp_path / "cut.bz2"
    path.write_bytes(blob[: len(blob) * 2 // 3])
    scans, warned = read(path)
    assert [s.stamp for s in scans] == [float(i) for i in range(len(scans))]
    assert len(warned) == 1 and "compressed data is corrupt" in warned[0]
    with pytest.raises(DataError, match="compressed data is corrupt after line"):
        list(CarmenLog(path, strict=True))


# --------------------------------------------------------------------------- writer


def sample_scans(n: int = 6, beams: int = 8, *, fov: float = 2 * math.pi) -> list[Scan]:
    rng = np.random.default_rng(7)
    step = fov / beams if fov >= 2 * math.pi else fov / (beams - 1)
    angles = -fov / 2 + step * np.arange(beams)
    out = []
    for i in range(n):
        ranges = rng.uniform(0.2, 9.0, beams).round(4)
        out.append(Scan(1000.0 + 0.1 * i, ranges, angles, 10.0, 0.0, rng.normal(size=3), i))
    return out


def assert_same(a: Scan, b: Scan) -> None:
    assert b.stamp == pytest.approx(a.stamp, abs=1e-6)
    np.testing.assert_allclose(b.ranges, a.ranges, atol=5e-5, equal_nan=True)
    np.testing.assert_allclose(b.angles, a.angles, atol=1e-8)
    assert b.max_range == pytest.approx(a.max_range, abs=1e-4)
    np.testing.assert_array_equal(b.valid, a.valid)
    if a.odom is None:
        assert b.odom is None
    else:
        np.testing.assert_allclose(b.odom, a.odom, atol=1e-6)


@pytest.mark.parametrize("name", ["sim.clf", "sim.clf.gz", "sim.log.bz2"])
def test_write_read_round_trip(tmp_path: Path, name: str) -> None:
    scans = sample_scans()
    scans[2].ranges[[0, 1, 2, 3]] = [np.nan, np.inf, 10.0, 0.0]  # invalid beams survive
    scans[3].max_range = math.inf  # "no limit"
    odometry = [(999.95 + 0.1 * i, np.array([0.1 * i, 0.0, 0.01 * i])) for i in range(8)]
    path = tmp_path / name
    assert write_log(path, scans, odometry, params={"robot_frontlaser_offset": 0.25}) == 6
    back, warned = read(path)
    assert warned == []
    assert len(back) == len(scans)
    for a, b in zip(scans, back, strict=True):
        assert_same(a, b)
    info = CarmenLog(path).info()
    assert info.odometry == 8 and info.fov_deg == 360.0 and info.beams == 8
    assert info.extra["laser"] == "ROBOTLASER1"
    lines = (
        (gzip.open if name.endswith("gz") else bz2.open if name.endswith("bz2") else open)(
            path, "rt"
        )
        .read()
        .splitlines()
    )
    body = [ln.split()[0] for ln in lines if not ln.startswith("#")]
    assert body[0] == "PARAM" and body[1] == "ODOM" and body[2] == "ROBOTLASER1"
    assert [p for p in tmp_path.iterdir() if p.name != name] == []  # no temporary left


def test_write_sector_scan_and_rawlaser(tmp_path: Path) -> None:
    sector = sample_scans(3, 181, fov=math.pi)
    path = tmp_path / "sector.clf"
    write_log(path, sector)
    back, _ = read(path)
    for a, b in zip(sector, back, strict=True):
        assert_same(a, b)
    assert CarmenLog(path).info().fov_deg == pytest.approx(180.0)
    # scans without odometry: RAWLASER1, poses from the ODOM stream
    bare = [Scan(s.stamp, s.ranges, s.angles, s.max_range) for s in sector]
    odometry = [(900.0, np.zeros(3)), (1100.0, np.array([2.0, 0.0, 0.0]))]
    write_log(path, bare, odometry)
    back, _ = read(path)
    assert CarmenLog(path).info().extra["laser"] == "RAWLASER1"
    expected_x = 2.0 * (np.array([s.stamp for s in bare]) - 900.0) / 200.0
    np.testing.assert_allclose([b.odom[0] for b in back], expected_x, atol=1e-9)


def test_writer_is_atomic(tmp_path: Path) -> None:
    path = tmp_path / "out.clf"
    path.write_text("old content\n")

    def failing():
        yield from sample_scans(2)
        raise RuntimeError("simulator crashed")

    with pytest.raises(RuntimeError):
        write_log(path, failing())
    assert path.read_text() == "old content\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.clf"]  # no temporary left
    mixed = sample_scans(2)
    mixed[1] = Scan(mixed[1].stamp, mixed[1].ranges, mixed[1].angles, 10.0)
    with pytest.raises(DataError, match="scan 1 lacks an odometry pose"):
        write_log(path, mixed)
    uneven = sample_scans(1)
    uneven[0].angles = uneven[0].angles ** 3 / 10
    with pytest.raises(DataError, match="not evenly spaced"):
        write_log(path, uneven)
    with pytest.raises(DataError, match="nothing to write"):
        write_log(path, [])
    (tmp_path / "folder.clf").mkdir()
    with pytest.raises(DataError, match="cannot write"):
        write_log(tmp_path / "folder.clf", sample_scans(1))
    with pytest.raises(DataError, match="output folder does not exist"):
        write_log(tmp_path / "missing" / "x.clf", sample_scans(1))
    with pytest.raises(UserError, match="hostname"):
        write_log(path, sample_scans(1), hostname="two words")
    with pytest.raises(UserError, match="one ASCII word"):
        write_log(path, sample_scans(1), params={"robot_name": "R2 D2"})
    assert path.read_text() == "old content\n"
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


# --------------------------------------------------------------------------- real data


def test_intel_real_log() -> None:
    """The real Intel log: counts, the first scan by hand, stamps kept in file order."""
    path = shared_file("carmen/intel.clf.bz2")
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)  # no bad line in the real log
        info = CarmenLog(path, strict=True).info()  # one full pass
    assert (info.scans, info.beams, info.odometry) == (13631, 180, 26915)
    assert "beam_counts" not in info.extra  # every scan has 180 beams
    assert info.extra["messages"] == {"FLASER": 13631, "ODOM": 26915, "PARAM": 2}
    assert info.extra["stamps_backwards"] == 631  # file order kept, never sorted
    assert info.fov_deg == pytest.approx(179.0) and info.max_range == 80.0  # -90..+89 deg
    assert info.duration_s == pytest.approx(2691.2, abs=0.5)
    it = iter(CarmenLog(path))
    first, second = next(it), next(it)
    it.close()
    assert (first.index, second.index) == (0, 1)
    assert first.stamp == pytest.approx(976052857.337530, abs=1e-6)
    np.testing.assert_allclose(first.ranges[:3], [1.07, 1.07, 1.08])
    assert first.ranges[89] == 81.83 and not first.valid[89] and first.ranges[179] == 1.05
    np.testing.assert_allclose(first.odom, [0.0, 0.0, -0.002458])
    assert first.max_range == 80.0
    assert first.angles[0] == pytest.approx(-math.pi / 2)
    assert np.diff(first.angles) == pytest.approx(math.pi / 180)


@pytest.mark.parametrize(
    ("name", "scans", "beams", "max_range", "last_deg"),
    [
        ("belgioioso", 395, 361, 80.99, 90.0),
        ("freiburg-101", 292, 360, 80.99, 89.5),
        ("freiburg-campus", 2008, 360, 80.99, 89.5),
        ("intel", 910, 180, 80.0, 89.0),
        ("orebro", 237, 181, 32.7545, 90.0),
        ("seattle", 241, 361, 80.0, 90.0),
    ],
)
def test_corrected_logs(name: str, scans: int, beams: int, max_range: float, last_deg: float):
    path = shared_file(f"carmen-corrected/{name}-corrected.log.gz")
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)  # no bad lines allowed
        info = CarmenLog(path, strict=True).info()
    assert (info.scans, info.beams, info.max_range) == (scans, beams, max_range)
    assert info.extra["bad_lines"] == 0 and info.extra["laser"] == "FLASER"
    assert info.extra["first_angle_deg"] == pytest.approx(-90.0)
    assert info.extra["last_angle_deg"] == pytest.approx(last_deg)


# --------------------------------------------------------------------------- property tests


def _prefix_lines(path: Path, count: int) -> bytes:
    out = []
    with bz2.open(path, "rb") as f:
        for _ in range(count):
            out.append(f.readline())
    return b"".join(out)


def _generated_log() -> bytes:
    rng = np.random.default_rng(11)
    lines = ["PARAM robot_front_laser_max 20.0 nohost 0\n"]
    for i in range(150):
        lines.append(f"ODOM {0.1 * i:.6f} 0.0 0.0 0 0 0 {i:.6f} h 0\n")
        lines.append(flaser(list(rng.uniform(0.1, 25.0, 40)), (0.1 * i, 0, 0), i + 0.5))
    return "".join(lines).encode()


@pytest.fixture(scope="module")
def damage_sources(tmp_path_factory) -> dict[str, tuple[bytes, list[tuple[int, Scan]]]]:
    """name -> (text, [(end offset of the scan's line, scan)]) of the undamaged logs."""
    sources = {"generated": _generated_log()}
    try:
        sources["intel"] = _prefix_lines(shared_file("carmen/intel.clf.bz2"), 300)
    except pytest.skip.Exception:
        pass
    out = {}
    folder = tmp_path_factory.mktemp("damage")
    for name, text in sources.items():
        path = folder / f"{name}.clf"
        path.write_bytes(text)
        ends = np.cumsum([len(x) for x in text.splitlines(keepends=True)])
        scans = list(CarmenLog(path, strict=True))
        starts = [i for i, x in enumerate(text.splitlines()) if x.startswith(b"FLASER")]
        out[name] = (text, [(int(ends[i]), s) for i, s in zip(starts, scans, strict=True)])
    return out


def _check_damaged(text: bytes, reference, damage_at: int, tmp: Path, strict: bool) -> None:
    path = tmp / "damaged.clf"
    path.write_bytes(text)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DataWarning)
            got = list(CarmenLog(path, strict=strict))
    except DataError:
        return
    intact = [s for end, s in reference if end <= damage_at]
    assert len(got) >= len(intact)
    for a, b in zip(intact, got, strict=False):
        assert_same(a, b)
    for s in got:
        assert math.isfinite(s.stamp) and (s.odom is None or np.isfinite(s.odom).all())


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    source=st.sampled_from(["generated", "intel"]),
    where=st.floats(0.0, 1.0),
    byte=st.integers(0, 255),
    truncate=st.booleans(),
    strict=st.booleans(),
)
def test_damage_never_escapes(damage_sources, tmp_path, source, where, byte, truncate, strict):
    if source not in damage_sources:
        pytest.skip("real Intel log not available")
    text, reference = damage_sources[source]
    at = int(where * (len(text) - 1))
    if truncate:
        damaged = text[:at]
    else:
        damaged = text[:at] + bytes([byte]) + text[at + 1 :]
    _check_damaged(damaged, reference, at, tmp_path, strict)


@settings(max_examples=25, deadline=None)
@given(where=st.floats(0.05, 1.0), byte=st.integers(0, 255), kind=st.sampled_from(["gz", "bz2"]))
def test_compressed_damage_never_escapes(tmp_path_factory, where, byte, kind):
    text = _generated_log()
    blob = bytearray(gzip.compress(text) if kind == "gz" else bz2.compress(text))
    at = int(where * (len(blob) - 1))
    blob[at] ^= byte or 1
    path = tmp_path_factory.mktemp("z") / f"log.{kind}"
    path.write_bytes(bytes(blob))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DataWarning)
            for s in CarmenLog(path):
                assert math.isfinite(s.stamp)
    except DataError:
        pass
