"""The checks with no pose prior, phase by phase: where their time goes, and where the
rejected ones could be stopped.

Two steps::

    python benchmarks/prior_free_phases.py collect LOG [LOG ...] --out CHECKS.pkl
    python benchmarks/prior_free_phases.py phases CHECKS.pkl

``collect`` maps each log as ``loopclosure run`` does (the default pipeline in one
process, the front end in it; a corrected log with the drifting odometry of seed 0)
and records every correlative check (`loopclosure.geometric_check._verify_correlative`):
the query submap, the candidate's submap, the heading hypotheses, ``max_distance``,
and the verdict (reason, fitness, consistency, relative pose).  The file stays
outside the repository (data is never copied in).

``phases`` replays each check in this process on a registration target made as the
keyframe store makes it (one per distinct candidate submap, its caches kept as the
store keeps them) and times (``time.process_time``) the phases of
`loopclosure.prior_free.match_prior_free`: the likelihood grids and the candidate's
free-space submap (once per target), the coarse and fine lattices, the ICP runs, the
free-space tests at the runs' poses and the axis profile; it prints per log and per
verdict the CPU seconds of each phase, checks that the replay reproduces every
recorded verdict, and, for each check, the free-space consistency at the lattice
peaks (before ICP) against the one at the ICP poses: the margin a test before ICP
would have below the bar for the accepted checks.
"""

from __future__ import annotations

import argparse
import pickle
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.exact_stage_speed import load_revision  # noqa: E402


def collect(logs: list[Path], out: Path) -> None:
    import loopclosure.geometric_check as gc
    from evaluation.slam_input import load_input
    from loopclosure.warm_up import warm_up
    from slam.config import PipelineConfig
    from slam.pipeline import Mapper

    warm_up()
    real = gc._verify_correlative
    records: list[dict] = []
    targets: dict[int, int] = {}  # id(target) -> index into `points`
    points: list[np.ndarray] = []
    current = [""]

    def recording(query_points, candidate, headings, max_distance, cfg):
        start = time.process_time()
        v = real(query_points, candidate, headings, max_distance, cfg)
        cpu = time.process_time() - start
        tid = targets.get(id(candidate))
        if tid is None or points[tid].shape != candidate.points.shape or not np.array_equal(
                points[tid], candidate.points):
            tid = targets[id(candidate)] = len(points)
            points.append(np.array(candidate.points, dtype=float))
        records.append({
            "log": current[0], "query": np.array(query_points, dtype=float), "target": tid,
            "headings": None if headings is None else np.array(headings, dtype=float),
            "max_distance": max_distance, "accepted": bool(v.accepted), "reason": v.reason,
            "fitness": float(v.fitness), "consistency": float(v.consistency),
            "relative": np.array(v.relative, dtype=float), "cpu": cpu,
        })
        return v

    gc._verify_correlative = recording
    try:
        for log in logs:
            name = current[0] = log.name.split(".")[0]
            data = load_input(log, odometry_noise=0 if "corrected" in log.name else None)
            start = time.process_time()
            result = Mapper(PipelineConfig(front_end_worker=False)).run(data.scans)
            run_cpu = time.process_time() - start
            mine = [r for r in records if r["log"] == name]
            print(f"{name}: {len(mine)} correlative checks, "
                  f"{sum(r['accepted'] for r in mine)} accepted, "
                  f"{sum(r['cpu'] for r in mine):.2f} s of {run_cpu:.1f} s CPU; timings_s "
                  f"{ {k: round(v, 2) for k, v in getattr(result, 'timings', {}).items()} }",
                  flush=True)
    finally:
        gc._verify_correlative = real
    with open(out, "wb") as fh:
        pickle.dump({"records": records, "points": points}, fh)


def _kind(reason: str) -> str:
    return reason.split(" (")[0].split(" 0")[0][:32]


def phases(path: Path) -> None:
    import dataclasses

    from loopclosure import correlative, prior_free
    from loopclosure.fast_icp import estimate_normals_fast, register_target
    from loopclosure.free_space import Submap, consistency
    from loopclosure.geometric_check import GeometricCheckConfig, _verify_correlative
    from loopclosure.registration import RegistrationTarget, voxel_downsample
    from loopclosure.warm_up import warm_up

    warm_up()
    with open(path, "rb") as fh:
        blob = pickle.load(fh)
    records, points = blob["records"], blob["points"]
    cfg = GeometricCheckConfig()
    pf = cfg.search
    tgts: dict[int, RegistrationTarget] = {}
    # per log, per verdict kind: phase -> CPU s
    cpu: dict[str, dict[str, defaultdict]] = defaultdict(lambda: defaultdict(
        lambda: defaultdict(float)))
    count: dict[str, defaultdict] = defaultdict(lambda: defaultdict(int))
    mismatch = 0
    rows = []
    for r in records:
        tid = r["target"]
        t0 = time.process_time()
        first = tid not in tgts
        if first:
            tgts[tid] = RegistrationTarget(points[tid], cfg.icp, normals=estimate_normals_fast)
        tgt = tgts[tid]
        t_target = time.process_time() - t0
        # the verdict, replayed, on a copy of the target's caches (the timing run
        # below builds its own)
        t0 = time.process_time()
        v = _verify_correlative(r["query"], tgt, r["headings"], r["max_distance"], cfg)
        t_whole = time.process_time() - t0
        same = (v.reason == r["reason"] and v.fitness == r["fitness"]
                and np.array_equal(v.relative, r["relative"]))
        mismatch += not same
        kind = "accepted" if v.accepted else _kind(v.reason)
        log = r["log"]
        count[log][kind] += 1
        c = cpu[log][kind]
        c["target"] += t_target
        c["whole"] += t_whole
        # phases, on a fresh target (its grids and free submap counted once)
        fresh = RegistrationTarget(points[tid], cfg.icp, normals=estimate_normals_fast)
        q = np.asarray(r["query"], dtype=float)
        h = r["headings"]
        if h is None or len(np.atleast_1d(h)) == 0:
            angles = correlative.search_angles([0.0], np.pi, np.radians(pf.coarse_angle_step_deg))
        else:
            h = np.atleast_1d(np.asarray(h, dtype=float))
            h = np.concatenate([h, h + np.pi])
            angles = correlative.search_angles(h, np.radians(pf.angle_window_deg),
                                               np.radians(pf.coarse_angle_step_deg))
        radius = pf.radius if r["max_distance"] is None else r["max_distance"] + pf.radius_margin
        if first:
            t0 = time.process_time()
            correlative.LikelihoodGrid.widths(fresh.points, pf.grid_resolution,
                                              (pf.coarse_sigma, pf.grid_sigma))
            c["grids(once/target)"] += time.process_time() - t0
        t0 = time.process_time()
        starts, scores = prior_free._two_level(q, tgt, angles, radius, pf)
        c["lattices"] += time.process_time() - t0
        keep = (scores > 0) & (scores >= pf.refine_ratio * scores[:1].max(initial=0.0))
        starts, scores = starts[keep], scores[keep]
        if len(starts) == 0:
            rows.append((log, kind, np.nan, np.nan, np.nan, 0, np.nan, np.nan))
            continue
        t0 = time.process_time()
        source = voxel_downsample(q, cfg.source_voxel)
        icp = dataclasses.replace(cfg.icp, max_correspondence_distance=pf.icp_gate,
                                  max_iterations=pf.icp_iterations)
        results = register_target(source, tgt, starts, config=icp)
        c["icp"] += time.process_time() - t0
        if first:
            t0 = time.process_time()
            Submap.of(voxel_downsample(fresh.points, pf.submap_voxel), pf.free_bins)
            c["cand free submap(once/target)"] += time.process_time() - t0
        cand = prior_free._cached(
            tgt, ("free", pf.submap_voxel, pf.free_bins),
            lambda t=tgt: Submap.of(voxel_downsample(t.points, pf.submap_voxel), pf.free_bins))
        t0 = time.process_time()
        qs = Submap.of(source, pf.free_bins)
        c["query free submap"] += time.process_time() - t0
        t0 = time.process_time()
        at_icp = [consistency(qs, cand, res.pose, pf.consistency_tolerance, pf.free_margin)
                  for res in results]
        c["free space at ICP poses"] += time.process_time() - t0
        t0 = time.process_time()
        at_peak = [consistency(qs, cand, s, pf.consistency_tolerance, pf.free_margin)
                   for s in starts]
        c["(free space at peaks)"] += time.process_time() - t0
        order = sorted(range(len(results)), key=lambda i: prior_free._rank(results[i]))
        b = order[0]
        moved = float(np.hypot(*(results[b].pose[:2] - starts[b][:2])))
        rows.append((log, kind, at_peak[b].consistency, at_icp[b].consistency,
                     max(p.consistency for p in at_peak), len(starts), moved,
                     scores[0]))
    print(f"replayed {len(records)} checks, {mismatch} verdicts differ from the run's")
    for log in cpu:
        total: defaultdict = defaultdict(float)
        for c in cpu[log].values():
            for k, v in c.items():
                total[k] += v
        print(f"\n{log}: {sum(count[log].values())} checks; all: "
              + ", ".join(f"{k} {v:.3f}" for k, v in total.items()))
        for kind, c in sorted(cpu[log].items(), key=lambda kv: -kv[1]["whole"]):
            parts = ", ".join(f"{k} {v:.3f}" for k, v in c.items() if k not in ("whole",))
            print(f"  {kind} x{count[log][kind]}: whole {c['whole']:.3f} s; {parts}")
    print("\nconsistency of the best run: at its lattice peak / after ICP "
          "(accepted; rejected for free space)")
    for log in cpu:
        acc = [r for r in rows if r[0] == log and r[1] == "accepted"]
        inc = [r for r in rows if r[0] == log and r[1].startswith("inconsistent")]
        for name, sel in (("accepted", acc), ("inconsistent", inc)):
            if not sel:
                continue
            a = np.array([r[2] for r in sel])
            b = np.array([r[3] for r in sel])
            mx = np.array([r[4] for r in sel])
            mv = np.array([r[6] for r in sel])
            print(f"  {log} {name} x{len(sel)}: at peak min {a.min():.3f} med "
                  f"{np.median(a):.3f} max {a.max():.3f}; best peak min {mx.min():.3f}; "
                  f"after ICP min {b.min():.3f} med {np.median(b):.3f} max {b.max():.3f}; "
                  f"ICP moved med {np.median(mv):.3f} max {mv.max():.3f} m")
    with open(path.with_suffix(".rows.pkl"), "wb") as fh:
        pickle.dump(rows, fh)


def _same(a, b) -> bool:
    """Every field of two `LoopVerification`s equal (NaN equal to NaN, arrays bytewise)."""
    import dataclasses

    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            if not np.array_equal(np.asarray(x), np.asarray(y), equal_nan=True):
                return False
        elif isinstance(x, float) and isinstance(y, float):
            if not (x == y or (np.isnan(x) and np.isnan(y))):
                return False
        elif x != y:
            return False
    return True


def speed(paths: list[Path], rev: str, repeat: int) -> None:
    """The recorded checks replayed with revision `rev`'s `loopclosure.prior_free` and
    `loopclosure.correlative` and the working tree's, `repeat` alternate passes each,
    in this process."""
    import tempfile

    import loopclosure
    import loopclosure.geometric_check as gc
    from loopclosure.fast_icp import estimate_normals_fast
    from loopclosure.registration import RegistrationTarget
    from loopclosure.warm_up import warm_up

    warm_up()
    records: list[dict] = []
    for path in paths:
        with open(path, "rb") as fh:
            blob = pickle.load(fh)
        for r in blob["records"]:
            r["points"] = blob["points"][r["target"]]
            r["target"] = (str(path), r["target"])
            records.append(r)
    cfg = gc.GeometricCheckConfig()
    now = gc.match_prior_free
    now_corr = loopclosure.correlative
    with tempfile.TemporaryDirectory() as tmp:
        base = load_revision(rev, "loopclosure/prior_free.py", Path(tmp)).match_prior_free
        base_corr = load_revision(rev, "loopclosure/correlative.py", Path(tmp))

    def use(corr) -> None:
        # `loopclosure.prior_free` imports the kernel module from the package when called
        loopclosure.correlative = sys.modules["loopclosure.correlative"] = corr

    targets: dict = {}
    for r in records:  # the targets and their cached grids, shared by both codes
        if r["target"] not in targets:
            targets[r["target"]] = RegistrationTarget(r["points"], cfg.icp,
                                                      normals=estimate_normals_fast)
        gc._verify_correlative(r["query"], targets[r["target"]], r["headings"],
                               r["max_distance"], cfg)
    logs = sorted({r["log"] for r in records})
    best = {(code, log): np.inf for code in ("baseline", "now") for log in logs}
    out: dict[str, list] = {}
    for _ in range(repeat):
        for code, fn, corr in (("baseline", base, base_corr), ("now", now, now_corr)):
            gc.match_prior_free = fn
            use(corr)
            spent: dict[str, float] = dict.fromkeys(logs, 0.0)
            verdicts = []
            try:
                for r in records:
                    start = time.process_time()
                    v = gc._verify_correlative(r["query"], targets[r["target"]],
                                               r["headings"], r["max_distance"], cfg)
                    spent[r["log"]] += time.process_time() - start
                    verdicts.append(v)
            finally:
                gc.match_prior_free = now
                use(now_corr)
            out[code] = verdicts
            for log in logs:
                best[code, log] = min(best[code, log], spent[log])
    same = [_same(a, b) for a, b in zip(out["baseline"], out["now"], strict=True)]
    print(f"{len(records)} checks with no prior replayed, {repeat} alternate passes, "
          f"best pass CPU s (baseline {rev} / now)")
    for log in logs:
        idx = [i for i, r in enumerate(records) if r["log"] == log]
        b, n = best["baseline", log], best["now", log]
        print(f"  {log}: {len(idx)} checks, {b:.3f} / {n:.3f} s, ratio {b / n:.3f}, "
              f"verdicts identical {sum(same[i] for i in idx)}/{len(idx)}")
    b = sum(best["baseline", log] for log in logs)
    n = sum(best["now", log] for log in logs)
    print(f"  all: {b:.3f} / {n:.3f} s, ratio {b / n:.3f}, identical {sum(same)}/{len(same)}")


def split(logs: list[Path]) -> None:
    """Each log mapped as ``collect`` maps it, with `benchmarks/loop_time_split.py`'s
    CPU timers around the stages of a run; prints their totals per log."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import loop_time_split as lts

    from evaluation.slam_input import load_input
    from loopclosure.warm_up import warm_up
    from slam.config import PipelineConfig
    from slam.pipeline import Mapper

    warm_up()
    lts.install()
    for log in logs:
        data = load_input(log, odometry_noise=0 if "corrected" in log.name else None)
        lts.TOTAL.clear()
        lts.CALLS.clear()
        start = time.process_time()
        Mapper(PipelineConfig(front_end_worker=False)).run(data.scans)
        whole = time.process_time() - start
        print(f"\n{log.name.split('.')[0]}: whole run {whole:.2f} s CPU", flush=True)
        for label in sorted(lts.TOTAL, key=lambda k: -lts.TOTAL[k]):
            print(f"  {label:26s} {lts.TOTAL[label]:7.2f} s {100 * lts.TOTAL[label] / whole:5.1f}%"
                  f" {lts.CALLS[label]:7d} calls", flush=True)


def outputs(logs: list[Path], out: Path) -> None:
    """Each log mapped as ``collect`` maps it; writes ``<log>/loops.csv`` (every
    candidate, `slam.outputs.write_loops_csv`) and ``<log>/poses.bin`` (the optimised
    and front-end poses of every scan, float64 bytes) under `out`, for ``cmp`` against
    another code's (run this file from outside the tree with the other code on
    ``PYTHONPATH``)."""
    from evaluation.slam_input import load_input
    from loopclosure.warm_up import warm_up
    from slam.config import PipelineConfig
    from slam.outputs import write_loops_csv
    from slam.pipeline import Mapper
    from slam.results import loop_records

    warm_up()
    for log in logs:
        data = load_input(log, odometry_noise=0 if "corrected" in log.name else None)
        start = time.process_time()
        result = Mapper(PipelineConfig(front_end_worker=False)).run(data.scans)
        cpu = time.process_time() - start
        folder = out / log.name.split(".")[0]
        folder.mkdir(parents=True, exist_ok=True)
        write_loops_csv(folder / "loops.csv", loop_records(result))
        poses = np.concatenate([np.asarray(result.scan_poses, dtype=np.float64).ravel(),
                                np.asarray(result.odometry_poses, dtype=np.float64).ravel()])
        (folder / "poses.bin").write_bytes(poses.tobytes())
        print(f"{folder.name}: {len(result.loops)} candidates, "
              f"{len(result.accepted_loops)} loops, {cpu:.1f} s CPU", flush=True)


def runs(logs: list[Path], rev: str, repeat: int) -> None:
    """Whole runs of each log (as ``collect`` maps it) with revision `rev`'s
    `loopclosure.prior_free` and `loopclosure.correlative` and with the working
    tree's, `repeat` alternate passes each in this process: best CPU s of a run and
    of its checks with no prior, and whether every scan's pose is the same."""
    import tempfile

    import loopclosure
    import loopclosure.geometric_check as gc
    from evaluation.slam_input import load_input
    from loopclosure.warm_up import warm_up
    from slam.config import PipelineConfig
    from slam.pipeline import Mapper

    warm_up()
    now, now_corr = gc.match_prior_free, loopclosure.correlative
    with tempfile.TemporaryDirectory() as tmp:
        base = load_revision(rev, "loopclosure/prior_free.py", Path(tmp)).match_prior_free
        base_corr = load_revision(rev, "loopclosure/correlative.py", Path(tmp))
    spent = [0.0]

    def timed(fn):
        def wrapper(*args, **kwargs):
            start = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[0] += time.process_time() - start
        return wrapper

    print(f"whole runs, {repeat} alternate passes, best CPU s (baseline {rev} / now)")
    for log in logs:
        data = load_input(log, odometry_noise=0 if "corrected" in log.name else None)
        best = {"baseline": (np.inf, np.inf), "now": (np.inf, np.inf)}
        poses = {}
        for _ in range(repeat):
            for code, fn, corr in (("baseline", base, base_corr), ("now", now, now_corr)):
                gc.match_prior_free = timed(fn)
                loopclosure.correlative = sys.modules["loopclosure.correlative"] = corr
                spent[0] = 0.0
                try:
                    start = time.process_time()
                    result = Mapper(PipelineConfig(front_end_worker=False)).run(data.scans)
                    whole = time.process_time() - start
                finally:
                    gc.match_prior_free = now
                    loopclosure.correlative = sys.modules["loopclosure.correlative"] = now_corr
                best[code] = (min(best[code][0], whole), min(best[code][1], spent[0]))
                poses[code] = np.asarray(result.scan_poses, dtype=float)
        (bw, bc), (nw, nc) = best["baseline"], best["now"]
        print(f"  {log.name.split('.')[0]}: run {bw:.2f} / {nw:.2f} s (ratio {bw / nw:.3f}); "
              f"match_prior_free {bc:.2f} / {nc:.2f} s (ratio {bc / nc:.3f}); poses "
              f"identical {np.array_equal(poses['baseline'], poses['now'])}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("collect")
    c.add_argument("logs", nargs="+", type=Path)
    c.add_argument("--out", type=Path, required=True)
    p = sub.add_parser("phases")
    p.add_argument("checks", type=Path)
    t = sub.add_parser("split")
    t.add_argument("logs", nargs="+", type=Path)
    o = sub.add_parser("outputs")
    o.add_argument("logs", nargs="+", type=Path)
    o.add_argument("--out", type=Path, required=True)
    r = sub.add_parser("runs")
    r.add_argument("logs", nargs="+", type=Path)
    r.add_argument("--baseline", default="main")
    r.add_argument("--repeat", type=int, default=2)
    s = sub.add_parser("speed")
    s.add_argument("checks", nargs="+", type=Path)
    s.add_argument("--baseline", default="main")
    s.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    if a.cmd == "collect":
        collect(a.logs, a.out)
    elif a.cmd == "outputs":
        outputs(a.logs, a.out)
    elif a.cmd == "runs":
        runs(a.logs, a.baseline, a.repeat)
    elif a.cmd == "split":
        split(a.logs)
    elif a.cmd == "phases":
        phases(a.checks)
    else:
        speed(a.checks, a.baseline, a.repeat)


if __name__ == "__main__":
    main()
