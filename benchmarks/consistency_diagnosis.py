"""Why true prior-free fits fail the free-space consistency bar: where their conflicts lie.

Run from the repository root::

    python benchmarks/consistency_diagnosis.py LOG [--max-queries N] [--queries FIRST-LAST] \
        [--csv OUT.csv]

The log is mapped as ``loopclosure bench loops LOG --reference-from-log
--odometry-noise 0`` maps it (`evaluation.loop_bench.mapped_input`); every planned
query checks each of its places on its own (`verify_places`, as the global search
checks them).  Every check that reached the consistency test (accepted, or rejected
by it) is judged against the reference: ``true`` when the fit is within 0.2 m and 2
degrees of the reference's relative pose, ``wrong`` when more than 1 m or 5 degrees
off (the tolerance cases between are left out).  For each, at the check's pose, the
conflicts of `loopclosure.free_space` (2) are split by

- the direction (query points in the candidate's free space, or the reverse);
- whether the submap point that *made* the free space (the nearest one in the
  conflicting point's bearing sector, (1)) belongs to the submap keyframe's own
  scan (observed from the sensor origin the model assumes) or to another keyframe's
  scan of the submap (observed from elsewhere);
- the conflicting point's distance to the other submap (a near miss within the free
  margin, or a point far from any surface);

and the consistency is recomputed with the free space of the keyframe's own scan
only (``own``: every ray of the model then starts at the origin it assumes) and with
the union of the free spaces of every scan of the submap, each about its own sensor
origin (``multi``: the rays each scan observed).
Nothing here changes a verdict.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.rows_csv import write_rows  # noqa: E402
from data import se2  # noqa: E402
from evaluation.loop_bench import _query_plan, mapped_input  # noqa: E402
from evaluation.loop_bench_input import LoopSource  # noqa: E402
from loopclosure.free_space import RangeImage, Submap, consistency  # noqa: E402
from loopclosure.registration import voxel_downsample  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402


def labelled(mapper, key: int, first: int, last: int, points: np.ndarray) -> np.ndarray:
    """``(N,)`` the keyframe whose scan put each of `points` (a submap of keyframes
    ``first .. last`` in `key`'s frame) there: the keyframe of its nearest raw point."""
    centre = mapper._keyframe(key).odom_pose
    raw, lab = [], []
    for j in range(first, last + 1):
        kf = mapper._keyframe(j)
        raw.append(se2.transform_points(se2.between(centre, kf.odom_pose), kf.points))
        lab.append(np.full(len(kf.points), j))
    _, idx = cKDTree(np.vstack(raw)).query(points)
    return np.concatenate(lab)[idx]


def maker(image: RangeImage, points: np.ndarray, own: np.ndarray, where: np.ndarray
          ) -> np.ndarray:
    """``(M,)`` whether the free range of the sector of each of `where` was set by a
    point of the own scan (`own` over `points`, the image's points)."""
    sec_p = image._sector(points)
    rng = np.hypot(points[:, 0], points[:, 1])
    best_own = np.full(image.bins, np.inf)
    best_all = np.full(image.bins, np.inf)
    np.minimum.at(best_all, sec_p, rng)
    np.minimum.at(best_own, sec_p[own], rng[own])
    sec = image._sector(where)
    out = np.zeros(len(where), bool)
    for k in range(-2, 3):  # the model's spread of 2 sectors
        s = (sec + k) % image.bins
        out |= np.isfinite(best_own[s]) & (best_own[s] <= image.ranges[sec] + 1e-9)
    return out


def scans_of(mapper, key: int, first: int, last: int, bins: int) -> list:
    """``(pose, RangeImage)`` of every scan of keyframes ``first .. last``: its sensor
    pose in `key`'s frame and the free space it observed about its own origin."""
    centre = mapper._keyframe(key).odom_pose
    return [(se2.between(centre, mapper._keyframe(j).odom_pose),
             RangeImage(mapper._keyframe(j).points, bins)) for j in range(first, last + 1)]


def union_free(scans: list, points: np.ndarray, margin: float) -> np.ndarray:
    """``(N,)`` points (the submap's frame) in the free space of any of `scans`
    (`scans_of`): each scan's rays from its own origin (module docstring, ``multi``)."""
    out = np.zeros(len(points), bool)
    for pose, image in scans:
        out |= image.free(se2.transform_points(se2.inverse(pose), points), margin)
    return out


def decompose(q_pts, q_lab, q_key, c_pts, c_lab, c_key, pose, tol, margin, bins,
              q_scans=None, c_scans=None):
    """Conflict split (module docstring), the consistency with own-scan free space
    (``own``) and, given each submap's scans (`scans_of`), with the union of their
    free spaces (``multi``)."""
    q, c = Submap.of(q_pts, bins), Submap.of(c_pts, bins)
    base = consistency(q, c, pose, tol, margin)
    out = dict(consistency=base.consistency, hits=base.hits, conflicts=base.conflicts)
    own_hits = own_conf = multi_conf = 0
    for name, moved, other, other_lab, other_key, scans in (
            ("q_in_c", se2.transform_points(pose, q_pts), c, c_lab, c_key, c_scans),
            ("c_in_q", se2.transform_points(se2.inverse(pose), c_pts), q, q_lab, q_key,
             q_scans)):
        d, _ = other.tree.query(moved, k=1)
        hit = d <= tol
        conf = ~hit & other.image.free(moved, margin)
        by_own = maker(other.image, other.points, other_lab == other_key, moved)
        out[f"{name}_conf"] = int(conf.sum())
        out[f"{name}_conf_own_made"] = int((conf & by_own).sum())
        out[f"{name}_conf_near"] = int((conf & (d <= margin)).sum())
        for lo, hi in ((tol, 0.15), (0.15, 0.2), (0.2, margin)):
            out[f"{name}_conf_{lo:.2f}_{hi:.2f}"] = int((conf & (d > lo) & (d <= hi)).sum())
        rng = np.hypot(moved[conf, 0], moved[conf, 1])
        out[f"{name}_conf_range_med"] = float(np.median(rng)) if len(rng) else float("nan")
        own_img = RangeImage(other.points[other_lab == other_key], bins)
        oc = ~hit & own_img.free(moved, margin)
        own_hits += int(hit.sum())
        own_conf += int(oc.sum())
        if scans is not None:
            multi_conf += int((~hit & union_free(scans, moved, margin)).sum())
    out["own"] = own_hits / (own_hits + own_conf) if own_hits + own_conf else 0.0
    if q_scans is not None and c_scans is not None:
        out["multi"] = own_hits / (own_hits + multi_conf) if own_hits + multi_conf else 0.0
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log")
    ap.add_argument("--max-queries", type=int)
    ap.add_argument("--csv")
    ap.add_argument("--queries", help="first-last keyframe ids (default: every planned one)")
    args = ap.parse_args()
    cfg = PipelineConfig()
    source = LoopSource(args.log, reference_from_log=True, odometry_noise=0,
                        folder=str(Path.cwd()))
    mapper, result, ref = mapped_input(source, cfg)
    det = mapper.detector
    check = cfg.loops.check
    s = check.search
    nb = cfg.submap_neighbours()
    last_kf = len(mapper.keyframes.keyframes) - 1
    poses = np.array([result.keyframe_poses[kf.id] for kf in result.keyframes], float)
    keys = np.array(sorted(det.database.keys), dtype=np.intp)
    covered = np.isfinite(ref).all(axis=1)
    plan = _query_plan(len(ref), args.max_queries)
    if args.queries:
        first, last = (int(x) for x in args.queries.split("-"))
        plan[:first] = False
        plan[last + 1:] = False
    rows = []
    for k in np.flatnonzero(plan & covered):
        older = keys[keys < k]
        cand = older[det.eligible(k)[older] & covered[older]]
        if len(cand) == 0:
            continue
        pts = mapper.query_submaps.get(int(k))
        for p in det.places(det.query_places(int(k), cand), poses):
            for c in det.verify_places(int(k), [p], poses, pts):
                if not (c.accepted or c.reason.startswith("inconsistent")):
                    continue
                m = int(c.match)
                err = se2.between(se2.between(ref[m], ref[k]), np.asarray(c.relative))
                e_m, e_deg = float(np.hypot(err[0], err[1])), abs(float(np.degrees(err[2])))
                kind = ("true" if e_m <= 0.2 and e_deg <= 2.0 else
                        "wrong" if e_m > 1.0 or e_deg > 5.0 else "")
                if not kind:
                    continue
                q_pts = voxel_downsample(pts, check.source_voxel)
                c_pts = voxel_downsample(mapper.submap(m), s.submap_voxel)
                q_lab = labelled(mapper, int(k), max(0, int(k) - nb), int(k), q_pts)
                c_lab = labelled(mapper, m, max(0, m - nb), min(last_kf, m + nb), c_pts)
                row = dict(query=int(k), match=m, kind=kind, accepted=int(c.accepted),
                           err_m=round(e_m, 3), err_deg=round(e_deg, 2),
                           fitness=round(c.verification.fitness, 3))
                fig = decompose(q_pts, q_lab, int(k), c_pts, c_lab, m, c.relative,
                                s.consistency_tolerance, s.free_margin, s.free_bins,
                                scans_of(mapper, int(k), max(0, int(k) - nb), int(k),
                                         s.free_bins),
                                scans_of(mapper, m, max(0, m - nb), min(last_kf, m + nb),
                                         s.free_bins))
                row.update({a: round(b, 4) if isinstance(b, float) else b
                            for a, b in fig.items()})
                rows.append(row)
                print(row, flush=True)
    if args.csv:
        write_rows(args.csv, rows)


if __name__ == "__main__":
    main()
