"""The stripes benchmark's methods: each one's distance matrix over the scanned set.

Every function describes every scan (or its silhouette) with one method and returns the
full ``(n, n)`` distance matrix with the wall seconds of description and matching
(`evaluation.stripes_benchmark` says what each method is): the stripes
(`stripes_distances`), the stripe profiles (`profile_distances`), the height-map
methods (`relief_distances`, `surface_distances`, `canonical_distances`) and the
silhouette baselines, registered matchers of `loopclosure.matchers` with scale
invariance on where they have it (`baseline_matcher`, `baseline_distances`,
`_available_baselines`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError, warn
from data.stripe_scanner import ScannerConfig, StripeScan
from evaluation.stripes_objects import height_map
from loopclosure.polygon import Polygon
from loopclosure.stripes import (
    CanonicalConfig,
    CanonicalDatabase,
    DescriptorConfig,
    ProfileConfig,
    ProfileDatabase,
    ReliefConfig,
    ReliefDatabase,
    StripeDatabase,
    SurfaceConfig,
    SurfaceDatabase,
    describe_canonical,
    describe_many,
    describe_profiles,
    describe_relief,
    describe_surface,
)
from loopclosure.stripes.fusion import VERIFIER_PRESETS, verifier_options

Array = NDArray[np.float64]
Progress = Callable[[str, int, int], None]


def stripes_distances(
    scans: Sequence[StripeScan], config: DescriptorConfig | None = None
) -> tuple[Array, float]:
    """Stripe descriptors of every scan and the full distance matrix; wall time [s]."""
    t0 = time.perf_counter()
    descs = describe_many([s.stripes for s in scans], config, names=[s.name for s in scans])
    d = StripeDatabase(descs).pairwise()
    return d, time.perf_counter() - t0


def profile_distances(
    scans: Sequence[StripeScan], config: ProfileConfig | None = None
) -> tuple[Array, float]:
    """Stripe profiles of every scan and the full distance matrix; wall time [s]."""
    t0 = time.perf_counter()
    profiles = describe_profiles([s.stripes for s in scans], config,
                                 names=[s.name for s in scans])
    d = ProfileDatabase(profiles).pairwise()
    return d, time.perf_counter() - t0


def _height_map_distances(
    describe: Callable[..., Any], database: Callable[[list[Any]], Any],
    scans: Sequence[StripeScan], scanner: ScannerConfig, config: Any,
) -> tuple[Array, float]:
    """`describe` of every scan's height map (`StripeScan.height_map` with the `scanner`
    that made them), the full distance matrix of their `database`; wall time [s]."""
    t0 = time.perf_counter()
    parts = [describe(*height_map(s, scanner), config, s.name) for s in scans]
    d = database(parts).pairwise()
    return d, time.perf_counter() - t0


def relief_distances(
    scans: Sequence[StripeScan], scanner: ScannerConfig, config: ReliefConfig | None = None
) -> tuple[Array, float]:
    """Reliefs of every scan and their full distance matrix (`_height_map_distances`)."""
    return _height_map_distances(describe_relief, ReliefDatabase, scans, scanner, config)


def surface_distances(
    scans: Sequence[StripeScan], scanner: ScannerConfig, config: SurfaceConfig | None = None
) -> tuple[Array, float]:
    """Surface contexts of every scan and their full distance matrix
    (`_height_map_distances`)."""
    return _height_map_distances(describe_surface, SurfaceDatabase, scans, scanner, config)


def canonical_distances(
    scans: Sequence[StripeScan], scanner: ScannerConfig, config: CanonicalConfig | None = None
) -> tuple[Array, float]:
    """Canonical profiles of every scan and their full distance matrix
    (`_height_map_distances`)."""
    return _height_map_distances(describe_canonical, CanonicalDatabase, scans, scanner,
                                 config)


def baseline_matcher(name: str) -> tuple[Any, dict[str, Any]]:
    """The matcher `name` with scale invariance on when it has the option; and its options.

    Raises:
        UserError: `name` is not a registered matcher.
        ImportError: the matcher is registered but its module is not importable yet.
    """
    from loopclosure.matcher_registry import MATCHER_NAMES, matcher_class

    base, preset = verifier_options(name)
    if base not in MATCHER_NAMES:
        raise UserError(f"unknown baseline matcher {name!r}; known: "
                        f"{', '.join((*MATCHER_NAMES, *VERIFIER_PRESETS))}")
    cls = matcher_class(base)
    try:
        return cls(scale_invariant=True, **preset), {"scale_invariant": True, **preset}
    except UserError:  # the matcher has no such option
        return cls(**preset), {"scale_invariant": False, **preset}


def baseline_distances(
    name: str, polygons: Sequence[Polygon], progress: Progress | None = None
) -> tuple[Array, float, dict[str, Any]]:
    """Distance matrix of matcher `name` on the silhouette polygons; wall time [s]; options.

    The time covers the matcher's description of every silhouette and the matching;
    the silhouettes themselves are made once for all baselines (`silhouette_polygon`).
    """
    matcher, options = baseline_matcher(name)
    t0 = time.perf_counter()
    descs = [matcher.describe(p) for p in polygons]
    if getattr(matcher, "symmetric_pairwise", False):  # each unordered pair once
        d = np.asarray(matcher.pairwise(descs), dtype=float)
        if progress is not None:
            progress(name, len(descs), len(descs))
        return d, time.perf_counter() - t0, options
    stacked = matcher.stack(descs)
    rows = []
    for i, q in enumerate(descs):
        rows.append(np.asarray(matcher.distances(q, stacked), dtype=float))
        if progress is not None:
            progress(name, i + 1, len(descs))
    return np.stack(rows), time.perf_counter() - t0, options


def _available_baselines(names: Sequence[str]) -> tuple[list[str], dict[str, str]]:
    """The baselines that can run, and name -> reason for those skipped (one warning).

    Raises:
        UserError: a name that is not a registered matcher.
    """
    available: list[str] = []
    skipped: dict[str, str] = {}
    for name in names:
        try:
            baseline_matcher(name)
            available.append(name)
        except ImportError as exc:
            skipped[name] = f"not available yet ({exc})"
    if skipped:
        warn(f"skipped {len(skipped)} baseline(s) not available yet: {', '.join(skipped)}")
    return available, skipped
