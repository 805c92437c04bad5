"""Benchmark: variants of the fused object matcher on the two YCB labelled sets, one run.

Run from the repository root::

    python benchmarks/stripes_variants.py [--meshes DIR] [--seeds 0,1]

Scans the YCB multi-instance classes and the second labelled set
(``benchmarks/stripes_ycb_other_labels.csv``) at every seed, same pose (one scan per
object, yaw within +-15 degrees) and different pose (two scans per object, any yaw),
exactly as ``benchmarks/stripes_real.py``; then scores every variant on the same
scans: one column per (set, seed, pose), figure = the nearest other object is of the
query's class (same-pose / different-pose rule of ``stripes_real``), and the minimum
and mean over the columns.  Variants (distances per query; "fuse" = each method's
distances divided by their per-query median, then averaged, `loopclosure.stripes.fuse`):

- ``prof+elong``: the profile with one more feature, the footprint's elongation
  ``0.5 log(lambda_max / lambda_min)`` of the silhouette polygon's second moments of
  area (unitless, yaw invariant), median-normalised like the profile's features;
- ``fuse(...)``: the profile (or ``prof+elong``) fused with FFT, ring projection,
  shape context (100 points, and 40 / 60 points: ``sc40``, ``sc60``) or MRM;
- ``sc50``: the ``shape-context-50`` verifier preset (50 points, compiled kernel;
  `loopclosure.stripes.fusion.VERIFIER_PRESETS`), the default ``fused-sc`` verifier;
  ``fuse(p,sc)`` is the profile fused with the 100-point shape context;
- ``p>sc topK``: the profile's K nearest re-ranked by shape context;
- ``rank(p+sc)``: the sum of the two methods' rank positions;
- ``relief`` (`loopclosure.stripes.relief`, the ``relief`` row of ``bench stripes``)
  and ``fused-relief`` (profile + relief + ``shape-context-50``, the ``fused-relief``
  row); ``fuse(p,relief)``, ``fuse(relief,sc50)``, ``fuse(p,relief,mrm)``: the relief
  with other partners;
- ``surface`` (`loopclosure.stripes.surface`, the surface context), ``canonical``
  (`loopclosure.stripes.canonical`), ``fused-stripes`` (profile + relief + surface +
  canonical, locally scaled: nothing but the stripes) and ``fused`` (profile, relief,
  surface and ``shape-context-50``, locally scaled: the default matcher), the rows of
  ``bench stripes``;
  ``fuse(p,fft,ring)`` is the earlier default (profile + FFT + ring projection);
- ``fused+aspect``: ``fused`` with a fifth part, the aspect ratio of the 3D extent
  ``log(top height / r_eq)`` (metres from the scanner's calibration; ``r_eq`` the
  radius of the disc of the footprint's area), median-normalised like the others;
- ``stripes n=32``: the paper's descriptor and Eq. 4-6 with every object described by
  32 evenly spaced stripes (``DescriptorConfig(stripe_count=32)``, ``bench stripes
  --stripe-count 32``): the sweep density the paper leaves to the arm's speed.

Time (column ``s/100``): seconds of representation + matching of 100 objects (every
descriptor and the full distance matrix), one wall-clock measurement per method on
the first 100 scans made (over the columns in order); a variant's time is the sum
of its methods' times and of the fusion step.  ``x`` is ``fuse(p,sc)``'s time
divided by the variant's, both measured in this run.  Time it with one BLAS thread
(``OPENBLAS_NUM_THREADS=1``), as shape context's docstring says.

Nothing is written; the meshes are read in place.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from benchmarks.stripes_real import DEFAULT_MESHES, different_pose, same_pose  # noqa: E402
from data.stripe_scanner import ScannerConfig  # noqa: E402
from evaluation.stripes_benchmark import (  # noqa: E402
    StripesBenchmarkConfig,
    baseline_distances,
    canonical_distances,
    profile_distances,
    relief_distances,
    run_stripes_benchmark,
    stripes_distances,
    surface_distances,
)
from evaluation.stripes_objects import mesh_folder_objects, silhouette_polygon  # noqa: E402
from loopclosure.matchers import get_matcher  # noqa: E402
from loopclosure.stripes import (  # noqa: E402
    SC_VERIFIERS,
    DescriptorConfig,
    describe_profiles,
    fuse,
)
from loopclosure.stripes.profile import _median_scale  # noqa: E402

OTHER_LABELS = ROOT / "benchmarks" / "stripes_ycb_other_labels.csv"
#: Silhouette matchers of `run_stripes_benchmark` here (each also a variant row).
BASELINES: tuple[str, ...] = ("shape-context", "mrm", "fft", "ring")
#: Objects of the timing set.
TIMING_OBJECTS = 100


def elongation(vertices: np.ndarray) -> float:
    """``0.5 log(l_max / l_min)`` of the polygon's central second moments of area."""
    v = np.asarray(vertices, float)
    x, y = v[:, 0] - v[:, 0].mean(), v[:, 1] - v[:, 1].mean()
    x1, y1 = np.roll(x, -1), np.roll(y, -1)
    a = x * y1 - x1 * y
    area = a.sum() / 2
    cx, cy = ((x + x1) * a).sum() / (6 * area), ((y + y1) * a).sum() / (6 * area)
    ixx = ((x * x + x * x1 + x1 * x1) * a).sum() / (12 * area) - cx * cx
    iyy = ((y * y + y * y1 + y1 * y1) * a).sum() / (12 * area) - cy * cy
    ixy = ((x * y1 + 2 * x * y + 2 * x1 * y1 + x1 * y) * a).sum() / (24 * area) - cx * cy
    w = np.linalg.eigvalsh(np.array([[ixx, ixy], [ixy, iyy]]))
    return float(0.5 * np.log(w[1] / max(w[0], 1e-12)))


def aspect(scan, scanner: ScannerConfig) -> float:
    """``log(top / r_eq)``: the 98th-percentile height [m] over the radius [m] of the disc
    of the seen footprint's area (`StripeScan.height_map`)."""
    z, (dy, dx) = scan.height_map(scanner)
    h = z[np.isfinite(z)]
    return float(np.log(np.percentile(h, 98.0) / np.sqrt(len(h) * dx * dy / np.pi)))


def scalar_distances(values: np.ndarray) -> np.ndarray:
    """``|a_i - a_j|`` of one scalar per object."""
    return np.abs(values[:, None] - values[None])


def profile_plus(stripes: list, extra: np.ndarray) -> np.ndarray:
    """Profile distances with per-object scalar features `extra` ``(M, G)`` added."""
    s = np.stack([p.profile for p in describe_profiles(stripes)])
    fwd = np.abs(s[:, None] - s[None]).mean(axis=2)
    rev = np.abs(s[:, None, ::-1] - s[None]).mean(axis=2)
    gd = np.abs(extra[:, None] - extra[None])
    fwd, rev = np.concatenate([fwd, gd], axis=2), np.concatenate([rev, gd], axis=2)
    scale = _median_scale(np.minimum(fwd, rev))
    return np.minimum((fwd / scale).mean(axis=2), (rev / scale).mean(axis=2))


def rerank(base: np.ndarray, verifier: np.ndarray, k: int) -> np.ndarray:
    """Rank positions: `base`'s k nearest others re-ordered by `verifier`."""
    dd = np.where(np.isfinite(base), base, np.inf).copy()
    np.fill_diagonal(dd, -1.0)
    out = np.empty_like(dd)
    for i in range(len(dd)):
        o = np.argsort(dd[i], kind="stable")
        top = o[1:k + 1]
        order = np.concatenate([[o[0]], top[np.argsort(verifier[i, top], kind="stable")],
                                o[k + 1:]])
        out[i, order] = np.arange(len(order)) - 1.0
    return out


def ranks(d: np.ndarray) -> np.ndarray:
    dd = np.where(np.isfinite(d), d, np.inf).copy()
    np.fill_diagonal(dd, np.inf)
    return np.argsort(np.argsort(dd, axis=1, kind="stable"), axis=1).astype(float)


def shape_context(polys: list, n_points: int) -> np.ndarray:
    m = get_matcher("shape-context", scale_invariant=True, n_points=n_points)
    ds = [m.describe(p) for p in polys]
    st = m.stack(ds)
    return np.stack([np.asarray(m.distances(q, st), float) for q in ds])


def prof_elong(stripes: list, polys: list) -> np.ndarray:
    """``prof+elong`` distances: the profile with the footprint's elongation."""
    el = np.array([[elongation(p.vertices)] for p in polys])
    return profile_plus(stripes, el)


#: Methods of every variant (module docstring; "fuse" = the fusion step).
P_SC = ("profile", "shape-context", "fuse")
PARTS: dict[str, tuple[str, ...]] = {
    "fused-sc": ("profile", *SC_VERIFIERS, "fuse"),
    "fuse(pel,fft,ring)": ("prof+elong", "fft", "ring", "fuse"),
    "fuse(p,sc)": P_SC, "fuse(pel,sc)": ("prof+elong", "shape-context", "fuse"),
    "fuse(p,sc,fft)": ("profile", "shape-context", "fft", "fuse"),
    "fuse(p,sc,fft,ring)": ("profile", "shape-context", "fft", "ring", "fuse"),
    "fuse(p,2sc)": P_SC, "fuse(2p,sc)": P_SC, "fuse(p,mrm)": ("profile", "mrm", "fuse"),
    "sc50": ("shape-context-50",), "fuse(p,sc50)": ("profile", "shape-context-50", "fuse"),
    "fuse(p,sc40)": ("profile", "sc40", "fuse"), "fuse(p,sc60)": ("profile", "sc60", "fuse"),
    "fused-relief": ("profile", "relief", *SC_VERIFIERS, "fuse"),
    "fuse(p,relief)": ("profile", "relief", "fuse"),
    "fuse(relief,sc50)": ("relief", "shape-context-50", "fuse"),
    "fuse(p,relief,mrm)": ("profile", "relief", "mrm", "fuse"),
    "fused-stripes": ("profile", "relief", "surface", "canonical", "fuse"),
    "fused": ("profile", "relief", "surface", *SC_VERIFIERS, "fuse"),
    "fuse(p,fft,ring)": ("profile", "fft", "ring", "fuse"),
    "fused+aspect": ("profile", "relief", "surface", *SC_VERIFIERS, "aspect", "fuse"),
    "p>sc top2": P_SC, "p>sc top3": P_SC, "p>sc top5": P_SC, "rank(p+sc)": P_SC,
}


def method_seconds(scans: list, polys: list) -> dict[str, float]:
    """Wall seconds of representation + matching of `scans` per method (and "fuse")."""
    out = {"stripes": stripes_distances(scans)[1]}
    p, out["profile"] = profile_distances(scans)
    out["relief"] = relief_distances(scans, ScannerConfig())[1]
    out["surface"] = surface_distances(scans, ScannerConfig())[1]
    out["canonical"] = canonical_distances(scans, ScannerConfig())[1]
    out["stripes n=32"] = stripes_distances(scans, DescriptorConfig(stripe_count=32))[1]
    t0 = time.perf_counter()
    scalar_distances(np.array([aspect(s, ScannerConfig()) for s in scans]))
    out["aspect"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    prof_elong([s.stripes for s in scans], polys)
    out["prof+elong"] = time.perf_counter() - t0
    for name in dict.fromkeys((*BASELINES, *SC_VERIFIERS, "shape-context-50")):
        d, out[name], _ = baseline_distances(name, polys)
    for n in (40, 60):
        t0 = time.perf_counter()
        shape_context(polys, n)
        out[f"sc{n}"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    fuse([p, d])
    out["fuse"] = time.perf_counter() - t0
    return out


def variant_seconds(name: str, seconds: dict[str, float]) -> float:
    """A variant's seconds: the sum of its methods' (`PARTS`; else the method itself)."""
    return sum(seconds[m] for m in PARTS.get(name, (name,)))


def variants(r, scanner: ScannerConfig) -> dict[str, np.ndarray]:
    m = {n: x.distances for n, x in r.methods().items()}
    polys = [silhouette_polygon(s, scanner, 1.0) for s in r.scanned.scans]
    p, sc = m["profile"], m["shape-context"]
    v = dict(m)
    v["prof+elong"] = pel = prof_elong([s.stripes for s in r.scanned.scans], polys)
    v["fuse(pel,fft,ring)"] = fuse([pel, m["fft"], m["ring"]])
    v["fuse(p,sc)"] = fuse([p, sc])
    v["fuse(pel,sc)"] = fuse([pel, sc])
    v["fuse(p,sc,fft)"] = fuse([p, sc, m["fft"]])
    v["fuse(p,sc,fft,ring)"] = fuse([p, sc, m["fft"], m["ring"]])
    v["fuse(p,2sc)"] = fuse([p, sc], [1, 2])
    v["fuse(2p,sc)"] = fuse([p, sc], [2, 1])
    v["fuse(p,mrm)"] = fuse([p, m["mrm"]])
    v["sc50"] = sc50 = baseline_distances("shape-context-50", polys)[0]
    v["fuse(p,sc50)"] = fuse([p, sc50])
    for n in (40, 60):
        v[f"sc{n}"] = scn = shape_context(polys, n)
        v[f"fuse(p,sc{n})"] = fuse([p, scn])
    for k in (2, 3, 5):
        v[f"p>sc top{k}"] = rerank(p, sc, k)
    v["rank(p+sc)"] = ranks(p) + ranks(sc)
    rel = m["relief"]
    v["fuse(p,relief)"] = fuse([p, rel])
    v["fuse(relief,sc50)"] = fuse([rel, sc50])
    v["fuse(p,relief,mrm)"] = fuse([p, rel, m["mrm"]])
    v["fuse(p,fft,ring)"] = fuse([p, m["fft"], m["ring"]])
    asp = scalar_distances(np.array([aspect(s, scanner) for s in r.scanned.scans]))
    v["fused+aspect"] = fuse([p, rel, m["surface"], sc50, asp])
    v["stripes n=32"] = stripes_distances(r.scanned.scans, DescriptorConfig(stripe_count=32))[0]
    return v


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--meshes", type=Path, default=DEFAULT_MESHES)
    ap.add_argument("--seeds", default="0,1")
    args = ap.parse_args(argv)
    if not args.meshes.is_dir():
        print(f"skipped: no mesh folder {args.meshes}")
        return
    res: dict[str, dict[str, float]] = {}
    cols = []
    timing: tuple[list, list] = ([], [])  # scans and silhouettes of the timing set
    for name, labels in (("ycb", None), ("other", OTHER_LABELS)):
        objs = mesh_folder_objects(args.meshes, labels)
        for seed in (int(s) for s in args.seeds.split(",")):
            for pose in ("same", "diff"):
                sc = (ScannerConfig() if pose == "same"
                      else replace(ScannerConfig(), yaw_range_deg=180.0))
                r = run_stripes_benchmark(objs, StripesBenchmarkConfig(
                    seed=seed, scans_per_object=1 if pose == "same" else 2, scanner=sc,
                    baselines=BASELINES))
                lab = np.array(r.scanned.labels)
                timing[0].extend(r.scanned.scans)
                timing[1].extend(silhouette_polygon(s, sc, 1.0) for s in r.scanned.scans)
                col = f"{name}{seed}{pose[0]}"
                cols.append(col)
                for n, d in variants(r, sc).items():
                    res.setdefault(n, {})[col] = (
                        same_pose(d, lab, np.ones(len(lab), bool)) if pose == "same"
                        else different_pose(d, lab, r.scanned.objects, None))
    k = min(TIMING_OBJECTS, len(timing[0]))
    secs = method_seconds(timing[0][:k], timing[1][:k])
    scale = (TIMING_OBJECTS / k) ** 2  # all pairs: quadratic (only when fewer scans)
    ref = variant_seconds("fuse(p,sc)", secs)
    print(f"time: representation + matching of {k} scans"
          + ("" if k == TIMING_OBJECTS else f", scaled by (100/{k})^2"))
    print(f"{'variant':22s}" + " ".join(f"{c:>8s}" for c in cols)
          + "     min    mean   s/100       x")
    for n, row in res.items():
        vals = [row[c] for c in cols]
        t = variant_seconds(n, secs)
        print(f"{n:22s}" + " ".join(f"{x:8.3f}" for x in vals)
              + f"  {min(vals):6.3f}  {np.mean(vals):6.3f}  {t * scale:6.2f}  {ref / t:6.1f}")


if __name__ == "__main__":
    main()
