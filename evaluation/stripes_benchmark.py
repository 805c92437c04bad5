"""The stripes paper's object-retrieval benchmark: Table I, Table II, Bull's eye, timing.

Paper: "Stripes-based Object Matching" (``papers/stripes-object-matching.txt``),
Section VI.B-C.  `run_stripes_benchmark` scans an object set
(`evaluation.stripes_objects`), ranks every scan against all of them with each
method, and scores every distance matrix with the paper's retrieval figures
(`evaluation.stripes_retrieval`: Table I counts, Table II class accuracy, Bull's
eye, nearest-neighbour precision, each also without the query's sibling scans, the
"other objects" figures).  The YCB target (nearest-neighbour precision >= 0.9) is
reported both ways and the report (`evaluation.stripes_report`) says which is which.

Methods on the same scans:

- ``stripes``: `loopclosure.stripes` descriptors ``[l, d, o]`` (Eq. 1-3) and the
  vectorised `StripeDatabase` (Eq. 4-6, lambda = 0.6, 0.3, 0.1).
- Baselines on the object's silhouette (`evaluation.stripes_objects.silhouette_polygon`:
  the scanned footprint, `StripeScan.silhouette()`, made isotropic in millimetres,
  closed by one pixel, outer contour smoothed as the MPEG-7 rule of
  `data.mpeg7.contour_from_image`), compared by the place-recognition matchers of
  `loopclosure.matchers` with scale invariance switched on where the matcher has it
  (customary for object shapes).  The baseline list is a parameter; a registered
  matcher whose module is not importable yet is skipped with one warning.
- ``profile``: the same stripes as `loopclosure.stripes.StripeProfile`s (``[l, d, e]``
  resampled to 32 positions along the sweep, scale-free, order kept; see
  `loopclosure.stripes.profile`) and `ProfileDatabase`: the stripe matcher for object
  classes whose members differ in size.
- ``surface``: the same stripes' heights as 3D surface points in metres and
  `loopclosure.stripes.SurfaceDatabase`: the joint histogram of the distances
  (scale-free) and elevations of pairs of surface points, Eq. 1-2 over the whole
  object instead of within one stripe.
- ``canonical``: the same stripes' heights cut into virtual stripes along the
  footprint's long axis (`loopclosure.stripes.CanonicalDatabase`): a profile free of
  the scan direction and of the object's yaw.
- ``fused-stripes``: profile, relief, surface context and canonical profile combined
  by `loopclosure.stripes.fuse` (each method's distances locally scaled,
  ``D(q, j) / sqrt(s(q) s(j))`` with ``s`` the distance to the 5th nearest other
  object, `StripesBenchmarkConfig.scaling`; their geometric mean with equal weights,
  `StripesBenchmarkConfig.mean`): the matcher that reads nothing but the stripes.
- ``fused``: the default matcher (`loopclosure.stripes.FusedObjectDatabase`): profile,
  relief, surface context and the silhouette verifiers (default
  ``shape-context-50``), same rule; its time is the parts' times plus the fusion.
- ``fused-sc``: the same rule with shape context as the one verifier (the profile's
  distance and shape context's, each divided by its per-query median, equal
  weights); by default the ``shape-context-50`` preset of
  `loopclosure.stripes.fusion.VERIFIER_PRESETS` (50 boundary points, the compiled
  kernel, each unordered pair solved once).  The profile reads the object along the
  sweep (where along its length it is tall, round or flat) and is blind to the
  footprint's outline once resampled (a long box and a can are one profile); shape
  context reads the outline and is blind to height: the two miss different objects,
  so their sum verifies each other.  FFT and ring projection are global summaries of
  the outline and repeat much of what the profile's ``l`` already says.  Its time is
  the profile's plus shape context's (all pairs: quadratic in the set, shape
  context's point matching dominates).
- ``relief``: the same stripes' rows as heights above the table
  (`data.stripe_scanner.StripeScan.height_map`, the scanner's calibration) and
  `loopclosure.stripes.ReliefDatabase`: the mean depth below the object's top, in
  units of its size, in rings about the footprint's centre (yaw and scale free).
- ``fused-relief``: the ``fused-sc`` rule with the relief as a third part (profile,
  relief and shape context, each divided by its per-query median, equal weights).
  The relief says what the other two cannot: how deep the surface falls below the
  top (flat box tops against studded bricks, lids, domes and hollows); its time is
  the three parts' times.

With two or more scans per object every method also gets the different-pose figures
(`evaluation.stripes_retrieval.cross_pose`): first scans as queries against a
database of second scans, each scan from its own random pose.

Timing (`seconds`): representation + matching of the whole set (descriptors of every
object and the full distance matrix), wall clock in this process, against the paper's
0.0375 h (Matlab, stripes) and 1.6223 h (shape context).  Scanning is the simulator's
cost and is reported apart (`scan_seconds`).

Unit of work
------------
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
import uuid
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError, warn
from data.stripe_scanner import ScannerConfig, StripeScan
from evaluation.stripes_objects import (
    ObjectSet,
    ScannedSet,
    height_map,
    scan_objects,
    silhouette_polygon,
)
from evaluation.stripes_retrieval import MethodResult, evaluate
from loopclosure.polygon import Polygon
from loopclosure.stripes import (
    DEFAULT_VERIFIERS,
    SC_VERIFIERS,
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
    fuse,
)
from loopclosure.stripes.fusion import (
    DEFAULT_MEAN,
    DEFAULT_SCALING,
    LOCAL_NEIGHBOUR,
    MEANS,
    SCALINGS,
    VERIFIER_PRESETS,
    verifier_options,
)

Array = NDArray[np.float64]
Progress = Callable[[str, int, int], None]

#: Baselines run by default (the paper's shape context and two more silhouette methods).
DEFAULT_BASELINES: tuple[str, ...] = ("shape-context", "mrm", "fft")

#: The paper's Table I (counts at positions 1..10 over its 100 queries).
PAPER_TABLE_I: dict[str, list[int]] = {
    "SC [41]": [100, 79, 84, 71, 75, 74, 64, 67, 58, 48],
    "ID [42]": [100, 80, 77, 70, 68, 68, 64, 66, 54, 41],
    "PS [18]": [100, 81, 79, 78, 76, 71, 65, 60, 55, 53],
    "HF [43]": [100, 80, 71, 67, 64, 54, 52, 43, 49, 51],
    "Our": [100, 95, 91, 89, 86, 77, 73, 72, 66, 63],
}
#: The paper's Table II (mean accuracy [%] per class, classes in `DAILY_CLASSES` order).
PAPER_TABLE_II: dict[str, list[int]] = {
    "SC [41]": [46, 100, 79, 73, 87, 77, 51, 79, 100, 28],
    "HF [43]": [53, 82, 48, 61, 51, 43, 54, 97, 100, 30],
    "Our": [100, 78, 48, 100, 100, 96, 84, 100, 42, 64],
}
#: The paper's run times (Section VI.C, Matlab R2015a, Core i7 2.2 GHz) [s].
PAPER_SECONDS: dict[str, float] = {"stripes": 0.0375 * 3600.0, "shape-context": 1.6223 * 3600.0}


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


@dataclass(slots=True)
class StripesBenchmarkConfig:
    """Parameters of `run_stripes_benchmark`.

    Attributes:
        seed: seed of the scanner's random poses and noise (and of the Daily set).
        scans_per_object: independent scans of every object.
        k: deepest retrieval position (the paper: 10).
        baselines: silhouette matchers to compare (names of `loopclosure.matchers`).
        scanner: the simulated scanner.
        descriptor: stripe descriptor parameters.
        silhouette_smooth: contour smoothing of the silhouettes [px].
        profile: stripe profile parameters (the ``profile`` row and the fused matcher).
        fused: silhouette verifiers of the ``fused`` row (profile, relief, surface
            context and these; empty: no fused row).
        fused_sc: silhouette verifiers of the ``fused-sc`` row (empty: no such row).
        relief: relief parameters (the ``relief`` row and the ``fused-relief`` row).
        fused_relief: silhouette verifiers of the ``fused-relief`` row, the profile and
            the relief verified by them (empty: no such row).
        surface: surface-context parameters (the ``surface`` row, ``fused-stripes``
            and ``fused``).
        canonical: canonical-profile parameters (the ``canonical`` row and
            ``fused-stripes``).
        scaling: how ``fused-stripes`` and ``fused`` make each part unitless:
            ``"local"`` (local scaling) or ``"median"`` (per-query median); the
            ``fused-sc`` and ``fused-relief`` rows keep the median.
        neighbour: neighbour rank of local scaling.
        mean: how ``fused-stripes`` and ``fused`` average the unitless parts:
            ``"geometric"`` or ``"arithmetic"`` (`loopclosure.stripes.combine`); the
            ``fused-sc`` and ``fused-relief`` rows keep the arithmetic mean.
    """

    seed: int = 0
    scans_per_object: int = 1
    k: int = 10
    baselines: tuple[str, ...] = DEFAULT_BASELINES
    scanner: ScannerConfig = field(default_factory=ScannerConfig)
    descriptor: DescriptorConfig = field(default_factory=DescriptorConfig)
    silhouette_smooth: float = 1.0
    profile: ProfileConfig = field(default_factory=ProfileConfig)
    fused: tuple[str, ...] = DEFAULT_VERIFIERS
    fused_sc: tuple[str, ...] = SC_VERIFIERS
    relief: ReliefConfig = field(default_factory=ReliefConfig)
    fused_relief: tuple[str, ...] = SC_VERIFIERS
    surface: SurfaceConfig = field(default_factory=SurfaceConfig)
    canonical: CanonicalConfig = field(default_factory=CanonicalConfig)
    scaling: str = DEFAULT_SCALING
    neighbour: int = LOCAL_NEIGHBOUR
    mean: str = DEFAULT_MEAN

    def __post_init__(self) -> None:
        if self.scaling not in SCALINGS:
            raise UserError(f"unknown scaling {self.scaling!r}; known: {', '.join(SCALINGS)}")
        if self.mean not in MEANS:
            raise UserError(f"unknown mean {self.mean!r}; known: {', '.join(MEANS)}")
        if self.neighbour < 1:
            raise UserError(f"--neighbour must be at least 1, got {self.neighbour}")

    def to_json(self) -> dict[str, Any]:
        """Plain dict of every parameter."""

        return {
            "seed": self.seed,
            "scans_per_object": self.scans_per_object,
            "k": self.k,
            "baselines": list(self.baselines),
            "scanner": asdict(self.scanner),
            "descriptor": asdict(self.descriptor),
            "silhouette_smooth": self.silhouette_smooth,
            "profile": asdict(self.profile),
            "fused": list(self.fused),
            "fused_sc": list(self.fused_sc),
            "relief": asdict(self.relief),
            "fused_relief": list(self.fused_relief),
            "surface": asdict(self.surface),
            "canonical": asdict(self.canonical),
            "scaling": self.scaling,
            "neighbour": self.neighbour,
            "mean": self.mean,
        }


@dataclass(slots=True)
class StripesBenchmarkResult:
    """Everything the benchmark measured (see `to_json` for the published figures)."""

    dataset: str
    config: StripesBenchmarkConfig
    objects: ObjectSet
    scanned: ScannedSet
    stripes: MethodResult
    profile: MethodResult
    baselines: dict[str, MethodResult]
    fused: MethodResult | None
    skipped_baselines: dict[str, str]
    silhouette_seconds: float
    fused_sc: MethodResult | None = None
    relief: MethodResult | None = None
    fused_relief: MethodResult | None = None
    surface: MethodResult | None = None
    fused_stripes: MethodResult | None = None
    canonical: MethodResult | None = None

    @property
    def classes(self) -> list[str]:
        """Class names in order of first occurrence."""
        return list(dict.fromkeys(self.scanned.labels))

    def per_class(self) -> dict[str, dict[str, float]]:
        """class -> method -> Table II accuracy (stripes first)."""
        return {c: {n: r.class_accuracy[c] for n, r in self.methods().items()}
                for c in self.classes}

    def methods(self) -> dict[str, MethodResult]:
        """Every method's figures: stripes, profile, relief, surface, canonical,
        fused-stripes, fused, fused-sc and fused-relief (when run), then the baselines."""
        out = {"stripes": self.stripes, "profile": self.profile}
        for name, res in (("relief", self.relief), ("surface", self.surface),
                          ("canonical", self.canonical),
                          ("fused-stripes", self.fused_stripes), ("fused", self.fused),
                          ("fused-sc", self.fused_sc), ("fused-relief", self.fused_relief)):
            if res is not None:
                out[name] = res
        return {**out, **self.baselines}

    def wins_and_losses(
        self, margin: float = 0.005, method: str = "stripes"
    ) -> dict[str, dict[str, list[str]]]:
        """baseline -> {"wins": classes where `method` (``stripes`` or ``profile``) is
        better, "losses": worse, "ties"}."""
        mine = self.methods()[method]
        out: dict[str, dict[str, list[str]]] = {}
        for name, res in self.baselines.items():
            wins, losses, ties = [], [], []
            for c in self.classes:
                delta = mine.class_accuracy[c] - res.class_accuracy[c]
                (wins if delta > margin else losses if delta < -margin else ties).append(c)
            out[name] = {"wins": wins, "losses": losses, "ties": ties}
        return out

    def to_json(self) -> dict[str, Any]:
        """The CLI's JSON: the required keys first, then the details."""
        s = self.stripes
        return {
            "objects": len(set(self.scanned.objects.tolist())),
            "classes": len(self.classes),
            "top10_counts": s.top_counts.tolist(),
            "class_accuracy": s.class_accuracy,
            "bullseye": s.bullseye,
            "seconds": s.seconds,
            "baselines": {n: r.to_json() for n, r in self.baselines.items()},
            "profile": self.profile.to_json(),
            "fused": None if self.fused is None else self.fused.to_json(),
            "fused_sc": None if self.fused_sc is None else self.fused_sc.to_json(),
            "relief": None if self.relief is None else self.relief.to_json(),
            "fused_relief": None if self.fused_relief is None else self.fused_relief.to_json(),
            "surface": None if self.surface is None else self.surface.to_json(),
            "fused_stripes": None if self.fused_stripes is None else self.fused_stripes.to_json(),
            "canonical": None if self.canonical is None else self.canonical.to_json(),
            "different_pose": s.different_pose,
            "dataset": self.dataset,
            "scans": len(self.scanned.scans),
            "scans_per_object": self.config.scans_per_object,
            "seed": self.config.seed,
            "class_names": self.classes,
            "nn_precision": s.nn_precision,
            "top10_counts_other_objects": s.top_counts_other.tolist(),
            "class_accuracy_other_objects": s.class_accuracy_other,
            "nn_precision_other_objects": s.nn_precision_other,
            "mean_stripes_per_object": float(np.mean([len(x.stripes)
                                                      for x in self.scanned.scans])),
            "scan_seconds": self.scanned.seconds,
            "silhouette_seconds": self.silhouette_seconds,
            "paper_seconds": PAPER_SECONDS,
            "speedup_vs_paper": PAPER_SECONDS["stripes"] / max(s.seconds, 1e-12),
            "wins_and_losses": self.wins_and_losses(),
            "profile_wins_and_losses": self.wins_and_losses(method="profile"),
            "skipped_baselines": self.skipped_baselines,
            "failed_objects": {**self.objects.failed, **self.scanned.failed},
            "not_watertight": self.objects.not_watertight,
            "config": self.config.to_json(),
        }


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


def run_stripes_benchmark(
    objects: ObjectSet,
    config: StripesBenchmarkConfig | None = None,
    progress: Progress | None = None,
    *,
    source: StripesSource | None = None,
    cluster: str | None = None,
) -> StripesBenchmarkResult:
    """Scan `objects`, rank them with stripes and with every available baseline.

    One `MatcherTask` per matcher, here in order or, with `cluster` (an
    `evaluation.cluster` address), on Dask, the workers rebuilding the objects from
    `source` (the source `objects` came from: required).

    Raises:
        UserError: bad parameters, unknown baseline name, nothing scanned, a matcher's
            task that failed.
    """
    from evaluation.cluster import map_tasks

    cfg = config or StripesBenchmarkConfig()
    if cfg.k < 2:
        raise UserError(f"k must be at least 2, got {cfg.k}")
    if cluster is not None and source is None:
        raise UserError("a cluster run needs the objects as a StripesSource, not meshes in "
                        "memory")
    available, skipped = _available_baselines(cfg.baselines)
    scanned = scan_objects(objects, cfg.scanner, cfg.seed, cfg.scans_per_object, progress)
    verifiers = list(dict.fromkeys(n for n in (*cfg.fused, *cfg.fused_sc, *cfg.fused_relief)
                                   if n not in available))
    for name in verifiers:
        baseline_matcher(name)  # unknown verifier names fail before any silhouette work
    key: StripesSource | str = source if source is not None else f"memory-{uuid.uuid4().hex}"
    tasks = [MatcherTask(key, cfg, m)
             for m in ("stripes", "profile", "relief", "surface", "canonical", *available,
                       *verifiers)]
    _SCANNED[_scan_key(key, cfg)] = (scanned, progress)
    try:
        rows = {}
        for o in map_tasks(matcher_task, tasks, cluster=cluster, retries=0,
                           description="bench stripes", progress=cluster is not None):
            rows[o.item.method] = o.result(f"bench stripes, {o.item.method}")
    finally:
        _SCANNED.pop(_scan_key(key, cfg), None)
        _SILHOUETTES.pop(_scan_key(key, cfg), None)
    stripes = _rank_with_stripes(scanned, cfg, rows.pop("stripes"))
    profile = _rank_with_profile(scanned, cfg, rows.pop("profile"))
    relief_rows = rows.pop("relief")
    relief = evaluate("relief", relief_rows.distances, scanned.labels, scanned.objects,
                      relief_rows.seconds, cfg.k, asdict(cfg.relief))
    surface_rows = rows.pop("surface")
    surface = evaluate("surface", surface_rows.distances, scanned.labels, scanned.objects,
                       surface_rows.seconds, cfg.k, asdict(cfg.surface))
    canonical_rows = rows.pop("canonical")
    canonical = evaluate("canonical", canonical_rows.distances, scanned.labels,
                         scanned.objects, canonical_rows.seconds, cfg.k, asdict(cfg.canonical))
    ranked = {n: evaluate(n, r.distances, scanned.labels, scanned.objects, r.seconds, cfg.k,
                          r.options) for n, r in rows.items()}
    silhouette_seconds = next((r.silhouette_seconds for r in rows.values()), 0.0)
    three = [profile, relief, surface]
    fused_stripes = _fused(scanned, [*three, canonical], ranked, cfg, (), "fused-stripes",
                           cfg.scaling, cfg.mean)
    fused = (_fused(scanned, three, ranked, cfg, cfg.fused, "fused", cfg.scaling, cfg.mean)
             if cfg.fused else None)
    fused_sc = (_fused(scanned, [profile], ranked, cfg, cfg.fused_sc, "fused-sc")
                if cfg.fused_sc else None)
    fused_relief = (_fused(scanned, [profile, relief], ranked, cfg, cfg.fused_relief,
                           "fused-relief") if cfg.fused_relief else None)
    baselines = {n: r for n, r in ranked.items() if n in available}
    return StripesBenchmarkResult(objects.name, cfg, objects, scanned, stripes, profile,
                                  baselines, fused, skipped, silhouette_seconds, fused_sc,
                                  relief, fused_relief, surface, fused_stripes, canonical)


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


def _rank_with_stripes(
    scanned: ScannedSet, cfg: StripesBenchmarkConfig, rows: MatcherRows
) -> MethodResult:
    """The retrieval figures of the stripes' distance matrix of the scans."""
    d, secs = rows.distances, rows.seconds
    return evaluate("stripes", d, scanned.labels, scanned.objects, secs, cfg.k,
                    {"weights": [0.6, 0.3, 0.1], "stripe_count": cfg.descriptor.stripe_count,
                     "scale_free": cfg.descriptor.scale_free})


def _rank_with_profile(
    scanned: ScannedSet, cfg: StripesBenchmarkConfig, rows: MatcherRows
) -> MethodResult:
    """The retrieval figures of the stripe profiles' distance matrix of the scans."""
    d, secs = rows.distances, rows.seconds
    return evaluate("profile", d, scanned.labels, scanned.objects, secs, cfg.k,
                    {"samples": cfg.profile.samples, "features": ["l", "d", "e"],
                     "normalisation": "per-query median per feature"})


def _fused(
    scanned: ScannedSet, stripe_side: Sequence[MethodResult], ranked: dict[str, MethodResult],
    cfg: StripesBenchmarkConfig, verifiers: Sequence[str], name: str = "fused",
    scaling: str = "median", mean: str = "arithmetic",
) -> MethodResult:
    """A fused matcher's figures from the matrices of its stripe-side parts (the profile,
    and the relief, surface context and canonical profile when given) and of the
    `verifiers`, each made unitless by `scaling` and averaged by `mean`
    (`loopclosure.stripes.fuse`)."""
    t0 = time.perf_counter()
    d = fuse([*(r.distances for r in stripe_side), *(ranked[n].distances for n in verifiers)],
             scaling=scaling, neighbour=cfg.neighbour, mean=mean)
    secs = (sum(r.seconds for r in stripe_side) + sum(ranked[n].seconds for n in verifiers)
            + time.perf_counter() - t0)
    return evaluate(name, d, scanned.labels, scanned.objects, secs, cfg.k,
                    {"verifiers": list(verifiers),
                     "normalisation": ("local scaling, neighbour "
                                       f"{cfg.neighbour}" if scaling == "local"
                                       else "per-query median"),
                     "mean": mean,
                     "stripes": " + ".join(r.name for r in stripe_side),
                     "samples": cfg.profile.samples})
