"""What sets the final stage's precision of ``bench loops``: records of every check.

Run from the repository root::

    python benchmarks/final_precision.py record LOG [--relations FILE] [--max-queries N]
        --out FILE.pkl [--set KEY=VALUE ...]
    python benchmarks/final_precision.py report FILE.pkl [FILE.pkl ...] [--top N]

``record`` maps the log as ``loopclosure bench loops LOG --reference-from-log
--odometry-noise 0 --stages fused`` maps it (``--relations``: the relations-fitted
reference), runs every query (`evaluation.loop_bench_queries.query_all`, the final
row exactly as the benchmark's) and keeps, per query, the benchmark's final record and
every candidate the geometric check judged (`verify_places`' list, in order): its
place, verdict, reason, fused score, the check's figures, and its distance and
heading from the reference (the fit's pose against the reference's relative pose).

``report`` prints per log: the final row's R@100P / R@99P / AP (as the benchmark);
the accepted wrong detections with their rank in the final order (how many correct
ones score below them), the reference's distance of the two places, the fit's error,
and the check's evidence; the class of each (a wrong place more than 1 m / 5 deg
away, a tolerance case within them, a relations-reference case); and the revisits
with no correct detection by cause (no candidate at the place, every candidate
refused, an accepted fit beyond the tolerance, a wrong place accepted instead).
"""

from __future__ import annotations

import argparse
import dataclasses
import pickle
import re
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from refused_places import ModelSides  # noqa: E402

from data import se2  # noqa: E402
from evaluation.loop_bench import _query_plan, mapped_input  # noqa: E402
from evaluation.loop_bench_input import LoopSource  # noqa: E402
from evaluation.loop_bench_queries import CHECK_FIGURES, query_all  # noqa: E402
from evaluation.loop_bench_truth import (  # noqa: E402
    average_precision,
    pose_correct,
    pr_curve,
    recall_at_precision,
)
from loopclosure.registration import (  # noqa: E402
    RegistrationTarget,
    register,
    voxel_downsample,
)
from slam.config import PipelineConfig  # noqa: E402
from slam.config_io import apply_overrides  # noqa: E402

FIGS = ("fitness", "inlier_ratio", "rms", "degeneracy", "margin", "consistency",
        "conflict_ratio", "matched_length", "axis_length", "axis_hold", "pinned_length")


def fit_error(ref: np.ndarray, q: int, m: int, rel: np.ndarray) -> tuple[float, float]:
    """The fit's error against the reference: metres, degrees."""
    if not (np.isfinite(ref[[q, m]]).all() and np.isfinite(rel).all()):
        return float("nan"), float("nan")
    off = se2.between(se2.between(ref[m], ref[q]), rel)
    return float(np.hypot(off[0], off[1])), float(abs(np.degrees(off[2])))


def record(args: argparse.Namespace) -> None:
    cfg = PipelineConfig()
    if args.set:
        cfg = apply_overrides(cfg, args.set)
    if args.relations:
        source = LoopSource(args.log, relations=args.relations, folder=str(Path.cwd()))
    else:
        source = LoopSource(args.log, reference_from_log=True, odometry_noise=0,
                            folder=str(Path.cwd()))
    t0 = time.time()
    mapper, result, ref = mapped_input(source, cfg)
    print(f"mapped {len(ref)} keyframes in {time.time() - t0:.0f} s", flush=True)
    det = mapper.detector
    checks: dict[int, list] = {}
    original = det.verify_places

    check = cfg.loops.check
    icp = dataclasses.replace(check.icp, max_correspondence_distance=check.search.icp_gate,
                              max_iterations=60)
    targets: dict[int, RegistrationTarget] = {}

    def own_scans(key: int, c, query_points) -> dict:
        """Each keyframe's own scan refitted from the accepted pose onto the other's
        submap: how far (m, deg) and how well (fitness, degeneracy) it moves."""
        m, rel = int(c.match), np.asarray(c.relative, float)
        if m not in targets:
            targets[m] = RegistrationTarget(det._submap_points(m), check.icp)
        qt = RegistrationTarget(np.asarray(query_points, float), check.icp)
        out = {}
        for tag, src, tgt, start, inv in (
                ("q", mapper._keyframe(key).points, targets[m], rel, False),
                ("m", mapper._keyframe(m).points, qt, se2.inverse(rel), True)):
            r = register(voxel_downsample(np.asarray(src, float), check.source_voxel), tgt,
                         start, config=icp)
            pose = se2.inverse(r.pose) if inv else np.asarray(r.pose, float)
            dd = se2.between(rel, pose)
            out[tag] = dict(ok=bool(r.ok), pose=pose, dm=float(np.hypot(*dd[:2])),
                            ddeg=float(np.degrees(dd[2])), fitness=float(r.fitness),
                            degeneracy=float(r.degeneracy))
        return out

    sides = ModelSides(mapper, cfg) if args.models else None

    def models(key: int, c, qpts) -> dict:
        """Every free-space model at the check's fit and at the reference's pose
        (`refused_places`), for a check that reached the consistency test."""
        if sides is None or c.verification is None or not np.isfinite(
                c.verification.consistency) or not np.isfinite(ref[[key, c.match]]).all():
            return {}
        q = sides.query(key, qpts)
        p = sides.candidate(int(c.match))
        return dict(fit=sides.figures(q, p, np.asarray(c.relative, float)),
                    ref=sides.figures(q, p, se2.between(ref[int(c.match)], ref[key])))

    def recorded(key, *a, **kw):
        out = original(key, *a, **kw)
        qpts = a[2] if len(a) > 2 else kw.get("query_points")
        checks[key] = [dict(models=models(key, c, qpts),
                            own=own_scans(key, c, qpts) if c.accepted and args.own else {},
                            match=int(c.match), accepted=bool(c.accepted), reason=str(c.reason),
                            relative=np.asarray(c.relative, float), score=float(c.fused_score),
                            covariance=np.asarray(c.covariance, float),
                            axis=np.asarray(c.verification.degenerate_axis, float)
                            if c.verification is not None else np.zeros(2),
                            figs={f: float(getattr(c.verification, f)) for f in FIGS}
                            if c.verification is not None else {})
                       for c in out]
        return out

    det.verify_places = recorded
    covered = np.isfinite(ref).all(axis=1)
    poses = np.array([result.keyframe_poses[kf.id] for kf in result.keyframes], float)
    t0 = time.process_time()
    raw = query_all(mapper, ref, covered, poses, ["fused"],
                    _query_plan(len(ref), args.max_queries), 10**9, 2.0, lambda *_: None)
    print(f"queried {len(raw.keys)} in {time.process_time() - t0:.0f} s CPU", flush=True)
    sigmas = None
    out = dict(log=Path(args.log).name, ref=ref, poses=poses, keys=np.asarray(raw.keys),
               revisit=np.asarray(raw.revisit), nearest=np.asarray(raw.nearest, float),
               candidate_hit=np.asarray(raw.candidate_hit), accepted=np.asarray(raw.accepted),
               final_match=np.asarray(raw.final_match), final_score=np.asarray(raw.final_score),
               relative=np.asarray(raw.relative, float), reason=list(raw.reason),
               figures=np.asarray(raw.figures, float), check_figures=CHECK_FIGURES,
               accepted_places=np.asarray(raw.accepted_places), checks=checks,
               sigmas=sigmas, relations=bool(args.relations))
    with open(args.out, "wb") as f:
        pickle.dump(out, f)


def refcheck(args: argparse.Namespace) -> None:
    """The record's final row judged as ``bench loops`` judges it, with the reference's
    sigmas of every accepted detection (a relations reference: its own; a trajectory
    reference: its disagreement with its own scans, `evaluation.loop_bench_scan_truth`)
    and the wrong detections within them set aside (*unverifiable*); and each wrong
    detection's keyframes' disagreement (`scan_disagreement`) by the reference's poses
    and by the front end's."""
    from evaluation.loop_bench import _input_of, _mapping
    from evaluation.loop_bench_scan_truth import scan_disagreement
    from evaluation.loop_bench_truth import within_reference_uncertainty

    d = pickle.load(open(args.file, "rb"))
    j = judged(d)
    source = (LoopSource(args.log, relations=args.relations, folder=str(Path.cwd()))
              if args.relations else
              LoopSource(args.log, reference_from_log=True, odometry_noise=0,
                         folder=str(Path.cwd())))
    inp, _ = _input_of(source)
    _, result, _ = _mapping(source, inp, PipelineConfig(), lambda *_: None)
    ref = np.asarray(inp.reference(result), float)
    assert np.allclose(ref, d["ref"], equal_nan=True), "not the record's mapping"
    acc, ok = j["acc"], j["ok"]
    idx = np.flatnonzero(acc)
    pairs = np.column_stack([d["final_match"][idx], d["keys"][idx]])
    sig = np.full((len(acc), 3), np.nan)
    t0 = time.process_time()
    sig[idx] = inp.reference.sigmas(result, pairs)
    sig_cpu = time.process_time() - t0
    unver = acc & ~ok & within_reference_uncertainty(j["err"], j["place"], sig)
    d["sigmas"], d["unverifiable"] = sig, unver
    front = np.array([k.odom_pose for k in result.keyframes], float)
    points = [k.points for k in result.keyframes]
    wrong = np.flatnonzero(acc & ~ok)
    keys = sorted({int(k) for i in wrong for k in (d["keys"][i], d["final_match"][i])})
    d["turn"] = {k: tuple(np.degrees(scan_disagreement(points, p, k)[1]) for p in (ref, front))
                 for k in keys}
    with open(args.file, "wb") as f:
        pickle.dump(d, f)
    score = np.where(acc, d["final_score"], -np.inf)
    keep = ~unver
    print(f"{d['log']}: R@100P / R@99P / AP {fmt(figures_of(score, ok, j['revisits']))}; "
          f"unverifiable {int(unver.sum())} of {len(wrong)} wrong; without them "
          f"{fmt(figures_of(score[keep], ok[keep], j['revisits']))}; reference sigmas of "
          f"{len(idx)} detections {sig_cpu:.1f} s CPU")
    for i in wrong[np.argsort(-score[wrong])]:
        q, m = int(d["keys"][i]), int(d["final_match"][i])
        print(f"  {q} -> {m} score {score[i]:.3f} error {j['err'][i, 0]:.3f} m "
              f"{j['err'][i, 1]:.2f} deg place {j['place'][i]:.2f} m; reference sigma "
              f"{np.hypot(*sig[i, :2]):.3f} m {np.degrees(sig[i, 2]):.2f} deg; unverifiable "
              f"{bool(unver[i])}; scan disagreement q ref/front {d['turn'][q][0]:.2f}/"
              f"{d['turn'][q][1]:.2f} deg, m {d['turn'][m][0]:.2f}/{d['turn'][m][1]:.2f}")
    fine = np.flatnonzero(ok)
    s = sig[fine]
    print(f"  correct detections' reference sigma: median {np.nanmedian(np.hypot(*s[:, :2].T)):.3f}"
          f" m {np.degrees(np.nanmedian(s[:, 2])):.2f} deg, 90th pct "
          f"{np.nanpercentile(np.hypot(*s[:, :2].T), 90):.3f} m "
          f"{np.degrees(np.nanpercentile(s[:, 2], 90)):.2f} deg")


def fmt(t: tuple) -> str:
    return " / ".join(f"{v:.3f}" for v in t)


def judged(d: dict) -> dict:
    """The final row as the benchmark judges it, and each detection's fit error."""
    ref, q, m = d["ref"], d["keys"], d["final_match"]
    acc = d["accepted"] & (m >= 0)
    ok = np.zeros(len(q), bool)
    ok[acc] = pose_correct(ref[q[acc]], ref[m[acc]], d["relative"][acc])
    err = np.array([fit_error(ref, qi, mi, r) if a else (np.nan, np.nan)
                    for qi, mi, r, a in zip(q, m, d["relative"], acc, strict=True)])
    place = np.array([float(np.hypot(*(ref[qi, :2] - ref[mi, :2]))) if a else np.nan
                      for qi, mi, a in zip(q, m, acc, strict=True)])
    return dict(acc=acc, ok=ok, err=err.reshape(-1, 2), place=place,
                revisits=int(np.sum(d["revisit"])))


def figures_of(score: np.ndarray, ok: np.ndarray, revisits: int) -> tuple[float, float, float]:
    curve = pr_curve(score, ok, revisits)
    return (recall_at_precision(curve, 1.0), recall_at_precision(curve, 0.99),
            average_precision(curve))


def classify(place: float, err: tuple[float, float]) -> str:
    if place > 2.0 and err[0] <= 0.2 and err[1] <= 2.0:
        return "fit right, places just over 2 m apart"
    if place > 2.0:
        return "wrong place (>2 m)"
    if err[0] > 1.0 or err[1] > 5.0:
        return "right place, wrong fit"
    return "tolerance (<=1 m, 5 deg)"


def report(args: argparse.Namespace) -> None:
    for path in args.files:
        d = pickle.load(open(path, "rb"))
        j = judged(d)
        acc, ok = j["acc"], j["ok"]
        score = np.where(acc, d["final_score"], -np.inf)
        r100, r99, ap = figures_of(score, ok, j["revisits"])
        print(f"\n## {d['log']} ({Path(path).name}): queries {len(d['keys'])} revisits "
              f"{j['revisits']} accepted {int(acc.sum())} correct {int(ok.sum())}; "
              f"R@100P {r100:.3f} R@99P {r99:.3f} AP {ap:.3f}")
        wrong = np.flatnonzero(acc & ~ok)
        fig = list(d["check_figures"])
        print("wrong accepted (correct below = correct detections scored lower):")
        print("  query match score correct_below place_m fit_err_m fit_err_deg "
              "consistency fitness matched_len margin degeneracy class")
        for i in wrong[np.argsort(-score[wrong])]:
            below = int(np.sum(ok & (score < score[i])))
            f = d["figures"][i]
            print(f"  {d['keys'][i]:5d} {d['final_match'][i]:5d} {score[i]:.3f} "
                  f"{below:4d}/{int(ok.sum())} {j['place'][i]:6.2f} {j['err'][i, 0]:.3f} "
                  f"{j['err'][i, 1]:.2f} {f[fig.index('consistency')]:.3f} "
                  f"{f[fig.index('fitness')]:.3f} {f[fig.index('matched_length')]:.1f} "
                  f"{f[fig.index('margin')]:.3f} {f[fig.index('degeneracy')]:.3f} "
                  f"{classify(j['place'][i], j['err'][i])}"
                  + ("" if "turn" not in d else " | ref/front turn q {:.2f}/{:.2f} m {:.2f}/{:.2f}"
                     .format(*d["turn"][int(d["keys"][i])], *d["turn"][int(d["final_match"][i])])))
        causes: dict[str, int] = {}
        rev = np.asarray(d["revisit"], bool)
        for i in np.flatnonzero(rev & ~ok):
            if acc[i]:
                c = "accepted: " + classify(j["place"][i], j["err"][i])
            elif not d["candidate_hit"][i]:
                c = "no candidate at the place (prefilter/fused)"
            else:
                ref, q = d["ref"], int(d["keys"][i])
                at = [x for x in d["checks"].get(q, [])
                      if np.hypot(*(ref[q, :2] - ref[x["match"], :2])) <= 2.0]
                c = ("true place checked, refused: "
                     + re.sub(r"[0-9.]+", "N", at[0]["reason"].split("(")[0].strip())
                     if at else "true place among the candidates, not checked")
            causes[c] = causes.get(c, 0) + 1
        print("revisits with no correct detection:")
        for c, n in sorted(causes.items(), key=lambda t: -t[1]):
            print(f"  {n:4d}  {c}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("log")
    r.add_argument("--relations")
    r.add_argument("--max-queries", type=int)
    r.add_argument("--out", required=True)
    r.add_argument("--set", action="append", default=[])
    r.add_argument("--models", action="store_true",
                   help="every free-space model at each check's fit and the reference's "
                        "pose (refused_places)")
    r.add_argument("--own", action="store_true",
                   help="also refit each keyframe's own scan from every accepted pose")
    p = sub.add_parser("report")
    p.add_argument("files", nargs="+")
    c = sub.add_parser("refcheck")
    c.add_argument("log")
    c.add_argument("file")
    c.add_argument("--relations")
    args = ap.parse_args()
    {"record": record, "report": report, "refcheck": refcheck}[args.cmd](args)


if __name__ == "__main__":
    main()
