"""The pose-gated geometric check: variants of its ICP on the same recorded checks.

Two steps::

    python benchmarks/gated_check.py collect LOG [LOG ...] --out CHECKS.pkl [--limit N]
    python benchmarks/gated_check.py compare CHECKS.pkl [--variant NAME:KEY=VALUE,...]

``collect`` maps each log as ``loopclosure run`` does (the default pipeline in one
process; a corrected log with the drifting odometry of seed 0, as ``loopclosure
bench slam --odometry-noise 0`` feeds it) and records every check made from a pose
prior (`loopclosure.loop_detector.LoopClosureDetector._check_prior`): the query
submap, the candidate's submap, the prior and its covariance, the offsets and
``max_distance`` passed to `loopclosure.geometric_check.verify`.  The file stays
outside the repository (data is never copied in).

``compare`` re-runs `verify` on every recorded check once per variant, all in this
one process, variants interleaved check by check (a noisy machine slows them
alike), and prints per log: CPU seconds (``time.process_time``) and their ratio to
the first variant, ICP runs and iterations, how many verdicts (accepted or not)
differ from the first variant's, and the largest difference of an accepted relative
pose from the first variant's (translation [m], rotation [deg]).  A variant is the
default `GeometricCheckConfig` with ``KEY=VALUE`` overrides (``icp.`` for its
`IcpConfig`, e.g. ``icp.max_iterations=20``; ``fast_icp.`` for a constant of
`loopclosure.fast_icp`, e.g. ``fast_icp.JOIN_TRANSLATION=0`` for no joined runs).
"""

from __future__ import annotations

import argparse
import dataclasses
import pickle
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from data import se2  # noqa: E402


def collect(logs: list[Path], out: Path, limit: int | None) -> None:
    import loopclosure.candidate_checks as cc
    from evaluation.slam_input import load_input
    from loopclosure.warm_up import warm_up
    from slam.config import PipelineConfig
    from slam.pipeline import Mapper

    warm_up()
    records: list[dict] = []
    real_verify = cc.verify

    def recording(query_points, candidate, **kw):
        result = real_verify(query_points, candidate, **kw)
        if kw.get("prior") is not None:
            records.append({
                "log": current, "query": np.asarray(query_points, dtype=np.float32),
                "target": np.asarray(candidate.points, dtype=np.float32),
                "prior": np.asarray(kw["prior"], dtype=float),
                "prior_covariance": kw.get("prior_covariance"),
                "offsets": kw.get("offsets"), "max_distance": kw.get("max_distance"),
            })
        return result

    cc.verify = recording
    try:
        for log in logs:
            current = log.name.split(".")[0]
            corrected = "corrected" in log.name
            data = load_input(log, odometry_noise=0 if corrected else None)
            scans = data.scans if limit is None else data.scans[:limit]
            n0 = len(records)
            Mapper(PipelineConfig(front_end_worker=False)).run(scans)
            print(f"{current}: {len(records) - n0} checks from a prior", flush=True)
    finally:
        cc.verify = real_verify
    with open(out, "wb") as fh:
        pickle.dump(records, fh)


def _config(overrides: str):
    """``(config, module constants)``: the default `GeometricCheckConfig` with
    ``KEY=VALUE`` overrides (``icp.KEY`` for its `IcpConfig`), and the
    ``fast_icp.NAME=VALUE`` overrides of `loopclosure.fast_icp`'s constants."""
    from loopclosure.geometric_check import GeometricCheckConfig

    cfg, icp, constants = GeometricCheckConfig(), {}, {}
    for item in filter(None, overrides.split(",")):
        key, value = item.split("=", 1)
        if key.startswith("fast_icp."):
            constants[key[9:]] = float(value)
            continue
        obj, name = (cfg.icp, key[4:]) if key.startswith("icp.") else (cfg, key)
        current = getattr(obj, name)
        parsed = value == "true" if isinstance(current, bool) else type(current)(value)
        if obj is cfg:
            setattr(cfg, name, parsed)
        else:
            icp[name] = parsed
    cfg.icp = dataclasses.replace(cfg.icp, **icp)
    return cfg, constants


def compare(path: Path, variants: list[str]) -> None:
    from loopclosure import fast_icp
    from loopclosure.geometric_check import verify
    from loopclosure.registration import RegistrationTarget
    from loopclosure.warm_up import warm_up

    warm_up()
    with open(path, "rb") as fh:
        records = pickle.load(fh)
    specs = [v.split(":", 1) if ":" in v else (v, "") for v in variants] or [("defaults", "")]
    configs = [(name, _config(over)) for name, over in specs]
    iterations = {name: [0, 0] for name, _ in configs}
    real = fast_icp._register_grid

    def counting(*args, **kw):
        res = real(*args, **kw)
        counting.runs += 1
        counting.iterations += res[1] if isinstance(res, tuple) else res.iterations
        return res

    counting.runs = counting.iterations = 0
    fast_icp._register_grid = counting
    logs = sorted({r["log"] for r in records}, key=[r["log"] for r in records].index)
    rows = []
    try:
        for log in logs:
            mine = [r for r in records if r["log"] == log]
            cpu = {name: 0.0 for name, _ in configs}
            verdicts: dict[str, list] = {name: [] for name, _ in configs}
            for rec in mine:
                for name, (cfg, constants) in configs:
                    saved = {k: getattr(fast_icp, k) for k in constants}
                    for k, v in constants.items():
                        setattr(fast_icp, k, v)
                    target = RegistrationTarget(rec["target"].astype(float), cfg.icp)
                    runs0, its0 = counting.runs, counting.iterations
                    start = time.process_time()
                    res = verify(rec["query"].astype(float), target, prior=rec["prior"],
                                 prior_covariance=rec["prior_covariance"],
                                 offsets=rec["offsets"], max_distance=rec["max_distance"],
                                 config=cfg)
                    cpu[name] += time.process_time() - start
                    for k, v in saved.items():
                        setattr(fast_icp, k, v)
                    iterations[name][0] += counting.runs - runs0
                    iterations[name][1] += counting.iterations - its0
                    verdicts[name].append(res)
            first = configs[0][0]
            for name, _ in configs:
                differ = sum(a.accepted != b.accepted
                             for a, b in zip(verdicts[first], verdicts[name], strict=True))
                dt = dr = 0.0
                for a, b in zip(verdicts[first], verdicts[name], strict=True):
                    if a.accepted and b.accepted:
                        d = se2.between(a.relative, b.relative)
                        dt = max(dt, float(np.hypot(d[0], d[1])))
                        dr = max(dr, abs(float(np.degrees(d[2]))))
                rows.append((log, name, len(mine), sum(v.accepted for v in verdicts[name]),
                             cpu[name], cpu[name] / max(cpu[first], 1e-9), differ, dt, dr))
    finally:
        fast_icp._register_grid = real
    print(f"{'log':16s} {'variant':14s} {'checks':>6s} {'accepted':>8s} {'cpu s':>7s} "
          f"{'ratio':>6s} {'differ':>6s} {'max dt m':>9s} {'max dr deg':>10s}")
    for log, name, n, acc, cpu_s, ratio, differ, dt, dr in rows:
        print(f"{log:16s} {name:14s} {n:6d} {acc:8d} {cpu_s:7.2f} {ratio:6.2f} {differ:6d} "
              f"{dt:9.4f} {dr:10.3f}")
    for name, (runs, its) in iterations.items():
        print(f"{name}: {runs} ICP runs, {its / max(runs, 1):.1f} iterations per run")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    c = sub.add_parser("collect")
    c.add_argument("logs", nargs="+", type=Path)
    c.add_argument("--out", type=Path, required=True)
    c.add_argument("--limit", type=int, default=None, help="first N scans of each log")
    m = sub.add_parser("compare")
    m.add_argument("checks", type=Path)
    m.add_argument("--variant", action="append", default=[],
                   help="NAME:KEY=VALUE,... (the first is the reference)")
    args = parser.parse_args()
    if args.command == "collect":
        collect(args.logs, args.out, args.limit)
    else:
        compare(args.checks, args.variant)


if __name__ == "__main__":
    main()
