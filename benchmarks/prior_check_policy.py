"""The checks from a pose prior, one by one: what each costs, and what a policy would skip.

Two steps::

    python benchmarks/prior_check_policy.py collect LOG [LOG ...] --out CHECKS.json
    python benchmarks/prior_check_policy.py analyse CHECKS.json

``collect`` maps each log as ``loopclosure run`` does (the default pipeline in one
process, the front end in it; a corrected log with the drifting odometry of seed 0,
as ``loopclosure bench slam --odometry-noise 0`` feeds it) and records, in order,
every check `loopclosure.candidate_checks.CandidateChecks._check_prior` makes: the
query and candidate keys, the search that proposed it (``pose`` or
``appearance``), the query's position sigma [m], its verdict and reason, the best
run's fitness, inlier ratio and degeneracy, the ICP runs, and its CPU seconds
(``time.process_time``, the target or grid build included); and every loop the
detector accepted (any search), with the CPU seconds of each ``detect`` and of the
whole run; and, per query that ran them, the checks with no prior
(`CandidateChecks._verify_free`: how many, how many accepted, their verdicts, their
CPU seconds).
Nothing goes into the repository.

``analyse`` prints per log: the checks from a prior per keyframe queried, how many
were accepted, and the CPU seconds of the accepted, of those a pre-ICP screen
stopped, and of those rejected after ICP (by reason); the checks with no prior, how
many were accepted, their CPU seconds (and those of queries where none was) and
their verdicts; then, for each candidate
policy, the checks it would skip, the CPU seconds they cost, and the accepted loops
among them (the loops it would lose, to first order: a skipped check changes
nothing later in this replay).  The policies:

- ``joined W``: a pose candidate ``(key, cand)`` is skipped when a loop accepted
  from a prior at an earlier query joins ``key - W .. key - 1`` to
  ``cand - W .. cand + W``: the two passes are already tied together there;
  ``joined-all W``: the same for every candidate checked from a prior.
- ``rejected W``: skipped when a check of ``key - W .. key - 1`` against
  ``cand - W .. cand + W`` was rejected after ICP, and none there accepted.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SCREENS = ("no overlap", "no fit within reach")


def collect(logs: list[Path], out: Path, inputs: Path | None = None) -> None:
    import pickle

    import loopclosure.candidate_checks as cc
    from evaluation.slam_input import load_input
    from loopclosure.candidate_checks import CandidateChecks
    from loopclosure.loop_detector import LoopClosureDetector
    from loopclosure.warm_up import warm_up
    from slam.config import PipelineConfig
    from slam.pipeline import Mapper

    warm_up()
    result: dict[str, dict] = {}
    real_check, real_detect = CandidateChecks._check_prior, LoopClosureDetector.detect
    checks: list[dict] = []
    loops: list[tuple[int, int, str, bool]] = []
    detect_cpu = [0.0, 0]
    records: list[dict] = []  # the inputs of `verify` per check (``--inputs``)
    real_verify = cc.verify
    current = [""]

    def recording(query_points, candidate, **kw):
        if inputs is not None and kw.get("prior") is not None:
            grid = kw.get("grid")
            target = grid.points if grid is not None else candidate.points
            records.append({
                "log": current[0], "index": len(checks),
                "query": np.asarray(query_points, dtype=np.float32),
                "target": np.asarray(target, dtype=np.float32),
                "prior": np.asarray(kw["prior"], dtype=float),
                "prior_covariance": kw.get("prior_covariance"),
                "offsets": kw.get("offsets"), "max_distance": kw.get("max_distance"),
            })
        return real_verify(query_points, candidate, **kw)

    def check_prior(self, key, cand, match, poses, cov, sigma, query_points):
        start = time.process_time()
        c = real_check(self, key, cand, match, poses, cov, sigma, query_points)
        v = c.verification
        checks.append({
            "key": int(key), "cand": int(cand), "source": c.source, "sigma": float(sigma),
            "accepted": bool(c.accepted), "reason": c.reason,
            "fitness": float(v.fitness), "inlier_ratio": float(v.inlier_ratio),
            "degeneracy": float(v.degeneracy), "hypotheses": int(v.hypotheses),
            "distance": float(c.predicted_distance),
            "cpu": time.process_time() - start,
        })
        return c

    def detect(self, key, *args, **kwargs):
        start = time.process_time()
        out = real_detect(self, key, *args, **kwargs)
        detect_cpu[0] += time.process_time() - start
        detect_cpu[1] += 1
        loops.extend((int(c.query), int(c.match), c.source, bool(c.prior))
                     for c in out if c.accepted)
        return out

    real_free = CandidateChecks._verify_free
    free: list[dict] = []  # per `_verify_free` call: its checks with no prior

    def verify_free(self, key, matches, *args, **kwargs):
        start = time.process_time()
        out = real_free(self, key, matches, *args, **kwargs)
        free.append({"key": int(key), "checks": len(out),
                     "accepted": sum(bool(c.accepted) for c in out),
                     "reasons": [c.reason for c in out],
                     "cpu": time.process_time() - start})
        return out

    CandidateChecks._check_prior = check_prior
    CandidateChecks._verify_free = verify_free
    LoopClosureDetector.detect = detect
    cc.verify = recording
    try:
        for log in logs:
            name = current[0] = log.name.split(".")[0]
            corrected = "corrected" in log.name
            data = load_input(log, odometry_noise=0 if corrected else None)
            checks.clear()
            loops.clear()
            free.clear()
            detect_cpu[:] = [0.0, 0]
            start = time.process_time()
            Mapper(PipelineConfig(front_end_worker=False)).run(data.scans)
            result[name] = {"checks": list(checks), "loops": list(loops), "free": list(free),
                            "detect_cpu": detect_cpu[0], "queries": detect_cpu[1],
                            "run_cpu": time.process_time() - start}
            print(f"{name}: {len(checks)} checks from a prior, {len(loops)} loops, "
                  f"detect {detect_cpu[0]:.1f} s of {result[name]['run_cpu']:.1f} s CPU",
                  flush=True)
    finally:
        CandidateChecks._check_prior = real_check
        CandidateChecks._verify_free = real_free
        LoopClosureDetector.detect = real_detect
        cc.verify = real_verify
    out.write_text(json.dumps(result))
    if inputs is not None:
        with open(inputs, "wb") as fh:
            pickle.dump(records, fh)


def _kind(reason: str) -> str:
    if reason == "accepted":
        return "accepted"
    if reason.startswith(SCREENS):
        return "screened"
    return "icp-rejected"


def _joined(checks: list[dict], w: int, sources: tuple[str, ...]) -> np.ndarray:
    """Per check: a candidate of `sources` whose two passes an earlier loop joins."""
    skip = np.zeros(len(checks), dtype=bool)
    accepted: list[tuple[int, int]] = []
    for i, c in enumerate(checks):
        if c["source"] in sources:
            skip[i] = any(1 <= c["key"] - q <= w and abs(c["cand"] - m) <= w
                          for q, m in accepted)
        if c["accepted"]:
            accepted.append((c["key"], c["cand"]))
    return skip


def _rejected(checks: list[dict], w: int) -> np.ndarray:
    skip = np.zeros(len(checks), dtype=bool)
    seen: list[tuple[int, int, str]] = []
    for i, c in enumerate(checks):
        near = [k for q, m, k in seen if 1 <= c["key"] - q <= w and abs(c["cand"] - m) <= w]
        skip[i] = bool(near) and "accepted" not in near and all(k == "icp-rejected"
                                                                 for k in near)
        seen.append((c["key"], c["cand"], _kind(c["reason"])))
    return skip


def analyse(path: Path) -> None:
    data = json.loads(path.read_text())
    for name, d in data.items():
        checks = d["checks"]
        kinds = np.array([_kind(c["reason"]) for c in checks])
        cpu = np.array([c["cpu"] for c in checks])
        keys = len({c["key"] for c in checks})
        print(f"\n{name}: run {d['run_cpu']:.1f} s CPU, detect {d['detect_cpu']:.1f} s "
              f"({d['queries']} queries); {len(d['loops'])} loops accepted, "
              f"{sum(1 for lp in d['loops'] if lp[3])} from a prior")
        print(f"  checks from a prior {len(checks)} ({len(checks) / max(d['queries'], 1):.2f} "
              f"per query, {keys} queries with one), {cpu.sum():.1f} s CPU")
        for k in ("accepted", "screened", "icp-rejected"):
            m = kinds == k
            print(f"    {k:13s} {m.sum():6d}  {cpu[m].sum():7.1f} s  "
                  f"{1e3 * cpu[m].mean() if m.any() else 0:6.1f} ms each")
        reasons: dict[str, list[float]] = {}
        for c, k in zip(checks, kinds, strict=True):
            if k == "icp-rejected":
                reasons.setdefault(c["reason"].split(" (")[0].split(" ")[0], []).append(c["cpu"])
        for r, v in sorted(reasons.items(), key=lambda f: -sum(f[1])):
            print(f"      rejected: {r:12s} {len(v):6d}  {sum(v):7.1f} s")
        if "free" in d:
            f = d["free"]
            print(f"  checks with no prior {sum(x['checks'] for x in f)} in {len(f)} queries, "
                  f"{sum(x['accepted'] for x in f)} accepted, "
                  f"{sum(x['cpu'] for x in f):.1f} s CPU "
                  f"({sum(x['cpu'] for x in f if not x['accepted']):.1f} s in queries with "
                  f"none accepted)")
            why: dict[str, int] = {}
            for x in f:
                for r in x.get("reasons", []):
                    k = r.split(" (")[0].split(" ")[0]
                    why[k] = why.get(k, 0) + 1
            print("    " + ", ".join(f"{k} {n}" for k, n in sorted(why.items(),
                                                                  key=lambda f: -f[1])))
        for src in ("pose", "appearance"):
            m = np.array([c["source"] == src for c in checks])
            print(f"    {src:10s} {m.sum():6d} checks, {(m & (kinds == 'accepted')).sum():5d} "
                  f"accepted, {cpu[m].sum():7.1f} s")
        both = ("pose", "appearance")
        for label, skip in [*((f"joined {w}", _joined(checks, w, ("pose",))) for w in (2, 5, 10)),
                            *((f"joined-all {w}", _joined(checks, w, both)) for w in (1, 2, 5)),
                            *((f"rejected {w}", _rejected(checks, w)) for w in (2, 5))]:
            print(f"  policy {label:13s}: skips {skip.sum():5d} checks, {cpu[skip].sum():6.1f} s; "
                  f"loses {(skip & (kinds == 'accepted')).sum():4d} accepted")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    c = sub.add_parser("collect")
    c.add_argument("logs", nargs="+", type=Path)
    c.add_argument("--out", type=Path, required=True)
    c.add_argument("--inputs", type=Path, default=None,
                   help="also pickle every check's verify inputs here (outside the repo)")
    a = sub.add_parser("analyse")
    a.add_argument("checks", type=Path)
    args = parser.parse_args()
    if args.command == "collect":
        collect(args.logs, args.out, args.inputs)
    else:
        analyse(args.checks)


if __name__ == "__main__":
    main()
