"""The plugin: scan -> polygon -> descriptors -> place database -> verified loop closures.

A host (any mapper) needs only what this front door exports::

    from loopclosure import LoopClosureDetector

    detector = LoopClosureDetector(submap=lambda key: keyframes[key].points())
    detector.add_keyframe(key, stamp, scan)
    for loop in detector.detect(key, poses):
        ...  # loop.relative, loop.covariance -> gtsam.BetweenFactorPose2(match, query)

`LoopClosureDetector` owns a `PlaceDatabase` (cheap rotation-invariant prefilters
over every keyframe, expensive verifiers on the few best, fused score) and the
geometric check; `get_matcher` builds any of the place-recognition paper's eight
shape matchers, or the cascade, by name (`MATCHER_NAMES`).  Every error raised on
purpose is a `LoopClosureError`; a caller's mistake is a `UserError` (also a
`ValueError`), an unreadable file a `DataError`.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

from data.errors import DataError, LoopClosureError, UserError
from loopclosure.geometric_check import GeometricCheckConfig, LoopVerification, verify
from loopclosure.loop_detector import LoopCandidate, LoopClosureConfig, LoopClosureDetector
from loopclosure.matcher_registry import MATCHER_NAMES, get_matcher, matcher_class
from loopclosure.matchers.base import Matcher
from loopclosure.place_config import PlaceDatabaseConfig
from loopclosure.place_database import PlaceDatabase
from loopclosure.place_match import PlaceMatch
from loopclosure.polygon import DegeneratePolygonError, Polygon, PolygonConfig, polygon_from_scan

try:
    __version__ = version("loopclosure")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"

__all__ = [
    "MATCHER_NAMES",
    "DataError",
    "DegeneratePolygonError",
    "GeometricCheckConfig",
    "LoopCandidate",
    "LoopClosureConfig",
    "LoopClosureDetector",
    "LoopClosureError",
    "LoopVerification",
    "Matcher",
    "PlaceDatabase",
    "PlaceDatabaseConfig",
    "PlaceMatch",
    "Polygon",
    "PolygonConfig",
    "UserError",
    "__version__",
    "get_matcher",
    "matcher_class",
    "polygon_from_scan",
    "verify",
]
