"""A bar for the free-space consistency that needs no loop truth: the front end's own
overlaps.

Run from the repository root::

    python benchmarks/consistency_bar_rule.py LOG [LOG ...] [--relations FILE] [--step S]
        [--bar 0.92] [--surface-cap C ...] [--return-window W ...] [--variant C:W ...]
        [--confirm-window W ...] [--out FILE.npz]

Each log is mapped as ``loopclosure bench loops`` maps it (`scan_origins_bench.py`).
For every `step`-th keyframe k, two submaps made of disjoint scans overlap by
construction: the trailing submap of k (keyframes ``k - n .. k``, a query's submap)
and that of ``m = k + n + 1`` (keyframes ``k + 1 .. m``), n the pipeline's submap
neighbours, at their front-end relative pose: a true overlap with no fit error and
no loop.  Their consistency (`loopclosure.free_space` (2)) is computed with the free
space about the keyframe (1) and about each scan (1') (each submap's scans from the
keyframe store, as the check gets them; the query at the check's ``source_voxel``,
the other at the search's ``submap_voxel``).

The rule: the bar of (1') is the value that these pairs, pooled over every log
given, fall below as often as they fall below the bar of (1) (``--bar``, the
config's by default): the same share of the front end's own true overlaps refused
by either model.  Prints each log's and the pooled quantiles and that bar.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


from scan_origins_bench import loop_source  # noqa: E402

from data import se2  # noqa: E402
from evaluation.loop_bench import mapped_input  # noqa: E402
from loopclosure.free_space import ScanFreeSpace, Submap, consistency  # noqa: E402
from loopclosure.registration import voxel_downsample  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402


def matched_bar(keyframe: np.ndarray, scans: np.ndarray, bar: float) -> float:
    """The value of `scans` below which the same share of pairs lies as of `keyframe`
    below `bar` (the share's quantile of `scans`; pairs paired, shares pooled)."""
    share = float(np.mean(np.asarray(keyframe) < bar))
    return float(np.quantile(np.asarray(scans), share))


def pairs_of(log: str, relations: str | None, step: int,
             caps=(1.0,)) -> tuple[np.ndarray, dict[float, np.ndarray]]:
    """``(keyframe, {cap: scans})`` consistencies of the log's front-end pairs
    (docstring; `pairs_in_caps`)."""
    cfg = PipelineConfig()
    cfg.loops.check.free_space_origins = "scans"
    source = loop_source(log, relations)
    mapper, _, _ = mapped_input(source, cfg)
    return pairs_in_caps(mapper, step, caps)


def pairs_in(mapper, step: int) -> tuple[np.ndarray, np.ndarray]:
    """`pairs_of` on a mapped `slam.pipeline.Mapper` (its store keeping the scans' free space)."""
    one, per = pairs_in_caps(mapper, step, ((1.0, 0),))
    return one, per[(1.0, 0)]


def pairs_in_caps(mapper, step: int, caps) -> tuple[np.ndarray, dict]:
    """`pairs_in` with (1') at each variant of `caps`: a surface cap
    (`ScanFreeSpace.surface_cap`; 1: the margin along the ray) or a pair (cap,
    return window) (`ScanFreeSpace.return_window`): the keyframe model's and each
    variant's consistencies."""
    det = mapper.detector
    check, s = det.config.check, det.config.check.search
    n = mapper.config.submap_neighbours()
    from loopclosure.fast_icp import voxel_downsample_fast

    one, per = [], {c: [] for c in caps}
    for k in range(n, len(mapper.keyframes.keyframes) - n - 1, step):
        m = k + n + 1
        q_pts = voxel_downsample_fast(mapper.trailing_map(k, n), check.source_voxel)
        c_pts = voxel_downsample(mapper.trailing_map(m, n), s.submap_voxel)
        if len(q_pts) == 0 or len(c_pts) == 0:
            continue
        pose = se2.between(mapper._keyframe(m).odom_pose, mapper._keyframe(k).odom_pose)
        args = (pose, s.consistency_tolerance, s.free_margin)
        one.append(consistency(Submap.of(q_pts, s.free_bins), Submap.of(c_pts, s.free_bins),
                               *args).consistency)
        q_free, c_free = det.submap_free_space(k, last=k), det.submap_free_space(m, last=m)
        for variant, out in per.items():
            v = variant if isinstance(variant, tuple) else (variant,)
            both = len(v) > 2 and bool(v[2])  # (5): confirmed by (1)
            out.append(consistency(
                Submap.of(q_pts, s.free_bins,
                          scans=ScanFreeSpace(q_free.poses, q_free.ranges, *v[:2]),
                          confirm=both),
                Submap.of(c_pts, s.free_bins,
                          scans=ScanFreeSpace(c_free.poses, c_free.ranges, *v[:2]),
                          confirm=both),
                *args).consistency)
    return np.array(one), {c: np.array(v) for c, v in per.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("logs", nargs="+")
    ap.add_argument("--relations", help="for a log without its own reference (one log)")
    ap.add_argument("--step", type=int, default=3)
    ap.add_argument("--bar", type=float, default=PipelineConfig().loops.check.min_consistency)
    ap.add_argument("--surface-cap", type=float, action="append",
                    help="(1'') with this cap (`ScanFreeSpace.surface_cap`) besides (1') "
                         "along the ray; repeatable")
    ap.add_argument("--return-window", type=int, action="append",
                    help="(4) with this window (`ScanFreeSpace.return_window`), margin "
                         "along the ray; repeatable")
    ap.add_argument("--variant", action="append", metavar="CAP:WINDOW",
                    help="(1'') with cap CAP and (4) with window WINDOW; repeatable")
    ap.add_argument("--confirm-window", type=int, action="append", metavar="W",
                    help="the confirmed model (5), (1) and (1') with returns window W "
                         "(0: none); repeatable")
    ap.add_argument("--out", help="save every log's pairs here (npz: keyframe, then "
                                  "each cap's row, 1 first)")
    args = ap.parse_args()
    caps = ([(1.0, 0)] + [(c, 0) for c in args.surface_cap or [] if c != 1.0]
            + [(1.0, w) for w in args.return_window or [] if w > 0]
            + [(float(v.split(":")[0]), int(v.split(":")[1])) for v in args.variant or []]
            + [(1.0, w, 1) for w in args.confirm_window or []])
    q = [1, 5, 10, 25, 50]
    pooled_one, pooled_per, saved = [], {c: [] for c in caps}, {}
    for log in args.logs:
        one, per = pairs_of(log, args.relations, args.step, caps)
        pooled_one.append(one)
        saved[Path(log).name.split("-corrected")[0].split(".")[0]] = np.stack(
            [one] + [per[c] for c in caps])
        print(f"{Path(log).name}: {len(one)} pairs; below {args.bar} with (1) "
              f"{np.mean(one < args.bar):.3f}; quantiles {q}%: (1) "
              f"{np.round(np.percentile(one, q), 3).tolist()}", flush=True)
        for c in caps:
            pooled_per[c].append(per[c])
            quant = np.round(np.percentile(per[c], q), 3).tolist()
            print(f"  cap {c[0]:g} window {c[1]}{' confirmed' if len(c) > 2 else ''}: "
                  f"quantiles {quant}; "
                  f"matched bar {matched_bar(one, per[c], args.bar):.3f}", flush=True)
    one = np.concatenate(pooled_one)
    print(f"pooled: {len(one)} pairs; below {args.bar} with (1) {np.mean(one < args.bar):.3f}")
    for c in caps:
        bar = matched_bar(one, np.concatenate(pooled_per[c]), args.bar)
        print(f"  cap {c[0]:g} window {c[1]}{' confirmed' if len(c) > 2 else ''}: "
              f"matched bar {bar:.3f}")
    if args.out:
        np.savez(args.out, **saved)


if __name__ == "__main__":
    main()
