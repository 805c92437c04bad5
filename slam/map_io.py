"""Writing occupancy maps: ROS map_server PGM + YAML, and PNG pictures.

Format (as ROS ``map_server`` / nav2 ``map_server`` read it):

* ``<stem>.pgm``: binary PGM (``P5``), ``width height`` = ``cols rows``, maxval 255,
  one byte per cell, *image row 0 = the largest y* (the loader flips rows so that
  the bottom image row becomes map row 0).  Pixels are trinary: 0 occupied,
  254 free, 205 unknown (`slam.occupancy_map.OccupancyGrid.trinary`).
* ``<stem>.yaml``::

      image: map.pgm            # relative to the YAML file
      mode: trinary
      resolution: 0.05          # m per cell
      origin: [x, y, 0.0]       # map-frame pose of the lower-left corner of the
                                # lower-left cell (x, y [m], yaw [rad], always 0)
      negate: 0                 # occupancy = (255 - pixel) / 255
      occupied_thresh: 0.65     # occupancy above this is occupied
      free_thresh: 0.196        # occupancy below this is free

  With ``negate: 0`` the three pixel values read back as occupancy 1.0, 0.004 and
  0.196; 0.196 lies between the thresholds, so unknown stays unknown (nav2's
  map_saver default ``free_thresh: 0.25`` would turn 205 into free; ROS 1's
  0.196 does not).
* ``<stem>.png``: the same trinary image as PNG, optionally with the trajectory
  (blue polyline) and loop closures (lines between the two poses: red for those the
  pose-gated search proposed, green for those the place database proposed) drawn
  over it, upscaled with nearest-neighbour so small maps stay legible.

Every file is written atomically (`data.atomic_write`): an interrupted run leaves
the previous file or none, never half a file.  `write_map` writes the PGM before
the YAML that names it.
"""

from __future__ import annotations

import os
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.atomic_write import output_dir, write_bytes_atomic
from data.errors import DataError, UserError

if TYPE_CHECKING:
    from slam.occupancy_map import OccupancyGrid

PathArg = str | PathLike[str]

#: Colours (B, G, R) of the overlays.
TRAJECTORY_BGR = (200, 90, 20)
LOOP_BGR = (40, 40, 220)
APPEARANCE_LOOP_BGR = (40, 170, 40)
#: Upscaled PNGs aim at about this many pixels on the longer side (at most 8x).
PNG_TARGET_PIXELS = 2000


def pgm_bytes(image: NDArray[np.uint8]) -> bytes:
    """Binary PGM (P5, maxval 255) of an ``(H, W)`` uint8 image, row 0 first."""
    img = np.ascontiguousarray(image, dtype=np.uint8)
    h, w = img.shape
    return f"P5\n{w} {h}\n255\n".encode("ascii") + img.tobytes()


def _num(x: float) -> str:
    """Shortest round-trip text of `x`, rounded to 1e-9 (no ``-0.0``)."""
    v = round(float(x), 9)
    return repr(v + 0.0)


def yaml_text(grid: OccupancyGrid, image_name: str) -> str:
    """The map_server YAML of `grid` naming `image_name` (module docstring)."""
    if not image_name or any(c in image_name for c in "\n\r:#'\"") or image_name.strip() != (
        image_name
    ):
        raise UserError(f"map image name {image_name!r} cannot be written to a map YAML")
    c = grid.config
    return (
        f"image: {image_name}\n"
        "mode: trinary\n"
        f"resolution: {_num(grid.resolution)}\n"
        f"origin: [{_num(grid.origin[0])}, {_num(grid.origin[1])}, 0.0]\n"
        "negate: 0\n"
        f"occupied_thresh: {_num(c.occupied_thresh)}\n"
        f"free_thresh: {_num(c.free_thresh)}\n"
    )


def write_pgm(grid: OccupancyGrid, path: PathArg) -> Path:
    """Write the trinary map image of `grid` as binary PGM, atomically."""
    return write_bytes_atomic(path, pgm_bytes(grid.trinary()))


def write_yaml(grid: OccupancyGrid, path: PathArg, image_name: str) -> Path:
    """Write the map_server YAML of `grid` (naming `image_name`), atomically."""
    return write_bytes_atomic(path, yaml_text(grid, image_name).encode("utf-8"))


def _to_pixels(grid: OccupancyGrid, xy: NDArray[np.float64], scale: int) -> NDArray[np.float64]:
    """Image coordinates (x right, y down; pixel centres at integers) of map points [m]."""
    h = grid.shape[0]
    u = (xy[:, 0] - grid.origin[0]) / grid.resolution * scale - 0.5
    v = (h - (xy[:, 1] - grid.origin[1]) / grid.resolution) * scale - 0.5
    return np.column_stack([u, v])


def map_image(
    grid: OccupancyGrid,
    trajectory_xy: ArrayLike | None = None,
    loops: ArrayLike | None = None,
    scale: int | None = None,
    appearance_loops: ArrayLike | None = None,
) -> NDArray[np.uint8]:
    """``(H * s, W * s, 3)`` BGR picture of the map with optional overlays.

    Args:
        trajectory_xy: ``(N, 2)`` (or ``(N, >=2)``, extra columns ignored) positions in
            the map frame [m], drawn as a polyline; non-finite rows break the line.
        loops: ``(L, 2, 2)`` or ``(L, 4)`` loop closures as pairs of map-frame
            positions ``(x1, y1, x2, y2)`` [m], each drawn as a line (`LOOP_BGR`).
        appearance_loops: loop closures of the same shape drawn in
            `APPEARANCE_LOOP_BGR` (those the place database proposed).
        scale: integer upscaling factor ``s``; default: about `PNG_TARGET_PIXELS`
            on the longer side, between 1 and 8.
    """
    import cv2

    base = grid.trinary()
    h, w = base.shape
    s = int(scale) if scale is not None else int(np.clip(PNG_TARGET_PIXELS // max(h, w), 1, 8))
    if s < 1:
        raise UserError(f"map picture scale must be a positive integer, got {scale}")
    img = np.repeat(np.repeat(base, s, axis=0), s, axis=1)
    img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    shift = 4  # sub-pixel bits of cv2 drawing
    thick = max(1, s // 2)
    if trajectory_xy is not None:
        xy = np.asarray(trajectory_xy, dtype=float)
        xy = xy.reshape(len(xy), -1)[:, :2] if xy.size else np.zeros((0, 2))
        ok = np.all(np.isfinite(xy), axis=1)
        # One polyline per run of finite positions.
        runs = np.split(np.arange(len(xy)), np.flatnonzero(np.diff(ok.astype(np.int8))) + 1)
        lines = [
            np.round(_to_pixels(grid, xy[r], s) * (1 << shift)).astype(np.int32)
            for r in runs
            if len(r) > 1 and ok[r[0]]
        ]
        if lines:
            cv2.polylines(img, lines, False, TRAJECTORY_BGR, thick, cv2.LINE_AA, shift)
    for segments, colour in ((loops, LOOP_BGR), (appearance_loops, APPEARANCE_LOOP_BGR)):
        if segments is None:
            continue
        seg = np.asarray(segments, dtype=float).reshape(-1, 4)
        seg = seg[np.all(np.isfinite(seg), axis=1)]
        if len(seg):
            a = np.round(_to_pixels(grid, seg[:, :2], s) * (1 << shift)).astype(np.int32)
            b = np.round(_to_pixels(grid, seg[:, 2:], s) * (1 << shift)).astype(np.int32)
            lines = list(np.stack([a, b], axis=1))
            cv2.polylines(img, lines, False, colour, thick, cv2.LINE_AA, shift)
    return img


def render_png(
    grid: OccupancyGrid,
    path: PathArg,
    trajectory_xy: ArrayLike | None = None,
    loops: ArrayLike | None = None,
    scale: int | None = None,
    appearance_loops: ArrayLike | None = None,
) -> Path:
    """Write `map_image` as PNG, atomically; returns the path."""
    import cv2

    image = map_image(grid, trajectory_xy, loops, scale, appearance_loops=appearance_loops)
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise DataError(path, "cannot encode the map as PNG")
    return write_bytes_atomic(path, buf.tobytes())


def write_map(
    grid: OccupancyGrid,
    out_dir: PathArg,
    stem: str = "map",
    trajectory_xy: ArrayLike | None = None,
    loops: ArrayLike | None = None,
    appearance_loops: ArrayLike | None = None,
) -> dict[str, Path]:
    """Write ``<stem>.pgm``, ``<stem>.yaml`` (naming the PGM) and ``<stem>.png`` into
    `out_dir` (created if needed); returns ``{"pgm": ..., "yaml": ..., "png": ...}``.
    The overlays are `map_image`'s."""
    if not stem or "/" in stem or os.sep in stem:
        raise UserError(f"map file stem must be a plain file name, got {stem!r}")
    out = output_dir(out_dir)
    pgm = write_pgm(grid, out / f"{stem}.pgm")
    yml = write_yaml(grid, out / f"{stem}.yaml", pgm.name)
    png = render_png(grid, out / f"{stem}.png", trajectory_xy=trajectory_xy, loops=loops,
                     appearance_loops=appearance_loops)
    return {"pgm": pgm, "yaml": yml, "png": png}
