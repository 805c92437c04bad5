"""Triangle meshes for the laser-stripe scanner: loading, checking, labelled folders.

Formats: ``.ply`` (ASCII or binary), ``.obj``, ``.stl``, each optionally gzip- or
bzip2-compressed (``name.ply.gz``; compression is detected from the bytes, the format
from the name without the compression suffix).  Parsing is done by trimesh.

Conventions of the loaded `Mesh`: metres, z up (the YCB meshes are metric, z up).
Files of arbitrary real meshes come in other units and frames, which the formats do
not record:

- Units (`units`, default ``"auto"``): a tabletop object is between about a
  centimetre and a metre, so a mesh whose largest bounding-box extent exceeds
  `MAX_METRES_EXTENT` (2 units) cannot be in metres and is read as millimetres (a
  millimetre mesh of an object below 2 mm could not be scanned anyway); ``"m"`` and
  ``"mm"`` force the unit.  Centimetres are not guessed (an object of 20-100 units
  could be either): give ``"cm"``.
- Up axis (`up`, default ``"z"``): which model axis points up on the table, as the
  file's author modelled it (``"y"`` for the Y-up convention of many OBJ/PLY
  exporters; ``"x"`` also accepted).  It is not guessed from the geometry: on the
  YCB meshes, which are z up, the flattest lowest face lies on another axis for
  several objects (Lego bricks, rounded boxes), so a "resting face" rule would turn
  correct meshes over.  The mesh is rotated (right-handed, proper rotation) so that
  axis becomes +z.

What was converted is recorded in `Mesh.notes` and said in one warning (per file for
`load_mesh`, per folder for `load_mesh_rows`).

A labelled folder is a folder of meshes plus a CSV ``file,class`` (a header line
``file,class`` is optional; ``#`` starts a comment).  `load_mesh_folder` loads every
listed file; files that fail to load are skipped and reported, meshes that are not
watertight are kept and reported (the scanner only needs the visible surface), and one
warning summarises the problems.  No usable mesh at all is an error.
"""

from __future__ import annotations

import csv
import io
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.compression import open_binary, read_magic
from data.errors import DataError, UserError, warn

Array = NDArray[np.float64]

MESH_FORMATS = ("ply", "obj", "stl")
#: Largest bounding-box extent [units] of a mesh read as metres with ``units="auto"``.
MAX_METRES_EXTENT = 2.0
#: Unit names -> metres per unit.
UNITS: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001}
#: Model axes that can be the up axis.
UP_AXES = ("x", "y", "z")


@dataclass(slots=True)
class Mesh:
    """A triangle mesh in metres.

    Attributes:
        vertices: ``(V, 3)`` float64 positions [m] in the object frame (z up).
        faces: ``(F, 3)`` int64 vertex indices, counter-clockwise seen from outside.
        name: identifier (file name without suffixes, or generator name).
        watertight: every edge shared by exactly two faces (None: not checked).
        notes: conventions converted on loading (units, up axis), for messages.
    """

    vertices: Array
    faces: NDArray[np.int64]
    name: str = "mesh"
    watertight: bool | None = None
    notes: tuple[str, ...] = ()

    @property
    def extent(self) -> Array:
        """``(3,)`` size of the bounding box [m]."""
        return self.vertices.max(axis=0) - self.vertices.min(axis=0)


def edges_watertight(faces: NDArray[np.int64]) -> bool:
    """True when every undirected edge of `faces` is used by exactly two faces."""
    f = np.asarray(faces, dtype=np.int64)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    key = e[:, 0] * (int(f.max()) + 1) + e[:, 1]  # one int64 per undirected edge
    _, counts = np.unique(key, return_counts=True)
    return bool(len(counts) and np.all(counts == 2))


def mesh_from_arrays(vertices: ArrayLike, faces: ArrayLike, name: str = "mesh") -> Mesh:
    """A checked `Mesh` from arrays (raises `DataError` naming `name` when unusable)."""
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3:
        raise DataError(name, f"expected (V, 3) vertices with V >= 3, got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise DataError(name, f"expected (F, 3) triangle faces, got shape {f.shape}")
    f = f.astype(np.int64)
    if f.min() < 0 or f.max() >= len(v):
        raise DataError(name, "face indices outside the vertex list")
    if not np.isfinite(v).all():
        raise DataError(name, "vertex coordinates contain NaN or inf")
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    if not np.any(area > 0):
        raise DataError(name, "every face has zero area")
    return Mesh(v, f, name, edges_watertight(f))


def _format_of(path: Path) -> str:
    suffixes = [s.lower().lstrip(".") for s in path.suffixes]
    while suffixes and suffixes[-1] in ("gz", "bz2", "gzip"):
        suffixes.pop()
    ext = suffixes[-1] if suffixes else ""
    if ext not in MESH_FORMATS:
        raise DataError(path, f"unknown mesh format {ext!r} (expected .ply, .obj, .stl, "
                        "optionally .gz or .bz2)")
    return ext


def mesh_name(path: str | Path) -> str:
    """File name without mesh and compression suffixes (``013_apple.ply.gz``: ``013_apple``)."""
    name = Path(path).name
    return re.sub(r"(\.(ply|obj|stl))?(\.(gz|bz2|gzip))?$", "", name, flags=re.IGNORECASE)


def check_conventions(units: str, up: str) -> None:
    """Raise `UserError` for a unit other than ``auto`` / `UNITS` or an axis not in `UP_AXES`."""
    if units != "auto" and units not in UNITS:
        raise UserError(f"unknown mesh units {units!r}; expected auto, {', '.join(UNITS)}")
    if up not in UP_AXES:
        raise UserError(f"unknown up axis {up!r}; expected one of {', '.join(UP_AXES)}")


def to_metres(vertices: ArrayLike, units: str = "auto") -> tuple[Array, str | None]:
    """Vertices in metres and a note saying what was converted (None: nothing).

    ``units="auto"``: millimetres when the largest bounding-box extent exceeds
    `MAX_METRES_EXTENT`, else metres (module docstring).
    """
    check_conventions(units, "z")
    v = np.asarray(vertices, dtype=float)
    if units == "auto":
        extent = float((v.max(axis=0) - v.min(axis=0)).max())
        if extent <= MAX_METRES_EXTENT:
            return v, None
        return v * UNITS["mm"], (f"largest extent {extent:.4g} units > {MAX_METRES_EXTENT:g} "
                                 "m: read as millimetres")
    if units == "m":
        return v, None
    return v * UNITS[units], f"units {units}: scaled to metres"


def to_z_up(vertices: ArrayLike, up: str = "z") -> tuple[Array, str | None]:
    """Vertices rotated so the model axis `up` becomes +z, and a note (None: z already).

    ``y``: ``(x, y, z) -> (x, -z, y)`` (a quarter turn about x); ``x``:
    ``(x, y, z) -> (-z, y, x)`` (a quarter turn about y).  Both are proper rotations.
    """
    check_conventions("auto", up)
    v = np.asarray(vertices, dtype=float)
    if up == "z":
        return v, None
    if up == "y":
        return np.column_stack([v[:, 0], -v[:, 2], v[:, 1]]), "y up: rotated to z up"
    return np.column_stack([-v[:, 2], v[:, 1], v[:, 0]]), "x up: rotated to z up"


def load_mesh(
    path: str | Path, units: str = "auto", up: str = "z", warn_conversions: bool = True
) -> Mesh:
    """Load one mesh file (plain, ``.gz`` or ``.bz2``) in metres, z up (module docstring).

    `DataError` names the file on failure; conversions are in `Mesh.notes` and, with
    `warn_conversions`, said in one warning.
    """
    import trimesh  # heavy import: only when meshes are loaded

    check_conventions(units, up)
    path = Path(path)
    read_magic(path)  # existence and readability, with a clear error
    fmt = _format_of(path)
    try:
        with open_binary(path) as fh:
            raw = fh.read()
    except (OSError, EOFError) as exc:
        raise DataError(path, f"cannot read: {exc}") from exc
    if not raw.strip():
        raise DataError(path, "file is empty")
    try:
        loaded = trimesh.load(io.BytesIO(raw), file_type=fmt, force="mesh", process=True)
    except Exception as exc:  # trimesh raises many kinds on garbage
        raise DataError(path, f"not a readable {fmt.upper()} mesh ({type(exc).__name__}: "
                        f"{exc})") from exc
    vertices = getattr(loaded, "vertices", None)
    faces = getattr(loaded, "faces", None)
    if vertices is None or faces is None or len(faces) == 0:
        raise DataError(path, f"no triangles in this {fmt.upper()} file")
    mesh = mesh_from_arrays(np.asarray(vertices), np.asarray(faces), str(path))
    mesh.name = mesh_name(path)
    v, unit_note = to_metres(mesh.vertices, units)
    v, up_note = to_z_up(v, up)
    mesh.vertices = v
    mesh.notes = tuple(n for n in (unit_note, up_note) if n)
    if mesh.notes and warn_conversions:
        warn(f"{path}: " + "; ".join(mesh.notes))
    return mesh


def read_labels(path: str | Path) -> list[tuple[str, str]]:
    """``(file, class)`` rows of a labels CSV (header ``file,class`` optional)."""
    path = Path(path)
    read_magic(path)
    rows: list[tuple[str, str]] = []
    with path.open(newline="", encoding="utf-8", errors="replace") as fh:
        for lineno, row in enumerate(csv.reader(fh), start=1):
            cells = [c.strip() for c in row]
            if not cells or not any(cells) or cells[0].startswith("#"):
                continue
            if len(cells) < 2 or not cells[0] or not cells[1]:
                raise DataError(path, f"line {lineno}: expected 'file,class', got {row!r}")
            if lineno == 1 and cells[0].lower() == "file" and cells[1].lower() == "class":
                continue
            rows.append((cells[0], cells[1]))
    if not rows:
        raise DataError(path, "no 'file,class' rows")
    return rows


@dataclass(slots=True)
class MeshSet:
    """Meshes of a labelled folder with what went wrong.

    Attributes:
        meshes: the usable meshes, in CSV order.
        labels: class of each mesh.
        failed: file -> reason, for listed files that could not be used.
        not_watertight: names of kept meshes that are not watertight.
    """

    meshes: list[Mesh]
    labels: list[str]
    failed: dict[str, str] = field(default_factory=dict)
    not_watertight: list[str] = field(default_factory=list)


def load_mesh_folder(
    folder: str | Path, labels_csv: str | Path, units: str = "auto", up: str = "z"
) -> MeshSet:
    """Load the meshes listed in `labels_csv` from `folder` (see the module docstring)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(folder, "not a directory")
    return load_mesh_rows(folder, read_labels(labels_csv), source=labels_csv, units=units,
                          up=up)


def load_mesh_rows(
    folder: str | Path, rows: list[tuple[str, str]], source: str | Path,
    units: str = "auto", up: str = "z",
) -> MeshSet:
    """Load the ``(file, class)`` `rows` from `folder`; files that fail are skipped.

    What went wrong (files that did not load, meshes that are not watertight) and
    what was converted (units, up axis: `load_mesh`) is reported once as a warning
    naming `source` (the labels CSV, or the folder).

    Raises:
        DataError: none of the rows could be loaded (names `source`).
    """
    check_conventions(units, up)
    folder = Path(folder)
    out = MeshSet([], [])
    converted: dict[str, list[str]] = {}
    for file, cls in rows:
        try:
            mesh = load_mesh(folder / file, units, up, warn_conversions=False)
        except DataError as exc:
            out.failed[file] = exc.message
            continue
        if not mesh.watertight:
            out.not_watertight.append(mesh.name)
        for note in mesh.notes:
            kind = "millimetres" if note.startswith("largest") else note
            converted.setdefault(kind, []).append(mesh.name)
        out.meshes.append(mesh)
        out.labels.append(cls)
    if out.failed or out.not_watertight or converted:
        parts = []
        for kind, names in converted.items():
            what = (f"read as millimetres (largest extent > {MAX_METRES_EXTENT:g} units)"
                    if kind == "millimetres" else kind)
            parts.append(f"{len(names)} meshes {what}: {', '.join(names[:3])}"
                         f"{', ...' if len(names) > 3 else ''}")
        if out.failed:
            first = next(iter(out.failed.items()))
            parts.append(f"{len(out.failed)} of {len(rows)} meshes failed to load and were "
                         f"skipped (first: {first[0]}: {first[1]})")
        if out.not_watertight:
            parts.append(f"{len(out.not_watertight)} meshes are not watertight (kept: "
                         f"{', '.join(out.not_watertight[:3])}"
                         f"{', ...' if len(out.not_watertight) > 3 else ''})")
        warn(f"{source}: " + "; ".join(parts))
    if not out.meshes:
        raise DataError(source, f"none of the {len(rows)} listed meshes could be loaded")
    return out


#: YCB multi-instance classes (SOURCES.md): file-name stem prefix -> class.
YCB_MULTI_INSTANCE: dict[str, str] = {
    "053_": "ball", "054_": "ball", "055_": "ball", "056_": "ball", "057_": "ball",
    "058_": "ball",
    "065-": "cup",
    "073-": "lego_duplo",
    "072-": "toy_airplane",
    "003_": "box", "004_": "box", "008_": "box", "009_": "box",
}


def ycb_labels(folder: str | Path) -> list[tuple[str, str]]:
    """``(file, class)`` of the YCB meshes in `folder` that belong to a multi-instance class.

    Classes: balls (053-058), stacking cups (065-*), Lego Duplo (073-*), toy airplane
    parts (072-*) and the food boxes (003, 004, 008, 009).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(folder, "not a directory")
    out = []
    for p in sorted(folder.iterdir()):
        for prefix, cls in YCB_MULTI_INSTANCE.items():
            if p.name.startswith(prefix):
                out.append((p.name, cls))
                break
    if not out:
        raise DataError(folder, "no YCB multi-instance meshes (053-058, 065, 072, 073, boxes)")
    return out


def write_labels(path: str | Path, rows: list[tuple[str, str]]) -> None:
    """Write a ``file,class`` labels CSV with a header."""
    path = Path(path)
    if not rows:
        raise UserError("no labels to write")
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["file", "class"])
        w.writerows(rows)
