"""Benchmark: ring projection and FFT about other reference points than the area centroid.

Run from the repository root::

    python benchmarks/place_centres.py --dataset box --dataset robot:DIR
        [--range-cap M] [--centre NAME ...] [--per-log]

Each data set is loaded as ``loopclosure bench places`` loads it (seed 0).  For every
centre below, the default ring projection (32 rings to 20 m, arc lengths, L2) and the
default FFT (256 bins, 16 amplitudes, farthest hit) are computed about that point
instead of the polygon's area centroid, and the Bull's eye [%] is printed (the
matchers' own arithmetic: `ring_projection.ring_profile`, `fft.range_function`).
Shape sets (MPEG-7, scale invariant) have no sensor: they are skipped.

Centres (sensor frame [m]).  A vertex is *observed* unless it lies at the polygon's
largest range from the sensor (the range cap: open space), up to a relative 1e-6;
when fewer than 3 are observed every vertex counts.

- ``area``: area centroid (the matchers' default).
- ``sensor``: the sensor origin (0, 0), the paper's own for the FFT of a raw scan.
- ``boundary``: centroid of the boundary edges between two observed vertices,
  weighted by their length (walls, not open space or the cap).
- ``walls``: as ``boundary`` but only edges of at most 0.5 m (no depth jumps).
- ``mean``: mean of the observed vertices (one per beam).
- ``median``: geometric median of the observed vertices (Weiszfeld, 50 steps).
- ``near``: area centroid of the polygon within 5 m of the sensor
  (`loopclosure.polygon.polygon_within`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import scipy.fft
from numpy.typing import NDArray

sys.path.insert(0, str(Path(__file__).resolve().parent))

from paper_place_matchers import bullseye_by_group, bullseye_rows

from evaluation.place_datasets import RobotPlacesConfig, load_dataset
from loopclosure.matchers.fft import range_function
from loopclosure.matchers.ring_projection import ring_profile
from loopclosure.polygon import Polygon, polygon_within

Array = NDArray[np.float64]


def observed(v: Array) -> NDArray[np.bool_]:
    """Vertices of `v` ``(N, 2)`` not at the largest range from the origin (all if < 3)."""
    r = np.hypot(v[:, 0], v[:, 1])
    keep = r < r.max() * (1.0 - 1e-6)
    return keep if keep.sum() >= 3 else np.ones(len(v), bool)


def boundary_centre(v: Array, max_edge: float = np.inf) -> Array:
    """Length-weighted centroid of the edges between two observed vertices [m]."""
    keep = observed(v)
    nxt = np.roll(v, -1, axis=0)
    length = np.linalg.norm(nxt - v, axis=1)
    length = length * (keep & np.roll(keep, -1) & (length <= max_edge))
    if length.sum() <= 0:
        return Polygon(v).centroid()
    return (0.5 * (v + nxt) * length[:, None]).sum(axis=0) / length.sum()


def geometric_median(points: Array, steps: int = 50) -> Array:
    """Point minimising the sum of distances to `points` (Weiszfeld iterations) [m]."""
    c = np.median(points, axis=0)
    for _ in range(steps):
        w = 1.0 / np.maximum(np.linalg.norm(points - c, axis=1), 1e-9)
        c = (points * w[:, None]).sum(axis=0) / w.sum()
    return c


CENTRES = {
    "area": lambda v: Polygon(v).centroid(),
    "sensor": lambda v: np.zeros(2),
    "boundary": boundary_centre,
    "walls": lambda v: boundary_centre(v, 0.5),
    "mean": lambda v: v[observed(v)].mean(axis=0),
    "median": lambda v: geometric_median(v[observed(v)]),
    "near": lambda v: polygon_within(Polygon(v), 5.0).centroid(),
}


def ring_about(v: Array, centre: Array) -> Array:
    """Default ring profile (32 arc lengths [m], rings 0.625 m apart) about `centre`."""
    return ring_profile(v, centre, 20.0 / 32, 32) * ((np.arange(32) + 0.5) * 20.0 / 32)


def fft_about(v: Array, centre: Array) -> Array:
    """Default FFT amplitudes (16 of 256 bins [m]) about `centre`."""
    return np.abs(scipy.fft.rfft(range_function(v, centre, 256)))[:16] / 256


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", action="append", required=True)
    ap.add_argument("--range-cap", type=float, default=None)
    ap.add_argument("--centre", action="append", choices=sorted(CENTRES), default=[])
    ap.add_argument("--per-log", action="store_true")
    args = ap.parse_args()
    robot = RobotPlacesConfig(range_cap=args.range_cap)
    for spec in args.dataset:
        polygons, labels, description = load_dataset(spec, robot=robot)
        if description.get("scale_invariant", False):
            print(f"{spec}: a shape set, no sensor: skipped")
            continue
        labels = np.asarray(labels)
        rows = np.arange(len(polygons))
        for name in args.centre or list(CENTRES):
            centre = CENTRES[name]
            for kind, describe in (("ring", ring_about), ("fft", fft_about)):
                x = np.stack([describe(p.vertices, centre(p.vertices)) for p in polygons])
                d = np.linalg.norm(x[:, None, :] - x[None, :, :], axis=2)
                print(
                    f"{spec} cap={args.range_cap} {kind} about {name}: Bull's eye "
                    f"{bullseye_rows(d, labels, rows):.2f} %",
                    flush=True,
                )
                if args.per_log:
                    parts = bullseye_by_group(d, labels, rows)
                    print("    " + "  ".join(f"{g} {v:.1f}" for g, v in parts.items()))


if __name__ == "__main__":
    main()
