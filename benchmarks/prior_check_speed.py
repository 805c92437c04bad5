"""The checks from a pose prior, replayed: a revision's `verify` against the working
tree's, in one process, outputs compared to the bit.

Two steps::

    python benchmarks/prior_check_speed.py collect LOG [LOG ...] --out CHECKS.pkl
    python benchmarks/prior_check_speed.py speed CHECKS.pkl --baseline REV [--repeat R]

``collect`` maps each log as ``loopclosure run LOG`` does (the default pipeline, the
front end in the mapper's process, the log's own odometry) and records every call
`loopclosure.candidate_checks.CandidateChecks._check_prior` makes to
`loopclosure.geometric_check.verify`: the query submap and the candidate's submap
(float64, as given: the replay is exact), the prior, its covariance, the offsets
and ``max_distance``.  The file stays outside the repository (data is never copied
in).

``speed`` replays every recorded check with revision REV's
`loopclosure.geometric_check` (``git show``, loaded beside the working tree's, on
the working tree's other modules) and with the working tree's, R passes, the two
codes interleaved check by check (a busy machine slows both alike).  Each code
keeps its own lazy grids of the candidates' submaps for a pass (least recently
used, 256 of them, as the loop detector keeps them: a grid's normals resolved by
one check serve the next), made outside the timed calls.  Per log it prints the
checks (accepted, stopped before ICP, rejected after ICP), the CPU seconds
(``time.process_time``) of each code's checks, best pass, their ratio (REV / now:
above 1 is faster now), the same for the rejected checks alone, and whether every
verdict, reason, relative pose, covariance and figure is the same to the bit.
"""

from __future__ import annotations

import argparse
import hashlib
import pickle
import sys
import tempfile
import time
from collections import OrderedDict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.exact_stage_speed import load_revision  # noqa: E402

SCREENS = ("no overlap", "no fit within")


def collect(logs: list[Path], out: Path) -> None:
    import loopclosure.candidate_checks as cc
    from evaluation.slam_input import load_input
    from loopclosure.warm_up import warm_up
    from slam.config import PipelineConfig
    from slam.pipeline import Mapper

    warm_up()
    real_verify = cc.verify
    targets: dict[str, np.ndarray] = {}
    records: list[dict] = []
    current = [""]

    def recording(query_points, candidate, **kw):
        if kw.get("prior") is not None:
            grid = kw.get("grid")
            target = np.array(grid.input_points if grid is not None else candidate.points,
                              dtype=float)
            tid = hashlib.sha1(target.tobytes()).hexdigest()
            targets.setdefault(tid, target)
            records.append({
                "log": current[0], "query": np.array(query_points, dtype=float),
                "target": tid, "prior": np.array(kw["prior"], dtype=float),
                "prior_covariance": (None if kw.get("prior_covariance") is None
                                     else np.array(kw["prior_covariance"], dtype=float)),
                "offsets": kw.get("offsets"), "max_distance": kw.get("max_distance"),
            })
        return real_verify(query_points, candidate, **kw)

    cc.verify = recording
    try:
        for log in logs:
            current[0] = log.name.split(".")[0]
            n0 = len(records)
            Mapper(PipelineConfig(front_end_worker=False)).run(load_input(log).scans)
            print(f"{current[0]}: {len(records) - n0} checks from a prior", flush=True)
    finally:
        cc.verify = real_verify
    with open(out, "wb") as fh:
        pickle.dump({"targets": targets, "records": records}, fh)


def _same(a, b) -> bool:
    """Every field of two `LoopVerification`s the same to the bit."""
    for name in type(a).__slots__:
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            x, y = np.asarray(x), np.asarray(y)
            if x.shape != y.shape or x.tobytes() != y.tobytes():
                return False
        elif isinstance(x, float) and isinstance(y, float):
            if np.float64(x).tobytes() != np.float64(y).tobytes():
                return False
        elif x != y:
            return False
    return True


class _Grids:
    """One code's lazy grids of the candidates' submaps (least recently used)."""

    def __init__(self, targets: dict, size: int = 256) -> None:
        self.targets, self.size = targets, size
        self.grids: OrderedDict[str, object] = OrderedDict()

    def get(self, tid: str, cfg):
        from loopclosure.fast_icp import TARGET_GRID_CELL, GridTarget

        grid = self.grids.get(tid)
        if grid is None:
            grid = GridTarget(self.targets[tid], cfg.icp, TARGET_GRID_CELL, lazy=True)
            self.grids[tid] = grid
            while len(self.grids) > self.size:
                self.grids.popitem(last=False)
        self.grids.move_to_end(tid)
        return grid


def _kind(reason: str) -> str:
    return ("accepted" if reason == "accepted" else
            "screened" if reason.startswith(SCREENS) else "rejected")


def speed(path: Path, baseline: str, repeat: int) -> None:
    import loopclosure.geometric_check as now_module
    from loopclosure.warm_up import warm_up
    from slam.config import PipelineConfig

    warm_up()
    with open(path, "rb") as fh:
        data = pickle.load(fh)
    targets, records = data["targets"], data["records"]
    cfg = PipelineConfig().loops.check
    with tempfile.TemporaryDirectory() as tmp:
        old_module = load_revision(baseline, "loopclosure/geometric_check.py", Path(tmp))
        codes = {"baseline": old_module.verify, "now": now_module.verify}
        logs = list(dict.fromkeys(r["log"] for r in records))
        print(f"{'log':<28} {'checks':>6} {'acc':>5} {'scr':>4} {'rej':>4} "
              f"{'old s':>7} {'new s':>7} {'ratio':>6} {'old rej':>7} {'new rej':>7} "
              f"{'ratio':>6}  outputs")
        for log in logs:
            rows = [r for r in records if r["log"] == log]
            best = {c: np.inf for c in codes}
            best_rej = {c: np.inf for c in codes}
            same = True
            kinds: list[str] = []
            for p in range(repeat):
                grids = {c: _Grids(targets) for c in codes}
                spent = dict.fromkeys(codes, 0.0)
                spent_rej = dict.fromkeys(codes, 0.0)
                kinds = []
                for i, r in enumerate(rows):
                    order = list(codes) if (i + p) % 2 == 0 else list(codes)[::-1]
                    out, dts = {}, {}
                    for c in order:
                        grid = grids[c].get(r["target"], cfg)
                        t0 = time.process_time()
                        out[c] = codes[c](r["query"], None, prior=r["prior"],
                                          prior_covariance=r["prior_covariance"],
                                          offsets=r["offsets"],
                                          max_distance=r["max_distance"], config=cfg,
                                          grid=grid)
                        dts[c] = time.process_time() - t0
                    same = same and _same(out["baseline"], out["now"])
                    kinds.append(_kind(out["now"].reason))
                    for c in codes:
                        spent[c] += dts[c]
                        if kinds[-1] == "rejected":
                            spent_rej[c] += dts[c]
                for c in codes:
                    best[c] = min(best[c], spent[c])
                    best_rej[c] = min(best_rej[c], spent_rej[c])
            count = {k: kinds.count(k) for k in ("accepted", "screened", "rejected")}
            print(f"{log:<28} {len(rows):>6} {count['accepted']:>5} {count['screened']:>4} "
                  f"{count['rejected']:>4} {best['baseline']:7.3f} {best['now']:7.3f} "
                  f"{best['baseline'] / best['now']:6.2f} {best_rej['baseline']:7.3f} "
                  f"{best_rej['now']:7.3f} {best_rej['baseline'] / max(best_rej['now'], 1e-9):6.2f}"
                  f"  {'identical' if same else 'DIFFER'}", flush=True)


def split(path: Path, baseline: str | None) -> None:
    """Where a check's CPU goes (the working tree's `verify`, or revision `baseline`'s,
    one pass, the mapper's grid cache): per log and verdict, the seconds of the whole
    checks, of the screens as `loopclosure.fast_icp.overlap_screen` computes them
    (every point of every guess),
    and of the ICP runs (`loopclosure.multi_start.register_multi`, the checks that
    reach it), each timed on its own grid state (the screen first, as `verify` runs
    it, on a copy of the grid)."""
    import copy

    from loopclosure.fast_icp import overlap_screen, voxel_downsample_fast
    from loopclosure.geometric_check import _offset_grid, verify
    from loopclosure.multi_start import initial_guesses, register_multi
    from loopclosure.warm_up import warm_up
    from slam.config import PipelineConfig

    warm_up()
    with open(path, "rb") as fh:
        data = pickle.load(fh)
    targets, records = data["targets"], data["records"]
    cfg = PipelineConfig().loops.check
    if baseline is not None:
        folder = tempfile.mkdtemp()
        verify = load_revision(baseline, "loopclosure/geometric_check.py", Path(folder)).verify
    print(f"{'log':<28} {'verdict':<9} {'checks':>6} {'whole s':>8} {'screen s':>8} "
          f"{'ICP s':>8} {'ICP runs':>8}")
    for log in dict.fromkeys(r["log"] for r in records):
        grids = _Grids(targets)
        sums: dict[str, list[float]] = {}
        for r in (r for r in records if r["log"] == log):
            grid = grids.get(r["target"], cfg)
            before = copy.deepcopy(grid)
            t0 = time.process_time()
            v = verify(r["query"], None, prior=r["prior"],
                       prior_covariance=r["prior_covariance"], offsets=r["offsets"],
                       max_distance=r["max_distance"], config=cfg, grid=grid)
            whole = time.process_time() - t0
            step = cfg.offsets if r["offsets"] is None else r["offsets"]
            guesses = initial_guesses(r["prior"], None, _offset_grid(step))
            source = voxel_downsample_fast(r["query"], cfg.source_voxel)
            t0 = time.process_time()
            overlap_screen(source, before, guesses, cfg.icp.max_correspondence_distance,
                           cfg.bound_reach)
            screen = time.process_time() - t0
            icp = 0.0
            kind = _kind(v.reason)
            if kind != "screened":
                t0 = time.process_time()
                register_multi(source, None, guesses, config=cfg.icp, keep=cfg.keep,
                               compiled=True, grid=before)
                icp = time.process_time() - t0
            row = sums.setdefault(kind, [0, 0.0, 0.0, 0.0, 0])
            row[0] += 1
            row[1] += whole
            row[2] += screen
            row[3] += icp
            row[4] += v.hypotheses
        for kind, (n, whole, screen, icp, runs) in sums.items():
            print(f"{log:<28} {kind:<9} {n:>6} {whole:8.3f} {screen:8.3f} {icp:8.3f} "
                  f"{runs:>8}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("collect")
    c.add_argument("logs", nargs="+", type=Path)
    c.add_argument("--out", type=Path, required=True)
    s = sub.add_parser("speed")
    s.add_argument("checks", type=Path)
    s.add_argument("--baseline", required=True, help="a revision")
    s.add_argument("--repeat", type=int, default=3)
    t = sub.add_parser("split")
    t.add_argument("checks", type=Path)
    t.add_argument("--baseline", help="a revision whose verify to time (default: the tree's)")
    args = parser.parse_args()
    if args.cmd == "collect":
        collect(args.logs, args.out)
    elif args.cmd == "split":
        split(args.checks, args.baseline)
    else:
        speed(args.checks, args.baseline, args.repeat)


if __name__ == "__main__":
    main()
