"""Who is wrong in a tolerance case of ``bench loops``: the geometric check or the reference?

Run from the repository root, after ``loopclosure bench loops LOG ... --out DIR``::

    python benchmarks/tolerance_cases.py LOG --queries DIR/queries.csv \
        [--relations FILE] [--correct N] [--keys Q,Q,...]

The log is mapped as the benchmark maps it (`evaluation.loop_bench.mapped_input`).
For every accepted final detection the benchmark judged wrong (and `--correct` correct
ones, the best-scored, for comparison; or the queries `--keys`), the two keyframes
are registered again carefully, at full resolution, by point-to-line ICP
(`loopclosure.registration.register`, a tight gate and many iterations):

* ``submap``: the query's submap (as the benchmark's check saw it, not voxelised
  again) onto the match's submap;
* ``scan``: the query keyframe's own scan onto the match keyframe's own scan (no
  drift inside a submap can bend them);

each from two starts, the reference's relative pose and the check's.  Per start it
prints where ICP ends (the difference to the reference and to the check, metres and
degrees), the fitness, inlier ratio and RMS; and, at each of the two poses held
fixed, the share of the query's points within 5 cm of the other's surface and their
median point-to-line distance (``at-pose``).  Then the heading profile: the truncated
point-to-line cost (mean of ``min(d, 0.1 m)^2``) with the heading held at offsets
from the check's heading and the translation re-fitted (`fixed_heading_fit`), the
heading whose cost is least, on both submaps and scans.  A reference pose the data
supports lands near the reference; a check whose pose is imprecise moves towards it.

Whether the submaps themselves are bent: ``drift_*`` (the largest disagreement, over
a submap's keyframes, between the front end's and the reference's pose of each
keyframe relative to the submap's own), ``refsubmap`` (the two submaps rebuilt from
the reference's keyframe poses, same span, crop and voxel, then registered as
above), ``consistency_*`` (`self_consistency`: how far ICP moves each keyframe's
scan onto the others' as the front end's, or the reference's, poses place them: the
poses that hold the scans together move them least), ``short{j}_*`` (the query's
last j keyframes onto the match's j either side, or onto its whole submap: less
path for a bend to build up in) and ``scan_to_submap`` / ``submap_to_scan`` (one
keyframe's own scan onto the other's submap).
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.rows_csv import write_rows  # noqa: E402
from data import se2  # noqa: E402
from evaluation.loop_bench import mapped_input  # noqa: E402
from evaluation.loop_bench_input import LoopSource  # noqa: E402
from loopclosure.geometric_check import verify  # noqa: E402
from loopclosure.registration import IcpConfig, RegistrationTarget, register  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402

FINE = IcpConfig(max_correspondence_distance=0.3, max_iterations=200,
                 translation_tolerance=1e-6, rotation_tolerance=1e-7)


def line_distances(source: np.ndarray, target: RegistrationTarget, pose: np.ndarray,
                   gate: float = 0.5) -> np.ndarray:
    """Point-to-line distance [m] of each source point (at `pose`, target frame) to its
    nearest usable target point's line; inf beyond `gate`."""
    pts = se2.transform_points(pose, source)
    usable = np.flatnonzero(target.usable)
    from scipy.spatial import cKDTree

    tree = cKDTree(target.points[usable])
    d, i = tree.query(pts, distance_upper_bound=gate)
    out = np.full(len(pts), np.inf)
    ok = np.isfinite(d)
    j = usable[i[ok]]
    out[ok] = np.abs(np.sum((pts[ok] - target.points[j]) * target.normals[j], axis=1))
    return out


def fixed_heading_fit(source: np.ndarray, target: RegistrationTarget, pose: np.ndarray,
                      cap: float = 0.1, iterations: int = 30) -> tuple[np.ndarray, float]:
    """The translation that minimises the point-to-line cost with the heading held at
    ``pose[2]`` (Gauss-Newton, correspondences within `cap` re-found each step); the
    refined pose and its truncated cost, mean over source points of
    ``min(d, cap)^2 / cap^2`` in [0, 1]."""
    from scipy.spatial import cKDTree

    usable = np.flatnonzero(target.usable)
    tree = cKDTree(target.points[usable])
    x = np.asarray(pose, float).copy()
    for _ in range(iterations):
        pts = se2.transform_points(x, source)
        d, i = tree.query(pts, distance_upper_bound=cap)
        ok = np.isfinite(d)
        if ok.sum() < 10:
            break
        j = usable[i[ok]]
        n = target.normals[j]
        r = np.sum((pts[ok] - target.points[j]) * n, axis=1)
        h = n.T @ n
        step = -np.linalg.solve(h + 1e-9 * np.eye(2), n.T @ r)
        x[:2] += step
        if np.hypot(*step) < 1e-6:
            break
    d = line_distances(source, target, x, gate=cap)
    cost = float(np.mean(np.minimum(d, cap) ** 2) / cap**2)
    return x, cost


def describe(tag: str, source: np.ndarray, target_pts: np.ndarray, ref_rel: np.ndarray,
             check_rel: np.ndarray) -> dict:
    """ICP from the reference and from the check, at-pose figures, heading profile."""
    target = RegistrationTarget(target_pts, FINE)
    row: dict = {}
    for start_name, start in (("ref", ref_rel), ("check", check_rel)):
        d = line_distances(source, target, start)
        row[f"{tag}_atpose_{start_name}_within5cm"] = float(np.mean(d <= 0.05))
        row[f"{tag}_atpose_{start_name}_median_cm"] = float(100 * np.median(d[np.isfinite(d)]))
        r = register(source, target, start, config=FINE)
        to_ref = se2.between(ref_rel, r.pose)
        to_chk = se2.between(check_rel, r.pose)
        row[f"{tag}_icp_from_{start_name}"] = (
            f"dref {np.hypot(*to_ref[:2]):.3f} m {np.degrees(to_ref[2]):+.2f} deg | "
            f"dcheck {np.hypot(*to_chk[:2]):.3f} m {np.degrees(to_chk[2]):+.2f} deg | "
            f"fit {r.fitness:.3f} inl {r.inlier_ratio:.3f} rms {100 * r.rms:.2f} cm "
            f"it {r.iterations}")
    offsets = np.arange(-4.0, 4.01, 0.25)
    base = se2.between(check_rel, ref_rel)
    costs = []
    for o in offsets:
        p = np.asarray(check_rel, float).copy()
        p[2] += np.radians(o)
        costs.append(fixed_heading_fit(source, target, p)[1])
    costs = np.array(costs)
    row[f"{tag}_profile_best_deg_from_check"] = float(offsets[np.argmin(costs)])
    row[f"{tag}_profile_ref_deg_from_check"] = float(np.degrees(base[2]))
    row[f"{tag}_profile"] = " ".join(f"{o:+.2f}:{c:.4f}" for o, c in zip(offsets, costs,
                                                                           strict=True))
    return row


def local_points(mapper, poses: np.ndarray, key: int, first: int, last: int) -> np.ndarray:
    """Keyframes ``first .. last`` in `key`'s frame by the given keyframe `poses`
    ``(n, 3)``, cropped and voxelised as the mapper's submaps
    (`slam.pipeline.Mapper._local_points`, which uses the front end's poses)."""
    from loopclosure.fast_icp import voxel_downsample_fast

    kfs = mapper.keyframes.keyframes
    parts = [se2.transform_points(se2.between(poses[key], poses[i]), kfs[i].points)
             for i in range(first, last + 1) if np.isfinite(poses[i]).all()]
    pts = np.vstack(parts)
    pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= mapper.config.submap.max_range]
    return voxel_downsample_fast(pts, mapper.config.submap.voxel)


def drift(front: np.ndarray, ref: np.ndarray, key: int, first: int, last: int) -> str:
    """Largest heading [deg] / position [m] disagreement, over the submap's keyframes,
    between the front end's and the reference's pose of each keyframe relative to
    `key`: how far the front end's submap is bent against the reference's."""
    worst_deg, worst_m = 0.0, 0.0
    for i in range(first, last + 1):
        if not np.isfinite(ref[i]).all():
            continue
        e = se2.between(se2.between(front[key], front[i]), se2.between(ref[key], ref[i]))
        worst_deg = max(worst_deg, abs(float(np.degrees(e[2]))))
        worst_m = max(worst_m, float(np.hypot(e[0], e[1])))
    return f"{worst_m:.3f} m {worst_deg:.2f} deg"


def self_consistency(mapper, poses: np.ndarray, first: int, last: int) -> str:
    """How well each keyframe's scan of ``first .. last`` fits the others' as placed by
    `poses`: ICP of each scan onto the union of the other scans (in the first's
    frame), started at its given pose; the median of how far ICP moves it (metres,
    degrees) and the median RMS [cm].  Poses that hold the scans consistently move
    little."""
    kfs = mapper.keyframes.keyframes
    ids = [i for i in range(first, last + 1) if np.isfinite(poses[i]).all()]
    placed = {i: se2.between(poses[first], poses[i]) for i in ids}
    moves_m, moves_deg, rms = [], [], []
    for i in ids:
        others = np.vstack([se2.transform_points(placed[j], kfs[j].points)
                            for j in ids if j != i])
        target = RegistrationTarget(others, FINE)
        r = register(np.asarray(kfs[i].points, float), target, placed[i], config=FINE)
        d = se2.between(placed[i], r.pose)
        moves_m.append(float(np.hypot(d[0], d[1])))
        moves_deg.append(abs(float(np.degrees(d[2]))))
        rms.append(100 * r.rms)
    worst = int(np.argmax(moves_deg))
    return (f"moves {np.median(moves_m):.3f} m {np.median(moves_deg):.2f} deg "
            f"(max {moves_deg[worst]:.2f} deg at keyframe {ids[worst]}; the last, "
            f"{ids[-1]}: {moves_deg[-1]:.2f} deg), rms {np.median(rms):.2f} cm")


def keyframe_consistency(mapper, poses: np.ndarray, half: int = 5) -> np.ndarray:
    """For every keyframe i, how far [deg] ICP turns its scan onto the scans of
    keyframes ``i - half .. i + half`` (itself left out) as `poses` place them, started
    at its pose in `poses` (NaN: no pose); `self_consistency` over the whole log."""
    kfs = mapper.keyframes.keyframes
    out = np.full(len(kfs), np.nan)
    for i in range(len(kfs)):
        if not np.isfinite(poses[i]).all():
            continue
        ids = [j for j in range(max(0, i - half), min(len(kfs), i + half + 1))
               if j != i and np.isfinite(poses[j]).all()]
        if len(ids) < 2:
            continue
        others = np.vstack([se2.transform_points(se2.between(poses[i], poses[j]),
                                                 kfs[j].points) for j in ids])
        r = register(np.asarray(kfs[i].points, float), RegistrationTarget(others, FINE),
                     np.zeros(3), config=FINE)
        if r.ok:
            out[i] = abs(float(np.degrees(r.pose[2])))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log")
    ap.add_argument("--queries", type=Path, required=True, help="queries.csv of bench loops")
    ap.add_argument("--relations")
    ap.add_argument("--correct", type=int, default=5, help="correct detections to compare")
    ap.add_argument("--keys", help="only these query keys (comma-separated)")
    ap.add_argument("--csv", type=Path, help="write the rows here")
    ap.add_argument("--keyframe-consistency", action="store_true",
                    help="also every keyframe's scan against its neighbours', by the front "
                         "end's and by the reference's poses (`keyframe_consistency`)")
    args = ap.parse_args()
    rows = list(csv.DictReader(open(args.queries)))
    source = LoopSource(args.log, relations=args.relations,
                        reference_from_log=args.relations is None,
                        odometry_noise=None if args.relations else 0, folder=str(Path.cwd()))
    mapper, result, ref = mapped_input(source, PipelineConfig())
    det = mapper.detector
    if args.keyframe_consistency:
        front = np.array([k.odom_pose for k in mapper.keyframes.keyframes], float)
        for name, poses in (("front end", front), ("reference", ref)):
            turn = keyframe_consistency(mapper, poses)
            t = turn[np.isfinite(turn)]
            print(f"keyframe scan vs its neighbours' by the {name}'s poses: ICP turns it "
                  f"median {np.median(t):.3f} deg, 90th pct {np.percentile(t, 90):.3f}, "
                  f"> 1 deg {np.mean(t > 1):.3f}, > 2 deg {np.mean(t > 2):.3f} "
                  f"({len(t)} keyframes)", flush=True)
    acc = [r for r in rows if r["final_match"] != ""]
    if args.keys:
        keys = {int(k) for k in args.keys.split(",")}
        chosen = [r for r in acc if int(r["keyframe"]) in keys]
    else:
        wrong = [r for r in acc if r["final_correct"] != "1"]
        right = sorted((r for r in acc if r["final_correct"] == "1"),
                       key=lambda r: -float(r["final_score"]))[: args.correct]
        chosen = wrong + right
    out = []
    for r in chosen:
        q, m = int(r["keyframe"]), int(r["final_match"])
        ref_rel = se2.between(ref[m], ref[q])
        qs = np.asarray(mapper.query_submaps[q], float)
        ms = det._submap_points(m)
        # The check again, from the reference's heading (queries.csv keeps its error,
        # not its pose): the same search and ICP, so the same pose when its error
        # matches the benchmark's.
        v = verify(qs, det._target(m), headings=[float(ref_rel[2])],
                   translation=ref_rel[:2], max_distance=det.config.max_distance,
                   config=det.config.check)
        check_rel = np.asarray(v.relative, float)
        diff = se2.between(ref_rel, check_rel)
        row = dict(query=q, match=m, correct=r["final_correct"], score=r["final_score"],
                   check_minus_ref=f"{np.hypot(*diff[:2]):.3f} m {np.degrees(diff[2]):+.2f} deg")
        row["bench_error"] = f"{float(r['error_m']):.3f} m {float(r['error_deg']):.2f} deg"
        row["recheck"] = (f"{v.reason}; fit {v.fitness:.3f} cons {v.consistency:.3f} "
                          f"rms {100 * v.rms:.2f} cm")
        row.update(describe("submap", qs, ms, ref_rel, check_rel))
        n = mapper.config.submap_neighbours()
        last = len(result.keyframes) - 1
        front = np.array([k.odom_pose for k in mapper.keyframes.keyframes], float)
        row["drift_query_submap"] = drift(front, ref, q, max(0, q - n), q)
        row["drift_match_submap"] = drift(front, ref, m, max(0, m - n), min(last, m + n))
        for tag, lo, hi in (("query", max(0, q - n), q),
                            ("match", max(0, m - n), min(last, m + n))):
            row[f"consistency_{tag}_front"] = self_consistency(mapper, front, lo, hi)
            row[f"consistency_{tag}_ref"] = self_consistency(mapper, ref, lo, hi)
        row.update(describe("refsubmap", local_points(mapper, ref, q, max(0, q - n), q),
                            local_points(mapper, ref, m, max(0, m - n), min(last, m + n)),
                            ref_rel, check_rel))
        qk, mk = result.keyframes[q], result.keyframes[m]
        for j in (1, 2, 3, 5):
            short_q = local_points(mapper, front, q, max(0, q - j), q)
            short_m = local_points(mapper, front, m, max(0, m - j), min(last, m + j))
            for tag, src, tgt in ((f"short{j}_to_short{j}", short_q, short_m),
                                  (f"short{j}_to_submap", short_q, ms)):
                rr = register(src, RegistrationTarget(tgt, FINE), check_rel, config=FINE)
                to_ref = se2.between(ref_rel, rr.pose)
                row[tag] = (f"dref {np.hypot(*to_ref[:2]):.3f} m "
                            f"{np.degrees(to_ref[2]):+.2f} deg | fit {rr.fitness:.3f} "
                            f"rms {100 * rr.rms:.2f} cm it {rr.iterations}")
        for tag, src, tgt, inv in (("scan_to_submap", qk.points, ms, False),
                                   ("submap_to_scan", mk.points, qs, True)):
            tgt_t = RegistrationTarget(np.asarray(tgt, float), FINE)
            start = se2.inverse(check_rel) if inv else check_rel
            rr = register(np.asarray(src, float), tgt_t, start, config=FINE)
            pose = se2.inverse(rr.pose) if inv else rr.pose
            to_ref, to_chk = se2.between(ref_rel, pose), se2.between(check_rel, pose)
            row[tag] = (f"dref {np.hypot(*to_ref[:2]):.3f} m {np.degrees(to_ref[2]):+.2f} deg"
                        f" | dcheck {np.hypot(*to_chk[:2]):.3f} m "
                        f"{np.degrees(to_chk[2]):+.2f} deg | fit {rr.fitness:.3f} "
                        f"rms {100 * rr.rms:.2f} cm it {rr.iterations}")
        row.update(describe("scan", np.asarray(qk.points, float), np.asarray(mk.points, float),
                            ref_rel, check_rel))
        out.append(row)
        print(f"\nquery {q} -> {m} ({'correct' if row['correct'] == '1' else 'WRONG'},"
              f" score {float(row['score']):.3f}): check - ref {row['check_minus_ref']}")
        for k, v in row.items():
            if k.endswith("_profile") or k in ("query", "match", "correct", "score",
                                               "check_minus_ref"):
                continue
            print(f"  {k}: {v}")
        sys.stdout.flush()
    if args.csv:
        write_rows(args.csv, out)


if __name__ == "__main__":
    main()
