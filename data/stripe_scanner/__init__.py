"""A laser-stripe scanner simulator and the meshes it scans (stripes paper, Section III).

- `meshes`: load ``.ply/.obj/.stl`` (also compressed) and labelled mesh folders.
- `daily`: parametric generators of the paper's ten Daily100 classes.
- `scanner`: the simulated scanner (line laser, triangulation camera, occlusion and
  laser shadow, noise) producing each object's ordered stripes.
- `line_detector`: the scanner's per-column laser-line detector.
"""

from data.stripe_scanner.daily import DAILY_CLASSES, daily_set, make_object
from data.stripe_scanner.line_detector import laser_line_positions
from data.stripe_scanner.meshes import (
    Mesh,
    MeshSet,
    load_mesh,
    load_mesh_folder,
    mesh_from_arrays,
    read_labels,
    write_labels,
    ycb_labels,
)
from data.stripe_scanner.scanner import ScannerConfig, StripeScan, scan_mesh, scan_meshes

__all__ = [
    "DAILY_CLASSES",
    "Mesh",
    "MeshSet",
    "ScannerConfig",
    "StripeScan",
    "daily_set",
    "laser_line_positions",
    "load_mesh",
    "load_mesh_folder",
    "make_object",
    "mesh_from_arrays",
    "read_labels",
    "scan_mesh",
    "scan_meshes",
    "write_labels",
    "ycb_labels",
]
