"""Benchmark: which stage of the final pass rejects a corrected log's loops, and whether
keeping them would help, next to where the keyframes' error against the reference lies.

Run from the repository root::

    python benchmarks/front_end_loop_rejections.py [--data DIR] [--log intel-corrected] \
        [--set icp2d.jump_scale=largest ...]

The log is mapped (`slam.pipeline.Mapper`, the defaults of `slam.config.PipelineConfig`
with the ``--set`` overrides, the simulator's wheel odometry of seed 0 as
``benchmarks/pipeline.py``); its pose graph and the poses the final GNC starts from
are kept, and the final GNC (`slam.optimize.optimize`, ``gnc_start="incremental"``) is
re-run with the segment re-check, the group test or the fast path off, to see which
stage removes the loops it removes.  Then:

- the plain least-squares solution with every loop, and each loop's factor error
  (gtsam units; the TLS threshold ``c`` at 0.99) at each rung of the odometry ladder
  (odometry information x100, x10, x1, as the fast path solves them), for the
  rejected loops;
- the keyframes' position error against the reference (rigid 2D alignment), RMS
  per 50 keyframes, for the TLS and the least-squares solutions;
- every rejected loop's measurement against the reference's relative pose (along,
  across [m], heading [deg]) and its ``chi2`` under the loop's stated information.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from data import se2
from evaluation.slam_input import load_input
from evaluation.slam_reference import logged_reference
from slam.config import PipelineConfig
from slam.config_io import apply_overrides
from slam.innovation import tls_threshold
from slam.least_squares import solve
from slam.optimize import optimize
from slam.pipeline import Mapper
from slam.pose_graph import RobustKernel, poses_from_values
from slam.variance_components import with_information_scaled

BLOCK = 50


class _Capturing(Mapper):
    """A mapper that keeps the poses its final GNC starts from."""

    start: dict[int, np.ndarray]

    def finish(self, interrupted: bool = False):
        graph, known = self.smoother.graph, len(self._estimate)
        self.start = {k: np.array(self._estimate[k] if k < known else graph.initial[k])
                      for k in graph.initial}
        return super().finish(interrupted)


def _errors(poses: dict[int, np.ndarray], truth: np.ndarray) -> np.ndarray:
    """Position error [m] of each keyframe after a rigid 2D alignment onto `truth`."""
    est = np.array([poses[k] for k in sorted(poses)])[:, :2]
    ref = truth[:, :2]
    mp, mr = est.mean(0), ref.mean(0)
    u, _, vt = np.linalg.svd((est - mp).T @ (ref - mr))
    rot = vt.T @ np.diag([1.0, np.linalg.det(vt.T @ u.T)]) @ u.T
    return np.hypot(*((rot @ (est - mp).T).T + mr - ref).T)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2]
                        / "shared" / "data")
    parser.add_argument("--log", default="intel-corrected")
    parser.add_argument("--set", action="append", default=[], dest="sets")
    args = parser.parse_args()
    name = args.log.removesuffix("-corrected")
    loaded = load_input(args.data / "carmen-corrected" / f"{name}-corrected.log.gz",
                        odometry_noise=0)
    mapper = _Capturing(apply_overrides(PipelineConfig(), args.sets))
    result = mapper.run(loaded.scans)
    graph = mapper.smoother.graph
    position = {s.index: i for i, s in enumerate(loaded.scans)}
    truth = logged_reference(loaded).xytheta()[[position[k.scan_index]
                                                 for k in result.keyframes]]
    print(f"{args.log} {' '.join(args.sets) or 'defaults'}: {len(graph.initial)} keyframes, "
          f"{len(graph.loops)} loops, rejected by the final GNC {sorted(result.loop_outliers)}")
    stages = {"all stages": {}, "no segment re-check": {"segments": False},
              "no group test": {"groups": False}, "no fast path": {"fast_path": False}}
    tls = None
    for label, kwargs in stages.items():
        res = optimize(graph, method="gnc", initial=mapper.start, gnc_start="incremental",
                       **kwargs)
        tls = tls or res
        print(f"  {label:<20} {res.solver:<34} rejected {res.loop_outliers}")
    assert tls is not None
    factors, index = graph.factor_graph(RobustKernel("none"))
    c = tls_threshold(graph.dim, 0.99)
    rejected = sorted(tls.loop_outliers)
    values = graph.gtsam_values(mapper.start)
    for factor in (100.0, 10.0, 1.0):
        rung = factors if factor == 1.0 else with_information_scaled(
            graph, factor).factor_graph(RobustKernel("none"))[0]
        values, _, _ = solve(rung, values, 100)
        errs = np.array([factors.at(k).error(values) for k in index])
        print(f"  least squares, odometry x{factor:g}: {int((errs > c).sum())} loops over "
              f"c = {c:.2f}; rejected loops' errors "
              + " ".join(f"{errs[k]:.2f}" for k in rejected))
    solutions = {"TLS": _errors(tls.poses, truth),
                 "all loops": _errors(poses_from_values(values, graph.dim), truth)}
    for label, err in solutions.items():
        blocks = " ".join(f"{np.sqrt(np.mean(err[i:i + BLOCK] ** 2)):.3f}"
                          for i in range(0, len(err), BLOCK))
        print(f"  keyframe RMS {np.sqrt(np.mean(err ** 2)):.4f} m ({label}); per {BLOCK}: {blocks}")
    for k in rejected:
        loop = graph.loops[k]
        rel = se2.between(truth[loop.i][None], truth[loop.j][None])
        e = se2.between(rel, np.asarray(loop.measurement)[None])[0]
        e[2] = se2.wrap_angle(e[2])
        chi2 = float(e @ np.asarray(loop.information) @ e)
        print(f"  loop {k} ({loop.i}-{loop.j}) against the reference: along {e[0]:+.3f} "
              f"across {e[1]:+.3f} m heading {np.degrees(e[2]):+.2f} deg, chi2 {chi2:.1f}")


if __name__ == "__main__":
    main()
