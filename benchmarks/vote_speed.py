"""Benchmark: CPU per query of the keypoint-pair vote at a database size, before vs after.

Run from the repository root::

    python benchmarks/vote_speed.py LOG[:RELATIONS] --cache DIR [--baseline REV]
        [--sizes 1000,10000] [--variant NAME:FIELD=VALUE,...] [--queries 50]

The log's keyframes are described as `benchmarks/local_vote.py` describes them (the
cache of `prefilter_misses.py`, FLIRT at 0.2 m steps, points within 15 m, 80
features) and cycled to each size (as many postings per key as a log of that many
keyframes like these).  Queries: `--queries` keyframes evenly spread, each moved by a
small rigid motion (0.013 rad, (0.031, -0.017) m) so that no query pair lies exactly
on a stored pair's cell edge.  `place_vote` of `--baseline` (git revision, read with
``git show``) and of the working tree vote the same queries in one process,
interleaved, best of 3 CPU (`time.process_time`); their scores are compared
(the number of differing scores is printed).  A `--variant` runs the working tree's
index only, with those `PairVoteConfig` fields.  Also printed: time to fill the index
(CPU s) and postings stored.
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from local_vote import keypoints  # noqa: E402
from prefilter_misses import mapped  # noqa: E402

from loopclosure import place_vote  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402


def baseline_module(rev: str):
    """`loopclosure/place_vote.py` of git revision `rev`, imported as a module."""
    text = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:loopclosure/place_vote.py"],
                          check=True, capture_output=True, text=True).stdout
    path = Path(tempfile.mkdtemp()) / "place_vote_baseline.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location("place_vote_baseline", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["place_vote_baseline"] = mod
    spec.loader.exec_module(mod)
    return mod


def moved(p: np.ndarray, o: np.ndarray, lab: np.ndarray) -> tuple:
    th = 0.013
    c, s = np.cos(th), np.sin(th)
    return p @ np.array([[c, s], [-s, c]]) + np.array([0.031, -0.017]), o + th, lab


def fill(module, cfg, items: list, size: int):
    index = module.PairVoteIndex(cfg)
    t0 = time.process_time()
    for i in range(size):
        p, o, lab = items[i % len(items)]
        index.add(p, o, lab % cfg.n_labels)
    return index, time.process_time() - t0


def timed(index, queries: list, n_labels: int) -> tuple[float, list]:
    t0 = time.process_time()
    out = [index.scores(p, o, lab % n_labels) for p, o, lab in queries]
    return (time.process_time() - t0) / len(queries), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log", help="LOG or LOG:RELATIONS")
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--baseline", default="main")
    ap.add_argument("--sizes", default="1000,10000")
    ap.add_argument("--queries", type=int, default=50)
    ap.add_argument("--variant", action="append", default=[])
    args = ap.parse_args()
    config = PipelineConfig()
    data = mapped(args.log, config, args.cache)
    kp = keypoints(data["own"], config, 0.2, 15.0, 80)
    items = list(kp.values())
    queries = [moved(*items[i]) for i in
               np.linspace(0, len(items) - 1, args.queries).astype(int)]
    old = baseline_module(args.baseline)
    print(f"{data['name']}: {len(items)} keyframes described, median "
          f"{np.median([len(v[0]) for v in items]):.0f} keypoints", flush=True)
    variants = {}
    for v in args.variant:
        name, _, rest = v.partition(":")
        kv = dict(item.split("=") for item in rest.split(",") if item)
        ints = ("neighbours", "n_labels", "length_slack")
        variants[name] = replace(place_vote.PairVoteConfig(), **{
            a: int(b) if a in ints else float(b) for a, b in kv.items()})
    for size in [int(s) for s in args.sizes.split(",")]:
        new_index, t_new_fill = fill(place_vote, place_vote.PairVoteConfig(), items, size)
        old_index, t_old_fill = fill(old, old.PairVoteConfig(), items, size)
        timed(old_index, queries[:1], 6)  # the baseline sorts its index on its first query
        timed(new_index, queries[:1], 6)  # numba compiles (or loads) on first use
        best_old = best_new = np.inf
        for _ in range(3):
            t, s_old = timed(old_index, queries, 6)
            best_old = min(best_old, t)
            t, s_new = timed(new_index, queries, 6)
            best_new = min(best_new, t)
        differ = sum(int((a != b).sum()) for a, b in zip(s_old, s_new, strict=True))
        print(f"  size {size}: postings {new_index.postings}; fill CPU s old {t_old_fill:.2f} "
              f"new {t_new_fill:.2f}; query CPU ms old {1000 * best_old:.2f} new "
              f"{1000 * best_new:.2f} (ratio old/new {best_old / best_new:.2f}); scores "
              f"differing {differ} of {size * len(queries)}", flush=True)
        del old_index
        for name, cfg in variants.items():
            index, t_fill = fill(place_vote, cfg, items, size)
            timed(index, queries[:1], cfg.n_labels)
            best = min(timed(index, queries, cfg.n_labels)[0] for _ in range(3))
            print(f"    {name}: postings {index.postings}; fill {t_fill:.2f} s; query CPU ms "
                  f"{1000 * best:.2f}", flush=True)


if __name__ == "__main__":
    main()
