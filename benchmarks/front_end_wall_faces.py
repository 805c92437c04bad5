"""Benchmark: where a corrected log's reference puts a wall's two faces and one scan's
view of it.

Run from the repository root::

    python benchmarks/front_end_wall_faces.py [--data DIR] --log belgioioso \
        --scan 168 --near 160-171 --far 137-152 \
        --box 0,1.5,-31.1,-30.5 --box 1.6,2.1,-32.5,-31.2

The end points (as the icp2d front end takes them) of the ``--near`` scans (those that
saw the wall from the side scan ``--scan`` is on; the scan itself left out) and of the
``--far`` scans (from the other side) are placed at the GMapping reference's poses.
Per ``--box`` (``xmin,xmax,ymin,ymax`` in the reference's frame [m], one straight
piece of wall): a line fitted to the near points (total least squares), its normal
``n`` pointing to the scan's side, and the median signed offset along ``n`` [m] of
the far points, the near points and the scan's points at its reference pose.  An
opaque wall's far face lies behind its near face (negative offset), and a scan from
the near side sees the near face (offset about zero): a scan placed behind the near
face, or behind the far one, is misplaced by the reference by that much.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from data import se2
from evaluation.slam_input import load_input
from evaluation.slam_reference import logged_reference
from slam.odometry.icp2d import Icp2dOdometry


def _span(text: str) -> list[int]:
    first, _, last = text.partition("-")
    return list(range(int(first), int(last or first) + 1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2]
                        / "shared" / "data")
    parser.add_argument("--log", default="belgioioso")
    parser.add_argument("--scan", type=int, required=True)
    parser.add_argument("--near", required=True, help="FIRST-LAST scans")
    parser.add_argument("--far", required=True, help="FIRST-LAST scans")
    parser.add_argument("--box", action="append", required=True)
    args = parser.parse_args()
    log = args.log.removesuffix("-corrected")
    loaded = load_input(args.data / "carmen-corrected" / f"{log}-corrected.log.gz",
                        odometry_noise=0)
    ref = logged_reference(loaded).xytheta()
    odo = Icp2dOdometry()
    placed = {k: se2.transform_points(ref[k], odo.scan_points(loaded.scans[k]))
              for k in {args.scan, *_span(args.near), *_span(args.far)}}
    near_scans = [k for k in _span(args.near) if k != args.scan]
    for text in args.box:
        x0, x1, y0, y1 = (float(v) for v in text.split(","))

        def inside(ks: list[int], x0=x0, x1=x1, y0=y0, y1=y1) -> np.ndarray:
            p = np.vstack([placed[k] for k in ks])
            return p[(p[:, 0] > x0) & (p[:, 0] < x1) & (p[:, 1] > y0) & (p[:, 1] < y1)]

        near, far, scan = inside(near_scans), inside(_span(args.far)), inside([args.scan])
        centre = near.mean(axis=0)
        normal = np.linalg.svd(near - centre)[2][1]
        if normal @ (ref[args.scan][:2] - centre) < 0:
            normal = -normal
        off = {name: float(np.median((pts - centre) @ normal)) if len(pts) else np.nan
               for name, pts in (("far", far), ("near", near), ("scan", scan))}
        print(f"box {text}: normal ({normal[0]:+.2f}, {normal[1]:+.2f}); median offset "
              f"far face {off['far']:+.3f} ({len(far)} points), near face "
              f"{off['near']:+.3f} ({len(near)}), scan {args.scan} {off['scan']:+.3f} "
              f"({len(scan)}) m; scan behind the near face by "
              f"{off['near'] - off['scan']:+.3f} m")


if __name__ == "__main__":
    main()
