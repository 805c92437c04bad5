"""CPU of the free-space consistency (`loopclosure.free_space` (2)) under (1') along the
ray, the surface margin (1'') and the returns margin (4), on real submap pairs.

Run from the repository root::

    python benchmarks/scan_margin_speed.py LOG [--step 3] [--rounds 5] [--variant C:W ...]

The log is mapped as `consistency_bar_rule.py` maps it and its front-end pairs are
made the same way (query at the check's ``source_voxel``, the other at the search's
``submap_voxel``, their scans' free space from the store).  Each round times every
variant over all pairs, interleaved (`time.process_time`); prints the best round per
variant and its ratio to (1') along the ray, and the mean consistency (a check that the
variants differ).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from scan_origins_bench import loop_source  # noqa: E402

from data import se2  # noqa: E402
from evaluation.loop_bench import mapped_input  # noqa: E402
from loopclosure.fast_icp import voxel_downsample_fast  # noqa: E402
from loopclosure.free_space import ScanFreeSpace, Submap, consistency  # noqa: E402
from loopclosure.registration import voxel_downsample  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log")
    ap.add_argument("--step", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--variant", action="append", metavar="CAP:WINDOW")
    args = ap.parse_args()
    variants = [(1.0, 0)] + [(float(v.split(":")[0]), int(v.split(":")[1]))
                             for v in args.variant or ["5:0", "1:8", "5:8"]]
    cfg = PipelineConfig()
    cfg.loops.check.free_space_origins = "scans"
    mapper, _, _ = mapped_input(loop_source(args.log, None), cfg)
    det = mapper.detector
    check, s = det.config.check, det.config.check.search
    n = mapper.config.submap_neighbours()
    pairs = []
    for k in range(n, len(mapper.keyframes.keyframes) - n - 1, args.step):
        m = k + n + 1
        q = voxel_downsample_fast(mapper.trailing_map(k, n), check.source_voxel)
        c = voxel_downsample(mapper.trailing_map(m, n), s.submap_voxel)
        if len(q) and len(c):
            pose = se2.between(mapper._keyframe(m).odom_pose, mapper._keyframe(k).odom_pose)
            pairs.append((q, c, pose, det.submap_free_space(k, last=k),
                          det.submap_free_space(m, last=m)))
    # submaps prepared once per variant (KD-trees), as the check caches its target's
    prepared = {v: [(Submap.of(q, s.free_bins, scans=ScanFreeSpace(qf.poses, qf.ranges, *v)),
                     Submap.of(c, s.free_bins, scans=ScanFreeSpace(cf.poses, cf.ranges, *v)),
                     pose) for q, c, pose, qf, cf in pairs] for v in variants}
    best = {v: np.inf for v in variants}
    mean = {}
    for _ in range(args.rounds):
        for v in variants:
            t0 = time.process_time()
            vals = [consistency(a, b, pose, s.consistency_tolerance, s.free_margin).consistency
                    for a, b, pose in prepared[v]]
            best[v] = min(best[v], time.process_time() - t0)
            mean[v] = float(np.mean(vals))
    base = best[variants[0]]
    print(f"{Path(args.log).name}: {len(pairs)} pairs, best of {args.rounds} rounds")
    for v in variants:
        print(f"  cap {v[0]:g} window {v[1]}: {1000 * best[v] / len(pairs):.2f} ms a pair "
              f"(x{best[v] / base:.2f}), mean consistency {mean[v]:.4f}")


if __name__ == "__main__":
    main()
