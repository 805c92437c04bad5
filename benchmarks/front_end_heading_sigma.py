"""Benchmark: is the ``icp2d`` front end's stated heading sigma honest on weak overlap?

Run from the repository root::

    python benchmarks/front_end_heading_sigma.py [--data DIR]
        [--logs intel-corrected,orebro,belgioioso] [--limit N]
        [--variant NAME:key=value,key=value ...]

On the GMapping-corrected logs (pose fields the reference; the front end gets the
simulator's drifting odometry, seed 0, as `front_end_precision.py`), every scan's
increment heading error ``e = wrap(theta_est - theta_ref)`` [deg] of the increment
since the previous scan is compared with the stated sigma ``s = sqrt(cov[2, 2])``
[deg] of that increment (`OdometryEstimate.covariance`, right perturbation).  Scans
are binned by ICP fitness, inlier ratio and degeneracy (quartiles of the first
variant); per bin: scans, median |e|, RMS e, median s, and RMS of ``z = e / s``
(1 for an honest covariance; larger: the covariance is too confident).  The
reference has its own error, so z includes it: compare bins, not absolute values.
Only ``ok``/``searched`` scans after the first are scored.
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from data import se2  # noqa: E402
from data.carmen import CarmenLog  # noqa: E402
from evaluation.slam_input import synthetic_odometry  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402
from slam.config_io import apply_overrides  # noqa: E402
from slam.odometry.icp2d import Icp2dOdometry  # noqa: E402

DEFAULT_DATA = ROOT.parent / "shared" / "data"
KEYS = ("fitness", "inlier_ratio", "degeneracy")


def run(scans, ref, cfg) -> dict[str, np.ndarray]:
    """Per-scan error, stated sigma [deg] and ICP figures of one front-end run."""
    odo = Icp2dOdometry(cfg)
    est = [odo.process(s) for s in scans]
    ref_inc = se2.between(ref[:-1], ref[1:])
    inc = np.array([e.delta for e in est[1:]])
    out = {
        "err": np.degrees(se2.wrap_angle(inc[:, 2] - ref_inc[:, 2])),
        "sigma": np.degrees(np.sqrt([e.covariance[2, 2] for e in est[1:]])),
        "good": np.array([e.status in ("ok", "searched") for e in est[1:]]),
    }
    out["fitness"] = np.array([e.fitness for e in est[1:]])
    for k in KEYS[1:]:
        out[k] = np.array([float(e.extra.get(k, np.nan)) for e in est[1:]])
    return out


def table(name: str, r: dict[str, np.ndarray], edges: dict[str, np.ndarray]) -> None:
    g = r["good"]
    z = r["err"] / r["sigma"]
    print(f"  {name}: scored {int(g.sum())}, all: med|e| {np.median(np.abs(r['err'][g])):.3f} "
          f"RMS e {np.sqrt(np.mean(r['err'][g]**2)):.3f} med s {np.median(r['sigma'][g]):.3f} "
          f"RMS z {np.sqrt(np.mean(z[g]**2)):.2f}")
    for k in KEYS:
        bins = np.digitize(r[k], edges[k])
        for b in range(len(edges[k]) + 1):
            m = g & (bins == b)
            if m.sum() < 5:
                continue
            lo = edges[k][b - 1] if b > 0 else -np.inf
            hi = edges[k][b] if b < len(edges[k]) else np.inf
            e = r["err"][m]
            print(f"    {k:<12} [{lo:6.3f},{hi:6.3f}) n {int(m.sum()):5d}  med|e| "
                  f"{np.median(np.abs(e)):.3f}  RMS e {np.sqrt(np.mean(e**2)):.3f}"
                  f"  med s {np.median(r['sigma'][m]):.3f}  RMS z {np.sqrt(np.mean(z[m]**2)):5.2f}"
                  f"  P(|z|>3) {np.mean(np.abs(z[m]) > 3):.3f}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, default=DEFAULT_DATA)
    p.add_argument("--logs", default="intel-corrected,orebro,belgioioso")
    p.add_argument("--limit", type=int, default=None)
    p.add_argument("--variant", action="append", default=None)
    args = p.parse_args()
    variants = []
    for spec in args.variant or ["default:"]:
        name, _, sets = spec.partition(":")
        overrides = [s for s in re.split(r",(?=[\w.]+=)", sets) if s]
        variants.append((name, apply_overrides(PipelineConfig(), overrides).icp2d))
    for log in args.logs.split(","):
        path = args.data / "carmen-corrected" / f"{log.removesuffix('-corrected')}-corrected.log.gz"
        scans = list(CarmenLog(path))[: args.limit]
        ref = np.array([s.odom for s in scans])
        scans = [dataclasses.replace(s, stamp=float(i))
                 for i, s in enumerate(synthetic_odometry(scans, ref, seed=0))]
        print(f"== {log}, {len(scans)} scans")
        edges = None
        for name, cfg in variants:
            r = run(scans, ref, cfg)
            if edges is None:
                edges = {k: np.nanquantile(r[k][r["good"]], [0.1, 0.25, 0.5, 0.75]) for k in KEYS}
            table(name, r, edges)
        sys.stdout.flush()


if __name__ == "__main__":
    main()
