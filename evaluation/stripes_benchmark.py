"""The stripes paper's object-retrieval benchmark: Table I, Table II, Bull's eye, timing.

Paper: "Stripes-based Object Matching" (``../shared/papers/stripes-object-matching.txt``),
Section VI.B-C.  Every scanned object is a query against the whole set, itself
included, so position 1 is always the query itself (the paper's row starts at 100):

- Table I (`retrieval_counts`): for positions 1..k (k = 10), how many queries have an
  object of their own class at that position.
- Table II (`class_accuracy`): per query, the fraction of same-class objects among its
  k nearest (itself included, as Table I: the paper's Table II means times 10 equal
  its Table I sums, e.g. 81.2 % and 812 for "Our"); averaged over the queries of
  each class.
- Bull's eye (`evaluation.retrieval.bullseye`): same-class hits among the 2n nearest
  (n = class size), the query included.
- Nearest-neighbour precision: Table I position 2 divided by the number of queries.

Ranking rule: the query is put first (a matcher whose self-distance is not the
smallest is not rewarded or punished for it); other ties keep the set's order (stable
sort).  With several scans per object (`scans_per_object`) the nearest neighbour is
usually another scan of the *same* object, so every figure is also given with the
query's sibling scans removed from its ranking ("other objects"); the YCB target
(nearest-neighbour precision >= 0.9) is reported both ways and the report says which
is which.

Methods on the same scans:

- ``stripes``: `loopclosure.stripes` descriptors ``[l, d, o]`` (Eq. 1-3) and the
  vectorised `StripeDatabase` (Eq. 4-6, lambda = 0.6, 0.3, 0.1).
- Baselines on the object's silhouette (`silhouette_polygon`: the scanned footprint,
  `StripeScan.silhouette()`, made isotropic in millimetres, closed by one pixel,
  outer contour smoothed as the MPEG-7 rule of `data.mpeg7.contour_from_image`),
  compared by the place-recognition matchers of `loopclosure.matchers` with scale
  invariance switched on where the matcher has it (customary for object shapes).
  The baseline list is a parameter; a registered matcher whose module is not
  importable yet is skipped with one warning.

Timing (`seconds`): representation + matching of the whole set (descriptors of every
object and the full distance matrix), wall clock in this process, against the paper's
0.0375 h (Matlab, stripes) and 1.6223 h (shape context).  Scanning is the simulator's
cost and is reported apart (`scan_seconds`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from data.errors import DataError, UserError, warn
from data.stripe_scanner import (
    DAILY_CLASSES,
    Mesh,
    ScannerConfig,
    StripeScan,
    daily_set,
    load_mesh,
    read_labels,
    scan_mesh,
    ycb_labels,
)
from data.stripe_scanner.meshes import load_mesh_folder
from evaluation.retrieval import bullseye
from loopclosure.polygon import Polygon
from loopclosure.stripes import DescriptorConfig, StripeDatabase, describe_many

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


# --------------------------------------------------------------------------- measures


def _ranking(
    distances: ArrayLike, exclude: NDArray[np.bool_] | None = None
) -> tuple[NDArray[np.intp], NDArray[np.bool_]]:
    """Each query's ranking (query first, stable) and which ranked entries are valid."""
    d = np.array(distances, dtype=float)
    if d.ndim != 2 or d.shape[0] != d.shape[1]:
        raise ValueError(f"expected a square distance matrix, got shape {d.shape}")
    m = d.shape[0]
    d[~np.isfinite(d)] = np.inf
    valid = np.ones((m, m), dtype=bool)
    if exclude is not None:
        ex = np.asarray(exclude, dtype=bool).copy()
        np.fill_diagonal(ex, False)
        valid = ~ex
        d[ex] = np.inf
    np.fill_diagonal(d, -np.inf)
    order = np.argsort(d, axis=1, kind="stable")
    # Excluded entries sort last (inf) but may tie with real inf distances: mask them.
    return order, np.take_along_axis(valid, order, axis=1)


def _hits(
    distances: ArrayLike,
    labels: ArrayLike,
    k: int,
    exclude: NDArray[np.bool_] | None = None,
) -> NDArray[np.bool_]:
    """``(M, k)`` same-class flags of each query's k nearest (False beyond the set's size)."""
    lab = np.asarray(labels)
    order, valid = _ranking(distances, exclude)
    kk = min(int(k), len(lab))
    out = np.zeros((len(lab), int(k)), dtype=bool)
    out[:, :kk] = (lab[order[:, :kk]] == lab[:, None]) & valid[:, :kk]
    return out


def retrieval_counts(
    distances: ArrayLike,
    labels: ArrayLike,
    k: int = 10,
    exclude: NDArray[np.bool_] | None = None,
) -> NDArray[np.int64]:
    """Table I: ``(k,)`` number of queries with a same-class object at positions 1..k.

    Positions beyond the set's size (sets of fewer than k objects) count 0.

    Args:
        distances: ``(M, M)`` distances, row i = query i against every object.
        labels: ``(M,)`` class of each object.
        k: deepest position.
        exclude: ``(M, M)`` True where object j must not be retrieved for query i
            (e.g. other scans of the query's own object); the diagonal is ignored.
    """
    return _hits(distances, labels, k, exclude).sum(axis=0).astype(np.int64)


def query_accuracy(
    distances: ArrayLike,
    labels: ArrayLike,
    k: int = 10,
    exclude: NDArray[np.bool_] | None = None,
) -> Array:
    """``(M,)`` fraction of same-class objects among each query's k nearest (itself included).

    The denominator is always k (the paper's "ratio between the matched objects and
    10"), so a set smaller than k cannot reach 1.
    """
    h = _hits(distances, labels, k, exclude)
    return h.sum(axis=1) / float(h.shape[1])


def class_accuracy(
    distances: ArrayLike,
    labels: ArrayLike,
    k: int = 10,
    exclude: NDArray[np.bool_] | None = None,
) -> dict[str, float]:
    """Table II: class -> mean of `query_accuracy` over the queries of that class.

    Classes appear in order of first occurrence in `labels`.
    """
    lab = np.asarray(labels)
    acc = query_accuracy(distances, lab, k, exclude)
    classes = list(dict.fromkeys(lab.tolist()))
    return {str(c): float(acc[lab == c].mean()) for c in classes}


def same_object_mask(objects: ArrayLike) -> NDArray[np.bool_]:
    """``(M, M)`` True where two scans come from the same object (the diagonal too)."""
    o = np.asarray(objects)
    return o[:, None] == o[None, :]


# --------------------------------------------------------------------------- data sets


@dataclass(slots=True)
class ObjectSet:
    """Objects to scan.

    Attributes:
        name: data set name (``daily-sim`` or the mesh folder).
        meshes: one mesh per object (metres, z up).
        labels: class of each object.
        failed: file -> reason for listed meshes that could not be loaded.
        not_watertight: names of kept meshes that are not watertight.
    """

    name: str
    meshes: list[Mesh]
    labels: list[str]
    failed: dict[str, str] = field(default_factory=dict)
    not_watertight: list[str] = field(default_factory=list)


def daily_objects(
    seed: int = 0, per_class: int = 10, classes: Sequence[str] = DAILY_CLASSES
) -> ObjectSet:
    """The parametric Daily-like set (`data.stripe_scanner.daily_set`): classes x per_class."""
    if per_class < 1:
        raise UserError(f"--per-class must be at least 1, got {per_class}")
    unknown = [c for c in classes if c not in DAILY_CLASSES]
    if unknown:
        raise UserError(f"unknown Daily class(es) {', '.join(unknown)}; known: "
                        f"{', '.join(DAILY_CLASSES)}")
    if not classes:
        raise UserError("no Daily class selected")
    meshes, labels = daily_set(seed=seed, per_class=per_class, classes=tuple(classes))
    return ObjectSet("daily-sim", meshes, labels)


def mesh_folder_objects(folder: str | Path, labels_csv: str | Path | None = None) -> ObjectSet:
    """Meshes of a folder with a ``file,class`` CSV, or the YCB multi-instance classes.

    Without `labels_csv` the classes come from `data.stripe_scanner.ycb_labels` (YCB file
    names).  A CSV row naming a file that is not in the folder is an error (a typo must
    not silently shrink the benchmark); files that exist but do not load are skipped and
    reported once (as `load_mesh_folder` does).

    Raises:
        DataError: missing folder or CSV, files listed but absent, nothing loadable.
    """
    root = Path(folder)
    if not root.exists():
        raise DataError(root, "no such folder")
    if not root.is_dir():
        raise DataError(root, "not a directory")
    if labels_csv is not None:
        rows = read_labels(labels_csv)
        source: str | Path = labels_csv
    else:
        rows = ycb_labels(root)
        source = root
    missing = [f for f, _ in rows if not (root / f).is_file()]
    if missing:
        shown = ", ".join(missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5
                                          else "")
        raise DataError(source, f"lists {len(missing)} file(s) not found in {root}: {shown}")
    if labels_csv is not None:
        loaded = load_mesh_folder(root, labels_csv)
        return ObjectSet(str(root), loaded.meshes, loaded.labels, loaded.failed,
                         loaded.not_watertight)
    out = ObjectSet(str(root), [], [])
    for file, cls in rows:
        try:
            mesh = load_mesh(root / file)
        except DataError as exc:
            out.failed[file] = exc.message
            continue
        if not mesh.watertight:
            out.not_watertight.append(mesh.name)
        out.meshes.append(mesh)
        out.labels.append(cls)
    if out.failed:
        first = next(iter(out.failed.items()))
        warn(f"{root}: {len(out.failed)} of {len(rows)} meshes failed to load and were "
             f"skipped (first: {first[0]}: {first[1]})")
    if not out.meshes:
        raise DataError(root, f"none of the {len(rows)} listed meshes could be loaded")
    return out


@dataclass(slots=True)
class ScannedSet:
    """The scans of an `ObjectSet`.

    Attributes:
        scans: one `StripeScan` per successful scan, object-major.
        labels: class of each scan.
        objects: index (into the object set) of the object each scan comes from.
        failed: object name -> reason for objects that gave no stripe (skipped).
        seconds: wall time of the scanning [s].
    """

    scans: list[StripeScan]
    labels: list[str]
    objects: NDArray[np.int64]
    failed: dict[str, str]
    seconds: float


def scan_objects(
    objects: ObjectSet,
    config: ScannerConfig | None = None,
    seed: int = 0,
    scans_per_object: int = 1,
    progress: Progress | None = None,
) -> ScannedSet:
    """Scan every object `scans_per_object` times (same draws as `scan_meshes` for `seed`).

    Objects that give no stripe are skipped; one warning summarises laser positions
    without stripe and skipped objects.

    Raises:
        UserError: bad `scans_per_object`, or no object gave any stripe.
    """
    if scans_per_object < 1:
        raise UserError(f"--scans-per-object must be at least 1, got {scans_per_object}")
    rng = np.random.default_rng(seed)
    total = len(objects.meshes) * scans_per_object
    scans: list[StripeScan] = []
    labels: list[str] = []
    source: list[int] = []
    failed: dict[str, str] = {}
    t0 = time.perf_counter()
    done = 0
    for i, mesh in enumerate(objects.meshes):
        for _ in range(scans_per_object):
            try:
                scans.append(scan_mesh(mesh, config, rng))
                labels.append(objects.labels[i])
                source.append(i)
            except DataError as exc:
                failed[mesh.name] = exc.message
            done += 1
            if progress is not None:
                progress("scanning", done, total)
    seconds = time.perf_counter() - t0
    empty = sum(s.empty_positions for s in scans)
    if empty:
        frames = sum(s.n_frames for s in scans)
        warn(f"stripe scanner: {empty} of {frames} laser positions over "
             f"{sum(1 for s in scans if s.empty_positions)} objects cut the object but gave "
             "no stripe (shadowed, hidden or grazing)")
    if failed:
        warn(f"stripe scanner: {len(failed)} objects gave no stripe at all and were skipped "
             f"({', '.join(list(failed)[:3])}{', ...' if len(failed) > 3 else ''})")
    if not scans:
        raise UserError(f"{objects.name}: no object gave any stripe; nothing to benchmark")
    return ScannedSet(scans, labels, np.array(source, dtype=np.int64), failed, seconds)


# --------------------------------------------------------------------------- silhouettes


def silhouette_polygon(
    scan: StripeScan, config: ScannerConfig | None = None, smooth: float = 1.0
) -> Polygon:
    """The object's scanned footprint as a polygon in millimetres (table plane, top view).

    The mask `StripeScan.silhouette()` has one row per laser position (`step` apart)
    and one column per image column (``field_of_view / width`` apart on the table):
    it is closed by a 3 x 3 structuring element (fills the detector's one-pixel gaps),
    its outer contour is taken and smoothed by `data.mpeg7.contour_from_image`
    (`smooth` pixels), and the axes are scaled to millimetres so the shape is not
    stretched.  A footprint too thin for a contour (one row or column) becomes its
    bounding rectangle, half a pixel wider on every side (never degenerate).
    """
    from data.mpeg7 import contour_from_image

    cfg = config or ScannerConfig()
    mask = scan.silhouette()
    mask = ndimage.binary_closing(np.pad(mask, 2), structure=np.ones((3, 3), bool))
    col_mm = 1000.0 * cfg.field_of_view / cfg.width
    row_mm = 1000.0 * cfg.step
    contour = contour_from_image(mask.astype(np.uint8) * 255, smooth=smooth)
    if contour is None:
        rows, cols = np.nonzero(mask)
        y = (mask.shape[0] - 1) - rows
        x0, x1, y0, y1 = cols.min() - 0.5, cols.max() + 0.5, y.min() - 0.5, y.max() + 0.5
        contour = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
    return Polygon(contour * np.array([col_mm, row_mm]))


# --------------------------------------------------------------------------- methods


@dataclass(slots=True)
class MethodResult:
    """Retrieval figures of one method on the scanned set.

    Attributes:
        name: ``stripes`` or a matcher name.
        distances: ``(M, M)`` distance matrix (row = query).
        seconds: representation + matching of the whole set [s].
        top_counts: Table I row (positions 1..k).
        class_accuracy: Table II row (class -> fraction).
        bullseye: Bull's eye [%].
        nn_precision: position 2 / queries.
        top_counts_other: Table I row with each query's sibling scans removed.
        class_accuracy_other: Table II row with sibling scans removed.
        nn_precision_other: nearest *other object* of the same class / queries.
        options: matcher options used (e.g. ``scale_invariant``).
    """

    name: str
    distances: Array
    seconds: float
    top_counts: NDArray[np.int64]
    class_accuracy: dict[str, float]
    bullseye: float
    nn_precision: float
    top_counts_other: NDArray[np.int64]
    class_accuracy_other: dict[str, float]
    nn_precision_other: float
    options: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """Figures of the method (without the distance matrix)."""
        return {
            "top10_counts": self.top_counts.tolist(),
            "class_accuracy": self.class_accuracy,
            "bullseye": self.bullseye,
            "nn_precision": self.nn_precision,
            "top10_counts_other_objects": self.top_counts_other.tolist(),
            "class_accuracy_other_objects": self.class_accuracy_other,
            "nn_precision_other_objects": self.nn_precision_other,
            "seconds": self.seconds,
            "options": self.options,
        }


def evaluate(
    name: str,
    distances: Array,
    labels: Sequence[str],
    objects: ArrayLike,
    seconds: float,
    k: int = 10,
    options: dict[str, Any] | None = None,
) -> MethodResult:
    """All retrieval figures of one distance matrix (see the module docstring)."""
    lab = np.asarray(labels)
    d = np.asarray(distances, dtype=float)
    siblings = same_object_mask(objects)
    np.fill_diagonal(siblings, False)
    counts = retrieval_counts(d, lab, k)
    counts_other = retrieval_counts(d, lab, k, exclude=siblings)
    m = len(lab)
    d_b = np.where(np.isfinite(d), d, np.finfo(float).max)
    return MethodResult(
        name=name,
        distances=d,
        seconds=float(seconds),
        top_counts=counts,
        class_accuracy=class_accuracy(d, lab, k),
        bullseye=bullseye(d_b, lab),
        nn_precision=float(counts[1] / m) if len(counts) > 1 else 0.0,
        top_counts_other=counts_other,
        class_accuracy_other=class_accuracy(d, lab, k, exclude=siblings),
        nn_precision_other=float(counts_other[1] / m) if len(counts_other) > 1 else 0.0,
        options=dict(options or {}),
    )


def stripes_distances(
    scans: Sequence[StripeScan], config: DescriptorConfig | None = None
) -> tuple[Array, float]:
    """Stripe descriptors of every scan and the full distance matrix; wall time [s]."""
    t0 = time.perf_counter()
    descs = describe_many([s.stripes for s in scans], config, names=[s.name for s in scans])
    d = StripeDatabase(descs).pairwise()
    return d, time.perf_counter() - t0


def baseline_matcher(name: str) -> tuple[Any, dict[str, Any]]:
    """The matcher `name` with scale invariance on when it has the option; and its options.

    Raises:
        UserError: `name` is not a registered matcher.
        ImportError: the matcher is registered but its module is not importable yet.
    """
    from loopclosure.matchers import MATCHER_NAMES, matcher_class

    if name not in MATCHER_NAMES:
        raise UserError(f"unknown baseline matcher {name!r}; known: {', '.join(MATCHER_NAMES)}")
    cls = matcher_class(name)
    try:
        return cls(scale_invariant=True), {"scale_invariant": True}
    except TypeError:
        return cls(), {"scale_invariant": False}


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
    stacked = matcher.stack(descs)
    rows = []
    for i, q in enumerate(descs):
        rows.append(np.asarray(matcher.distances(q, stacked), dtype=float))
        if progress is not None:
            progress(name, i + 1, len(descs))
    return np.stack(rows), time.perf_counter() - t0, options


# --------------------------------------------------------------------------- benchmark


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
    """

    seed: int = 0
    scans_per_object: int = 1
    k: int = 10
    baselines: tuple[str, ...] = DEFAULT_BASELINES
    scanner: ScannerConfig = field(default_factory=ScannerConfig)
    descriptor: DescriptorConfig = field(default_factory=DescriptorConfig)
    silhouette_smooth: float = 1.0

    def to_json(self) -> dict[str, Any]:
        """Plain dict of every parameter."""
        from dataclasses import asdict

        return {
            "seed": self.seed,
            "scans_per_object": self.scans_per_object,
            "k": self.k,
            "baselines": list(self.baselines),
            "scanner": asdict(self.scanner),
            "descriptor": asdict(self.descriptor),
            "silhouette_smooth": self.silhouette_smooth,
        }


@dataclass(slots=True)
class StripesBenchmarkResult:
    """Everything the benchmark measured (see `to_json` for the published figures)."""

    dataset: str
    config: StripesBenchmarkConfig
    objects: ObjectSet
    scanned: ScannedSet
    stripes: MethodResult
    baselines: dict[str, MethodResult]
    skipped_baselines: dict[str, str]
    silhouette_seconds: float

    @property
    def classes(self) -> list[str]:
        """Class names in order of first occurrence."""
        return list(dict.fromkeys(self.scanned.labels))

    def per_class(self) -> dict[str, dict[str, float]]:
        """class -> method -> Table II accuracy (stripes first)."""
        methods = {"stripes": self.stripes, **self.baselines}
        return {c: {n: r.class_accuracy[c] for n, r in methods.items()} for c in self.classes}

    def wins_and_losses(self, margin: float = 0.005) -> dict[str, dict[str, list[str]]]:
        """baseline -> {"wins": classes where stripes are better, "losses": worse, "ties"}."""
        out: dict[str, dict[str, list[str]]] = {}
        for name, res in self.baselines.items():
            wins, losses, ties = [], [], []
            for c in self.classes:
                delta = self.stripes.class_accuracy[c] - res.class_accuracy[c]
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
            "skipped_baselines": self.skipped_baselines,
            "failed_objects": {**self.objects.failed, **self.scanned.failed},
            "not_watertight": self.objects.not_watertight,
            "config": self.config.to_json(),
        }


def run_stripes_benchmark(
    objects: ObjectSet,
    config: StripesBenchmarkConfig | None = None,
    progress: Progress | None = None,
) -> StripesBenchmarkResult:
    """Scan `objects`, rank them with stripes and with every available baseline.

    Raises:
        UserError: bad parameters, unknown baseline name, nothing scanned.
    """
    cfg = config or StripesBenchmarkConfig()
    if cfg.k < 2:
        raise UserError(f"k must be at least 2, got {cfg.k}")
    matchers_ok: list[str] = []
    skipped: dict[str, str] = {}
    for name in cfg.baselines:
        try:
            baseline_matcher(name)
            matchers_ok.append(name)
        except ImportError as exc:
            skipped[name] = f"not available yet ({exc})"
    if skipped:
        warn(f"skipped {len(skipped)} baseline(s) not available yet: {', '.join(skipped)}")
    scanned = scan_objects(objects, cfg.scanner, cfg.seed, cfg.scans_per_object, progress)
    lab, obj = scanned.labels, scanned.objects
    d, secs = stripes_distances(scanned.scans, cfg.descriptor)
    stripes = evaluate("stripes", d, lab, obj, secs, cfg.k, {"weights": [0.6, 0.3, 0.1]})
    baselines: dict[str, MethodResult] = {}
    sil_secs = 0.0
    if matchers_ok:
        t0 = time.perf_counter()
        polygons = [silhouette_polygon(s, cfg.scanner, cfg.silhouette_smooth)
                    for s in scanned.scans]
        sil_secs = time.perf_counter() - t0
        for name in matchers_ok:
            db, secs_b, options = baseline_distances(name, polygons, progress)
            baselines[name] = evaluate(name, db, lab, obj, secs_b, cfg.k, options)
    return StripesBenchmarkResult(objects.name, cfg, objects, scanned, stripes, baselines,
                                  skipped, sil_secs)


# --------------------------------------------------------------------------- report


def _paper_table_one(result: StripesBenchmarkResult) -> list[list[Any]]:
    rows: list[list[Any]] = [[f"paper {n}", *v] for n, v in PAPER_TABLE_I.items()]
    methods = {"stripes": result.stripes, **result.baselines}
    for n, r in methods.items():
        rows.append([f"**{n}** (this run)", *r.top_counts.tolist()])
    if result.config.scans_per_object > 1:
        for n, r in methods.items():
            rows.append([f"{n}, other objects only", *r.top_counts_other.tolist()])
    return rows


def _table_two(result: StripesBenchmarkResult) -> tuple[list[str], list[list[Any]]]:
    classes = result.classes
    headers = ["method", *classes, "mean"]
    rows: list[list[Any]] = []
    if set(classes) <= set(DAILY_CLASSES):
        for n, v in PAPER_TABLE_II.items():
            paper = dict(zip(DAILY_CLASSES, v, strict=True))
            vals = [paper[c] for c in classes]
            rows.append([f"paper {n}", *vals, round(float(np.mean(vals)), 1)])
    methods = {"stripes": result.stripes, **result.baselines}
    for n, r in methods.items():
        vals = [round(100.0 * r.class_accuracy[c], 1) for c in classes]
        rows.append([f"**{n}** (this run)", *vals, round(float(np.mean(vals)), 1)])
    return headers, rows


def _plot_examples(result: StripesBenchmarkResult, path: Path) -> Path:
    """One object per class: its stripes (waterfall, every stripe offset by its frame)
    above its silhouette polygon (Fig. 6 of the paper: stripes and shape)."""
    from evaluation.plots import plt

    classes = result.classes[:10]
    first = {c: result.scanned.labels.index(c) for c in classes}
    fig, axes = plt.subplots(2, len(classes), figsize=(2.2 * len(classes), 4.8), squeeze=False)
    for j, c in enumerate(classes):
        scan = result.scanned.scans[first[c]]
        ax = axes[0, j]
        step = max(1, len(scan.stripes) // 40)
        cfg = result.config.scanner
        pitch = cfg.step / (cfg.field_of_view / cfg.width)  # one laser step in image columns
        for f, s in zip(scan.frame[::step], scan.stripes[::step], strict=True):
            ax.plot(s[:, 0], -s[:, 1] + pitch * f, lw=0.5, color="tab:red")
        ax.set_title(f"{c}\n{len(scan.stripes)} stripes", fontsize=8)
        ax.set_aspect("equal", adjustable="datalim")
        ax.axis("off")
        ax = axes[1, j]
        poly = silhouette_polygon(scan, result.config.scanner, result.config.silhouette_smooth)
        v = np.vstack([poly.vertices, poly.vertices[:1]])
        ax.fill(v[:, 0], v[:, 1], color="0.2")
        ax.set_aspect("equal", adjustable="datalim")
        ax.axis("off")
    fig.suptitle("stripes (every stripe shifted by its laser position) and silhouettes [mm]",
                 fontsize=9)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _plot_class_accuracy(result: StripesBenchmarkResult, path: Path) -> Path:
    """Grouped bars: Table II accuracy per class and method."""
    from evaluation.plots import plt

    methods = {"stripes": result.stripes, **result.baselines}
    classes = result.classes
    x = np.arange(len(classes))
    width = 0.8 / max(len(methods), 1)
    fig, ax = plt.subplots(figsize=(max(6.0, 0.8 * len(classes) + 2), 3.8))
    for i, (n, r) in enumerate(methods.items()):
        ax.bar(x + i * width - 0.4 + width / 2, [100 * r.class_accuracy[c] for c in classes],
               width, label=n)
    ax.set_xticks(x)
    ax.set_xticklabels(classes, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("mean accuracy over the 10 nearest [%]")
    ax.set_ylim(0, 105)
    ax.legend(fontsize=8)
    ax.grid(True, axis="y", lw=0.3)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _write_stripe_image(result: StripesBenchmarkResult, path: Path) -> Path:
    """The black/white image of the middle stripe of the first object (paper Section III)."""
    from evaluation.plots import plt

    scan = result.scanned.scans[0]
    img = scan.binary_image(len(scan.stripes) // 2)
    path.parent.mkdir(parents=True, exist_ok=True)
    plt.imsave(path, img, cmap="gray")
    return path


def write_stripes_report(result: StripesBenchmarkResult, out: str | Path) -> dict[str, Path]:
    """``report.md``, ``results.json`` and PNG figures in `out`; returns name -> path."""
    from evaluation.report import image, key_values, table, write_report
    from slam.cli.common import write_json

    out_dir = Path(out)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataError(out_dir, f"cannot create output folder: {exc.strerror or exc}") from exc
    if not out_dir.is_dir():
        raise DataError(out_dir, "output path exists and is not a folder")
    paths = {
        "results": out_dir / "results.json",
        "examples": _plot_examples(result, out_dir / "stripes_examples.png"),
        "class_accuracy": _plot_class_accuracy(result, out_dir / "class_accuracy.png"),
        "stripe_image": _write_stripe_image(
            result, out_dir / f"stripe_image_{result.scanned.scans[0].name}.png"),
    }
    js = result.to_json()
    write_json(paths["results"], js)
    s = result.stripes
    n_q = len(result.scanned.scans)
    k = len(s.top_counts)
    methods = {"stripes": s, **result.baselines}
    t1 = table(["method", *[str(i) for i in range(1, k + 1)]], _paper_table_one(result))
    h2, r2 = _table_two(result)
    t2 = table(h2, r2, digits=4)
    summary = table(
        ["method", "Bull's eye [%]", "NN precision", "NN precision (other objects)",
         "representation + matching [s]", "options"],
        [[n, r.bullseye, r.nn_precision, r.nn_precision_other, r.seconds,
          ", ".join(f"{a}={b}" for a, b in r.options.items())] for n, r in methods.items()],
    )
    timing = key_values({
        "stripes, this run [s]": s.seconds,
        "stripes, paper (Matlab) [s]": PAPER_SECONDS["stripes"],
        "shape context, paper (Matlab) [s]": PAPER_SECONDS["shape-context"],
        **{f"{n}, this run [s]": r.seconds for n, r in result.baselines.items()},
        "silhouettes (once for all baselines) [s]": result.silhouette_seconds,
        "scanning (simulator, not counted) [s]": result.scanned.seconds,
    })
    wl = result.wins_and_losses()
    wl_rows = [[n, ", ".join(v["wins"]) or "-", ", ".join(v["losses"]) or "-",
                ", ".join(v["ties"]) or "-"] for n, v in wl.items()]
    setting = key_values({
        "data set": result.dataset,
        "objects": js["objects"],
        "scans (queries)": n_q,
        "scans per object": result.config.scans_per_object,
        "classes": len(result.classes),
        "seed": result.config.seed,
        "mean stripes per scan": js["mean_stripes_per_object"],
        "laser step [m]": result.config.scanner.step,
        "failed objects": len(js["failed_objects"]),
        "baselines skipped": ", ".join(result.skipped_baselines) or "-",
    })
    sections = [
        ("Setting", setting),
        (f"Table I: same-class objects at positions 1..{k} (this run: of {n_q} queries; "
         "paper: of 100)", t1 + "\n\nPosition 1 is the query itself. \"Other objects only\" "
         "removes each query's other scans of the same object from its ranking."),
        (f"Table II: mean accuracy [%] per class over the {k} nearest", t2),
        ("Bull's eye, nearest neighbour, time", summary + "\n\nNN precision = position 2 / "
         "queries (any scan, which with several scans per object is usually another scan of "
         "the same object); \"other objects\" = the nearest scan of a *different* object."),
        ("Where stripes win and lose (Table II, per class)",
         table(["against", "stripes better", "stripes worse", "tie"], wl_rows)
         + "\n\nThe paper: stripes lose on banana and pen against shape."),
        ("Timing: representation + matching of the whole set", timing),
        ("Figures", "\n\n".join([
            image(paths["examples"], out_dir, "stripes and silhouettes"),
            image(paths["class_accuracy"], out_dir, "class accuracy"),
            image(paths["stripe_image"], out_dir, "one black/white stripe image"),
        ])),
    ]
    paths["report"] = write_report(out_dir / "report.md", "Stripes benchmark", sections)
    return paths
