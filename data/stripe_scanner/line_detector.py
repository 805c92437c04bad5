"""The laser-line detector of a laser-stripe scanner (stripes paper, Section III).

"In every column of the image array the start and the end of the laser line are
detected by an adjustable threshold.  Afterwards, the correct position of the laser
line in each column is calculated using a weighted average of the intensity values of
the laser between the threshold borders."

`laser_line_positions` does exactly that, vectorised over columns: ``start`` is the
first row whose intensity reaches the threshold, ``end`` the last one, and the line
position is ``sum(r * I(r)) / sum(I(r))`` over ``start <= r <= end`` (every row in
between counts, with its raw intensity, even if it is itself below the threshold).
Image coordinates: row 0 at the top, column 0 at the left; positions are in pixels.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError

Array = NDArray[np.float64]


def laser_line_positions(
    image: ArrayLike, threshold: float
) -> tuple[NDArray[np.int64], Array]:
    """Columns where the line is found and its sub-pixel row in each.

    Args:
        image: ``(rows, columns)`` intensities (any real dtype; NaN counts as dark).
        threshold: intensity a pixel must reach to be part of the line (same unit as
            the image).

    Returns:
        ``(columns, rows)``: increasing column indices with a detection, and the
        intensity-weighted row of the line in each (float, pixels).
    """
    img = np.nan_to_num(np.asarray(image, dtype=float), nan=0.0)
    if img.ndim != 2:
        raise UserError(f"image must be a 2D (rows, columns) array, got shape {img.shape}")
    h = img.shape[0]
    above = img >= threshold
    found = above.any(axis=0)
    start = np.argmax(above, axis=0)
    end = h - 1 - np.argmax(above[::-1], axis=0)
    r = np.arange(h, dtype=float)[:, None]
    zero = np.zeros((1, img.shape[1]))
    w = np.concatenate([zero, np.cumsum(img, axis=0)])
    rw = np.concatenate([zero, np.cumsum(img * r, axis=0)])
    cols = np.arange(img.shape[1])
    total = w[end + 1, cols] - w[start, cols]
    moment = rw[end + 1, cols] - rw[start, cols]
    ok = found & (total > 0)
    rows = np.where(ok, moment / np.where(ok, total, 1.0), 0.0)
    idx = np.flatnonzero(ok)
    return idx.astype(np.int64), rows[idx]
