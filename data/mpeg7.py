"""MPEG-7 CE-Shape-1 silhouettes (or any folder of binary shape images) as polygons.

The place-recognition paper evaluates its shape matchers on MPEG-7 Part B
(70 classes x 20 images) "converted to polygons and smoothed to remove redundant
points of polygons".  This module does that conversion, one rule for every image:

1. **Files.** Every file of the folder (not recursive) whose suffix is one of
   `IMAGE_SUFFIXES` (gif, png, bmp, jpg/jpeg, tif/tiff, pgm/pbm/ppm;
   case-insensitive).  Name ``<class>-<index>.<ext>`` (``-`` or ``_`` before the
   index): `Silhouette.name` is the stem, `Silhouette.label` the class lower-cased
   (``Bone-1.gif`` -> ``bone``, ``device0-1.gif`` -> ``device0``); a stem without a
   trailing index is its own label.  Sorted by label, then index (numerically),
   then name.
2. **Image -> mask.** The file is decoded to 8-bit grey by OpenCV (should an
   OpenCV build not decode GIF, Pillow, installed with matplotlib, decodes it
   instead; only the first frame counts).  Otsu's threshold splits it into two
   classes (for the 0/255 MPEG-7 images: the 255 pixels).  If
   more than half of the image's border pixels are foreground, the polarity is
   flipped (a dark shape on a light background).
3. **Mask -> outer contour.** The largest 8-connected component (at least
   `MIN_AREA_PX` pixels) is kept; its outer boundary is traced by
   ``cv2.findContours(RETR_EXTERNAL, CHAIN_APPROX_NONE)`` on the mask padded by one
   background pixel (so shapes touching the image edge are traced too).  Holes
   are ignored.
4. **Pixels -> polygon.** Vertex ``(x, y)`` = (column, ``H - 1 - row``): pixel
   units, y pointing up, origin at the bottom-left pixel centre.  Counter-clockwise,
   closed implicitly (first vertex not repeated).
5. **Smoothing** with one scale ``s = smooth`` [px] (default 1): the closed
   pixel contour (samples 1 or sqrt(2) px apart) is low-pass filtered by a
   circular Gaussian of sigma ``s`` samples (removes the 8-connected staircase),
   then simplified by Douglas-Peucker (``cv2.approxPolyDP``, closed) with
   tolerance ``s`` px, which drops the redundant points of straight and gently
   curved runs.  ``smooth=0`` keeps the raw pixel contour.  With `max_vertices` set, the
   Douglas-Peucker tolerance is multiplied by 1.25 until the polygon has at most
   that many vertices.
6. **Checks.** Consecutive duplicate vertices are dropped; a polygon with fewer
   than 3 vertices or zero area counts as an empty image.

Unreadable images and images without a shape are skipped with one warning that
names them; a missing folder, a folder without image files, or one where no image
gives a shape is a `DataError`.
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d

from data.errors import DataError, UserError, warn

Array = NDArray[np.float64]

IMAGE_SUFFIXES = frozenset(
    {".gif", ".png", ".bmp", ".jpg", ".jpeg", ".tif", ".tiff", ".pgm", ".pbm", ".ppm"}
)
"""Suffixes (lower-case) of the files `load_silhouettes` reads."""

MIN_AREA_PX = 9
"""A largest component smaller than this many pixels means the image has no shape."""

_NAME = re.compile(r"^(?P<label>.+?)[-_](?P<index>\d+)$")


@dataclass(slots=True)
class Silhouette:
    """One shape image as a polygon.

    Attributes:
        name: the file stem (``"Bone-1"``).
        label: the class: stem lower-cased with its trailing ``-<index>`` removed.
        contour: ``(N, 2)`` vertices [px], y up, counter-clockwise, closed implicitly.
    """

    name: str
    label: str
    contour: Array


def parse_name(stem: str) -> tuple[str, int | None]:
    """``(label, index)`` of a file stem: ``"Bone-12"`` -> ``("bone", 12)``; no index -> None."""
    m = _NAME.match(stem)
    if m is None:
        return stem.lower(), None
    return m.group("label").lower(), int(m.group("index"))


def _sort_key(path: Path) -> tuple[str, int, str]:
    label, index = parse_name(path.stem)
    return label, -1 if index is None else index, path.stem


def _decode(path: Path) -> NDArray[np.uint8] | None:
    """8-bit grey image of a file, or None when neither OpenCV nor Pillow can decode it."""
    try:
        raw = np.fromfile(path, dtype=np.uint8)
    except OSError:
        return None
    img = cv2.imdecode(raw, cv2.IMREAD_GRAYSCALE) if raw.size else None
    if img is not None:
        return img
    try:
        from PIL import Image  # only for builds of OpenCV without GIF support

        with Image.open(path) as im:
            return np.asarray(im.convert("L"), dtype=np.uint8)
    except Exception:  # Pillow raises many types for garbage; any of them means unreadable
        return None


def _mask(img: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """Foreground mask (0/1) by Otsu's threshold, shape pixels = 1 (step 2 of the rule)."""
    _, mask = cv2.threshold(img, 0, 1, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    border = np.concatenate([mask[0], mask[-1], mask[1:-1, 0], mask[1:-1, -1]])
    if border.size and border.mean() > 0.5:
        mask = 1 - mask
    return mask.astype(np.uint8)


def _outer_contour(mask: NDArray[np.uint8]) -> Array | None:
    """``(N, 2)`` (column, row) of the largest component's outer boundary, or None."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return None
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    if stats[k, cv2.CC_STAT_AREA] < MIN_AREA_PX:
        return None
    comp = cv2.copyMakeBorder(
        (labels == k).astype(np.uint8), 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0
    )
    contours, _ = cv2.findContours(comp, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return None
    return max(contours, key=len)[:, 0, :].astype(float) - 1.0


def _signed_area(v: Array) -> float:
    x, y = v[:, 0], v[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _drop_repeats(v: Array) -> Array:
    keep = np.linalg.norm(v - np.roll(v, 1, axis=0), axis=1) > 1e-9
    return v[keep] if keep.any() else v[:1]


def _simplify(v: Array, smooth: float, max_vertices: int | None) -> Array:
    """Gaussian + Douglas-Peucker smoothing of a closed contour (step 5 of the rule)."""
    if smooth > 0 and len(v) > 3:
        v = gaussian_filter1d(v, smooth, axis=0, mode="wrap")
    tol = smooth
    while True:
        out = v
        if tol > 0:
            approx = cv2.approxPolyDP(v.astype(np.float32).reshape(-1, 1, 2), tol, True)
            out = approx[:, 0, :].astype(float)
        if max_vertices is None or len(out) <= max_vertices:
            return out
        tol = max(tol * 1.25, 0.25)


def contour_from_image(img: NDArray[np.uint8], *, smooth: float = 1.0,
                       max_vertices: int | None = None) -> Array | None:
    """CCW polygon ``(N, 2)`` [px, y up] of the largest shape of a grey image, or None.

    Steps 2-6 of the module docstring; None when the image holds no usable shape.
    """
    img = np.asarray(img)
    if img.ndim != 2 or img.size == 0:
        return None
    pix = _outer_contour(_mask(img.astype(np.uint8, copy=False)))
    if pix is None:
        return None
    v = np.column_stack([pix[:, 0], (img.shape[0] - 1) - pix[:, 1]])
    if _signed_area(v) < 0:
        v = v[::-1].copy()
    v = _drop_repeats(_simplify(v, smooth, max_vertices))
    if len(v) < 3 or abs(_signed_area(v)) < 1e-9:
        return None
    return v if _signed_area(v) > 0 else v[::-1].copy()


def _validate(smooth: float, max_vertices: int | None) -> None:
    if not np.isfinite(smooth) or smooth < 0:
        raise UserError(f"smooth must be a finite number >= 0 [px], not {smooth}")
    if max_vertices is not None and max_vertices < 3:
        raise UserError(f"max_vertices must be None or at least 3, not {max_vertices}")


def load_silhouettes(
    folder: str | PathLike[str],
    *,
    smooth: float = 1.0,
    max_vertices: int | None = None,
) -> list[Silhouette]:
    """Silhouettes of every image in `folder`, sorted by class then index.

    Args:
        folder: a folder of shape images (e.g. MPEG-7 CE-Shape-1 Part B).
        smooth: smoothing scale [px]: Gaussian sigma along the contour and
            Douglas-Peucker tolerance (0 keeps the raw pixel contour).
        max_vertices: cap on the vertices of each polygon (None: no cap).

    Raises:
        DataError: missing folder, no image files, or no image with a shape.
        UserError: `smooth` < 0 or `max_vertices` < 3.
    """
    _validate(smooth, max_vertices)
    root = Path(folder)
    if not root.exists():
        raise DataError(root, "no such folder")
    if not root.is_dir():
        raise DataError(root, "is not a folder of images")
    files = sorted(
        (p for p in root.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()),
        key=_sort_key,
    )
    if not files:
        raise DataError(
            root, f"no image files ({', '.join(sorted(s[1:] for s in IMAGE_SUFFIXES))})"
        )
    out: list[Silhouette] = []
    skipped: list[str] = []
    for path in files:
        img = _decode(path)
        if img is None:
            skipped.append(f"{path.name} (unreadable)")
            continue
        contour = contour_from_image(img, smooth=smooth, max_vertices=max_vertices)
        if contour is None:
            skipped.append(f"{path.name} (no shape)")
            continue
        out.append(Silhouette(path.stem, parse_name(path.stem)[0], contour))
    if not out:
        raise DataError(root, f"none of the {len(files)} images holds a shape")
    if skipped:
        shown = ", ".join(skipped[:10]) + (f" and {len(skipped) - 10} more" if len(skipped) > 10
                                           else "")
        warn(f"{root}: skipped {len(skipped)} of {len(files)} images: {shown}")
    return out


def mpeg7_classes(silhouettes: Iterable[Silhouette]) -> dict[str, int]:
    """Number of silhouettes per class label, labels in sorted order."""
    counts = Counter(s.label for s in silhouettes)
    return {label: counts[label] for label in sorted(counts)}
