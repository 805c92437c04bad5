"""Benchmark: how much each scanning nuisance moves the stripe descriptor, against classes.

Run from the repository root::

    python benchmarks/stripes_nuisance.py [--meshes DIR] [--labels CSV] [--per-class 2]
                                          [--stripe-count N] [--scale-free]
                                          [--profile | --parts]

For a few objects of every class of a labelled mesh folder (default: the YCB
multi-instance classes of ``../shared/data/meshes-ycb``) it scans each object once
with the default scanner (the reference) and once per nuisance -- another pose on
the table, standoff, laser step, triangulation angle, image noise and gaps, holes
cut into the mesh -- and prints, per nuisance and per feature of Eq. 1-3 (``l``,
``d``, ``o``) and for their Eq. 5 sum, the median distance between the reference
scan and the disturbed scan of the same object divided by the median distance
between reference scans of objects of *different* classes.  A ratio near 0: the
nuisance does not matter; near 1: it moves an object as far as a class change does.
The last row, ``other member of class``, is the same ratio for two *different*
objects of one class (reference scans): the spread of a class against the distance
between classes, which no scanner setting can shrink.
It also prints the stripe counts and stripe widths per class (the paper: about 140
stripes per object on 600 x 712 images) and, per class, the spread (standard
deviation over the class's objects) of each object's mean ``d``: ``d`` is a size
feature in pixels, so it separates classes only where a class has one size.

With ``--profile`` the same table is made for the stripe profile
(`loopclosure.stripes.profile`): per feature ``l``, ``d`` (scale-free), ``e`` the
mean absolute difference of the two profiles, and for their combination the mean of
the three each divided by its median between classes, the smaller of the two
orientations (forward, reversed); and the same ratio for the relief
(`loopclosure.stripes.relief`: depth below the top, ring by ring, from each scan's
heights with the scanner configuration that made it).

With ``--parts`` the table is made for every part of the fused object matcher
(`loopclosure.stripes.fusion`), each with its own database class and distance, the
database being the reference scans: ``profile`` (stripe profile), ``relief``,
``surface`` (surface context), ``canonical`` (canonical profile), ``sc50`` (shape
context on 50 points of the silhouette, `evaluation.stripes_objects.silhouette_polygon`
of each scan with the scanner that made it), and the two fused matchers, ``fused``
(profile + relief + surface + sc50) and ``fused-stripes`` (profile + relief + surface +
canonical), each part locally scaled by the reference database's own distances
(`fusion.local_scaled`; the disturbed scan is a query against the reference scans),
their geometric mean (`fusion.combine`, the fused matcher's rule).
Ratio per cell: the median over the objects of the distance from the disturbed scan
to the same object's reference scan, divided by the median distance between
reference scans of different classes (the profile's and canonical profile's
per-query medians taken over the reference database, as `bench stripes` does).  The
last row is the same ratio for two different objects of one class.  Heights come
from each scan with the scanner configuration that made it.

Nothing is written; the meshes are read in place.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from data.stripe_scanner import Mesh, ScannerConfig, scan_mesh  # noqa: E402
from evaluation.stripes_objects import (  # noqa: E402
    height_map,
    mesh_folder_objects,
    silhouette_polygon,
)
from loopclosure.stripes import (  # noqa: E402
    CanonicalDatabase,
    DescriptorConfig,
    ProfileDatabase,
    ReliefDatabase,
    StripeDatabase,
    SurfaceDatabase,
    describe_canonical,
    describe_many,
    describe_profiles,
    describe_relief,
    describe_surface,
)
from loopclosure.stripes.fusion import (  # noqa: E402
    DEFAULT_MEAN,
    database_scales,
    local_scaled,
    verifier,
)
from loopclosure.stripes.fusion import combine as fusion_mean  # noqa: E402
from loopclosure.stripes.matching import LAMBDA_PAPER, combine  # noqa: E402

DEFAULT_MESHES = ROOT.parent / "shared" / "data" / "meshes-ycb"


def with_holes(mesh: Mesh, fraction: float, rng: np.random.Generator) -> Mesh:
    """The mesh with a random `fraction` of its faces removed (a non-watertight scan)."""
    keep = rng.random(len(mesh.faces)) >= fraction
    return Mesh(mesh.vertices, mesh.faces[keep], mesh.name, False)


NUISANCES: dict[str, tuple[dict, float]] = {
    "pose (seed)": ({}, 0.0),
    "yaw any": ({"yaw_range_deg": 180.0}, 0.0),
    "standoff 0.5 m": ({"standoff": 0.5}, 0.0),
    "standoff 0.7 m": ({"standoff": 0.7}, 0.0),
    "step 0.4 mm": ({"step": 0.0004}, 0.0),
    "step 1.6 mm": ({"step": 0.0016}, 0.0),
    "triangulation 20": ({"triangulation_deg": 20.0}, 0.0),
    "triangulation 40": ({"triangulation_deg": 40.0}, 0.0),
    "noise x3, gaps x3": ({"pixel_noise": 0.06, "gap_rate": 0.009}, 0.0),
    "holes 5 %": ({}, 0.05),
}
"""name -> (scanner overrides, fraction of faces removed)."""


def _profile_parts(db: ProfileDatabase, queries: list) -> tuple[np.ndarray, np.ndarray]:
    """``(Q, M, 3)`` per-feature profile distances, forward and reversed."""
    fw, rv = zip(*(db.feature_distances(q) for q in queries), strict=True)
    return np.stack(fw), np.stack(rv)


def _combined(fw: np.ndarray, rv: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Mean of the features divided by `scale`, the smaller orientation."""
    return np.minimum((fw / scale).mean(axis=-1), (rv / scale).mean(axis=-1))


def profile_table(meshes: list[Mesh], labels: np.ndarray, ref: list, base: ScannerConfig,
                  rng: np.random.Generator) -> None:
    """The nuisance table for the stripe profile (module docstring)."""
    ref_p = describe_profiles([s.stripes for s in ref])
    fw, rv = _profile_parts(ProfileDatabase(ref_p), ref_p)
    between = labels[:, None] != labels[None, :]
    both = np.minimum(fw, rv)
    scale = np.array([float(np.median(both[..., t][between])) for t in range(3)])
    comb = float(np.median(_combined(fw, rv, scale)[between]))
    ref_r = [describe_relief(*s.height_map(base)) for s in ref]
    rel_between = float(np.median(ReliefDatabase(ref_r).pairwise()[between]))
    print(f"\n{'nuisance':22s} {'l':>6s} {'d':>6s} {'e':>6s} {'all':>6s} {'relief':>6s}   "
          "(stripe profile, relief: same object, disturbed / different classes; medians)")
    for name, (over, holes) in NUISANCES.items():
        cfg = replace(base, **over)
        scans = [scan_mesh(with_holes(m, holes, rng) if holes > 0 else m, cfg, rng)
                 for m in meshes]
        db = ProfileDatabase(describe_profiles([s.stripes for s in scans]))
        f2, r2 = _profile_parts(db, ref_p)
        idx = np.arange(len(ref_p))
        f2, r2 = f2[idx, idx], r2[idx, idx]
        ratios = [float(np.median(np.minimum(f2, r2)[:, t])) / scale[t] for t in range(3)]
        ratios.append(float(np.median(_combined(f2, r2, scale))) / comb)
        db = ReliefDatabase([describe_relief(*s.height_map(cfg)) for s in scans])
        same = [db.distances(q)[i] for i, q in enumerate(ref_r)]
        ratios.append(float(np.median(same)) / rel_between)
        print(f"{name:22s} " + " ".join(f"{r:6.2f}" for r in ratios))
    within = (labels[:, None] == labels[None, :]) & ~np.eye(len(labels), dtype=bool)
    ratios = [float(np.median(both[..., t][within])) / scale[t] for t in range(3)]
    ratios.append(float(np.median(_combined(fw, rv, scale)[within])) / comb)
    ratios.append(float(np.median(ReliefDatabase(ref_r).pairwise()[within])) / rel_between)
    print(f"{'other member of class':22s} " + " ".join(f"{r:6.2f}" for r in ratios))


#: Parts of the fused matcher in the ``--parts`` table, and the two fusions of them.
PARTS: tuple[str, ...] = ("profile", "relief", "surface", "canonical", "sc50")
FUSIONS: dict[str, tuple[str, ...]] = {
    "fused": ("profile", "relief", "surface", "sc50"),
    "fused-stripes": ("profile", "relief", "surface", "canonical"),
}


def _fusion(scaled: list[np.ndarray]) -> np.ndarray:
    """The fused matcher's mean (`DEFAULT_MEAN`, equal weights) of locally scaled parts."""
    return fusion_mean(scaled, np.full(len(scaled), 1.0 / len(scaled)), DEFAULT_MEAN)


def part_descriptions(scans: list, cfg: ScannerConfig, sc) -> dict[str, list]:
    """Each part's description of every scan (`cfg`: the scanner that made them; `sc`
    the ``shape-context-50`` matcher)."""
    maps = [height_map(s, cfg) for s in scans]
    return {
        "profile": describe_profiles([s.stripes for s in scans]),
        "relief": [describe_relief(*m) for m in maps],
        "surface": [describe_surface(*m) for m in maps],
        "canonical": [describe_canonical(*m) for m in maps],
        "sc50": [sc.describe(silhouette_polygon(s, cfg, 1.0)) for s in scans],
    }


class PartDatabases:
    """The reference scans' databases of every part (`PARTS`), their own distances and
    local scales."""

    def __init__(self, ref: dict[str, list], sc) -> None:
        self.sc = sc
        self.dbs = {"profile": ProfileDatabase(ref["profile"]),
                    "relief": ReliefDatabase(ref["relief"]),
                    "surface": SurfaceDatabase(ref["surface"]),
                    "canonical": CanonicalDatabase(ref["canonical"])}
        self.sc_stack = sc.stack(ref["sc50"])
        self.own = {k: db.pairwise() for k, db in self.dbs.items()}
        self.own["sc50"] = np.asarray(sc.pairwise(ref["sc50"]), dtype=float)
        self.scales = {k: database_scales(d) for k, d in self.own.items()}

    def rows(self, queries: dict[str, list]) -> dict[str, np.ndarray]:
        """Part (and fusion) -> ``(Q, M)`` distances of the queries to the references."""
        out = {k: np.stack([db.distances(q) for q in queries[k]])
               for k, db in self.dbs.items()}
        out["sc50"] = np.stack([np.asarray(self.sc.distances(q, self.sc_stack), dtype=float)
                                for q in queries["sc50"]])
        for name, parts in FUSIONS.items():
            out[name] = _fusion([local_scaled(out[k], self.scales[k]) for k in parts])
        return out

    def pairwise(self) -> dict[str, np.ndarray]:
        """Part (and fusion) -> the reference scans' ``(M, M)`` distances."""
        out = dict(self.own)
        for name, parts in FUSIONS.items():
            out[name] = _fusion([local_scaled(self.own[k], self.scales[k]) for k in parts])
        return out


def parts_table(meshes: list[Mesh], labels: np.ndarray, ref: list, base: ScannerConfig,
                rng: np.random.Generator) -> None:
    """The nuisance table for every part of the fused matcher (module docstring)."""
    sc = verifier("shape-context-50")
    dbs = PartDatabases(part_descriptions(ref, base, sc), sc)
    own = dbs.pairwise()
    between = labels[:, None] != labels[None, :]
    scale = {k: float(np.median(d[between])) for k, d in own.items()}
    names = [*PARTS, *FUSIONS]
    print(f"\n{'nuisance':22s} " + " ".join(f"{n:>13s}" for n in names)
          + "\n(same object, disturbed scan vs reference scan / different classes; medians)")
    idx = np.arange(len(meshes))
    for name, (over, holes) in NUISANCES.items():
        cfg = replace(base, **over)
        scans = [scan_mesh(with_holes(m, holes, rng) if holes > 0 else m, cfg, rng)
                 for m in meshes]
        rows = dbs.rows(part_descriptions(scans, cfg, sc))
        print(f"{name:22s} " + " ".join(
            f"{float(np.median(rows[n][idx, idx])) / max(scale[n], 1e-12):13.2f}"
            for n in names))
    within = (labels[:, None] == labels[None, :]) & ~np.eye(len(labels), dtype=bool)
    print(f"{'other member of class':22s} " + " ".join(
        f"{float(np.median(own[n][within])) / max(scale[n], 1e-12):13.2f}" for n in names))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--meshes", type=Path, default=DEFAULT_MESHES)
    ap.add_argument("--labels", type=Path, default=None)
    ap.add_argument("--per-class", type=int, default=2)
    ap.add_argument("--stripe-count", type=int, default=None)
    ap.add_argument("--scale-free", action="store_true")
    ap.add_argument("--profile", action="store_true", help="the stripe profile's table")
    ap.add_argument("--parts", action="store_true",
                    help="the table of every part of the fused matcher")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if not args.meshes.is_dir():
        print(f"skipped: no mesh folder {args.meshes}")
        return
    objs = mesh_folder_objects(args.meshes, args.labels)
    pick: list[int] = []
    for c in dict.fromkeys(objs.labels):
        pick += [i for i, lab in enumerate(objs.labels) if lab == c][: args.per_class]
    meshes = [objs.meshes[i] for i in pick]
    labels = np.array([objs.labels[i] for i in pick])
    dcfg = DescriptorConfig(stripe_count=args.stripe_count, scale_free=args.scale_free)
    base = ScannerConfig()
    rng = np.random.default_rng(args.seed)
    ref = [scan_mesh(m, base, rng) for m in meshes]
    print(f"{len(meshes)} objects, classes {', '.join(dict.fromkeys(labels))}; "
          f"descriptor {dcfg}")
    ref_desc = describe_many([s.stripes for s in ref], dcfg)
    for c in dict.fromkeys(labels):
        idx = [i for i, lab in enumerate(labels) if lab == c]
        n = np.mean([len(ref[i].stripes) for i in idx])
        w = np.mean([np.mean([len(x) for x in ref[i].stripes]) for i in idx])
        spread = np.std([ref_desc[i].d.mean() for i in idx])
        print(f"  {c:14s} stripes per object {n:6.1f}   mean stripe width {w:6.1f} px   "
              f"spread of mean d {spread:5.2f}")
    if args.profile:
        profile_table(meshes, labels, ref, base, rng)
        return
    if args.parts:
        parts_table(meshes, labels, ref, base, rng)
        return
    fd = StripeDatabase(ref_desc).pairwise_features()
    between = labels[:, None] != labels[None, :]
    scale = [float(np.median(fd[..., t][between])) for t in range(3)]
    scale.append(float(np.median(combine(fd, LAMBDA_PAPER)[between])))
    print(f"\n{'nuisance':22s} {'l':>6s} {'d':>6s} {'o':>6s} {'Eq.5':>6s}   "
          "(same object, disturbed / different classes; medians)")
    for name, (over, holes) in NUISANCES.items():
        cfg = replace(base, **over)
        scans = []
        for m in meshes:
            mm = with_holes(m, holes, rng) if holes > 0 else m
            scans.append(scan_mesh(mm, cfg, rng))
        dist = describe_many([s.stripes for s in scans], dcfg)
        db = StripeDatabase(dist)
        same = np.stack([db.feature_distances(q)[i] for i, q in enumerate(ref_desc)])
        ratios = [float(np.median(same[:, t])) / max(scale[t], 1e-12) for t in range(3)]
        ratios.append(float(np.median(combine(same, LAMBDA_PAPER))) / max(scale[3], 1e-12))
        print(f"{name:22s} " + " ".join(f"{r:6.2f}" for r in ratios))
    within = (labels[:, None] == labels[None, :]) & ~np.eye(len(labels), dtype=bool)
    ratios = [float(np.median(fd[..., t][within])) / max(scale[t], 1e-12) for t in range(3)]
    ratios.append(float(np.median(combine(fd, LAMBDA_PAPER)[within])) / max(scale[3], 1e-12))
    print(f"{'other member of class':22s} " + " ".join(f"{r:6.2f}" for r in ratios))


if __name__ == "__main__":
    main()
