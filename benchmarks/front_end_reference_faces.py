"""Benchmark: where back-face culling moves the front end's increments away from a
corrected log's reference, does the reference agree with the faces the scan can see?

Run from the repository root::

    python benchmarks/front_end_reference_faces.py [--data DIR] [--log belgioioso] \
        [--seed 0] [--top 8] [--variant NAME:key=value,... (two)]

Two front ends (`slam.odometry.icp2d.Icp2dOdometry`, the defaults of
`slam.config.PipelineConfig` with each variant's overrides; by default ``largest``,
``icp2d.jump_scale=largest``, and ``largest+cull``, that and
``icp2d.cull_back_faces=true``) run alone over the log's scans with the simulator's
wheel odometry (seed `--seed`, as ``benchmarks/pipeline.py``).  The error of scan
``i`` is that of its registered increment ``i - 1 -> i`` against the GMapping
reference's, in the frame of scan ``i - 1`` (along, across [m], heading [deg]).

For the `--top` scans where the second front end's increment is worst against the
first's (norm of the translation error), scan ``i`` is registered again, from the
second front end's prediction, onto the keyframes of its local map at the time placed
at the *reference's* poses (anchored at scan ``i - 1``), so the front end's own map
errors are out:

- ``ref all``: every map keyframe (both faces of a wall where both were seen);
- ``ref cull``: the same, back faces culled from the newest keyframe
  (`slam.odometry.facing`);
- ``singles``: each of the newest six keyframes alone; the median and spread of
  their across errors.

If ``ref cull`` and the singles (scans that saw the faces the scan sees, at the
reference's own poses) agree with each other and not with the reference, the
reference's increment is inconsistent with the faces the scan can see; ``ref all``
then shows whether the far faces pull the registration onto the reference.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.front_end_facing import _with_frames
from data import se2
from evaluation.slam_input import load_input
from evaluation.slam_reference import logged_reference
from slam.config import PipelineConfig
from slam.config_io import apply_overrides
from slam.odometry.facing import scan_normals
from slam.odometry.icp2d import Icp2dOdometry

DEFAULT_VARIANTS = ("largest:icp2d.jump_scale=largest",
                    "largest+cull:icp2d.jump_scale=largest,icp2d.cull_back_faces=true")
SINGLES = 6


def _parse_variant(text: str) -> tuple[str, list[str]]:
    name, _, body = text.partition(":")
    return name, [s for s in body.split(",") if s]


def _error(truth: np.ndarray, delta: np.ndarray) -> np.ndarray:
    err = se2.between(truth[None], delta[None])[0]
    return np.array([err[0], err[1], np.degrees(se2.wrap_angle(err[2]))])


def run(loaded, ref: np.ndarray, sets: list[str], stop: set[int] | None = None):
    """Front end over the scans: per-scan increment errors and, at the scans in `stop`,
    a copy of the front end before that scan and its map keyframes' scan indices."""
    cfg = apply_overrides(PipelineConfig(), sets).icp2d
    odo = Icp2dOdometry(cfg)
    kf: list[int] = []
    poses: list[np.ndarray] = []
    errors = np.zeros((len(loaded.scans), 3))
    frozen: dict[int, tuple[Icp2dOdometry, list[int], np.ndarray]] = {}
    last = max(stop) if stop else len(loaded.scans) - 1
    for i, scan in enumerate(loaded.scans[:last + 1]):
        if stop and i in stop:
            frozen[i] = (copy.deepcopy(odo), kf[-len(odo._keyframes):], poses[i - 1])
        est = odo.process(scan)
        poses.append(est.pose)
        if i > 0:
            truth = se2.between(ref[i - 1][None], ref[i][None])[0]
            errors[i] = _error(truth, est.delta)
        if est.extra.get("keyframe"):
            kf.append(i)
    return errors, frozen, cfg


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2]
                        / "shared" / "data")
    parser.add_argument("--log", default="belgioioso")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--top", type=int, default=8)
    parser.add_argument("--variant", action="append", default=None)
    args = parser.parse_args()
    (name_a, sets_a), (name_b, sets_b) = map(_parse_variant, args.variant or DEFAULT_VARIANTS)
    log = args.log.removesuffix("-corrected")
    loaded = load_input(args.data / "carmen-corrected" / f"{log}-corrected.log.gz",
                        odometry_noise=args.seed)
    ref = logged_reference(loaded).xytheta()
    err_a, _, _ = run(loaded, ref, sets_a)
    err_b, _, _ = run(loaded, ref, sets_b)
    norm_a, norm_b = np.hypot(err_a[:, 0], err_a[:, 1]), np.hypot(err_b[:, 0], err_b[:, 1])
    print(f"{log} seed {args.seed}, {len(ref)} scans; increment error against the reference")
    for name, nrm, err in ((name_a, norm_a, err_a), (name_b, norm_b, err_b)):
        print(f"  {name:<14} mean {nrm.mean():.4f} m, over 5 cm {np.sum(nrm > 0.05)}, "
              f"mean |heading| {np.abs(err[:, 2]).mean():.3f} deg")
    worse = np.argsort(norm_a - norm_b)[:args.top]
    chosen = sorted(int(i) for i in worse if i > 0)
    if not chosen:
        return
    _, frozen, cfg_b = run(loaded, ref, sets_b, set(chosen))
    culled_cfg = dataclasses.replace(cfg_b, cull_back_faces=True)
    print(f"\nthe {len(chosen)} scans where {name_b} is worst against {name_a}; "
          f"across errors [m] (along, across, heading deg for the maps)")
    agree = []
    for i in chosen:
        odo, inmap, prev = frozen[i]
        scan = loaded.scans[i]
        truth = se2.between(ref[i - 1][None], ref[i][None])[0]
        anchor = se2.compose(prev, se2.inverse(ref[i - 1]))
        placed = [se2.compose(anchor, ref[k]) for k in inmap]
        pts = [odo.scan_points(loaded.scans[k]) for k in inmap]
        frames = [se2.transform_points(p, q) for p, q in zip(placed, pts, strict=True)]
        normals = []
        for p, q in zip(placed, pts, strict=True):
            c, s = np.cos(p[2]), np.sin(p[2])
            normals.append(scan_normals(q, cfg_b.facing_gap, cfg_b.facing_bend)
                           @ np.array([[c, s], [-s, c]]))
        plain = copy.deepcopy(odo)
        plain.config = dataclasses.replace(cfg_b, cull_back_faces=False)
        culled = copy.deepcopy(odo)
        culled.config = culled_cfg
        e_all = _error(truth, _with_frames(plain, frames).process(scan).delta)
        e_cull = _error(truth, _with_frames(culled, frames, normals).process(scan).delta)
        singles = np.array([_error(truth, _with_frames(plain, [f]).process(scan).delta)
                            for f in frames[-SINGLES:]])
        med = np.median(singles[:, 1])
        agree.append((e_cull[1], med, e_all[1]))
        print(f"  scan {i}: {name_a} {err_a[i, 1]:+.3f}  {name_b} {err_b[i, 1]:+.3f}  "
              f"ref all {e_all[0]:+.3f},{e_all[1]:+.3f},{e_all[2]:+.2f}  "
              f"ref cull {e_cull[0]:+.3f},{e_cull[1]:+.3f},{e_cull[2]:+.2f}  "
              f"singles median {med:+.3f} [{singles[:, 1].min():+.3f}, "
              f"{singles[:, 1].max():+.3f}]")
    if agree:
        a = np.array(agree)
        print(f"\nmedian |ref cull| {np.median(np.abs(a[:, 0])):.3f}, "
              f"|singles| {np.median(np.abs(a[:, 1])):.3f}, |ref all| "
              f"{np.median(np.abs(a[:, 2])):.3f} m; |ref cull - singles| "
              f"{np.median(np.abs(a[:, 0] - a[:, 1])):.3f} m")


if __name__ == "__main__":
    main()
