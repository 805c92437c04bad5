"""What a cheap test would see of the checks from a pose prior before their ICP.

Two steps::

    python benchmarks/prior_reject_features.py run INPUTS.pkl --out FEATURES.json
    python benchmarks/prior_reject_features.py analyse FEATURES.json

``INPUTS.pkl`` holds the inputs of every check from a prior of whole runs (the
``--inputs`` of ``benchmarks/prior_check_policy.py collect``).  ``run`` replays each
check as `loopclosure.candidate_checks.CandidateChecks._check_prior` makes it (the
candidate's lazy grid, one per distinct submap, kept as the detector keeps it) and
records, besides its verdict and its CPU seconds (``time.process_time``), what a test
before ICP could use: at the guesses `loopclosure.geometric_check.verify` would start
ICP from (the prior, and its four offsets unless the prior is tight), the coarse
overlap score at ICP's correspondence gate and the overlap bound (the share of the
query's points with a map point within a reach, `loopclosure.fast_icp.overlap_screen`)
at several reaches; and the Mahalanobis distance of the nearest revisit (a relative
pose within ``max_distance`` of the candidate) from the prior under the prior's
position covariance.

``analyse`` prints per log the checks by verdict and their CPU seconds, then for
each test "feature below a threshold" the checks it would stop, the CPU seconds of
those rejected after ICP that it would save, and the accepted checks it would lose.
Nothing is written into the repository.
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

REACHES = (0.15, 0.25, 0.35, 0.55)
SCREENS = ("no overlap", "no fit within reach")


def _kind(reason: str) -> str:
    if reason == "accepted":
        return "accepted"
    if reason.startswith(SCREENS):
        return "screened"
    return "icp-rejected"


def run(path: Path, out: Path) -> None:
    from loopclosure.fast_icp import TARGET_GRID_CELL, GridTarget, overlap_screen
    from loopclosure.fast_icp import voxel_downsample_fast as voxel
    from loopclosure.geometric_check import _offset_grid, verify
    from loopclosure.loop_config import LoopClosureConfig
    from loopclosure.multi_start import initial_guesses
    from loopclosure.warm_up import warm_up

    warm_up()
    cfg = LoopClosureConfig().check
    with open(path, "rb") as fh:
        records = [r for r in pickle.load(fh) if r["prior"] is not None]
    grids: dict[str, GridTarget] = {}
    rows: list[dict] = []
    for rec in records:
        pts = rec["target"].astype(float)
        key = hashlib.sha1(pts.tobytes()).hexdigest()
        if key not in grids:
            grids[key] = GridTarget(pts, cfg.icp, TARGET_GRID_CELL, lazy=True)
        grid = grids[key]
        query = rec["query"].astype(float)
        prior = np.asarray(rec["prior"], dtype=float)
        step = cfg.offsets if rec["offsets"] is None else rec["offsets"]
        guesses = initial_guesses(prior, None, _offset_grid(step))
        source = voxel(query, cfg.source_voxel)
        features: dict[str, float] = {}
        t0 = time.process_time()
        res = verify(query, None, prior=prior, prior_covariance=rec["prior_covariance"],
                     offsets=rec["offsets"], max_distance=rec["max_distance"], config=cfg,
                     grid=grid)
        t1 = time.process_time()
        for reach in REACHES:
            scores, bounds = overlap_screen(source, grid, guesses,
                                            cfg.icp.max_correspondence_distance, reach)
            features[f"bound{reach}"] = float(bounds.max(initial=0.0))
            features["overlap"] = float(scores.max(initial=0.0))
        t2 = time.process_time()
        cov = rec["prior_covariance"]
        if cov is not None and rec["max_distance"] is not None:
            c = np.asarray(cov, dtype=float)[:2, :2]
            features["revisit_sigma"] = _nearest_revisit_sigma(prior[:2], c,
                                                               rec["max_distance"])
        rows.append({"log": rec["log"], "accepted": bool(res.accepted), "reason": res.reason,
                     "kind": _kind(res.reason), "fitness": float(res.fitness),
                     "cpu": t1 - t0, "screen_cpu": (t2 - t1) / len(REACHES), **features})
    out.write_text(json.dumps(rows))
    print(f"{len(rows)} checks replayed", flush=True)


def _nearest_revisit_sigma(xy: np.ndarray, cov: np.ndarray, radius: float) -> float:
    """Smallest Mahalanobis distance (under `cov`) from `xy` to the disc of `radius`
    about 0, sampled on the disc's boundary (0 when `xy` lies inside)."""
    if float(np.hypot(*xy)) <= radius:
        return 0.0
    a = np.linspace(0, 2 * np.pi, 721)
    d = radius * np.column_stack([np.cos(a), np.sin(a)]) - xy
    inv = np.linalg.inv(cov + np.eye(2) * 1e-12)
    return float(np.sqrt(np.einsum("ni,ij,nj->n", d, inv, d).min()))


def analyse(path: Path) -> None:
    rows = json.loads(path.read_text())
    logs = sorted({r["log"] for r in rows}, key=lambda n: [r["log"] for r in rows].index(n))
    feats = [f"bound{r}" for r in REACHES] + ["overlap"]
    for log in logs:
        rs = [r for r in rows if r["log"] == log]
        kinds = np.array([r["kind"] for r in rs])
        cpu = np.array([r["cpu"] for r in rs])
        print(f"\n{log}: {len(rs)} checks, CPU {cpu.sum():.2f} s")
        for k in ("accepted", "screened", "icp-rejected"):
            m = kinds == k
            print(f"  {k:13s} {m.sum():5d} {cpu[m].sum():6.2f} s")
        acc = kinds == "accepted"
        rej = kinds == "icp-rejected"
        for f in feats:
            v = np.array([r[f] for r in rs])
            if acc.any():
                print(f"  {f:10s} accepted min {v[acc].min():.3f} p1 "
                      f"{np.percentile(v[acc], 1):.3f}; icp-rejected median "
                      f"{np.median(v[rej]) if rej.any() else float('nan'):.3f}")
            for t in (0.3, 0.35, 0.4, 0.45, 0.5, 0.6):
                stop = (v < t) & (kinds != "screened")
                print(f"    {f} < {t}: stops {stop.sum():4d}, saves "
                      f"{cpu[stop & rej].sum():5.2f} s, loses {(stop & acc).sum():3d}")
        if "revisit_sigma" in rs[0]:
            v = np.array([r.get("revisit_sigma", 0.0) for r in rs])
            for t in (2.0, 3.0, 4.0):
                stop = (v > t) & (kinds != "screened")
                print(f"    revisit_sigma > {t}: stops {stop.sum():4d}, saves "
                      f"{cpu[stop & rej].sum():5.2f} s, loses {(stop & acc).sum():3d}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run")
    r.add_argument("inputs", type=Path)
    r.add_argument("--out", type=Path, required=True)
    a = sub.add_parser("analyse")
    a.add_argument("features", type=Path)
    args = parser.parse_args()
    if args.command == "run":
        run(args.inputs, args.out)
    else:
        analyse(args.features)


if __name__ == "__main__":
    main()
