"""Benchmark: which feature carries the class signal on real meshes; trimming; lambda; images.

Run from the repository root::

    python benchmarks/stripes_features.py [--meshes DIR] [--seeds 0,1] [--figure PNG]

Scans (same pose: one scan per object, yaw within +-15 degrees, as
``benchmarks/stripes_real.py``) the YCB multi-instance classes and the second labelled
set (``benchmarks/stripes_ycb_other_labels.csv``) at every seed and prints, per set
and seed, the share of queries whose nearest other object is of the query's class for:

- the paper's descriptor (Eq. 1-3) compared by one feature alone (``l``, ``d``, ``o``:
  that feature's Bhattacharyya distance after Eq. 4's trimming) and by Eq. 5 with the
  paper's lambda (0.6, 0.3, 0.1) and with equal weights;
- Eq. 5 without the trimming: every object described by 32 stripes evenly spaced in
  scan order (`DescriptorConfig.stripe_count`), so objects swept by different stripe
  counts are compared whole;
- the lambda search of Section V (`search_weights`, gradient hill climbing with
  simulated annealing) trained on the *other* set of the same seed and applied here,
  and trained on a stratified half of this set and scored on the other half
  (``lambda half``, the queries of the test half against the test half), with the
  weights it found;
- the stripe profile (`loopclosure.stripes.profile`) by one feature alone (``l``,
  ``d``, ``e``: mean absolute difference) and whole; the relief
  (`loopclosure.stripes.relief`).

It also prints the stripe images against the paper's (Section VI.C: 600 x 712 pixel
images, 140 stripes per object on average): image size, stripes per object (mean,
min, max), stripe width in pixels, the share of columns missing inside a stripe's
span (detector gaps, occlusion), and the share of laser positions that cut the
object but gave no stripe.  With ``--figure PNG`` it draws, for the first object of
every class of both sets (first seed), every 4th stripe in image coordinates stacked
along the sweep (the paper's Fig. 4(c) / Fig. 6 second row) and the heights the
relief reads (`StripeScan.height_map`, millimetres, top view).

Nothing is written but the figure; the meshes are read in place.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from benchmarks.stripes_real import DEFAULT_MESHES, same_pose  # noqa: E402
from data.stripe_scanner import ScannerConfig  # noqa: E402
from evaluation.stripes_benchmark import relief_distances  # noqa: E402
from evaluation.stripes_objects import mesh_folder_objects, scan_objects  # noqa: E402
from loopclosure.stripes import (  # noqa: E402
    DescriptorConfig,
    ProfileDatabase,
    StripeDatabase,
    describe_many,
    describe_profiles,
    search_weights,
    stratified_split,
)
from loopclosure.stripes.matching import LAMBDA_PAPER, combine  # noqa: E402

OTHER_LABELS = ROOT / "benchmarks" / "stripes_ycb_other_labels.csv"
SETS = (("ycb", None), ("other", OTHER_LABELS))


def image_stats(scans: list) -> str:
    """One line: image size, stripes per object, stripe width, gaps, empty positions."""
    n = np.array([len(s.stripes) for s in scans])
    widths = np.concatenate([[len(x) for x in s.stripes] for s in scans])
    span = np.concatenate([[np.ptp(x[:, 0]) + 1 for x in s.stripes] for s in scans])
    empty = sum(s.empty_positions for s in scans) / max(sum(s.n_frames for s in scans), 1)
    rows, cols = scans[0].image_shape
    return (f"image {rows} x {cols} px; stripes per object mean {n.mean():.0f} "
            f"(min {n.min()}, max {n.max()}); stripe width median {np.median(widths):.0f} px; "
            f"columns missing inside a stripe {1 - widths.sum() / span.sum():.3f}; "
            f"positions without stripe {empty:.3f}")


def stripe_figures(scans: list, labels: np.ndarray, other: tuple[np.ndarray, np.ndarray],
                   seed: int) -> dict[str, float]:
    """Figures of the paper's descriptor (module docstring); `other` = the other set's
    (per-feature distances, labels) for the cross-set lambda."""
    everyone = np.ones(len(labels), bool)
    fd = StripeDatabase(describe_many([s.stripes for s in scans])).pairwise_features()
    out = {f: same_pose(fd[..., t], labels, everyone) for t, f in enumerate("ldo")}
    out["Eq.5 paper lambda"] = same_pose(combine(fd, LAMBDA_PAPER), labels, everyone)
    out["Eq.5 equal lambda"] = same_pose(combine(fd, (1, 1, 1)), labels, everyone)
    fd32 = StripeDatabase(describe_many([s.stripes for s in scans],
                                        DescriptorConfig(stripe_count=32))).pairwise_features()
    out["Eq.5, 32 stripes, no trim"] = same_pose(combine(fd32, LAMBDA_PAPER), labels, everyone)
    ofd, olab = other
    w = search_weights(ofd, olab, np.arange(len(olab)), seed=seed).weights
    out[f"lambda other set ({w[0]:.2f} {w[1]:.2f} {w[2]:.2f})"] = same_pose(
        combine(fd, w), labels, everyone)
    train, test = stratified_split(labels, 0.5, seed)
    w = search_weights(fd, labels, train, seed=seed).weights
    sub = combine(fd, w)[np.ix_(test, test)]
    out[f"lambda half ({w[0]:.2f} {w[1]:.2f} {w[2]:.2f})"] = same_pose(
        sub, labels[test], np.ones(len(test), bool))
    out["Eq.5 paper lambda, same half"] = same_pose(
        combine(fd, LAMBDA_PAPER)[np.ix_(test, test)], labels[test], np.ones(len(test), bool))
    return out


def profile_figures(scans: list, labels: np.ndarray, scanner: ScannerConfig) -> dict[str, float]:
    """Figures of the stripe profile per feature and whole, and of the relief."""
    everyone = np.ones(len(labels), bool)
    db = ProfileDatabase(describe_profiles([s.stripes for s in scans]))
    fw, rv = zip(*(db.feature_distances(p) for p in db.profiles), strict=True)
    both = np.minimum(np.stack(fw), np.stack(rv))
    out = {f"profile {f}": same_pose(both[..., t], labels, everyone)
           for t, f in enumerate("lde")}
    out["profile"] = same_pose(db.pairwise(), labels, everyone)
    out["relief"] = same_pose(relief_distances(scans, scanner)[0], labels, everyone)
    return out


def draw(scans: list, labels: list[str], scanner: ScannerConfig, path: Path) -> None:
    """The figure of ``--figure`` (module docstring): two panels per scan."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = 4
    rows = -(-len(scans) // cols)
    fig, axes = plt.subplots(rows, 2 * cols, figsize=(4 * cols, 2.2 * rows), squeeze=False)
    for ax in axes.flat:
        ax.set_axis_off()
    for k, (scan, lab) in enumerate(zip(scans, labels, strict=True)):
        a, b = axes[k // cols, 2 * (k % cols)], axes[k // cols, 2 * (k % cols) + 1]
        for i, st in enumerate(scan.stripes[::4]):
            a.plot(st[:, 0], -st[:, 1] - 3.0 * i, ",k")
        a.set_title(f"{lab}: {scan.name[:18]}\n{len(scan.stripes)} stripes", fontsize=6)
        z, (row_m, col_m) = scan.height_map(scanner)
        seen = np.flatnonzero(np.isfinite(z).any(axis=0))
        b.imshow(1000 * z[:, seen.min():seen.max() + 1], aspect=row_m / col_m,
                 interpolation="nearest")
        b.set_title(f"heights, top {1000 * np.nanmax(z):.0f} mm", fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"figure: {path}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--meshes", type=Path, default=DEFAULT_MESHES)
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--figure", type=Path, default=None, help="write the figure here (PNG)")
    args = ap.parse_args(argv)
    if not args.meshes.is_dir():
        print(f"skipped: no mesh folder {args.meshes}")
        return
    scanner = ScannerConfig()
    objs = {name: mesh_folder_objects(args.meshes, lab) for name, lab in SETS}
    for seed in (int(s) for s in args.seeds.split(",")):
        scanned = {n: scan_objects(o, scanner, seed) for n, o in objs.items()}
        labels = {n: np.array(s.labels) for n, s in scanned.items()}
        if args.figure is not None:
            first: dict[str, object] = {}  # class -> its first scan, both sets
            for sc in scanned.values():
                for scan, lab in zip(sc.scans, sc.labels, strict=True):
                    first.setdefault(lab, scan)
            draw(list(first.values()), list(first), scanner, args.figure)
            args.figure = None
        fds = {n: StripeDatabase(describe_many([x.stripes for x in s.scans])).pairwise_features()
               for n, s in scanned.items()}
        for name, _ in SETS:
            other = next(n for n, _ in SETS if n != name)
            scans = scanned[name].scans
            print(f"\n{name}, seed {seed}: {len(scans)} objects; {image_stats(scans)}")
            figs = stripe_figures(scans, labels[name], (fds[other], labels[other]), seed)
            figs.update(profile_figures(scans, labels[name], scanner))
            for k, v in figs.items():
                print(f"  {k:40s} {v:6.3f}")


if __name__ == "__main__":
    main()
