"""The objects of the stripes benchmark: the object sets, their scans and silhouettes.

An `ObjectSet` is the parametric Daily-like set (`daily_objects`) or a folder of
meshes (`mesh_folder_objects`, with a ``file,class`` CSV or the YCB classes).
`scan_objects` scans every object with the simulated laser-stripe scanner
(`data.stripe_scanner.scan_mesh`) one or more times.  `silhouette_polygon` turns a
scan's footprint into the polygon the silhouette baselines compare.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from data.errors import DataError, UserError, warn
from data.stripe_scanner import (
    DAILY_CLASSES,
    Mesh,
    ScannerConfig,
    StripeScan,
    daily_set,
    read_labels,
    scan_mesh,
    ycb_labels,
)
from data.stripe_scanner.meshes import load_mesh_rows
from loopclosure.polygon import Polygon

Progress = Callable[[str, int, int], None]
"""``progress(stage, done, total)``."""


@dataclass(slots=True)
class ObjectSet:
    """Objects to scan.

    Attributes:
        name: data set name (``daily-sim`` or the mesh folder).
        meshes: one mesh per object (metres, z up).
        labels: class of each object.
        failed: file -> reason for listed meshes that could not be loaded.
        not_watertight: names of kept meshes that are not watertight.
    """

    name: str
    meshes: list[Mesh]
    labels: list[str]
    failed: dict[str, str] = field(default_factory=dict)
    not_watertight: list[str] = field(default_factory=list)


def daily_objects(
    seed: int = 0, per_class: int = 10, classes: Sequence[str] = DAILY_CLASSES
) -> ObjectSet:
    """The parametric Daily-like set (`data.stripe_scanner.daily_set`): classes x per_class."""
    if per_class < 1:
        raise UserError(f"--per-class must be at least 1, got {per_class}")
    unknown = [c for c in classes if c not in DAILY_CLASSES]
    if unknown:
        raise UserError(f"unknown Daily class(es) {', '.join(unknown)}; known: "
                        f"{', '.join(DAILY_CLASSES)}")
    if not classes:
        raise UserError("no Daily class selected")
    meshes, labels = daily_set(seed=seed, per_class=per_class, classes=tuple(classes))
    return ObjectSet("daily-sim", meshes, labels)


def mesh_folder_objects(
    folder: str | Path, labels_csv: str | Path | None = None, units: str = "auto",
    up: str = "z",
) -> ObjectSet:
    """Meshes of a folder with a ``file,class`` CSV, or the YCB multi-instance classes.

    `units` and `up` are the meshes' conventions (`data.stripe_scanner.meshes`: units
    detected from the bounding box by default, z up unless told).

    Without `labels_csv` the classes come from `data.stripe_scanner.ycb_labels` (YCB file
    names).  A CSV row naming a file that is not in the folder is an error (a typo must
    not silently shrink the benchmark); files that exist but do not load are skipped and
    reported once (as `load_mesh_folder` does).

    Raises:
        DataError: missing folder or CSV, files listed but absent, nothing loadable.
    """
    root = Path(folder)
    if not root.exists():
        raise DataError(root, "no such folder")
    if not root.is_dir():
        raise DataError(root, "not a directory")
    if labels_csv is not None:
        rows = read_labels(labels_csv)
        source: str | Path = labels_csv
    else:
        rows = ycb_labels(root)
        source = root
    missing = [f for f, _ in rows if not (root / f).is_file()]
    if missing:
        shown = ", ".join(missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5
                                          else "")
        raise DataError(source, f"lists {len(missing)} file(s) not found in {root}: {shown}")
    loaded = load_mesh_rows(root, rows, source=source, units=units, up=up)
    return ObjectSet(str(root), loaded.meshes, loaded.labels, loaded.failed,
                     loaded.not_watertight)


@dataclass(slots=True)
class ScannedSet:
    """The scans of an `ObjectSet`.

    Attributes:
        scans: one `StripeScan` per successful scan, object-major.
        labels: class of each scan.
        objects: index (into the object set) of the object each scan comes from.
        failed: object name -> reason for objects that gave no stripe (skipped).
        seconds: wall time of the scanning [s].
    """

    scans: list[StripeScan]
    labels: list[str]
    objects: NDArray[np.int64]
    failed: dict[str, str]
    seconds: float


def scan_objects(
    objects: ObjectSet,
    config: ScannerConfig | None = None,
    seed: int = 0,
    scans_per_object: int = 1,
    progress: Progress | None = None,
) -> ScannedSet:
    """Scan every object `scans_per_object` times (same draws as `scan_meshes` for `seed`).

    Objects that give no stripe are skipped; one warning summarises laser positions
    without stripe and skipped objects.

    Raises:
        UserError: bad `scans_per_object`, or no object gave any stripe.
    """
    if scans_per_object < 1:
        raise UserError(f"--scans-per-object must be at least 1, got {scans_per_object}")
    rng = np.random.default_rng(seed)
    total = len(objects.meshes) * scans_per_object
    scans: list[StripeScan] = []
    labels: list[str] = []
    source: list[int] = []
    failed: dict[str, str] = {}
    t0 = time.perf_counter()
    done = 0
    for i, mesh in enumerate(objects.meshes):
        for _ in range(scans_per_object):
            try:
                scans.append(scan_mesh(mesh, config, rng))
                labels.append(objects.labels[i])
                source.append(i)
            except DataError as exc:
                failed[mesh.name] = exc.message
            done += 1
            if progress is not None:
                progress("scanning", done, total)
    seconds = time.perf_counter() - t0
    empty = sum(s.empty_positions for s in scans)
    if empty:
        frames = sum(s.n_frames for s in scans)
        warn(f"stripe scanner: {empty} of {frames} laser positions over "
             f"{sum(1 for s in scans if s.empty_positions)} objects cut the object but gave "
             "no stripe (shadowed, hidden or grazing)")
    if failed:
        warn(f"stripe scanner: {len(failed)} objects gave no stripe at all and were skipped "
             f"({', '.join(list(failed)[:3])}{', ...' if len(failed) > 3 else ''})")
    if not scans:
        raise UserError(f"{objects.name}: no object gave any stripe; nothing to benchmark")
    return ScannedSet(scans, labels, np.array(source, dtype=np.int64), failed, seconds)


def range_image(scan: StripeScan) -> NDArray[np.float64]:
    """`StripeScan.range_image` in one vectorised assignment (no loop over frames).

    Every stripe point writes its row into ``[frame, rint(column)]`` in the same order
    as the method's loop (numpy assigns repeated indices in order, the last one
    staying), so the image is the method's, element for element.
    """
    out = np.full((scan.n_frames, scan.image_shape[1]), np.nan)
    if not scan.stripes:
        return out
    points = np.concatenate([np.asarray(s, dtype=float).reshape(-1, 2) for s in scan.stripes])
    rows = np.repeat(np.asarray(scan.frame, dtype=np.int64), [len(s) for s in scan.stripes])
    out[rows, np.rint(points[:, 0]).astype(np.int64)] = points[:, 1]
    return out


def height_map(
    scan: StripeScan, config: ScannerConfig | None = None
) -> tuple[NDArray[np.float64], tuple[float, float]]:
    """`StripeScan.height_map` with the fast `range_image`, the same numbers.

    The scan's own method (the camera model is the scanner's, not a copy) runs on the
    seen pixels only: on a stand-in for the scan whose range image is the row of the
    finite values of `range_image`; the method's arithmetic is elementwise, so each
    height is the one it gives on the whole image, and the heights are put back in
    place (NaN elsewhere).
    """
    image = range_image(scan)
    seen = np.isfinite(image)
    z, cell = StripeScan.height_map(_WithRangeImage(scan, image[seen]), config)  # type: ignore[arg-type]
    out = np.full(image.shape, np.nan)
    out[seen] = z
    return out, cell


class _WithRangeImage:
    """A scan's `standoff` and `field_of_view` with a given range image."""

    def __init__(self, scan: StripeScan, image: NDArray[np.float64]) -> None:
        self.standoff = scan.standoff
        self.field_of_view = scan.field_of_view
        self._image = image

    def range_image(self) -> NDArray[np.float64]:
        return self._image


#: Pixels kept around the footprint's bounding box when the silhouette is closed and
#: traced on a crop: more than the closing's reach (1 px) and the tracer's border.
_CROP_MARGIN = 3


def silhouette_polygon(
    scan: StripeScan, config: ScannerConfig | None = None, smooth: float = 1.0
) -> Polygon:
    """The object's scanned footprint as a polygon in millimetres (table plane, top view).

    The mask `StripeScan.silhouette()` has one row per laser position (`step` apart)
    and one column per image column (the scan's ``field_of_view / width`` apart on the
    table):
    it is closed by a 3 x 3 structuring element (fills the detector's one-pixel gaps),
    its outer contour is taken and smoothed by `data.mpeg7.contour_from_image`
    (`smooth` pixels), and the axes are scaled to millimetres so the shape is not
    stretched.  A footprint too thin for a contour (one row or column) becomes its
    bounding rectangle, half a pixel wider on every side (never degenerate).

    Speed, same polygon to the bit: the mask is written straight from the stripe
    points onto the footprint's bounding box plus `_CROP_MARGIN` pixels
    (`_footprint_crop`; the image beyond is empty: nothing there can change the
    closing, the component or its boundary), closed by OpenCV (`_closed`) and traced
    there; the traced pixel coordinates are shifted back by whole pixels (exact)
    before the flip and the smoothing of `contour_from_image`, which see the same
    numbers as on the whole image (`_footprint_contour`).
    """
    cfg = config or ScannerConfig()
    col_mm = 1000.0 * scan.field_of_view / cfg.width
    row_mm = 1000.0 * cfg.step
    crop, (r0, c0), height = _footprint_crop(scan)
    crop = _closed(crop)
    contour = _footprint_contour(crop, (r0, c0), height, smooth)
    if contour is None:
        rows, cols = np.nonzero(crop)
        rows, cols = rows + r0, cols + c0
        y = (height - 1) - rows
        x0, x1, y0, y1 = cols.min() - 0.5, cols.max() + 0.5, y.min() - 0.5, y.max() + 0.5
        contour = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
    return Polygon(contour * np.array([col_mm, row_mm]))


def _footprint_crop(scan: StripeScan) -> tuple[NDArray[np.bool_], tuple[int, int], int]:
    """The footprint mask (`StripeScan.silhouette`, padded by 2 pixels) cut to its
    bounding box plus `_CROP_MARGIN`: ``(crop, (row, column) of its first pixel in the
    padded mask, the padded mask's row count)``.  Written straight from the stripe
    points (the same pixels as `range_image`, the last point on a pixel deciding);
    points outside the image, which `range_image` would wrap, take the whole mask."""
    height, width = scan.n_frames + 4, scan.image_shape[1] + 4
    points = np.concatenate([np.asarray(x, dtype=float).reshape(-1, 2) for x in scan.stripes])
    rows = np.repeat(np.asarray(scan.frame, dtype=np.int64), [len(x) for x in scan.stripes])
    cols = np.rint(points[:, 0]).astype(np.int64)
    seen = np.isfinite(points[:, 1])
    inside = ((cols >= 0) & (cols < scan.image_shape[1]) & (rows >= 0)
              & (rows < scan.n_frames))
    if not inside.all() or not seen.any():
        return np.pad(np.isfinite(range_image(scan)), 2), (0, 0), height
    rows, cols = rows + 2, cols + 2  # the padding
    r0 = max(int(rows[seen].min()) - _CROP_MARGIN, 0)
    c0 = max(int(cols[seen].min()) - _CROP_MARGIN, 0)
    r1 = min(int(rows[seen].max()) + _CROP_MARGIN + 1, height)
    c1 = min(int(cols[seen].max()) + _CROP_MARGIN + 1, width)
    crop = np.zeros((r1 - r0, c1 - c0), dtype=bool)
    # Points off the crop are unseen ones on pixels no seen point shares: False anyway.
    keep = (rows >= r0) & (rows < r1) & (cols >= c0) & (cols < c1)
    crop[rows[keep] - r0, cols[keep] - c0] = seen[keep]
    return crop, (r0, c0), height


def _closed(mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Binary closing by a 3 x 3 square (OpenCV's dilation then erosion: the same image as
    ``scipy.ndimage.binary_closing`` where the mask is empty within 2 pixels of its
    border, as the padded footprint is)."""
    kernel = np.ones((3, 3), np.uint8)
    m = cv2.dilate(mask.astype(np.uint8), kernel)
    return cv2.erode(m, kernel).astype(bool)


def _footprint_contour(
    crop: NDArray[np.bool_], origin: tuple[int, int], height: int, smooth: float
) -> NDArray[np.float64] | None:
    """`data.mpeg7.contour_from_image` of the whole mask (`height` rows), traced on its
    `crop` whose first pixel is `origin` (row, column) of the whole mask."""
    from data.mpeg7 import _drop_repeats, _outer_contour, _signed_area, _simplify

    # contour_from_image's foreground (Otsu on a 0/255 image with empty borders) is the
    # mask itself.
    pix = _outer_contour(crop.astype(np.uint8))
    if pix is None:
        return None
    v = np.column_stack([pix[:, 0] + origin[1], (height - 1) - (pix[:, 1] + origin[0])])
    if _signed_area(v) < 0:
        v = v[::-1].copy()
    v = _drop_repeats(_simplify(v, smooth, None))
    if len(v) < 3 or abs(_signed_area(v)) < 1e-9:
        return None
    return v if _signed_area(v) > 0 else v[::-1].copy()
