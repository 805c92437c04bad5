"""The stripes benchmark's unit of work: one matcher's distance matrix on the scans.

One matcher on the scanned set is one task (`MatcherTask`, run by `matcher_task`):
``stripes``, ``profile`` and every silhouette baseline or verifier, each returning
its distance matrix, wall seconds and options (`MatcherRows`); the retrieval figures
and the fused row are computed from the matrices afterwards.  The process running a
task scans the objects (and makes the silhouettes) once; without a cluster the tasks
run here on the scans already made, with ``cluster`` (`evaluation.cluster`) each
worker rebuilds the object set from a `StripesSource` and scans it with the same
seed, so the matrices are the same; only the seconds differ.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from evaluation.stripes_config import StripesBenchmarkConfig
from evaluation.stripes_methods import (
    Progress,
    baseline_distances,
    canonical_distances,
    profile_distances,
    relief_distances,
    stripes_distances,
    surface_distances,
)
from evaluation.stripes_objects import ObjectSet, ScannedSet, scan_objects, silhouette_polygon
from loopclosure.polygon import Polygon

Array = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class StripesSource:
    """The object set as a worker rebuilds it: the Daily-like set (`daily`: seed,
    `per_class`, `classes`) or a folder of meshes (`meshes`, `labels`, `units`, `up`);
    relative paths are taken from `folder` (the caller's working folder)."""

    daily: bool = True
    seed: int = 0
    per_class: int = 10
    classes: tuple[str, ...] | None = None
    meshes: str | None = None
    labels: str | None = None
    units: str = "auto"
    up: str = "z"
    folder: str = "."

    def objects(self) -> ObjectSet:
        from data.stripe_scanner import DAILY_CLASSES
        from evaluation.stripes_objects import daily_objects, mesh_folder_objects

        if self.daily:
            return daily_objects(self.seed, self.per_class, self.classes or DAILY_CLASSES)
        here = Path(self.folder)
        labels = here / self.labels if self.labels is not None else None
        return mesh_folder_objects(here / str(self.meshes), labels, units=self.units,
                                   up=self.up)


@dataclass(frozen=True, slots=True)
class MatcherTask:
    """One task: the distance matrix of `method` (``stripes``, ``profile`` or a
    silhouette matcher) on the scans of the object set `source` names (a
    `StripesSource`, or the key of a scanned set held in this process's memory)."""

    source: StripesSource | str
    config: StripesBenchmarkConfig
    method: str


@dataclass(slots=True)
class MatcherRows:
    """What one `MatcherTask` returns: the ``(n, n)`` matrix, its wall seconds, the
    matcher's options (silhouette matchers), and the seconds of the silhouettes in
    the process that made them (silhouette matchers only, else 0)."""

    method: str
    distances: Array
    seconds: float
    options: dict[str, Any] = field(default_factory=dict)
    silhouette_seconds: float = 0.0


_SCANNED: dict[Any, tuple[ScannedSet, Progress | None]] = {}
"""The scanned sets this process holds, by (source, scanner config)."""
_SILHOUETTES: dict[Any, tuple[list[Polygon], float]] = {}
"""Their silhouettes and the seconds they took, by the same key."""


def _scan_key(source: StripesSource | str, cfg: StripesBenchmarkConfig) -> tuple[Any, str]:
    return (source, repr((cfg.scanner, cfg.seed, cfg.scans_per_object)))


def _scanned_of(task: MatcherTask) -> tuple[ScannedSet, Progress | None]:
    """The scans `task` needs: held here already, or made now (once per process)."""
    key = _scan_key(task.source, task.config)
    if key not in _SCANNED:
        if not isinstance(task.source, StripesSource):
            raise UserError("bench stripes: this worker does not hold the scans in memory; "
                            "give the objects as a StripesSource")
        cfg = task.config
        scanned = scan_objects(task.source.objects(), cfg.scanner, cfg.seed,
                               cfg.scans_per_object)
        _SCANNED.clear()  # a worker holds one scanned set at a time
        _SILHOUETTES.clear()
        _SCANNED[key] = (scanned, None)
    return _SCANNED[key]


def matcher_task(task: MatcherTask) -> MatcherRows:
    """One matcher's distance matrix on the scans (`MatcherTask`)."""
    scanned, progress = _scanned_of(task)
    cfg = task.config
    if task.method == "stripes":
        return MatcherRows("stripes", *stripes_distances(scanned.scans, cfg.descriptor))
    if task.method == "profile":
        return MatcherRows("profile", *profile_distances(scanned.scans, cfg.profile))
    if task.method == "relief":
        return MatcherRows("relief", *relief_distances(scanned.scans, cfg.scanner, cfg.relief))
    if task.method == "surface":
        return MatcherRows("surface", *surface_distances(scanned.scans, cfg.scanner,
                                                         cfg.surface))
    if task.method == "canonical":
        return MatcherRows("canonical", *canonical_distances(scanned.scans, cfg.scanner,
                                                             cfg.canonical))
    key = _scan_key(task.source, cfg)
    if key not in _SILHOUETTES:
        t0 = time.perf_counter()
        polygons = [silhouette_polygon(s, cfg.scanner, cfg.silhouette_smooth)
                    for s in scanned.scans]
        _SILHOUETTES[key] = (polygons, time.perf_counter() - t0)
    polygons, silhouette_seconds = _SILHOUETTES[key]
    d, secs, options = baseline_distances(task.method, polygons, progress)
    return MatcherRows(task.method, d, secs, options, silhouette_seconds)
