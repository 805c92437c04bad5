"""Benchmark: where the icp2d front end registers chosen scans of a corrected log, onto
its local map as it was, onto parts of it, and onto it with back faces culled.

Run from the repository root::

    python benchmarks/front_end_facing.py [--data DIR] [--log intel-corrected] \
        [--scans 650,666] [--set icp2d.jump_scale=largest ...]

The front end (`slam.odometry.icp2d.Icp2dOdometry`, the defaults of
`slam.config.PipelineConfig` with the ``--set`` overrides) runs over the log's scans with
the simulator's wheel odometry (seed 0, as ``benchmarks/pipeline.py``) up to each chosen
scan ``i``; that scan is then registered, without changing the front end, onto

- ``as-is``: the local map as the front end holds it;
- ``reference``: the same map keyframes placed at the GMapping reference's poses (in
  the front end's frame, anchored at scan ``i - 1``), so a map error of the front end's
  own is taken out;
- ``last N``: only the newest ``N`` map keyframes;
- ``culled``: the map with ``icp2d.cull_back_faces`` (points whose surface faces away
  from the newest keyframe left out, `slam.odometry.facing`).

Printed per map: the map keyframes' scan range, fitness, inlier ratio and the error of
the registered increment ``i - 1 -> i`` against the reference's, in the frame of scan
``i - 1`` (along, across [m], heading [deg]).
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from data import se2
from evaluation.slam_input import load_input
from evaluation.slam_reference import logged_reference
from slam.config import PipelineConfig
from slam.config_io import apply_overrides
from slam.odometry.facing import scan_normals
from slam.odometry.icp2d import Icp2dOdometry

LAST = (6, 10, 15, 20, 25)


def _frozen(odo: Icp2dOdometry) -> Icp2dOdometry:
    """A copy of `odo` whose `process` registers without adding keyframes."""
    twin = copy.deepcopy(odo)
    twin._accept = lambda *args, **kwargs: None  # type: ignore[method-assign]
    return twin


def _with_frames(odo: Icp2dOdometry, frames: list[np.ndarray],
                 normals: list[np.ndarray] | None = None) -> Icp2dOdometry:
    twin = _frozen(odo)
    twin._keyframes.clear()
    twin._keyframes.extend(frames)
    twin._normals.clear()
    if normals is not None:
        twin._normals.extend(normals)
    twin._rebuild_map()
    return twin


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2]
                        / "shared" / "data")
    parser.add_argument("--log", default="intel-corrected")
    parser.add_argument("--scans", default="650,666")
    parser.add_argument("--set", action="append", default=[], dest="sets")
    args = parser.parse_args()
    chosen = sorted(int(s) for s in args.scans.split(","))
    name = args.log.removesuffix("-corrected")
    path = args.data / "carmen-corrected" / f"{name}-corrected.log.gz"
    loaded = load_input(path, odometry_noise=0)
    ref = logged_reference(loaded).xytheta()
    cfg = apply_overrides(PipelineConfig(), args.sets).icp2d
    odo = Icp2dOdometry(cfg)
    kf_scans: list[int] = []
    normals: list[np.ndarray] = []  # per map keyframe, map frame
    poses = []
    for i, scan in enumerate(loaded.scans[:chosen[-1] + 1]):
        if i in chosen:
            inmap = kf_scans[-len(odo._keyframes):]
            frames = list(odo._keyframes)
            anchor = se2.compose(poses[i - 1], se2.inverse(ref[i - 1]))
            at_ref = [se2.transform_points(se2.compose(anchor, ref[k]),
                                           odo.scan_points(loaded.scans[k])) for k in inmap]
            maps = [("as-is", _frozen(odo)), ("reference", _with_frames(odo, at_ref))]
            maps += [(f"last {n}", _with_frames(odo, frames[-n:])) for n in LAST]
            culled = copy.deepcopy(odo)
            culled.config = dataclasses.replace(cfg, cull_back_faces=True)
            maps.append(("culled", _with_frames(culled, frames, normals[-len(frames):])))
            truth = se2.between(ref[i - 1][None], ref[i][None])[0]
            print(f"\nscan {i}: map keyframes of scans {inmap[0]}-{inmap[-1]} ({len(inmap)})")
            for name, twin in maps:
                est = twin.process(scan)
                err = se2.between(truth[None], est.delta[None])[0]
                heading = np.degrees(se2.wrap_angle(err[2]))
                print(f"  {name:<10} fitness {est.fitness:.2f} inliers "
                      f"{est.extra.get('inlier_ratio', 0.0):.2f}  error along {err[0]:+.3f} "
                      f"across {err[1]:+.3f} m heading {heading:+.2f} deg")
        est = odo.process(scan)
        poses.append(est.pose)
        if est.extra.get("keyframe"):
            kf_scans.append(i)
            c, s = np.cos(est.pose[2]), np.sin(est.pose[2])
            normals.append(scan_normals(odo.scan_points(scan), cfg.facing_gap,
                                        cfg.facing_bend)
                           @ np.array([[c, s], [-s, c]]))


if __name__ == "__main__":
    main()
