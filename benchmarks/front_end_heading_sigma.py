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

Lags: the heading error of the ``k``-scan increments (k = 1 .. 40) against the sum of
the stated variances; a line ``var(e_k) = a + b k`` fitted on k <= 10 separates the
reference's own jitter (``sqrt(a / 2)``, white pose noise) from the front end's
random walk per increment (``sqrt(b)``).  Then the 10-scan errors binned by the
lowest fitness inside the window (quantiles).
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
        "poses": np.array([e.pose for e in est]),
        "var": np.array([e.covariance[2, 2] for e in est]),
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


def lag_errors(poses: np.ndarray, ref: np.ndarray, k: int) -> np.ndarray:
    """Heading errors [rad] of the ``k``-scan increments of `poses` against `ref`."""
    return se2.wrap_angle(se2.between(poses[:-k], poses[k:])[:, 2]
                          - se2.between(ref[:-k], ref[k:])[:, 2])


def jitter_and_walk(poses: np.ndarray, ref: np.ndarray, ks=(1, 2, 5, 10)) -> tuple[float, float]:
    """``(reference jitter, front-end sigma per increment)`` [rad] from the fit
    ``mean(e_k^2) = a + b k``: white heading noise of the reference ``sqrt(a / 2)``,
    a random walk of the estimate ``sqrt(b)``."""
    v = [np.mean(lag_errors(poses, ref, k) ** 2) for k in ks]
    a, b = np.linalg.lstsq(np.c_[np.ones(len(ks)), ks], np.array(v), rcond=None)[0]
    return float(np.sqrt(max(a, 0.0) / 2)), float(np.sqrt(max(b, 0.0)))


def lags(r: dict[str, np.ndarray], ref: np.ndarray, lag_list=(1, 2, 5, 10, 20, 40)) -> None:
    """The k-scan heading errors [deg] against the stated sigma and the fit (docstring)."""
    poses, var = r["poses"], r["var"]
    cum = np.concatenate([[0.0], np.cumsum(var[1:])])
    for k in lag_list:
        e = lag_errors(poses, ref, k)
        stated = cum[k:] - cum[:-k]
        z = np.sqrt(np.mean(e**2 / stated))
        print(f"    lag {k:3d}: RMS e {np.degrees(np.sqrt(np.mean(e**2))):.3f}  stated "
              f"{np.degrees(np.sqrt(np.median(stated))):.3f}  RMS z {z:.2f}")
    jitter, walk = jitter_and_walk(poses, ref)
    print(f"    fit k<=10: reference jitter {np.degrees(jitter):.3f} deg, "
          f"front end {np.degrees(walk):.3f} deg per increment, stated median "
          f"{np.degrees(np.sqrt(np.median(var[1:]))):.3f}")
    k = 10
    e = np.degrees(lag_errors(poses, ref, k))
    fit = np.concatenate([[1.0], r["fitness"]])
    low = np.array([fit[i + 1 : i + k + 1].min() for i in range(len(poses) - k)])
    edges = np.quantile(low, [0.1, 0.25, 0.5, 0.75])
    bins = np.digitize(low, edges)
    for j in range(len(edges) + 1):
        m = bins == j
        lo = edges[j - 1] if j > 0 else -np.inf
        hi = edges[j] if j < len(edges) else np.inf
        print(f"    lag 10, min fitness [{lo:5.2f},{hi:5.2f}) n {int(m.sum()):4d}  "
              f"RMS e {np.sqrt(np.mean(e[m]**2)):.3f}  med|e| {np.median(np.abs(e[m])):.3f}")


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
            lags(r, ref)
        sys.stdout.flush()


if __name__ == "__main__":
    main()
