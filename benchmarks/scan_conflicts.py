"""Where a fit's conflicts lie under the free space about each scan's own origin.

Run from the repository root, after `scan_origins_bench.py LOG --npz PREFIX`::

    python benchmarks/scan_conflicts.py LOG --npz PREFIX [--default keyframe-0.92]
        [--option scans-0.88] [--pairs Q:M,...] [--csv OUT.csv] [--surface-cap C]

The log is mapped as `scan_origins_bench.py` maps it.  The pairs examined: the
queries whose final detection the default pass accepted and got right and the option
pass did not, at the default's relative pose, and the option's wrong accepted
detections at the option's pose (or `--pairs`, at the pose of the pass that found the
pair).  For each, the consistency
(`loopclosure.free_space` (2)) with the free space about the keyframe (1) and about
each scan (1'); and every conflict of (1') described by the scan that saw through the
point: its range from that scan, the length of that scan's ray there (the sector's
free range), the angle between the ray and the surface the point lies on (its own
submap's points within 0.3 m, principal direction: 0 = the ray runs along the
surface, grazing), and the point's distance to the other submap (a near miss below
0.3 m).  With ``--surface-cap C`` the conflicts are those of (1'') (the margin across
each scan's surface, `ScanFreeSpace.surface_cap`).  Prints one line per pair and the
pooled shares.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


from scan_origins_bench import loop_source  # noqa: E402

from benchmarks.rows_csv import write_rows  # noqa: E402
from data import se2  # noqa: E402
from evaluation.loop_bench import mapped_input  # noqa: E402
from loopclosure.free_space import ScanFreeSpace, Submap, consistency  # noqa: E402
from loopclosure.registration import voxel_downsample  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402


def surface_angle(points: np.ndarray, tree: cKDTree, at: np.ndarray, ray: np.ndarray
                  ) -> np.ndarray:
    """``(M,)`` angle [deg] between each ray direction and the principal direction of
    the points within 0.3 m of `at` (90: the ray meets the surface square on)."""
    out = np.full(len(at), np.nan)
    for i, nb in enumerate(tree.query_ball_point(at, 0.3)):  # diagnostic: a few hundred
        if len(nb) < 3:
            continue
        p = points[nb] - points[nb].mean(axis=0)
        _, v = np.linalg.eigh(p.T @ p)
        d = v[:, 1]
        r = ray[i] / (np.linalg.norm(ray[i]) + 1e-12)
        out[i] = np.degrees(np.arccos(min(1.0, abs(float(d @ r)))))
    return out


def conflicts_of(moved: np.ndarray, own_pts: np.ndarray, other: Submap,
                 scans: ScanFreeSpace, margin: float, tol: float) -> list[dict]:
    """Each conflict of `moved` (the other submap's frame) under (1'), described."""
    d, _ = other.tree.query(moved, k=1)
    cand = np.flatnonzero((d > tol) & scans.free(moved, margin))
    rows = []
    if len(cand) == 0:
        return rows
    own_tree = cKDTree(own_pts)
    for i in cand:
        p = moved[i]
        best = None
        for k, pose in enumerate(scans.poses):  # the scans that saw through it
            local = se2.transform_points(se2.inverse(pose), p[None])[0]
            rho = float(np.hypot(*local))
            sec = int((np.arctan2(local[1], local[0]) + np.pi) * scans.bins / (2 * np.pi))
            ray = float(scans.ranges[k, sec % scans.bins])
            if rho < ray - margin and (best is None or ray - rho > best[2] - best[1]):
                best = (k, rho, ray, p - pose[:2])
        k, rho, ray, direction = best
        rows.append(dict(point=i, scan=k, range=rho, ray=ray, beyond=ray - rho,
                         other_distance=float(d[i]), ray_dir=direction))
    angles = surface_angle(own_pts, own_tree, moved[[r["point"] for r in rows]],
                           np.array([r["ray_dir"] for r in rows]))
    for r, a in zip(rows, angles, strict=True):
        r["surface_angle"] = float(a)
        del r["ray_dir"]
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log")
    ap.add_argument("--relations")
    ap.add_argument("--npz", required=True)
    ap.add_argument("--default", default="keyframe-0.92")
    ap.add_argument("--option", default="scans-0.88")
    ap.add_argument("--pairs")
    ap.add_argument("--csv")
    ap.add_argument("--surface-cap", type=float, default=1.0,
                    help="(1'') across each scan's surface with this cap instead of (1')")
    ap.add_argument("--return-window", type=int, default=0,
                    help="(4) beside each scan's returns in this many sectors")
    args = ap.parse_args()
    cfg = PipelineConfig()
    cfg.loops.check.free_space_origins = "scans"
    source = loop_source(args.log, args.relations)
    mapper, _, ref = mapped_input(source, cfg)
    det = mapper.detector
    s = det.config.check.search
    tol, margin, bins = s.consistency_tolerance, s.free_margin, s.free_bins
    a = np.load(f"{args.npz}-{args.default}.npz")
    b = np.load(f"{args.npz}-{args.option}.npz")
    todo = []
    if args.pairs:
        for item in args.pairs.split(","):
            q, m = map(int, item.split(":"))
            i = int(np.flatnonzero(a["keys"] == q)[0])  # the pose of the pass that found m
            rel = b["relative"][i] if b["match"][i] == m and a["match"][i] != m else \
                a["relative"][i]
            todo.append(("given", q, m, rel))
    else:
        lost = a["correct"] & ~(b["correct"] & (b["match"] == a["match"]))
        for i in np.flatnonzero(lost):
            todo.append(("lost-true", int(a["keys"][i]), int(a["match"][i]), a["relative"][i]))
        wrong = b["accepted"] & ~b["correct"] & ~(a["accepted"] & (a["match"] == b["match"]))
        for i in np.flatnonzero(wrong):
            todo.append(("new-wrong", int(b["keys"][i]), int(b["match"][i]), b["relative"][i]))
    from loopclosure.fast_icp import voxel_downsample_fast

    rows = []
    for kind, q, m, rel in todo:
        q_pts = voxel_downsample_fast(np.asarray(mapper.query_submaps[q], float), 0.1)
        c_pts = voxel_downsample(np.asarray(det._plain_points(m), float), s.submap_voxel)
        q_scans, c_scans = det.submap_free_space(q, last=q), det.submap_free_space(m)
        q_scans, c_scans = (ScanFreeSpace(f.poses, f.ranges, args.surface_cap,
                                          args.return_window)
                            for f in (q_scans, c_scans))
        one = consistency(Submap.of(q_pts, bins), Submap.of(c_pts, bins), rel, tol, margin)
        qs, cs = Submap.of(q_pts, bins, scans=q_scans), Submap.of(c_pts, bins, scans=c_scans)
        per = consistency(qs, cs, rel, tol, margin)
        confl = ([dict(r, way="q_in_c") for r in conflicts_of(
                     se2.transform_points(rel, q_pts), q_pts, cs, c_scans, margin, tol)]
                 + [dict(r, way="c_in_q") for r in conflicts_of(
                     se2.transform_points(se2.inverse(rel), c_pts), c_pts, qs, q_scans,
                     margin, tol)])
        # the moved point's own surface: the angle is computed on its own submap's
        # points, in the frame it was moved to (rotation keeps angles)
        err = se2.between(ref[m], ref[q]) if np.isfinite(ref[[q, m]]).all() else np.full(3, np.nan)
        off = se2.between(err, rel)
        ang = np.array([r["surface_angle"] for r in confl]) if confl else np.zeros(0)
        near = np.array([r["other_distance"] < 0.3 for r in confl], bool)
        far_ray = np.array([r["range"] > 8.0 for r in confl], bool)
        print(f"{kind} {q}->{m}: off {np.hypot(*off[:2]):.3f} m {np.degrees(off[2]):.2f} deg; "
              f"consistency (1) {one.consistency:.3f} ({one.hits} hits {one.conflicts} conf), "
              f"(1') {per.consistency:.3f} ({per.conflicts} conf: "
              f"{sum(r['way'] == 'c_in_q' for r in confl)} c_in_q; near miss {int(near.sum())}; "
              f"grazing <20deg {int(np.sum(ang < 20))}; range>8m {int(far_ray.sum())}; "
              f"median range {np.median([r['range'] for r in confl]) if confl else 0:.1f} m, "
              f"scans {len(set((r['way'], r['scan']) for r in confl))})", flush=True)
        for r in confl:
            rows.append(dict(kind=kind, query=q, match=m, **r))
    if rows:
        ang = np.array([r["surface_angle"] for r in rows])
        for kind in ("lost-true", "new-wrong", "given"):
            sel = [r for r in rows if r["kind"] == kind]
            if not sel:
                continue
            a_ = np.array([r["surface_angle"] for r in sel])
            print(f"{kind}: {len(sel)} conflicts; near miss (<0.3 m) "
                  f"{np.mean([r['other_distance'] < 0.3 for r in sel]):.2f}; grazing (<20 deg) "
                  f"{np.nanmean(a_ < 20):.2f}; range > 8 m "
                  f"{np.mean([r['range'] > 8 for r in sel]):.2f}; beyond the margin by < 0.5 m "
                  f"{np.mean([r['beyond'] - margin < 0.5 for r in sel]):.2f}")
        del ang
    if args.csv:
        write_rows(args.csv, rows)


if __name__ == "__main__":
    main()
