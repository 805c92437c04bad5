"""Benchmark: the prefilter's recall of revisits per view, by the heading between passes.

Run from the repository root::

    python benchmarks/view_retrieval.py LOG [--relations FILE] [--set KEY=VALUE ...]

The log is mapped as ``loopclosure bench loops`` maps it (`evaluation.loop_bench`,
the loop searches off; a corrected log takes its logged poses as the reference and
the drifting odometry of seed 0).  For every keyframe with a revisit (an eligible
older keyframe within 2 m by the reference) the combined prefilter distance to every
eligible stored keyframe is taken in each view the loop detector has
(`PlaceDatabase.prefilter_distances`): the keyframe's own description (``own``), its
wide view (``wide``, the map of its last ``loops.wide_keyframes`` keyframes; only
the keyframes that have one), and the two together, merged by the smaller distance
(``min``) or interleaved by rank (``interleaved``,
`evaluation.loop_bench_queries.interleaved_order`, as ``bench loops`` merges them).
It prints recall@1 and recall@10 (a true place among the K first) over all revisits
and by the heading difference between the query and its nearest true place
(same direction, oblique, opposite) by the reference, and the median path between
consecutive keyframes.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evaluation.loop_bench import mapped_input  # noqa: E402
from evaluation.loop_bench_input import LoopSource  # noqa: E402
from evaluation.loop_bench_misses import nearest_place, revisit_queries  # noqa: E402
from evaluation.loop_bench_queries import interleaved_order  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402
from slam.config_io import apply_overrides  # noqa: E402

HEADING_BINS = ((0.0, 45.0), (45.0, 135.0), (135.0, 180.1))  # degrees
VIEWS = ("own", "wide", "min", "interleaved")


def _hits(order: np.ndarray, near: np.ndarray) -> dict[int, bool]:
    return {k: bool(near[order[:k]].any()) for k in (1, 10)}


def retrieval(log: str, relations: str | None, config: PipelineConfig
              ) -> tuple[np.ndarray, dict[str, list[dict[int, bool]]], float]:
    """``(heading differences [deg], hits per view and K, median keyframe step [m])``
    over the revisits of `log` (module docstring)."""
    source = LoopSource(str(Path(log).resolve()), relations=relations,
                        reference_from_log=relations is None,
                        odometry_noise=None if relations else 0, folder=str(Path.cwd()))
    mapper, _, ref = mapped_input(source, config)
    det, db, wide = mapper.detector, mapper.detector.database, mapper.detector.wide_database
    keys = np.array(db.keys, dtype=np.intp)  # rows in key order
    wide_keys = np.array(wide.keys, dtype=np.intp) if wide is not None else keys[:0]
    turns: list[float] = []
    hits: dict[str, list[dict[int, bool]]] = {v: [] for v in VIEWS}
    for k, rows, _, near in revisit_queries(det, ref):
        turns.append(nearest_place(ref, k, keys[rows[near]])[2])
        own = db.prefilter_distances(db.descriptors(k), rows)[0]
        other = np.full(len(rows), np.inf)
        asked = det.wide_key(k)
        if wide is not None and asked is not None and asked in wide:
            w_rows = np.flatnonzero(np.isin(wide_keys, keys[rows]))
            at = np.searchsorted(keys[rows], wide_keys[w_rows])  # both in key order
            other[at] = wide.prefilter_distances(wide.descriptors(asked), w_rows)[0]
        orders = {
            "own": np.argsort(own, kind="stable"),
            "wide": np.argsort(other, kind="stable"),
            "min": np.argsort(np.minimum(own, other), kind="stable"),
            "interleaved": interleaved_order([own, other])[0],
        }
        for view, order in orders.items():
            hits[view].append(_hits(order, near))
    covered = np.isfinite(ref).all(axis=1)
    step = np.hypot(*np.diff(ref[covered, :2], axis=0).T)
    return np.array(turns), hits, float(np.median(step)) if len(step) else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log")
    ap.add_argument("--relations")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    config = apply_overrides(PipelineConfig(), args.set)
    turn, hits, step = retrieval(args.log, args.relations, config)
    print(f"{Path(args.log).name}: {len(turn)} revisits; keyframes {step:.2f} m apart "
          "(median)")
    for kk in (1, 10):
        print(f"recall@{kk}: " + "  ".join(
            f"{v} {np.mean([h[kk] for h in hits[v]]):.3f}" for v in VIEWS))
        for lo, hi in HEADING_BINS:
            m = (turn >= lo) & (turn < hi)
            if not m.any():
                continue
            print(f"  heading {lo:g}-{min(hi, 180.0):g} deg ({int(m.sum())}): " + "  ".join(
                f"{v} {np.mean([h[kk] for h, s in zip(hits[v], m, strict=True) if s]):.3f}"
                for v in VIEWS))

if __name__ == "__main__":
    main()
