"""Compile the numba kernels the mapper uses, once, on a small made-up place.

numba compiles a kernel on its first call and keeps the machine code in its on-disk
cache (``cache=True``), so only the first run after an install pays for it: about
half a minute on 2 cores, for the front end's ICP, the place descriptors (surface
pairs, FLIRT), the virtual scans, the pose-gated check's screens and ICP, and the correlative check.
`warm_up` makes those first calls on a synthetic room (a 10 m x 6 m rectangle with
a pillar, seen by a 360-beam scan from two poses) through the same public
functions, with the same argument types, as a real run; with a warm cache it only
loads the kernels (well under a second).

The embedded demo calls it, so that a log mapped after the install measures the
mapping, not the compiler.  `warm_up_isolated` compiles in a child process when the
cache is cold: LLVM's memory (over 100 MB) then leaves with the child, and the
mapper (with the front-end worker it forks) only loads the kernels.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable

import numpy as np

from data.types import Scan
from loopclosure import (
    correlative,
    fast_icp,
    fast_points,
    grid_overlap,
    icp_kernel,
    prior_screen,
)
from loopclosure.kernel_cache import kernels_cold
from loopclosure.matchers.flirt import FlirtMatcher
from loopclosure.matchers.pair_histogram import PairHistogramMatcher
from loopclosure.polygon import polygon_from_scan
from loopclosure.registration import RegistrationTarget
from loopclosure.virtual_scan import virtual_scan

_ROOM = ((-5.0, -3.0), (5.0, 3.0))  # lower-left and upper-right corners [m]
_PILLAR = ((1.0, 0.5), 0.4)  # centre [m], radius [m]


def room_scan(x: float, y: float, beams: int = 360, max_range: float = 20.0) -> Scan:
    """A noise-free ``beams``-beam 360-degree scan of the synthetic room from ``(x, y)``
    (heading 0): the nearest of the four walls and the pillar along each beam."""
    angles = np.linspace(-np.pi, np.pi, beams, endpoint=False)
    c, s = np.cos(angles), np.sin(angles)
    (x0, y0), (x1, y1) = _ROOM
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (x1 - x) / c, np.where(c < 0, (x0 - x) / c, np.inf))
        ty = np.where(s > 0, (y1 - y) / s, np.where(s < 0, (y0 - y) / s, np.inf))
    ranges = np.minimum(tx, ty)
    (px, py), radius = _PILLAR
    b = c * (x - px) + s * (y - py)  # ray-circle: t^2 + 2 b t + cc = 0
    cc = (x - px) ** 2 + (y - py) ** 2 - radius**2
    disc = b * b - cc
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    hit = (disc > 0) & (t > 0)
    ranges = np.where(hit, np.minimum(ranges, t), ranges)
    return Scan(0.0, ranges, angles, max_range)


def warm_up() -> None:
    """Compile (or load from numba's cache) every kernel a default run calls."""
    scans = [room_scan(-1.0, -0.5), room_scan(-0.8, -0.4)]
    points = [s.points() for s in scans]
    # Front end and geometric check: the beams' end points, voxel grid, grid normals,
    # ICP and its figures.
    scan = scans[0]
    fast_icp.beam_points_fast(scan.ranges, np.cos(scan.angles), np.sin(scan.angles),
                              (0.0, scan.max_range, 0.0, scan.max_range), 0.05)
    target = fast_icp.GridTarget(fast_icp.voxel_downsample_fast(points[0], 0.05))
    fast_icp.register_fast(points[1], target, (0.2, 0.1, 0.0))
    lazy = fast_icp.GridTarget(fast_icp.voxel_downsample_fast(points[0], 0.05), lazy=True)
    fast_icp.register_fast(points[1], lazy, (0.2, 0.1, 0.0))
    # The loop detector's targets (compiled normals) and the pose-gated check: both
    # screens in one pass, then multi-start ICP with joined runs on the candidate's grid.
    check = RegistrationTarget(points[0], normals=fast_icp.estimate_normals_fast)
    grid_check = fast_icp.GridTarget.from_target(check, fast_icp.TARGET_GRID_CELL)
    guesses = np.array([[0.2, 0.1, 0.0], [0.2, 0.1, 0.001], [-0.3, 0.0, 0.2]])
    fast_icp.overlap_screen(points[1], grid_check, guesses, 1.0, 0.55)
    fast_icp.overlap_bound(points[1], grid_check, guesses, 0.55)
    prior_screen.screen_passes(points[1], grid_check, guesses, 1.0, 0.55, 0.15, 0.35)
    fast_icp.register_target(points[1], check, guesses, grid=grid_check)
    # The check with no prior: the correlative search over a likelihood grid.
    grid = correlative.LikelihoodGrid(points[0], 0.1, 0.2)
    correlative.search(points[1], grid, np.array([-0.05, 0.0, 0.05]), 0.5, 1)
    # The place database: surface-pair histogram and FLIRT (its beta-grid counts
    # compiled too), described and compared.
    # The loop detector's 360-degree virtual scans of local maps.
    virtual_scan(np.vstack(points), 360, 20.0)
    polygons = [polygon_from_scan(s) for s in scans]
    PairHistogramMatcher().describe(polygons[0])
    flirt = FlirtMatcher()
    features = [flirt.describe(p) for p in polygons]
    flirt.distances(features[1], flirt.stack(features[:1]))


def cache_is_cold() -> bool:
    """True when a kernel `warm_up` compiles has no usable machine code in numba's
    on-disk cache (a first run after an install, sources changed since, or an index
    `loopclosure.kernel_cache.drop_stale` emptied).  Read from numba's cache objects;
    a numba that keeps them elsewhere counts as warm (no child)."""
    from loopclosure import virtual_scan_kernel
    from loopclosure.matchers import (
        flirt_curve_kernel,
        flirt_grid_kernel,
        flirt_kernel,
        flirt_peak_kernel,
        pair_kernel,
    )

    kernels = (icp_kernel._register_kernel, grid_overlap._screen_kernel,
               prior_screen._screen_until_kernel,
               fast_points._voxel_kernel, fast_points._beam_points_kernel,
               flirt_peak_kernel.responses_kernel,
               correlative._correlate, flirt_kernel.flirt_entries,
               flirt_kernel.euclidean_distances,
               flirt_grid_kernel.beta_grid_counts, flirt_grid_kernel.beta_posterior,
               flirt_peak_kernel.local_maxima_kernel, flirt_peak_kernel.peak_candidates_kernel,
               flirt_curve_kernel.resample_kernel, flirt_curve_kernel.origin_view_kernel,
               pair_kernel._pair_kernel, pair_kernel.surface_samples_kernel,
               virtual_scan_kernel.candidates,
               virtual_scan_kernel.front_most)
    return kernels_cold(kernels)


def warm_up_isolated(
    warm: Callable[[], None] | None = None, cold: Callable[[], bool] | None = None
) -> None:
    """`warm` (default `warm_up`), compiling in a spawned child process first when
    `cold()` (default `cache_is_cold`) says the cache is cold (module docstring); the
    kernels are then loaded here from the cache.  A higher layer passes its own pair
    (a module-level `warm`, which the child imports) that also covers this module's
    kernels (`slam.kernel_warm_up`)."""
    warm = warm or warm_up
    cold = cold or cache_is_cold
    if cold():
        child = multiprocessing.get_context("spawn").Process(target=warm)
        child.start()
        child.join()  # a child that failed leaves the compiling to the call below
    warm()


__all__ = ["cache_is_cold", "room_scan", "warm_up", "warm_up_isolated"]
