"""The pose-gated geometric check with its target builds: two checkouts, back to back.

Run from a checkout's root (its code is the one timed)::

    python benchmarks/gated_check.py collect LOG --out CHECKS.pkl
    python benchmarks/gated_screen.py run CHECKS.pkl --out A.json   # in checkout A
    python /path/to/B/benchmarks/gated_screen.py run CHECKS.pkl --out B.json
    python benchmarks/gated_screen.py diff A.json B.json

``run`` replays every recorded check made from a pose prior (the records of
``benchmarks/gated_check.py collect``): the candidate's registration target is
built as the loop detector builds it (`loopclosure.loop_detector.LoopClosureDetector`
with the recorded submap as its submap callback; one target per distinct submap, as
the detector's target cache keeps one), then
`loopclosure.geometric_check.verify` runs with the recorded prior, covariance,
offsets and ``max_distance``.  It prints the CPU seconds (``time.process_time``)
of the target builds and of the checks, and how many checks stopped at each
pre-ICP screen, and writes every verdict (accepted, reason, relative pose) to
``--out``.  ``diff`` prints the CPU ratio of the second file to the first and how
many verdicts differ (acceptance, or the screen that stopped a check), and the
largest difference of a relative pose both accepted (translation [m], rotation
[deg]).  ``--repeat R`` replays the whole set R times and keeps each check's
fastest time (a shared machine slows runs unevenly).

Nothing is written into the repository; the data stays in the shared folder.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import pickle
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _replay(records: list[dict]) -> tuple[list[float], list[float], list[dict]]:
    """Per check: CPU seconds of its target build (0 when its submap's target was
    built already), of `verify`, and its verdict."""
    from loopclosure.geometric_check import verify
    from loopclosure.loop_detector import LoopClosureConfig, LoopClosureDetector

    config = LoopClosureConfig()
    targets: dict[str, object] = {}
    build, check, verdicts = [], [], []
    for rec in records:
        pts = rec["target"].astype(float)
        key = hashlib.sha1(pts.tobytes()).hexdigest()
        t0 = time.process_time()
        if key not in targets:
            detector = LoopClosureDetector(config, submap=lambda _k, p=pts: p)
            targets[key] = detector._target(0)
        t1 = time.process_time()
        res = verify(rec["query"].astype(float), targets[key], prior=rec["prior"],
                     prior_covariance=rec["prior_covariance"], offsets=rec["offsets"],
                     max_distance=rec["max_distance"], config=config.check)
        t2 = time.process_time()
        build.append(t1 - t0)
        check.append(t2 - t1)
        verdicts.append({"accepted": bool(res.accepted), "reason": res.reason,
                         "relative": [float(v) for v in res.relative]})
    return build, check, verdicts


def run(path: Path, out: Path, repeat: int) -> None:
    from loopclosure.warm_up import warm_up

    warm_up()
    with open(path, "rb") as fh:
        records = [r for r in pickle.load(fh) if r["prior"] is not None]
    build = np.full(len(records), np.inf)
    check = np.full(len(records), np.inf)
    verdicts: list[dict] = []
    for _ in range(repeat):
        b, c, verdicts = _replay(records)
        build, check = np.minimum(build, b), np.minimum(check, c)
    stops = {"overlap": 0, "bound": 0, "icp": 0}
    for v in verdicts:
        kind = ("overlap" if v["reason"].startswith("no overlap") else
                "bound" if v["reason"].startswith("no fit within reach") else "icp")
        stops[kind] += 1
    print(f"{len(records)} checks, {sum(v['accepted'] for v in verdicts)} accepted; "
          f"stopped at the overlap screen {stops['overlap']}, at the bound "
          f"{stops['bound']}, ICP ran {stops['icp']}")
    print(f"CPU s: target builds {build.sum():.2f}, checks {check.sum():.2f}, "
          f"total {build.sum() + check.sum():.2f}")
    out.write_text(json.dumps({"root": str(ROOT), "build_s": float(build.sum()),
                               "check_s": float(check.sum()), "verdicts": verdicts}))


def _stop(reason: str) -> str:
    return reason.split(" (")[0]


def diff(a_path: Path, b_path: Path) -> None:
    from data import se2

    a, b = json.loads(a_path.read_text()), json.loads(b_path.read_text())
    for what in ("build_s", "check_s"):
        print(f"{what}: {a[what]:.2f} -> {b[what]:.2f} (x{b[what] / max(a[what], 1e-9):.2f})")
    ta, tb = a["build_s"] + a["check_s"], b["build_s"] + b["check_s"]
    print(f"total: {ta:.2f} -> {tb:.2f} (x{tb / max(ta, 1e-9):.2f})")
    va, vb = a["verdicts"], b["verdicts"]
    accepted = sum(x["accepted"] != y["accepted"] for x, y in zip(va, vb, strict=True))
    stops = sum(_stop(x["reason"]) != _stop(y["reason"]) for x, y in zip(va, vb, strict=True))
    dt = dr = 0.0
    for x, y in zip(va, vb, strict=True):
        if x["accepted"] and y["accepted"]:
            d = se2.between(np.asarray(x["relative"]), np.asarray(y["relative"]))
            dt, dr = max(dt, float(np.hypot(d[0], d[1]))), max(dr, abs(np.degrees(d[2])))
    print(f"{len(va)} checks: {accepted} differ in acceptance, {stops} in the rule that "
          f"decided; accepted in both: max |dt| {dt:.2e} m, max |dr| {dr:.2e} deg")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run")
    r.add_argument("checks", type=Path)
    r.add_argument("--out", type=Path, required=True)
    r.add_argument("--repeat", type=int, default=1)
    d = sub.add_parser("diff")
    d.add_argument("a", type=Path)
    d.add_argument("b", type=Path)
    args = parser.parse_args()
    if args.command == "run":
        run(args.checks, args.out, args.repeat)
    else:
        diff(args.a, args.b)


if __name__ == "__main__":
    main()
