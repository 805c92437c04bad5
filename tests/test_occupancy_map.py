"""Occupancy grids: hand-checked ray tracing, sensor model, ROS map files, real maps."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data.atomic_write import write_bytes_atomic
from data.errors import DataError, DataWarning, UserError
from data.types import Scan
from slam.map_io import map_image, render_png, write_map, write_pgm, write_yaml
from slam.occupancy_map import MapConfig, OccupancyGrid, build_occupancy_grid
from tests.helpers import shared_file

RES = 0.05
TIGHT = MapConfig(resolution=RES, margin_cells=0)


def beam_scan(angles, ranges, max_range: float = 10.0) -> Scan:
    """A scan with the given bearings [rad] and readings [m]."""
    return Scan(
        stamp=0.0,
        ranges=np.asarray(ranges, dtype=float),
        angles=np.asarray(angles, dtype=float),
        max_range=max_range,
    )


def cells(mask: np.ndarray) -> set[tuple[int, int]]:
    """``{(col, row)}`` of the True cells of a ``(rows, cols)`` mask."""
    r, c = np.nonzero(mask)
    return {(int(a), int(b)) for a, b in zip(c, r, strict=True)}


# ------------------------------------------------------------------ hand-checked beams


def test_one_beam_along_x_frees_the_cells_before_its_end_and_hits_the_end_cell():
    # Sensor at the centre of cell (0, 0); a 1 m return along +x ends in cell col 20.
    g = build_occupancy_grid([beam_scan([0.0], [1.0])], [[0.025, 0.025, 0.0]], config=TIGHT)
    assert g.shape == (1, 21)
    np.testing.assert_array_equal(g.origin, [0.0, 0.0])
    assert g.misses[0].tolist() == [1] * 20 + [0]
    assert g.hits[0].tolist() == [0] * 20 + [1]
    p = g.probabilities()[0]
    assert p[20] == pytest.approx(0.7)  # one hit: p_hit
    assert np.allclose(p[:20], 0.45)  # one pass: p_miss


def test_diagonal_and_shallow_beams_follow_bresenham_between_cell_centres():
    # 45 degrees to cell (7, 7); atan2(2, 4) to the centre of cell (col 4, row 2).
    ranges = [7 * RES * math.sqrt(2), math.hypot(4, 2) * RES]
    scan = beam_scan([math.pi / 4, math.atan2(2, 4)], ranges)
    g = build_occupancy_grid([scan], [[0.025, 0.025, 0.0]], config=TIGHT)
    assert cells(g.hits > 0) == {(7, 7), (4, 2)}
    diagonal = {(k, k) for k in range(7)}
    shallow = {(0, 0), (1, 1), (2, 1), (3, 2)}  # rows floor(k / 2 + 1/2)
    assert cells(g.misses > 0) == diagonal | shallow
    assert g.misses[0, 0] == 2  # the sensor's cell, passed by both beams


def test_rotated_sensor_pose_turns_the_beam():
    # Sensor facing +y; a beam at bearing -90 degrees points along +x.
    g = build_occupancy_grid(
        [beam_scan([-math.pi / 2], [0.5])], [[0.025, 0.025, math.pi / 2]], config=TIGHT
    )
    assert g.shape == (1, 11)
    assert cells(g.hits > 0) == {(10, 0)}


def test_no_return_beam_clears_up_to_the_cap_but_marks_no_hit():
    cfg = MapConfig(resolution=RES, margin_cells=0, no_return_range=0.5)
    for reading in (10.0, 12.0, np.inf):  # at or above max range, or +inf
        g = build_occupancy_grid([beam_scan([0.0], [reading])], [[0.025, 0.025, 0.0]], config=cfg)
        assert g.hits.sum() == 0
        # Free to x = 0.525 m: cells 0 .. 10, the last one included (nothing ended there).
        assert g.misses[0].tolist() == [1] * 11


def test_invalid_beams_are_ignored():
    pose = [[0.025, 0.025, 0.0]]
    ref = build_occupancy_grid([beam_scan([0.0], [1.0])], pose, config=TIGHT)
    noisy = beam_scan([0.0, 0.5, 1.0, 1.5, 2.0], [1.0, np.nan, 0.0, -np.inf, -1.0])
    g = build_occupancy_grid([noisy], pose, config=TIGHT)
    np.testing.assert_array_equal(g.hits, ref.hits)
    np.testing.assert_array_equal(g.misses, ref.misses)


def test_stray_long_return_is_clipped_to_max_hit_range_without_a_hit():
    cfg = MapConfig(resolution=RES, margin_cells=0, max_hit_range=2.0)
    g = build_occupancy_grid(
        [beam_scan([0.0], [5000.0], max_range=10_000.0)], [[0.025, 0.025, 0.0]], config=cfg
    )
    assert g.shape == (1, 41)  # 2 m, not 5 km
    assert g.hits.sum() == 0
    assert g.misses.sum() == 41


def test_log_odds_sum_and_clamp():
    hits = np.array([[0, 1, 0, 50, 3]], dtype=np.int32)
    misses = np.array([[0, 0, 1, 0, 4]], dtype=np.int32)
    g = OccupancyGrid(hits, misses, origin=[0.0, 0.0], resolution=RES)
    lo = g.log_odds()[0]
    l_hit, l_miss = math.log(0.7 / 0.3), math.log(0.45 / 0.55)
    assert lo[0] == 0.0
    assert lo[1] == pytest.approx(l_hit, rel=1e-6)
    assert lo[2] == pytest.approx(l_miss, rel=1e-6)
    assert lo[3] == pytest.approx(math.log(0.97 / 0.03), rel=1e-6)  # clamped at p_max
    assert lo[4] == pytest.approx(3 * l_hit + 4 * l_miss, rel=1e-6)
    p = g.probabilities()[0]
    assert p[0] == 0.5 and p[3] == pytest.approx(0.97)
    assert g.observed()[0].tolist() == [False, True, True, True, True]
    # Trinary: unknown, occupied, unknown (0.45 is not below 0.196), occupied, occupied.
    assert g.trinary()[0].tolist() == [205, 0, 205, 0, 0]


def test_walls_seen_many_times_become_occupied_and_the_room_free():
    # A 2 m x 2 m room (walls at 0.01 and 2.01 m, inside cells) scanned from its centre
    # 20 times: walls black, inside white.
    angles = np.linspace(-np.pi, np.pi, 720, endpoint=False)
    r = 1.0 / np.maximum(np.abs(np.cos(angles)), np.abs(np.sin(angles)))
    scans = [beam_scan(angles, r) for _ in range(20)]
    g = build_occupancy_grid(scans, np.tile([1.01, 1.01, 0.0], (20, 1)), 0.05)
    occ, free = g.occupied(), g.free()
    centres = g.cell_centres(np.argwhere(np.ones(g.shape, dtype=bool)))
    inner = (np.abs(centres - 1.01).max(axis=1) < 0.9).reshape(g.shape)
    assert not occ[inner].any()
    assert free[inner].mean() > 0.97  # the beams fan out: a few cells far out are missed
    # Cells containing a wall point are occupied.
    wall = g.world_to_cell(np.column_stack([np.full(41, 2.01), np.linspace(0.03, 1.99, 41)]))
    assert occ[wall[:, 0], wall[:, 1]].mean() > 0.9


# ------------------------------------------------------------------ properties


scan_sets = st.lists(
    st.tuples(
        st.floats(-3, 3), st.floats(-3, 3), st.floats(-np.pi, np.pi),
        st.lists(st.floats(0.1, 4.0), min_size=8, max_size=8),
    ),
    min_size=1,
    max_size=6,
)


def _build(items, shift=(0.0, 0.0)):
    angles = np.linspace(-np.pi / 2, np.pi / 2, 8)
    scans = [beam_scan(angles, r, max_range=3.5) for *_, r in items]
    poses = np.array([[x + shift[0], y + shift[1], t] for x, y, t, _ in items])
    return build_occupancy_grid(scans, poses, config=MapConfig(resolution=0.25))


@settings(max_examples=40, deadline=None)
@given(scan_sets, st.randoms(use_true_random=False))
def test_map_does_not_depend_on_scan_order(items, rnd):
    shuffled = list(items)
    rnd.shuffle(shuffled)
    a, b = _build(items), _build(shuffled)
    np.testing.assert_array_equal(a.origin, b.origin)
    np.testing.assert_array_equal(a.hits, b.hits)
    np.testing.assert_array_equal(a.misses, b.misses)


@settings(max_examples=25, deadline=None)
@given(scan_sets, st.integers(1, 40), st.integers(1, 60))
def test_counts_do_not_depend_on_bands_or_group_sizes(items, band, group):
    # A large grid is counted in bands of cells and traced in groups of beams; any
    # band and group size gives the counts of one band and one big group.
    import slam.occupancy_map as om

    whole = _build(items)
    old = om._BAND_CELLS
    try:
        om._BAND_CELLS = band
        angles = np.linspace(-np.pi / 2, np.pi / 2, 8)
        scans = [beam_scan(angles, r, max_range=3.5) for *_, r in items]
        poses = np.array([[x, y, t] for x, y, t, _ in items])
        split = build_occupancy_grid(scans, poses, config=MapConfig(resolution=0.25,
                                                                    chunk_cells=group))
    finally:
        om._BAND_CELLS = old
    np.testing.assert_array_equal(whole.hits, split.hits)
    np.testing.assert_array_equal(whole.misses, split.misses)
    assert split.hits.dtype == split.misses.dtype == np.int32


@settings(max_examples=40, deadline=None)
@given(scan_sets, st.integers(-20, 20), st.integers(-20, 20))
def test_shifting_the_world_by_whole_cells_shifts_only_the_origin(items, i, j):
    # Poses on a 1/64 m lattice and 0.25 m cells keep every coordinate exact in binary.
    items = [(round(x * 64) / 64, round(y * 64) / 64, t, r) for x, y, t, r in items]
    a, b = _build(items), _build(items, shift=(0.25 * i, 0.25 * j))
    np.testing.assert_allclose(b.origin - a.origin, [0.25 * i, 0.25 * j], atol=1e-9)
    np.testing.assert_array_equal(a.hits, b.hits)
    np.testing.assert_array_equal(a.misses, b.misses)


# ------------------------------------------------------------------ bad input and limits


def test_bad_input_is_a_user_error():
    scan = beam_scan([0.0], [1.0])
    with pytest.raises(UserError, match="no scans"):
        build_occupancy_grid([], np.zeros((0, 3)))
    with pytest.raises(UserError, match=r"one .* pose per scan"):
        build_occupancy_grid([scan, scan], [[0.0, 0.0, 0.0]])
    with pytest.raises(UserError, match="finite pose"):
        build_occupancy_grid([scan], [[np.nan, 0.0, 0.0]])
    with pytest.raises(UserError, match="resolution"):
        build_occupancy_grid([scan], [[0.0, 0.0, 0.0]], resolution=-1.0)
    with pytest.raises(UserError, match="p_miss"):
        MapConfig(p_miss=0.6)


def test_scans_with_non_finite_poses_are_skipped_with_one_warning():
    scan = beam_scan([0.0], [1.0])
    with pytest.warns(DataWarning, match="skipped 2 scans"):
        g = build_occupancy_grid(
            [scan, scan, scan], [[0.025, 0.025, 0.0], [np.nan, 0, 0], [0, np.inf, 0]], config=TIGHT
        )
    assert g.hits.sum() == 1 and g.shape == (1, 21)


def test_too_large_a_map_is_coarsened_with_a_warning():
    cfg = MapConfig(resolution=0.05, max_cells=10_000, max_hit_range=50.0)
    scans = [beam_scan([0.0, np.pi / 2], [20.0, 20.0], max_range=30.0)]
    with pytest.warns(DataWarning, match="too large"):
        g = build_occupancy_grid(scans, [[0.0, 0.0, 0.0]], config=cfg)
    assert g.shape[0] * g.shape[1] <= 10_000
    assert g.resolution == pytest.approx(0.05 * round(g.resolution / 0.05))
    assert g.config.resolution == g.resolution
    assert g.hits.sum() == 2


# ------------------------------------------------------------------ ROS map files


def read_map_yaml(path: Path) -> dict[str, object]:
    """A minimal reader of the flat ``key: value`` map YAML (test-side, independent)."""
    out: dict[str, object] = {}
    for line in path.read_text().splitlines():
        key, _, value = line.partition(":")
        value = value.strip()
        if value.startswith("["):
            out[key.strip()] = [float(v) for v in value.strip("[]").split(",")]
        else:
            try:
                out[key.strip()] = float(value) if "." in value else int(value)
            except ValueError:
                out[key.strip()] = value
    return out


def read_pgm(path: Path) -> np.ndarray:
    """Binary PGM (P5, maxval < 256) as an ``(H, W)`` uint8 array, first row first."""
    data = path.read_bytes()
    fields: list[bytes] = []
    pos = 0
    while len(fields) < 4:
        while data[pos : pos + 1].isspace():
            pos += 1
        if data[pos : pos + 1] == b"#":
            pos = data.index(b"\n", pos) + 1
            continue
        end = pos
        while not data[end : end + 1].isspace():
            end += 1
        fields.append(data[pos:end])
        pos = end
    assert fields[0] == b"P5"
    w, h, maxval = int(fields[1]), int(fields[2]), int(fields[3])
    assert maxval == 255
    pixels = np.frombuffer(data[pos + 1 :], dtype=np.uint8)
    assert pixels.size == w * h
    return pixels.reshape(h, w)


def ros_cells(yaml_path: Path) -> tuple[np.ndarray, dict[str, object]]:
    """What ROS map_server makes of a map: ``(H, W)`` int8 0 / 100 / -1, row 0 = bottom."""
    meta = read_map_yaml(yaml_path)
    img = read_pgm(yaml_path.parent / str(meta["image"]))
    occ = (255 - img.astype(float)) / 255.0  # negate: 0
    assert meta["negate"] == 0 and meta["mode"] == "trinary"
    out = np.full(img.shape, -1, dtype=np.int8)
    out[occ > meta["occupied_thresh"]] = 100
    out[occ < meta["free_thresh"]] = 0
    return out[::-1], meta  # the loader puts image row 0 at the top of the map


def test_pgm_and_yaml_round_trip_as_ros_map_server_reads_them(tmp_path):
    # Walls at y = 1.01 m (top) and x = 0.11 m / 3.91 m (sides), seen from (2.01, 0.11).
    angles = np.linspace(0.0, np.pi, 181)
    with np.errstate(divide="ignore"):
        r = np.minimum(0.9 / np.abs(np.sin(angles)), 1.9 / np.abs(np.cos(angles)))
    scans = [beam_scan(angles, r, max_range=2.5) for _ in range(5)]
    g = build_occupancy_grid(scans, np.tile([2.01, 0.11, 0.0], (5, 1)), 0.05)
    paths = write_map(g, tmp_path / "out", stem="map", trajectory_xy=[[2.0, 0.1], [2.0, 0.2]])
    assert {p.name for p in paths.values()} == {"map.pgm", "map.yaml", "map.png"}
    assert not list((tmp_path / "out").glob(".*tmp"))
    cells_ros, meta = ros_cells(paths["yaml"])
    assert meta["image"] == "map.pgm"
    assert meta["resolution"] == pytest.approx(0.05)
    np.testing.assert_allclose(meta["origin"], [g.origin[0], g.origin[1], 0.0], atol=1e-9)
    assert set(meta) == {"image", "mode", "resolution", "origin", "negate",
                         "occupied_thresh", "free_thresh"}
    # Every cell reads back as the grid classifies it, with map row 0 at the bottom.
    expect = np.full(g.shape, -1, dtype=np.int8)
    expect[g.free()] = 0
    expect[g.occupied()] = 100
    np.testing.assert_array_equal(cells_ros, expect)
    # Orientation: the wall at y = 1.01 m is near the top of the image, not the bottom.
    img = read_pgm(paths["pgm"])
    wall_row = int(np.floor((1.01 - g.origin[1]) / g.resolution))  # map row, from the bottom
    assert g.shape[0] - 1 - wall_row <= 3  # image row, from the top
    assert (img[g.shape[0] - 1 - wall_row] == 0).sum() > 60
    assert (cells_ros[wall_row] == 100).sum() > 60
    # The sensor's cell, reckoned from the lower-left origin, is free.
    col, row = np.floor((np.array([2.01, 0.11]) - g.origin) / g.resolution).astype(int)
    assert cells_ros[row, col] == 0


def test_written_files_replace_old_ones_and_errors_name_the_file(tmp_path):
    grid = OccupancyGrid(np.ones((2, 3), np.int32), np.zeros((2, 3), np.int32), [1.5, -2.0], 0.1)
    (tmp_path / "map.yaml").write_text("old")
    write_yaml(grid, tmp_path / "map.yaml", "map.pgm")
    assert read_map_yaml(tmp_path / "map.yaml")["origin"] == [1.5, -2.0, 0.0]
    write_pgm(grid, tmp_path / "map.pgm")
    assert read_pgm(tmp_path / "map.pgm").tolist() == [[0, 0, 0], [0, 0, 0]]
    with pytest.raises(DataError, match="does not exist"):
        write_bytes_atomic(tmp_path / "missing" / "map.pgm", b"x")
    (tmp_path / "file").write_text("not a directory")
    with pytest.raises(DataError, match="file"):
        write_map(grid, tmp_path / "file")
    with pytest.raises(UserError):
        write_yaml(grid, tmp_path / "x.yaml", "bad: name")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "map.pgm", "map.yaml"]


def test_png_picture_scales_and_draws_the_overlays(tmp_path):
    import cv2

    grid = OccupancyGrid(
        np.zeros((20, 40), np.int32), np.full((20, 40), 10, np.int32), [0.0, 0.0], 0.1
    )
    img = map_image(grid, trajectory_xy=[[0.5, 0.5, 0.0], [3.5, 0.5, 0.1]],
                    loops=[[0.5, 1.5, 3.5, 1.5]], scale=4,
                    appearance_loops=[[0.5, 1.0, 3.5, 1.0]])
    assert img.shape == (80, 160, 3)
    # Trajectory at y = 0.5 m: image row (2 - 0.5) / 0.1 * 4 = 60, blue-ish.
    assert img[60, 20:140, 0].min() > img[60, 20:140, 2].max()
    # Loop line at y = 1.5 m: image row 20, red-ish.
    assert img[20, 20:140, 2].min() > img[20, 20:140, 0].max()
    # Appearance loop at y = 1.0 m: image row 40, green-ish.
    row = img[40, 20:140].astype(int)
    assert (row[:, 1] > row[:, 0]).all() and (row[:, 1] > row[:, 2]).all()
    assert (img[5, :, 0] == 254).all()  # free elsewhere
    path = render_png(grid, tmp_path / "m.png", trajectory_xy=[[0.5, 0.5]])
    back = cv2.imread(str(path))
    assert back is not None and back.shape[2] == 3
    render_png(grid, tmp_path / "plain.png")
    assert cv2.imread(str(tmp_path / "plain.png")).shape[:2] == (20 * 8, 40 * 8)


# ------------------------------------------------------------------ real and simulated maps


def test_map_of_the_simulated_box_world_from_ground_truth_is_sharp():
    from data.sim import simulate_run

    run = simulate_run("box")
    gt = run.ground_truth.xytheta()
    g = build_occupancy_grid(run.scans[::3], gt[::3], 0.05)
    centres = g.cell_centres(np.argwhere(np.ones(g.shape, dtype=bool)))
    dist = run.world.distance_to_walls(centres).reshape(g.shape)
    occ = g.occupied()
    near_wall = (dist < 0.5 * g.resolution) & g.observed()
    assert occ[near_wall].mean() > 0.85
    # No occupied cell farther than two cells from a wall.
    assert not occ[dist > 2 * g.resolution].any()
    # Driving-lane free space is free.
    lane = g.world_to_cell(gt[:, :2])
    assert g.free()[lane[:, 0], lane[:, 1]].all()


def test_intel_map_from_corrected_poses_puts_scan_end_points_on_walls():
    from scipy import ndimage

    from data.carmen import CarmenLog

    scans = list(CarmenLog(shared_file("carmen-corrected/intel-corrected.log.gz")))
    poses = np.array([s.odom for s in scans])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no coarsening, no skipped scans
        g = build_occupancy_grid(scans, poses, 0.05)
    # The Intel lab is about 30 m x 30 m.
    x0, x1, y0, y1 = g.extent
    assert 25 < x1 - x0 < 60 and 25 < y1 - y0 < 60
    # End points of the scans lie on (within one cell of) occupied cells.
    occ = ndimage.binary_dilation(g.occupied(), iterations=1)
    ends = np.concatenate([
        (p[:2] + s.points() @ np.array([[np.cos(p[2]), np.sin(p[2])],
                                        [-np.sin(p[2]), np.cos(p[2])]]))
        for s, p in zip(scans[::10], poses[::10], strict=True)
    ])
    rc = g.world_to_cell(ends)
    assert occ[rc[:, 0], rc[:, 1]].mean() > 0.9
    # And the robot drove through free space.
    lane = g.world_to_cell(poses[:, :2])
    assert g.free()[lane[:, 0], lane[:, 1]].mean() > 0.95
