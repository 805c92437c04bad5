"""Place data sets of the benchmark: simulator, MPEG-7 folders, robot places from corrected logs."""

from __future__ import annotations

import warnings
from itertools import pairwise
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data.carmen import write_log
from data.errors import DataError, UserError
from data.raycast import LaserModel, cast
from evaluation.place_datasets import (
    RobotPlacesConfig,
    _capped,
    _membership_counts,
    choose_places,
    load_dataset,
    mpeg7_places,
    path_length,
    robot_log_places,
    robot_places,
    sim_places,
)
from loopclosure.polygon import polygon_from_scan
from tests.helpers import shared_file

# ---------------------------------------------------------------- simulator


def test_sim_places_shapes_labels_and_determinism() -> None:
    a = sim_places("box", seed=3, places=3, scans_per_place=4)
    polys, labels, desc = a
    assert len(polys) == 12 and labels.shape == (12,)
    assert list(labels) == [f"place{i:02d}" for i in range(3) for _ in range(4)]
    assert desc["shapes"] == 12 and desc["classes"] == 3 and desc["kind"] == "box"
    assert desc["class_sizes"] == {"place00": 4, "place01": 4, "place02": 4}
    assert desc["scale_invariant"] is False and desc["fov_deg"] == pytest.approx(360.0)
    b = sim_places("box", seed=3, places=3, scans_per_place=4)
    c = sim_places("box", seed=4, places=3, scans_per_place=4)
    assert all(np.array_equal(p.vertices, q.vertices) for p, q in zip(a[0], b[0], strict=True))
    assert not np.array_equal(a[0][0].vertices, c[0][0].vertices)
    # 360-degree scans close without the sensor origin as a vertex.
    assert all(np.linalg.norm(p.vertices, axis=1).min() > 0.2 for p in polys)


def test_load_dataset_specs() -> None:
    with pytest.raises(UserError, match="unknown data set"):
        load_dataset("kitchen")
    with pytest.raises(UserError, match="takes no folder"):
        load_dataset("box:/tmp")
    with pytest.raises(UserError, match="needs a folder"):
        load_dataset("mpeg7")
    with pytest.raises(UserError, match="needs a folder"):
        load_dataset("robot:")
    with pytest.raises(DataError, match="no such folder"):
        load_dataset("mpeg7:/nonexistent/folder")
    with pytest.raises(DataError, match="no such folder"):
        load_dataset("robot:/nonexistent/folder")


# ---------------------------------------------------------------- MPEG-7


def _write_shapes(folder: Path) -> None:
    """Three discs and three squares of different sizes and positions (64 x 64 PNG)."""
    for k in range(3):
        img = np.zeros((64, 64), np.uint8)
        cv2.circle(img, (30 + k, 32), 10 + 4 * k, 255, -1)
        cv2.imwrite(str(folder / f"disc-{k + 1}.png"), img)
        img = np.zeros((64, 64), np.uint8)
        s = 8 + 5 * k
        cv2.rectangle(img, (32 - s, 32 - s), (32 + s, 32 + s), 255, -1)
        cv2.imwrite(str(folder / f"square-{k + 1}.png"), img)


def test_mpeg7_folder(tmp_path: Path) -> None:
    _write_shapes(tmp_path)
    polys, labels, desc = load_dataset(f"mpeg7:{tmp_path}")
    assert list(labels) == ["disc"] * 3 + ["square"] * 3
    assert desc["scale_invariant"] is True and desc["units"] == "px"
    assert desc["shapes"] == 6 and desc["classes"] == 2
    # a disc of radius 10 px: the contour runs through the boundary pixels' centres and
    # is smoothed, so its area is a little below pi 10^2 (about pi 9.1^2)
    assert polys[0].area == pytest.approx(np.pi * 100, rel=0.2)
    assert polys[0].area < polys[1].area < polys[2].area


def test_mpeg7_empty_or_single_class(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="no image files"):
        mpeg7_places(tmp_path)
    img = np.zeros((32, 32), np.uint8)
    cv2.circle(img, (16, 16), 8, 255, -1)
    cv2.imwrite(str(tmp_path / "disc-1.png"), img)
    cv2.imwrite(str(tmp_path / "disc-2.png"), img)
    with pytest.raises(UserError, match="at least two"):
        mpeg7_places(tmp_path)


def test_mpeg7_subset_real() -> None:
    folder = shared_file("mpeg7-subset")
    polys, _, desc = mpeg7_places(folder)
    assert len(polys) == 200 and desc["classes"] == 10
    assert set(desc["class_sizes"].values()) == {20}


# ---------------------------------------------------------------- robot rule


def test_path_length_hand_checked() -> None:
    poses = np.array([[0, 0, 0], [3, 4, 1], [3, 4, 2], [3, 0, 0.0]])
    assert np.allclose(path_length(poses), [0, 5, 5, 9])
    poses[1, 0] = np.nan  # steps to and from a non-finite position count zero
    assert np.allclose(path_length(poses), [0, 0, 0, 4])


def _brute_counts(xy: np.ndarray, s: np.ndarray, radius: float, gap: float):
    members, passes = [], []
    for i in range(len(xy)):
        idx = [j for j in range(len(xy)) if np.hypot(*(xy[j] - xy[i])) <= radius]
        members.append(len(idx))
        passes.append(1 + sum(s[b] - s[a] > gap for a, b in pairwise(idx)))
    return np.array(members), np.array(passes)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000), st.integers(2, 60), st.integers(1, 7))
def test_membership_counts_match_brute_force(seed: int, n: int, block: int) -> None:
    rng = np.random.default_rng(seed)
    xy = np.cumsum(rng.normal(0, 0.6, size=(n, 2)), axis=0) % 3.0  # a walk folded on 3 x 3 m
    s = path_length(np.column_stack([xy, np.zeros(n)]))
    got = _membership_counts(xy, s, 0.5, 2.0, block=block)
    want = _brute_counts(xy, s, 0.5, 2.0)
    assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])


def test_capped_round_robin_over_passes() -> None:
    passes = np.array([0, 0, 0, 0, 1, 1, 2])
    rng = np.random.default_rng(0)
    keep = _capped(passes, 3, rng)
    assert sorted(passes[keep].tolist()) == [0, 1, 2]  # one scan of each pass
    keep5 = _capped(passes, 5, np.random.default_rng(0))
    assert np.bincount(passes[keep5]).tolist() == [2, 2, 1]
    assert np.array_equal(_capped(passes, 10, rng), np.arange(7))


def _shuttle(passes: int, step: float = 0.25, length: float = 16.0,
             both_ways: bool = True) -> np.ndarray:
    """Poses shuttling along y = 5 m between x = 2 and x = 2 + length; returning along
    y = 8 m instead when not `both_ways` (then every pass on y = 5 heads +x)."""
    xs = np.arange(2.0, 2.0 + length + 1e-9, step)
    legs = []
    for k in range(passes):
        if k % 2 == 0:
            legs.append(np.column_stack([xs, np.full_like(xs, 5.0), np.zeros_like(xs)]))
        else:
            y = 5.0 if both_ways else 8.0
            legs.append(np.column_stack([xs[::-1], np.full_like(xs, y), np.full_like(xs, np.pi)]))
    return np.vstack(legs)


def test_choose_places_rule() -> None:
    cfg = RobotPlacesConfig(max_scans=7)
    poses = _shuttle(4)
    places = choose_places(poses, cfg, seed=1)
    assert len(places) >= 3
    centres = poses[[p.centre for p in places], :2]
    d = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    assert d[~np.eye(len(places), dtype=bool)].min() > cfg.min_separation
    for p in places:
        assert cfg.min_scans <= len(p.members) <= cfg.max_scans
        assert np.all(np.linalg.norm(poses[p.members, :2] - poses[p.centre, :2], axis=1)
                      <= cfg.radius)
        # near a turn-around the way out and back is one pass (path < pass_gap between)
        assert p.n_passes >= 2 and len(np.unique(p.passes)) == p.n_passes  # each pass kept
        assert p.heading_spread_deg == pytest.approx(180.0)
        assert np.all(np.diff(p.members) > 0)
    # greedy: the most passes first; inside the shuttle 5 scans per pass are within
    # 0.5 m (inclusive, 0.25 m apart)
    assert places[0].n_passes == 4 and places[0].n_members == 20
    assert [p.n_passes for p in places] == sorted((p.n_passes for p in places), reverse=True)
    again = choose_places(poses, cfg, seed=1)
    assert all(np.array_equal(a.members, b.members) for a, b in zip(places, again, strict=True))
    other = choose_places(poses, cfg, seed=2)
    assert any(not np.array_equal(a.members, b.members)
               for a, b in zip(places, other, strict=True))


def test_choose_places_needs_several_passes_and_headings() -> None:
    assert choose_places(_shuttle(1)) == []  # one pass only
    # passes on y = 5 m all head +x (and on y = 8 m all head -x): not varied
    assert choose_places(_shuttle(4, both_ways=False)) == []
    relaxed = RobotPlacesConfig(min_heading_spread_deg=0.0)
    assert len(choose_places(_shuttle(4, both_ways=False), relaxed)) >= 2


def _segments() -> np.ndarray:
    """A 20 x 12 m room with a few boxes, as ``(S, 2, 2)`` wall segments [m]."""
    def rect(x0: float, y0: float, x1: float, y1: float) -> list:
        c = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
        return [[c[i], c[(i + 1) % 4]] for i in range(4)]
    segs = rect(0, 0, 20, 12) + rect(4, 1, 5, 3) + rect(9, 9, 11, 10) + rect(14, 2, 15.5, 2.5)
    segs += rect(16, 8, 17, 11) + rect(7, 1.5, 8, 2)
    return np.asarray(segs, dtype=float)


def _write_sim_log(path: Path, laser: LaserModel) -> None:
    poses = _shuttle(4, step=0.3, length=10.0)
    ranges = cast(_segments(), poses, laser, np.random.default_rng(0))
    scans = [laser.scan(r, stamp=0.1 * i, odom=p, index=i)
             for i, (r, p) in enumerate(zip(ranges, poses, strict=True))]
    write_log(path, scans)


def test_robot_places_on_simulated_logs(tmp_path: Path) -> None:
    _write_sim_log(tmp_path / "full-corrected.log.gz", LaserModel(fov_deg=360.0, beams=360))
    _write_sim_log(tmp_path / "half-corrected.log.gz",
                   LaserModel(fov_deg=180.0, beams=181, noise_sigma=0.0, dropout=0.0))
    (tmp_path / "ignored.log").write_text("not a corrected log name\n")
    cfg = RobotPlacesConfig(max_scans=6)
    polys, labels, desc = robot_places(tmp_path, cfg, seed=0)
    logs = desc["logs"]
    assert list(logs) == ["full", "half"]
    full, half = logs["full"], logs["half"]
    assert full["fov_deg"] == pytest.approx(360.0) and half["fov_deg"] == pytest.approx(180.0)
    assert full["places"] >= 2 and half["places"] == full["places"]
    assert all(n == 6 for n in full["scans_per_place"] + half["scans_per_place"])
    assert full["virtual_scans"] == 0 and half["virtual_scans"] == half["shapes"]
    assert len(polys) == full["shapes"] + half["shapes"] == desc["shapes"]
    assert sum(full["scans_per_place"]) == full["shapes"]
    assert labels[0] == "full/place00" and labels[-1].startswith("half/place")
    assert desc["classes"] == full["places"] + half["places"]
    # a virtual scan closes the circle: no sensor-origin vertex, vertices all around
    for p in polys[full["shapes"]:]:
        bearings = np.arctan2(p.vertices[:, 1], p.vertices[:, 0])
        assert np.linalg.norm(p.vertices, axis=1).min() > 0.5
        assert np.ptp(bearings) > np.radians(350)
    # one file works as well and gives the same polygons for its log
    one, lab1, _ = robot_log_places(tmp_path / "full-corrected.log.gz", cfg, seed=0)
    assert [len(p) for p in one] == [len(p) for p in polys[: len(one)]]
    assert lab1 == list(labels[: len(one)])


def test_robot_log_real_scan_when_360(tmp_path: Path) -> None:
    """A 360-degree laser's own scan is the polygon (no virtual scan)."""
    from data.carmen import CarmenLog

    path = tmp_path / "full-corrected.log.gz"
    _write_sim_log(path, LaserModel(fov_deg=360.0, beams=360))
    scans = list(CarmenLog(path))
    poses = np.array([s.odom for s in scans])
    cfg = RobotPlacesConfig(max_scans=5)
    places = choose_places(poses, cfg, seed=0)
    polys, _, _ = robot_log_places(path, cfg, seed=0)
    first = polygon_from_scan(scans[int(places[0].members[0])])
    assert np.allclose(polys[0].vertices, first.vertices)


def test_robot_range_cap_keeps_the_polygon_within_it(tmp_path: Path) -> None:
    """With range_cap the places are the same scans, every vertex within the cap and
    the nearer ones unchanged; a non-positive cap is a user error."""
    _write_sim_log(tmp_path / "half-corrected.log.gz",
                   LaserModel(fov_deg=180.0, beams=181, noise_sigma=0.0, dropout=0.0))
    full, lab_full, _ = robot_places(tmp_path, RobotPlacesConfig(max_scans=5), seed=0)
    capped, lab_cap, desc = robot_places(
        tmp_path, RobotPlacesConfig(max_scans=5, range_cap=3.0), seed=0)
    assert list(lab_cap) == list(lab_full) and desc["config"]["range_cap"] == 3.0
    for a, b in zip(full, capped, strict=True):
        rb = np.linalg.norm(b.vertices, axis=1)
        assert rb.max() <= 3.0 + 1e-9 and np.isclose(rb, 3.0).any()
        ra = np.linalg.norm(a.vertices, axis=1)
        near = {tuple(np.round(v, 9)) for v in a.vertices[ra < 2.9]}
        assert near <= {tuple(np.round(v, 9)) for v in b.vertices}
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(UserError, match="range_cap"):
            RobotPlacesConfig(range_cap=bad)


def test_robot_folder_errors(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="no corrected CARMEN logs"):
        robot_places(tmp_path)
    path = tmp_path / "line-corrected.log.gz"
    laser = LaserModel(fov_deg=360.0, beams=90)
    poses = _shuttle(1, step=0.3)
    scans = [laser.scan(r, stamp=0.1 * i, odom=p, index=i) for i, (r, p) in
             enumerate(zip(cast(_segments(), poses, laser), poses, strict=True))]
    write_log(path, scans)
    with pytest.raises(DataError, match="no place passed several times"):
        robot_places(tmp_path)
    with pytest.raises(UserError, match="max_scans"):
        RobotPlacesConfig(min_scans=5, max_scans=4)


def test_robot_real_corrected_log() -> None:
    """Seattle's corrected log (241 scans, 180-degree SICK): places with several passes."""
    path = shared_file("carmen-corrected/seattle-corrected.log.gz")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no degenerate polygons expected
        a = robot_places(path, seed=0)
    facts = a.description["logs"]["seattle"]
    assert facts["places"] >= 3 and facts["scans"] == 241
    assert facts["virtual_scans"] == a.description["shapes"] == len(a.polygons)
    assert all(5 <= n <= 20 for n in facts["scans_per_place"])
    assert all(n >= 2 for n in facts["passes_per_place"])
    assert all(s >= 45 for s in facts["heading_spread_deg"])
    assert a.description["classes"] == facts["places"]
    # 360-degree virtual scans of rooms and corridors: no origin vertex, metres
    assert all(np.linalg.norm(p.vertices, axis=1).min() > 0.1 for p in a.polygons)
    assert all(1.0 < p.area < 2000.0 for p in a.polygons)
