"""MPEG-7 silhouettes: drawn shapes checked by hand, naming, bad input, the real subset."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from data import mpeg7
from data.errors import DataError, DataWarning, UserError
from data.mpeg7 import contour_from_image, load_silhouettes, mpeg7_classes, parse_name
from tests.helpers import SHARED_DATA

H, W = 80, 100  # drawn test images: rows, columns


def _signed_area(v: np.ndarray) -> float:
    x, y = v[:, 0], v[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _square_image(x0: int = 20, y0: int = 30, x1: int = 59, y1: int = 69) -> np.ndarray:
    img = np.zeros((H, W), np.uint8)
    cv2.rectangle(img, (x0, y0), (x1, y1), 255, thickness=-1)  # columns x0..x1, rows y0..y1
    return img


def _save(folder: Path, name: str, img: np.ndarray) -> Path:
    path = folder / name
    assert cv2.imwrite(str(path), img)
    return path


# --------------------------------------------------------------------------- drawn shapes


def test_square_raw_contour_exact() -> None:
    v = contour_from_image(_square_image(), smooth=0)
    assert v is not None
    # Pixel centres: x = column 20..59, y = (H - 1) - row = 79 - 69 .. 79 - 30 = 10..49.
    np.testing.assert_array_equal(v.min(axis=0), [20, 10])
    np.testing.assert_array_equal(v.max(axis=0), [59, 49])
    assert _signed_area(v) == 39 * 39  # counter-clockwise, area between the pixel centres
    assert len(v) == 4 * 39  # every boundary pixel


def test_square_smoothed_is_a_few_vertices() -> None:
    v = contour_from_image(_square_image())
    assert v is not None
    assert 4 <= len(v) <= 16
    assert _signed_area(v) > 0
    # The Gaussian (sigma 1 px) pulls the corners in by less than half a pixel, so the
    # area changes by less than half a pixel times the perimeter.
    assert abs(_signed_area(v) - 39 * 39) < 0.5 * 4 * 39
    np.testing.assert_allclose(v.min(axis=0), [20, 10], atol=0.5)
    np.testing.assert_allclose(v.max(axis=0), [59, 49], atol=0.5)


def test_circle_contour() -> None:
    img = np.zeros((H, W), np.uint8)
    cv2.circle(img, (50, 40), 30, 255, thickness=-1)
    v = contour_from_image(img)
    assert v is not None
    centre = np.array([50.0, H - 1 - 40.0])
    r = np.linalg.norm(v - centre, axis=1)
    assert np.all(np.abs(r - 30) < 1.5)
    assert abs(_signed_area(v) - math.pi * 29.5**2) < 0.03 * math.pi * 30**2
    assert 12 <= len(v) <= 80
    angles = np.unwrap(np.arctan2(v[:, 1] - centre[1], v[:, 0] - centre[0]))
    assert np.all(np.diff(angles) > 0)  # counter-clockwise all the way round


def test_dark_shape_on_light_background_and_border_touching() -> None:
    inverted = 255 - _square_image()
    v = contour_from_image(inverted, smooth=0)
    assert v is not None and _signed_area(v) == 39 * 39
    touching = _square_image(0, 0, 39, 39)  # touches the top-left image corner
    v = contour_from_image(touching, smooth=0)
    assert v is not None
    np.testing.assert_array_equal(v.min(axis=0), [0, H - 40])
    assert _signed_area(v) == 39 * 39


def test_largest_component_wins() -> None:
    img = _square_image(60, 10, 90, 40)
    cv2.circle(img, (15, 60), 8, 255, thickness=-1)
    v = contour_from_image(img, smooth=0)
    assert v is not None and v.min(axis=0)[0] == 60


def test_empty_and_speck_images_have_no_shape() -> None:
    assert contour_from_image(np.zeros((H, W), np.uint8)) is None
    assert contour_from_image(np.full((H, W), 255, np.uint8)) is None
    speck = np.zeros((H, W), np.uint8)
    speck[5:7, 5:7] = 255  # 4 pixels < MIN_AREA_PX
    assert contour_from_image(speck) is None


def test_max_vertices_cap() -> None:
    img = np.zeros((H, W), np.uint8)
    cv2.ellipse(img, (50, 40), (40, 25), 30, 0, 360, 255, thickness=-1)
    free = contour_from_image(img)
    capped = contour_from_image(img, max_vertices=8)
    assert free is not None and capped is not None
    assert len(capped) <= 8 < len(free)
    assert _signed_area(capped) > 0.8 * _signed_area(free)


@settings(max_examples=30, deadline=None)
@given(
    w=st.integers(4, 60), h=st.integers(4, 50), dx=st.integers(0, 30), dy=st.integers(0, 20)
)
def test_rectangles_property(w: int, h: int, dx: int, dy: int) -> None:
    img = np.zeros((H, W + 40), np.uint8)
    cv2.rectangle(img, (5 + dx, 5 + dy), (5 + dx + w - 1, 5 + dy + h - 1), 255, thickness=-1)
    raw = contour_from_image(img, smooth=0)
    assert raw is not None
    assert _signed_area(raw) == (w - 1) * (h - 1)
    np.testing.assert_array_equal(raw.min(axis=0), [5 + dx, H - 1 - (5 + dy + h - 1)])
    smooth = contour_from_image(img)
    assert smooth is not None and _signed_area(smooth) > 0
    # Smoothing moves the boundary by about a pixel at most.
    assert abs(_signed_area(smooth) - (w - 1) * (h - 1)) <= 2.0 * (w + h)


# --------------------------------------------------------------------------- names and folders


@pytest.mark.parametrize(
    ("stem", "expected"),
    [
        ("Bone-1", ("bone", 1)),
        ("device0-1", ("device0", 1)),
        ("apple-20", ("apple", 20)),
        ("Heart_3", ("heart", 3)),
        ("car-bus-7", ("car-bus", 7)),
        ("lonely", ("lonely", None)),
    ],
)
def test_parse_name(stem: str, expected: tuple) -> None:
    assert parse_name(stem) == expected


def test_folder_sorted_by_class_then_index(tmp_path: Path) -> None:
    sq = _square_image()
    for name in ("b-10.png", "b-2.png", "B-1.PNG", "a-3.bmp", "notes.txt"):
        if name.endswith(".txt"):
            (tmp_path / name).write_text("not an image")
        else:
            _save(tmp_path, name, sq)
    sil = load_silhouettes(tmp_path)
    assert [s.name for s in sil] == ["a-3", "B-1", "b-2", "b-10"]
    assert [s.label for s in sil] == ["a", "b", "b", "b"]
    assert mpeg7_classes(sil) == {"a": 1, "b": 3}


def test_gif_read_and_pillow_fallback(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    image = pytest.importorskip("PIL.Image")
    image.fromarray(_square_image()).save(tmp_path / "sq-1.gif")
    direct = load_silhouettes(tmp_path, smooth=0)
    assert len(direct) == 1 and _signed_area(direct[0].contour) == 39 * 39
    # An OpenCV build without GIF support: Pillow decodes it instead.
    monkeypatch.setattr(mpeg7.cv2, "imdecode", lambda *_args: None)
    fallback = load_silhouettes(tmp_path, smooth=0)
    np.testing.assert_array_equal(fallback[0].contour, direct[0].contour)


def test_bad_images_skipped_with_one_warning(tmp_path: Path) -> None:
    _save(tmp_path, "good-1.png", _square_image())
    _save(tmp_path, "empty-1.png", np.zeros((H, W), np.uint8))
    (tmp_path / "broken-1.gif").write_bytes(b"GIF89a truncated garbage")
    with pytest.warns(DataWarning) as rec:
        sil = load_silhouettes(tmp_path)
    assert [s.name for s in sil] == ["good-1"]
    assert len(rec) == 1
    msg = str(rec[0].message)
    assert "skipped 2 of 3" in msg
    assert "broken-1.gif (unreadable)" in msg and "empty-1.png (no shape)" in msg


def test_bad_folders_are_data_errors(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="no such folder"):
        load_silhouettes(tmp_path / "missing")
    (tmp_path / "a.txt").write_text("x")
    with pytest.raises(DataError, match="no image files"):
        load_silhouettes(tmp_path)
    with pytest.raises(DataError, match="not a folder"):
        load_silhouettes(tmp_path / "a.txt")
    _save(tmp_path, "blank-1.png", np.zeros((H, W), np.uint8))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        with pytest.raises(DataError, match="none of the 1 images holds a shape"):
            load_silhouettes(tmp_path)


def test_bad_parameters(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="smooth"):
        load_silhouettes(tmp_path, smooth=-1)
    with pytest.raises(UserError, match="max_vertices"):
        load_silhouettes(tmp_path, max_vertices=2)


# --------------------------------------------------------------------------- the real subset


LABELS = ["apple", "bat", "bone", "butterfly", "camel", "device0", "fish", "key", "octopus",
          "watch"]


@pytest.fixture(scope="module")
def subset() -> list[mpeg7.Silhouette]:
    folder = SHARED_DATA / "mpeg7-subset"
    if not folder.is_dir():
        pytest.skip(f"real data folder {folder} not found (needs ../shared/data)")
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)
        return load_silhouettes(folder)


def test_real_subset_classes(subset: list[mpeg7.Silhouette]) -> None:
    assert len(subset) == 200
    assert mpeg7_classes(subset) == dict.fromkeys(LABELS, 20)
    assert [s.name for s in subset[:3]] == ["apple-1", "apple-2", "apple-3"]
    assert subset[40].name == "Bone-1" and subset[40].label == "bone"


def test_real_subset_contours_valid(subset: list[mpeg7.Silhouette]) -> None:
    from loopclosure.polygon import Polygon

    for s in subset:
        c = s.contour
        assert c.ndim == 2 and c.shape[1] == 2 and len(c) >= 8, s.name
        assert np.all(np.isfinite(c)) and c.min() >= -1.0, s.name
        assert _signed_area(c) > 500.0, s.name  # counter-clockwise, far from degenerate
        poly = Polygon(c)  # the polygon type the matchers use accepts it unchanged
        np.testing.assert_array_equal(poly.vertices, c)
    counts = np.array([len(s.contour) for s in subset])
    assert 30 < np.median(counts) < 200
