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

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

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
    """
    from data.mpeg7 import contour_from_image

    cfg = config or ScannerConfig()
    mask = scan.silhouette()
    mask = ndimage.binary_closing(np.pad(mask, 2), structure=np.ones((3, 3), bool))
    col_mm = 1000.0 * scan.field_of_view / cfg.width
    row_mm = 1000.0 * cfg.step
    contour = contour_from_image(mask.astype(np.uint8) * 255, smooth=smooth)
    if contour is None:
        rows, cols = np.nonzero(mask)
        y = (mask.shape[0] - 1) - rows
        x0, x1, y0, y1 = cols.min() - 0.5, cols.max() + 0.5, y.min() - 0.5, y.max() + 0.5
        contour = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
    return Polygon(contour * np.array([col_mm, row_mm]))
