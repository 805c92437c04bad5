"""Benchmark: which part of the fused object matcher moves with the object's pose, and why.

Run from the repository root::

    python benchmarks/stripes_diagnosis.py [--meshes DIR] [--labels CSV ...] [--seeds 0,1]
        [--cache DIR] [--baselines] [--failures] [--neighbour 5]

``--seeds '0,1;2,3;4,5'`` evaluates each group of seeds apart (its own poses and
columns, every table below per group) and ends with a summary: per row, the worst
and the mean column of each group and of all groups (a change judged on seeds 0, 1
and on the held-out groups in one run).

Object sets: the YCB multi-instance classes (balls, stacking cups, Lego Duplo, toy
airplane parts, food boxes) and the second labelled YCB set
(``benchmarks/stripes_ycb_other_labels.csv``: cans, bottles, fruit, utensils, tools,
clamps, cuboids), as ``benchmarks/stripes_variants.py``; ``--labels`` replaces them by
the given CSVs (``ycb`` for the multi-instance classes).  Every seed is one *pose* of
every object: each set scanned once per seed with any yaw on the table
(`ScannerConfig.yaw_range_deg` = 180, the scanner's other draws as ``bench stripes``).
Every (query pose ``a``, database pose ``b``) pair is one column: the queries are the
scans of pose ``a``, the database the scans of pose ``b``; ``a = b`` is the same-pose
case (each query against all other scans of its set), ``a != b`` the different-pose
case (the robot sees the object again from elsewhere; the query's own object, seen at
pose ``b``, is in the database but is not an answer); one column per (set, ``a``,
``b``).  Figure per column: the nearest *other* object is of the query's class.  The
table gives every column, their minimum and mean, and the mean over the same-pose
and over the different-pose columns.

Rows:

- the parts: ``profile`` (stripe profile), ``relief`` (size-free and fine rings),
  ``relief-coarse`` (size-free rings alone), ``surface`` (surface context),
  ``canonical`` (virtual stripes along the footprint's long axis) and ``sc50`` (shape
  context on 50 points, the fused matcher's verifier);
- ``fused-stripes`` (profile + relief + surface + canonical) and ``fused`` (profile +
  relief + surface + sc50), each part locally scaled (`loopclosure.stripes.fuse`,
  ``scaling="local"``: ``D(q, j) / sqrt(s(q) s(j))``, ``s`` the distance to the
  ``--neighbour``-th nearest other object of the database of pose ``b``), their
  geometric mean (`loopclosure.stripes.combine`); and the earlier rules for
  comparison: ``/arith`` (the arithmetic mean of the same scaled parts), ``/median``
  (each part divided by its per-query median over the database, arithmetic mean)
  and ``fused-stripes-3`` (without the canonical profile); ``/coarse`` (the relief
  without its fine half, ``relief-coarse``: the size-free rings alone, the relief
  before the fine relief was added);
- with ``--baselines``: shape context (100 points), MRM and FFT on the silhouettes, and
  the paper's stripe descriptor (``stripes``, Eq. 1-6).

Each part's distances are those of its own database class with the database of pose
``b`` (the profile's and canonical profile's per-query, per-feature medians are taken
over that database; the other parts' distances do not depend on the database).

Per part, over the different-pose columns of every set:

- ``own-nearest``: the query's own object (other pose) is the nearest database scan;
- ``within/between``: ``d(q, own object at pose b) / median d(q, other-class objects)``,
  the median over the queries: how far a pose change moves the part, in units of
  the distance between classes (1: as far as a typical other class);
- ``rho(elong)``: Spearman rank correlation, over the queries, of that per-query ratio
  with the footprint's elongation ``log(L / W)`` (`CanonicalProfile.length` / ``width``):
  whether the part moves more for long objects (a pose change re-cuts their stripes).

``--failures`` lists, per fused row and column, every query whose nearest other object
is of another class: the query, the object it took, and the part that moved the
decision (the largest ``s_k(q, wrong) - s_k(q, best same-class)`` in favour of the wrong
one, ``s_k`` the part's locally scaled distance), then the class confusions counted over
every column.

Time (``--timing``, on by default): representation + matching of 100 objects (every
descriptor and the full distance matrix of each part, the fusion), one wall-clock
measurement per row on 100 scans (the pooled scans, repeated when fewer), the
silhouettes' extraction reported apart.  Time it with one BLAS thread
(``OPENBLAS_NUM_THREADS=1``); each part is timed three times and the fastest kept.

``--cache DIR`` keeps the scans (pickles, one per seed and scanner) in DIR, e.g.
``/tmp/sd``, never in the repository.  Nothing else is written; the meshes are read
in place.
"""

from __future__ import annotations

import argparse
import hashlib
import pickle
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
from scipy.stats import spearmanr  # noqa: E402

from benchmarks.stripes_real import DEFAULT_MESHES  # noqa: E402
from benchmarks.stripes_variants import OTHER_LABELS  # noqa: E402
from data.stripe_scanner import ScannerConfig  # noqa: E402
from evaluation.stripes_benchmark import (  # noqa: E402
    baseline_distances,
    canonical_distances,
    profile_distances,
    relief_distances,
    surface_distances,
)
from evaluation.stripes_objects import (  # noqa: E402
    ScannedSet,
    mesh_folder_objects,
    scan_objects,
    silhouette_polygon,
)
from loopclosure.stripes import (  # noqa: E402
    ReliefConfig,
    ReliefDatabase,
    StripeDatabase,
    SurfaceDatabase,
    combine,
    database_scales,
    describe_canonical,
    describe_many,
    describe_profiles,
    describe_relief,
    describe_surface,
    fuse,
    local_scaled,
)
from loopclosure.stripes.fusion import GEOMETRIC_FLOOR  # noqa: E402
from loopclosure.stripes.profile import _median_scale  # noqa: E402

#: The fused matcher's parts, in the fusion's order.
PARTS: tuple[str, ...] = ("profile", "relief", "relief-coarse", "surface", "canonical", "sc50")
#: Fused rows: name -> (parts, scaling, mean).
FUSED: dict[str, tuple[tuple[str, ...], str, str]] = {
    "fused-stripes": (("profile", "relief", "surface", "canonical"), "local", "geometric"),
    "fused-stripes/arith": (("profile", "relief", "surface", "canonical"), "local",
                            "arithmetic"),
    "fused-stripes/median": (("profile", "relief", "surface", "canonical"), "median",
                             "arithmetic"),
    "fused-stripes-3": (("profile", "relief", "surface"), "local", "geometric"),
    "fused-stripes-3/arith": (("profile", "relief", "surface"), "local", "arithmetic"),
    "fused": (("profile", "relief", "surface", "sc50"), "local", "geometric"),
    "fused/arith": (("profile", "relief", "surface", "sc50"), "local", "arithmetic"),
    "fused/median": (("profile", "relief", "surface", "sc50"), "median", "arithmetic"),
    "fused-stripes/coarse": (("profile", "relief-coarse", "surface", "canonical"), "local",
                             "geometric"),
    "fused/coarse": (("profile", "relief-coarse", "surface", "sc50"), "local", "geometric"),
}
#: The relief without its fine half (the size-free rings alone): the ``/coarse`` rows.
COARSE = ReliefConfig(fine_window=0.0)
#: Rows whose misses ``--failures`` lists.
FAILURE_ROWS: tuple[str, ...] = ("fused-stripes", "fused", "fused/arith")
#: Silhouette baselines of ``--baselines`` (names of `loopclosure.matchers`).
BASELINES: tuple[str, ...] = ("shape-context", "mrm", "fft")
#: Objects of the timing set.
TIMING_OBJECTS = 100


def scanner() -> ScannerConfig:
    """The scanner of every pose: the default one with any yaw."""
    return replace(ScannerConfig(), yaw_range_deg=180.0)


def scanned_poses(meshes: Path, labels: Path | None, seeds: list[int],
                  cache: Path | None) -> list[ScannedSet]:
    """One `ScannedSet` per seed (one pose of every object), from `cache` when there."""
    cfg = scanner()
    key = hashlib.sha1(repr((str(meshes.resolve()), str(labels), cfg)).encode()).hexdigest()[:12]
    out: list[ScannedSet | None] = []
    for seed in seeds:
        path = None if cache is None else cache / f"scans-{key}-seed{seed}.pkl"
        if path is not None and path.is_file():
            with path.open("rb") as fh:
                out.append(pickle.load(fh))
        else:
            out.append(None)
    if any(s is None for s in out):
        objs = mesh_folder_objects(meshes, labels)
        for i, seed in enumerate(seeds):
            if out[i] is None:
                out[i] = scan_objects(objs, cfg, seed, 1)
                if cache is not None:
                    cache.mkdir(parents=True, exist_ok=True)
                    with (cache / f"scans-{key}-seed{seed}.pkl").open("wb") as fh:
                        pickle.dump(out[i], fh)
    return [s for s in out if s is not None]


def profile_block(stack: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """`ProfileDatabase` / `CanonicalDatabase` distances of the profiles `rows` (queries)
    against the database `cols` of the stacked ``(M, K, F)`` profiles (per-query,
    per-feature medians over `cols`; the smaller of forward and reversed)."""
    q, s = stack[rows], stack[cols]
    forward = np.abs(s[None] - q[:, None]).mean(axis=2)
    reverse = np.abs(s[None] - q[:, None, ::-1]).mean(axis=2)
    scale = _median_scale(np.minimum(forward, reverse))
    return np.minimum((forward / scale).mean(axis=2), (reverse / scale).mean(axis=2))


@dataclass
class Pooled:
    """Every pose's scans pooled: labels, object ids, pose of each scan, names,
    elongations, and per method either a pooled ``(n, n)`` matrix or a profile stack."""

    labels: np.ndarray
    objects: np.ndarray
    pose: np.ndarray
    names: list[str]
    elongation: np.ndarray
    matrices: dict[str, np.ndarray]
    stacks: dict[str, np.ndarray]

    def block(self, method: str, a: int, b: int) -> np.ndarray:
        rows, cols = np.flatnonzero(self.pose == a), np.flatnonzero(self.pose == b)
        if method in self.stacks:
            return profile_block(self.stacks[method], rows, cols)
        return self.matrices[method][np.ix_(rows, cols)]


def pool(sets: list[ScannedSet], baselines: bool) -> Pooled:
    """Describe every scan of every pose with every method (module docstring)."""
    cfg = scanner()
    scans = [s for ss in sets for s in ss.scans]
    labels = np.array([lab for ss in sets for lab in ss.labels])
    objects = np.concatenate([ss.objects for ss in sets])
    pose = np.concatenate([np.full(len(ss.scans), i) for i, ss in enumerate(sets)])
    maps = [s.height_map(cfg) for s in scans]
    canon = [describe_canonical(*m) for m in maps]
    stacks = {
        "profile": np.stack([p.profile for p in describe_profiles([s.stripes for s in scans])]),
        "canonical": np.stack([c.profile for c in canon]),
    }
    matrices = {
        "relief": ReliefDatabase([describe_relief(*m) for m in maps]).pairwise(),
        "relief-coarse": ReliefDatabase([describe_relief(*m, COARSE) for m in maps]).pairwise(),
        "surface": SurfaceDatabase([describe_surface(*m) for m in maps]).pairwise(),
    }
    polys = [silhouette_polygon(s, cfg, 1.0) for s in scans]
    matrices["sc50"] = baseline_distances("shape-context-50", polys)[0]
    if baselines:
        for name in BASELINES:
            matrices[name] = baseline_distances(name, polys)[0]
        matrices["stripes"] = StripeDatabase(describe_many([s.stripes for s in scans])).pairwise()
    elong = np.log(np.array([c.length / c.width for c in canon]))
    return Pooled(labels, objects, pose, [s.name for s in scans], elong, matrices, stacks)


@dataclass
class Column:
    """One (query pose, database pose) column: the labels and objects of its rows and
    columns, and the mask of pairs that are not answers (the query's own object)."""

    a: int
    b: int
    qlab: np.ndarray
    dlab: np.ndarray
    qobj: np.ndarray
    dobj: np.ndarray
    qnames: list[str]
    dnames: list[str]
    qelong: np.ndarray

    @property
    def own(self) -> np.ndarray:
        return self.qobj[:, None] == self.dobj[None, :]

    set_name: str = ""

    @property
    def name(self) -> str:
        return f"{self.set_name}{self.a}{self.b}"


def columns(p: Pooled, poses: int, set_name: str) -> list[Column]:
    out = []
    for a in range(poses):
        for b in range(poses):
            r, c = np.flatnonzero(p.pose == a), np.flatnonzero(p.pose == b)
            out.append(Column(a, b, p.labels[r], p.labels[c], p.objects[r], p.objects[c],
                              [p.names[i] for i in r], [p.names[i] for i in c],
                              p.elongation[r], set_name))
    return out


def scaled_parts(p: Pooled, col: Column, parts: tuple[str, ...], scaling: str,
                 neighbour: int) -> list[np.ndarray]:
    """Each part's distances of the column made unitless by `scaling` (the database's
    own distances: the database pose against itself)."""
    out = []
    for m in parts:
        d = p.block(m, col.a, col.b)
        if scaling == "median":
            out.append(fuse([d]))
        else:
            out.append(local_scaled(d, database_scales(p.block(m, col.b, col.b), neighbour),
                                    neighbour))
    return out


def nearest_other(d: np.ndarray, col: Column) -> np.ndarray:
    """Index of the nearest database scan of another object, per query."""
    dd = np.where(np.isfinite(d), d, np.inf)
    return np.argmin(np.where(col.own, np.inf, dd), axis=1)


def hit_rate(d: np.ndarray, col: Column) -> float:
    return float(np.mean(col.dlab[nearest_other(d, col)] == col.qlab))


def pose_figures(d: np.ndarray, col: Column) -> tuple[float, np.ndarray]:
    """Different-pose column: own-nearest rate and the per-query within/between ratio."""
    dd = np.where(np.isfinite(d), d, np.inf)
    own = col.own
    own_d = np.where(own, dd, np.inf).min(axis=1)
    other = np.where(own, np.inf, dd).min(axis=1)
    between = col.dlab[None, :] != col.qlab[:, None]
    med = np.array([np.median(row[m]) if m.any() else np.nan
                    for row, m in zip(dd, between, strict=True)])
    return float(np.mean(own_d < other)), own_d / med


def table(rows: dict[str, dict[str, float]], cols: list[Column]) -> None:
    names = [c.name for c in cols]
    same = [c.name for c in cols if c.a == c.b]
    diff = [c.name for c in cols if c.a != c.b]
    print(f"{'method':24s}" + " ".join(f"{n:>6s}" for n in names)
          + "    min   mean   same   diff")
    for name, r in rows.items():
        vals = [r[n] for n in names]
        sp = np.mean([r[n] for n in same])
        dp = np.mean([r[n] for n in diff]) if diff else float("nan")
        print(f"{name:24s}" + " ".join(f"{v:6.3f}" for v in vals)
              + f"  {min(vals):5.3f}  {np.mean(vals):5.3f}  {sp:5.3f}  {dp:5.3f}")


def failures(sets: list[tuple[Pooled, list[Column]]], neighbour: int) -> None:
    """The misses of the fused rows and the part that moved each decision (in the
    row's mean: scaled differences for the arithmetic, log ratios for the geometric)."""
    for name in FAILURE_ROWS:
        parts, scaling, mean = FUSED[name]
        confusions: dict[tuple[str, str], int] = {}
        movers: dict[str, int] = {}
        print(f"\nfailures of {name} ({scaling} scaling, {mean} mean; part = the one that "
              "preferred the wrong object most, in scaled units"
              + (", log" if mean == "geometric" else "") + ")")
        for p, col in ((p, c) for p, cols in sets for c in cols):
            sp = scaled_parts(p, col, parts, scaling, neighbour)
            fused = combine(sp, np.full(len(sp), 1.0 / len(sp)), mean)
            if mean == "geometric":
                sp = [np.log(np.maximum(s, GEOMETRIC_FLOOR)) for s in sp]
            near = nearest_other(fused, col)
            same_cls = (col.dlab[None, :] == col.qlab[:, None]) & ~col.own
            for q in np.flatnonzero(col.dlab[near] != col.qlab):
                w = near[q]
                cands = np.flatnonzero(same_cls[q])
                if len(cands) == 0:
                    continue
                c = cands[np.argmin(fused[q, cands])]
                delta = np.array([s[q, w] - s[q, c] for s in sp])
                k = int(np.argmin(delta))
                movers[parts[k]] = movers.get(parts[k], 0) + 1
                key = (col.qlab[q], col.dlab[w])
                confusions[key] = confusions.get(key, 0) + 1
                print(f"  {col.name} {col.qnames[q]:28s} -> {col.dnames[w]:28s} "
                      f"(best same class {col.dnames[c]}); {parts[k]} {delta[k]:+.2f}; "
                      + " ".join(f"{m}{x:+.2f}" for m, x in zip(parts, delta, strict=True)))
        print(f"  moved by: {movers}")
        print("  confusions (query class -> taken class: count): "
              + ", ".join(f"{a}->{b}: {n}" for (a, b), n in
                          sorted(confusions.items(), key=lambda kv: -kv[1])))


def timing(sets: list[ScannedSet], repeats: int = 3) -> None:
    """Representation + matching of 100 scans per row (module docstring): the fastest of
    `repeats` wall-clock measurements per part (the machine may be shared)."""
    cfg = scanner()
    scans = [s for ss in sets for s in ss.scans]
    scans = (scans * (TIMING_OBJECTS // len(scans) + 1))[:TIMING_OBJECTS]
    polys: list = []
    sil = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        polys = [silhouette_polygon(s, cfg, 1.0) for s in scans]
        sil = min(sil, time.perf_counter() - t0)
    runs = {
        "profile": lambda: profile_distances(scans),
        "relief": lambda: relief_distances(scans, cfg),
        "surface": lambda: surface_distances(scans, cfg),
        "canonical": lambda: canonical_distances(scans, cfg),
        "sc50": lambda: baseline_distances("shape-context-50", polys)[:2],
    }
    d, secs = {}, {}
    for name, run in runs.items():
        for _ in range(repeats):
            d[name], s = run()
            secs[name] = min(secs.get(name, np.inf), s)
    print(f"\ntime: representation + matching of {len(scans)} scans [s], fastest of "
          f"{repeats} (silhouettes {sil:.2f} s apart): "
          + ", ".join(f"{k} {v:.3f}" for k, v in secs.items()))
    for name in ("fused-stripes", "fused"):
        parts, scaling, mean = FUSED[name]
        t0 = time.perf_counter()
        fuse([d[m] for m in parts], scaling=scaling, mean=mean)
        total = sum(secs[m] for m in parts) + time.perf_counter() - t0
        print(f"  {name:14s} {total:.3f} s per {len(scans)} objects "
              f"({total + sil:.3f} s with the silhouettes)")


def run_seeds(args: argparse.Namespace, seeds: list[int]) -> tuple[dict[str, dict[str, float]],
                                                                  list[Column],
                                                                  list[ScannedSet]]:
    """Every table of the module docstring for one group of `seeds` (one pose each):
    the rows' figures per column, the columns and the scanned sets."""
    labels = args.labels or ["ycb", str(OTHER_LABELS)]
    pooled: list[tuple[Pooled, list[Column]]] = []
    all_sets: list[ScannedSet] = []
    for i, lab in enumerate(labels):
        csv = None if lab == "ycb" else Path(lab)
        sets = scanned_poses(args.meshes, csv, seeds, args.cache)
        all_sets += sets
        p = pool(sets, args.baselines)
        name = "ycb" if csv is None else ("oth" if csv == OTHER_LABELS else f"s{i}")
        pooled.append((p, columns(p, len(sets), name)))
        print(f"set {name}: {len(sets[0].scans)} objects ({lab})")
    cols = [c for _, cs in pooled for c in cs]
    print(f"poses = seeds {seeds} (any yaw); column <set><A><B>: queries at pose A, "
          "database at pose B; figure: nearest other object of the query's class")
    rows: dict[str, dict[str, float]] = {}
    methods = [*PARTS, *FUSED, *((*BASELINES, "stripes") if args.baselines else ())]
    for m in methods:
        rows[m] = {}
        for p, cs in pooled:
            for c in cs:
                if m in FUSED:
                    parts, scaling, mean = FUSED[m]
                    sp = scaled_parts(p, c, parts, scaling, args.neighbour)
                    d = combine(sp, np.full(len(sp), 1.0 / len(sp)), mean)
                else:
                    d = p.block(m, c.a, c.b)
                rows[m][c.name] = hit_rate(d, c)
    table(rows, cols)
    if len(seeds) > 1:
        print("\nper part over the different-pose columns: own-nearest = own object's "
              "other pose is the nearest scan; within/between = median over queries of "
              "d(own, other pose) / median d(other classes); rho = Spearman of that "
              "ratio with the footprint's elongation log(L/W)")
        print(f"{'part':24s} own-nearest  within/between  rho(elong)")
        for m in (*PARTS, *((*BASELINES, "stripes") if args.baselines else ())):
            own, ratios, elong = [], [], []
            for p, cs in pooled:
                for c in (c for c in cs if c.a != c.b):
                    o, r = pose_figures(p.block(m, c.a, c.b), c)
                    own.append(o)
                    ratios.append(r)
                    elong.append(c.qelong)
            r, e = np.concatenate(ratios), np.concatenate(elong)
            ok = np.isfinite(r)
            rho = spearmanr(r[ok], e[ok]).statistic
            print(f"{m:24s} {np.mean(own):11.3f}  {np.median(r[ok]):14.3f}  {rho:+10.2f}")
    if args.failures:
        failures(pooled, args.neighbour)
    return rows, cols, all_sets


def summary(groups: list[tuple[list[int], dict[str, dict[str, float]]]]) -> None:
    """Per row, the worst and mean column of every seed group and of all of them."""
    print("\nsummary: worst / mean column per seed group (each its own poses' columns)")
    heads = [",".join(map(str, seeds)) for seeds, _ in groups]
    print(f"{'method':24s}" + "".join(f"{h:>15s}" for h in heads) + f"{'all':>15s}")
    for m in groups[0][1]:
        vals = [list(rows[m].values()) for _, rows in groups]
        every = [v for vs in vals for v in vs]
        print(f"{m:24s}" + "".join(f"{min(v):8.3f}/{np.mean(v):.3f}" for v in vals)
              + f"{min(every):8.3f}/{np.mean(every):.3f}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--meshes", type=Path, default=DEFAULT_MESHES)
    ap.add_argument("--labels", nargs="*", default=None,
                    help="labels CSVs ('ycb': the multi-instance classes); default: ycb "
                         "and the second labelled YCB set")
    ap.add_argument("--seeds", default="0,1",
                    help="seeds, one pose each, comma-separated; groups separated by "
                         "';' (e.g. '0,1;2,3;4,5') are evaluated apart, then summarised")
    ap.add_argument("--cache", type=Path, default=None)
    ap.add_argument("--baselines", action="store_true")
    ap.add_argument("--failures", action="store_true")
    ap.add_argument("--neighbour", type=int, default=5)
    ap.add_argument("--no-timing", action="store_true")
    args = ap.parse_args(argv)
    if not args.meshes.is_dir():
        print(f"skipped: no mesh folder {args.meshes}")
        return
    groups = [[int(s) for s in g.split(",")] for g in args.seeds.split(";") if g.strip()]
    results = []
    timed: list[ScannedSet] = []  # the first group's scans: the timing set
    for i, seeds in enumerate(groups):
        if len(groups) > 1:
            print(f"{'' if i == 0 else chr(10)}=== seed group {i + 1} of {len(groups)}: {seeds}")
        rows, _, sets = run_seeds(args, seeds)
        results.append((seeds, rows))
        timed = timed or sets
    if len(groups) > 1:
        summary(results)
    if not args.no_timing and timed:
        timing(timed)


if __name__ == "__main__":
    main()
