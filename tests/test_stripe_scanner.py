"""The laser-stripe scanner simulator: geometry, visibility, determinism, meshes, Daily set."""

from __future__ import annotations

import gzip
import warnings

import numpy as np
import pytest

from data.errors import DataError, DataWarning
from data.stripe_scanner.daily import DAILY_CLASSES, daily_set, make_object
from data.stripe_scanner.meshes import (
    edges_watertight,
    load_mesh,
    load_mesh_folder,
    mesh_from_arrays,
    read_labels,
    ycb_labels,
)
from data.stripe_scanner.scanner import ScannerConfig, _Camera, scan_mesh, scan_meshes
from tests.helpers import shared_file

_BOX_FACES = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                       [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])


def box(hx: float, hy: float, height: float, name: str = "box"):
    v = np.array([[-hx, -hy, 0], [hx, -hy, 0], [hx, hy, 0], [-hx, hy, 0],
                  [-hx, -hy, height], [hx, -hy, height], [hx, hy, height], [-hx, hy, height]],
                 float)
    return mesh_from_arrays(v, _BOX_FACES, name)


CLEAN = dict(yaw_range_deg=0.0, turn_probability=0.0, position_jitter=0.0, pixel_noise=0.0,
             speckle=0.0, gap_rate=0.0, reflectance=(1.0, 1.0), quantize=False)


def _table_y(cfg: ScannerConfig, u: np.ndarray) -> np.ndarray:
    """Table y [m] seen in image column u on the laser plane (inverse of the projection)."""
    depth = cfg.standoff / np.cos(cfg.alpha)
    return (u - cfg.width / 2) * depth / cfg.focal


def test_box_top_projects_where_the_geometry_says():
    cfg = ScannerConfig(**CLEAN, step=0.005)
    scan = scan_mesh(box(0.03, 0.02, 0.05), cfg, seed=0)
    cam = _Camera(cfg)
    # Every stripe is the flat top: one row, the projection of z = 0.05 at y = 0.
    x_t = scan.positions[len(scan.positions) // 2]
    u, v, _ = cam.project(np.array([x_t, 0.0, 0.05]), cam.centre(x_t))
    mid = scan.stripes[len(scan.stripes) // 2]
    assert np.median(mid[:, 1]) == pytest.approx(v, abs=0.3)
    # Width of the top: 40 mm -> focal * 0.04 / depth columns.
    depth = cfg.standoff / np.cos(cfg.alpha) - 0.05 * np.cos(cfg.alpha)
    assert len(mid) == pytest.approx(cfg.focal * 0.04 / depth, abs=3)
    assert u == pytest.approx(cfg.width / 2, abs=1e-6)
    # One stripe per 5 mm of box length (60 mm), give or take the ends.
    assert abs(len(scan.stripes) - 12) <= 1
    assert scan.empty_positions == 0


def test_laser_shadow_and_camera_occlusion_on_a_box():
    hb, w = 0.10, 0.05
    cfg = ScannerConfig(**CLEAN, step=0.004, include_table=True, margin=0.08)
    scan = scan_mesh(box(0.04, w, hb), cfg, seed=0)
    frames = dict(zip(np.round(scan.positions, 6), scan.stripes, strict=True))
    xs = np.array(sorted(frames))
    # Laser shadow: a frame through the box; the table beside the box between
    # |y| = w and w * h / (h - hb) is not lit (the fan passes over the box edge).
    x_mid = xs[np.argmin(np.abs(xs))]
    s = frames[x_mid]
    on_table = np.abs(s[:, 1] - cfg.table_row) < 0.5
    y_table = _table_y(cfg, s[on_table, 0])
    shadow_out = w * cfg.standoff / (cfg.standoff - hb)
    in_shadow = (np.abs(y_table) > w + 0.002) & (np.abs(y_table) < shadow_out - 0.002)
    assert on_table.sum() > 200 and not in_shadow.any()
    assert (np.abs(y_table) > shadow_out + 0.002).sum() > 100  # lit table further out
    assert (~on_table).sum() > 100  # the top of the box is seen
    # Camera occlusion: just beyond the box (+x side) the camera, 30 degrees behind the
    # laser, looks over the box: the table behind it (|y| < w) is hidden.
    x_b = 0.04
    hidden = xs[(xs > x_b + 0.01) & (xs < x_b + hb * np.tan(cfg.alpha) - 0.01)]
    assert len(hidden) >= 3
    for x in hidden:
        y = _table_y(cfg, frames[x][:, 0])
        assert not np.any(np.abs(y) < 0.9 * w)
        assert np.any(np.abs(y) > 1.2 * w)
    # Far beyond the shadow of the camera the whole line is back.
    x_far = xs[xs > x_b + hb * np.tan(cfg.alpha) + 0.01][0]
    assert np.any(np.abs(_table_y(cfg, frames[x_far][:, 0])) < 0.5 * w)


def test_same_seed_same_scan_and_noise_changes_it():
    mesh = make_object("apple", np.random.default_rng(1))
    cfg = ScannerConfig(step=0.004)
    a = scan_mesh(mesh, cfg, seed=7)
    b = scan_mesh(mesh, cfg, seed=7)
    c = scan_mesh(mesh, cfg, seed=8)
    assert a.pose == b.pose and len(a.stripes) == len(b.stripes)
    for x, y in zip(a.stripes, b.stripes, strict=True):
        np.testing.assert_array_equal(x, y)
    assert a.pose != c.pose
    # Quantised rows: whole pixels, one point per column, ordered by column.
    for s in a.stripes:
        assert np.all(s[:, 1] == np.rint(s[:, 1])) and np.all(np.diff(s[:, 0]) > 0)


def test_object_without_stripe_is_a_clear_error():
    # A zero-thickness vertical wall: the laser only grazes it.
    v = np.array([[-0.02, 0, 0], [0.02, 0, 0], [0.02, 0, 0.03], [-0.02, 0, 0.03]], float)
    wall = mesh_from_arrays(v, np.array([[0, 1, 2], [0, 2, 3]]), "wall")
    cfg = ScannerConfig(yaw_range_deg=0.0, turn_probability=0.0, position_jitter=0.0)
    with pytest.raises(DataError, match="wall: the scanner saw no stripe"):
        scan_mesh(wall, cfg)
    with pytest.warns(DataWarning, match="1 objects gave no stripe"):
        scans, source, failed = scan_meshes([box(0.01, 0.01, 0.01), wall], cfg)
    assert source == [0] and list(failed) == ["wall"] and len(scans) == 1


def test_tall_and_wide_objects_are_scanned_from_higher_up():
    from data.stripe_scanner.scanner import fits_image, fitted_config, place_on_table

    cfg = ScannerConfig(**CLEAN)
    # The top of a 0.33 m post images below row 600 at 0.6 m (row ~610, by the camera
    # model): without the fit no stripe at all; with it the scanner rises and sees it.
    post = box(0.03, 0.03, 0.33, "post")
    with pytest.raises(DataError, match="post: the scanner saw no stripe"):
        scan_mesh(post, ScannerConfig(**CLEAN, fit_object=False))
    tall = scan_mesh(post, cfg)
    assert tall.standoff > 0.6 and tall.field_of_view / tall.standoff == pytest.approx(0.5)
    rows = np.concatenate([t[:, 1] for t in tall.stripes])
    assert rows.max() < cfg.height - cfg.fit_margin_px
    # A 0.36 m wide plate overflows the 0.30 m field of view: clipped at column 0 and
    # 711 without the fit, inside the image with it.
    plate = box(0.06, 0.18, 0.02, "plate")
    clipped = scan_mesh(plate, ScannerConfig(**CLEAN, fit_object=False))
    assert min(t[:, 0].min() for t in clipped.stripes) == 0
    wide = scan_mesh(plate, cfg)
    assert min(t[:, 0].min() for t in wide.stripes) > 0
    assert max(t[:, 0].max() for t in wide.stripes) < cfg.width - 1
    # Objects that fit keep the configured scanner exactly.
    small = place_on_table(box(0.03, 0.03, 0.05).vertices, 0.0, (0.0, 0.0))
    assert fits_image(small, cfg) and fitted_config(small, cfg) is cfg
    assert scan_mesh(box(0.03, 0.03, 0.05), cfg).standoff == cfg.standoff


# ----------------------------------------------------------------------- meshes


def test_mesh_formats_compression_and_bad_files(tmp_path):
    import trimesh

    m = box(0.02, 0.01, 0.03)
    tm = trimesh.Trimesh(m.vertices, m.faces, process=False)
    for ext in ("ply", "obj", "stl"):
        data = tm.export(file_type=ext)
        data = data.encode() if isinstance(data, str) else data
        (tmp_path / f"b.{ext}").write_bytes(data)
        (tmp_path / f"b.{ext}.gz").write_bytes(gzip.compress(data))
        for name in (f"b.{ext}", f"b.{ext}.gz"):
            got = load_mesh(tmp_path / name)
            assert got.name == "b" and got.watertight
            np.testing.assert_allclose(got.extent, [0.04, 0.02, 0.03], atol=1e-9)
    (tmp_path / "junk.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nnonsense\n")
    with pytest.raises(DataError, match=r"junk\.ply"):
        load_mesh(tmp_path / "junk.ply")
    (tmp_path / "empty.stl").write_bytes(b"")
    with pytest.raises(DataError, match="empty"):
        load_mesh(tmp_path / "empty.stl")
    (tmp_path / "points.xyz").write_text("0 0 0\n")
    with pytest.raises(DataError, match="unknown mesh format"):
        load_mesh(tmp_path / "points.xyz")


def test_mesh_folder_reports_failures_and_open_meshes(tmp_path):
    import trimesh

    closed = box(0.02, 0.01, 0.03)
    (tmp_path / "ok.ply").write_bytes(trimesh.Trimesh(closed.vertices, closed.faces).export(
        file_type="ply"))
    opened = trimesh.Trimesh(closed.vertices, closed.faces[:-2], process=False)
    (tmp_path / "open.obj").write_text(opened.export(file_type="obj"))
    (tmp_path / "bad.stl").write_bytes(b"solid x\nfacet garbage\n")
    labels = tmp_path / "labels.csv"
    labels.write_text("file,class\nok.ply,a\nopen.obj,a\nbad.stl,b\nmissing.ply,b\n")
    with pytest.warns(DataWarning, match=r"2 of 4 meshes failed to load.*1 meshes are not "
                      r"watertight"):
        ms = load_mesh_folder(tmp_path, labels)
    assert [m.name for m in ms.meshes] == ["ok", "open"] and ms.labels == ["a", "a"]
    assert set(ms.failed) == {"bad.stl", "missing.ply"} and ms.not_watertight == ["open"]
    only_bad = tmp_path / "bad.csv"
    only_bad.write_text("bad.stl,b\n")
    with pytest.raises(DataError, match="none of the 1 listed meshes"), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        load_mesh_folder(tmp_path, only_bad)
    (tmp_path / "broken.csv").write_text("file,class\nonly-one-cell\n")
    with pytest.raises(DataError, match="line 2"):
        read_labels(tmp_path / "broken.csv")


def test_watertight_check():
    m = box(0.01, 0.01, 0.01)
    assert edges_watertight(m.faces)
    assert not edges_watertight(m.faces[:-1])


# ----------------------------------------------------------------------- Daily set


def test_daily_generators_are_closed_sized_and_seeded():
    meshes, labels = daily_set(seed=3, per_class=2)
    assert labels == [c for c in DAILY_CLASSES for _ in range(2)]
    size = {m.name: np.sort(m.extent)[::-1] for m in meshes}
    for m in meshes:
        assert m.watertight, m.name
        assert m.vertices[:, 2].min() == pytest.approx(0.0, abs=1e-12)
    longest = {c: max(size[f"{c}_{i:02d}"][0] for i in range(2)) for c in DAILY_CLASSES}
    assert 0.06 < longest["apple"] < 0.1 and 0.2 < longest["chopstick"] < 0.26
    assert 0.13 < longest["pen"] < 0.16 and 0.02 < longest["bottle_cap"] < 0.045
    again, _ = daily_set(seed=3, per_class=2)
    for a, b in zip(meshes, again, strict=True):
        np.testing.assert_array_equal(a.vertices, b.vertices)
    other, _ = daily_set(seed=4, per_class=2)
    assert not np.allclose(meshes[0].vertices, other[0].vertices)


def test_ycb_mesh_scan_real_data():
    path = shared_file("meshes-ycb/065-a_cups.ply.gz")
    mesh = load_mesh(path)
    assert mesh.name == "065-a_cups" and mesh.watertight and len(mesh.faces) == 16384
    scan = scan_mesh(mesh, ScannerConfig(step=0.003), seed=1)
    assert len(scan.stripes) > 10
    assert all(np.isfinite(s).all() and len(s) > 0 for s in scan.stripes)
    rows = ycb_labels(path.parent)
    classes = {c for _, c in rows}
    assert classes == {"ball", "cup", "lego_duplo", "toy_airplane", "box"}
    assert sum(c == "cup" for _, c in rows) == 10


def test_height_map_inverts_the_camera_model():
    # A 50 mm box top, at the configured standoff and from a raised scanner (a 0.33 m
    # post): every seen cell reads the box's height; cells are step x fov/width apart.
    cfg = ScannerConfig(**CLEAN, step=0.005)
    z, cell = scan_mesh(box(0.03, 0.02, 0.05), cfg, seed=0).height_map(cfg)
    seen = z[np.isfinite(z)]
    assert seen.size > 0 and np.allclose(seen, 0.05, atol=2e-4)
    assert cell == pytest.approx((0.005, cfg.field_of_view / cfg.width))
    post = scan_mesh(box(0.03, 0.03, 0.33, "post"), cfg)
    zp, cell_p = post.height_map(cfg)
    assert post.standoff > cfg.standoff
    assert np.allclose(zp[np.isfinite(zp)], 0.33, atol=1e-3)
    assert cell_p[1] == pytest.approx(post.field_of_view / cfg.width)
