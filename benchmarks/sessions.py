"""Benchmark: multi-session mapping on split real logs, in one run.

Run from the repository root::

    python benchmarks/sessions.py [--data DIR] [--seeds 0,1,2] [--logs NAME,...]
        [--no-pairs]

For every log (Intel, ``carmen/intel.clf.bz2`` with its logged odometry, scored by
the relations metric against ``carmen/intel.relations``; the corrected logs of
``carmen-corrected/`` with the synthetic drifting odometry `bench slam` gives them,
``--odometry-noise 0``, scored by ATE against their GMapping poses):

1. the whole log is mapped once (`slam.pipeline.Mapper`, defaults): the single-run
   figure, and the reference frame of the join check;
2. its first half is mapped and saved (``session.npz``, written and read back);
3. for every seed, its second half, with its odometry moved by a random rigid
   transform (translation up to 50 m, any heading; `moved`), is mapped into that
   saved map: joined or not, after how many keyframes and metres, the inter-session
   loops, the join transform's difference from the one the single run implies, and
   the error of the joined map (all scans of both halves) beside the single run's.
   A join is *wrong* when it put the second half in the wrong place: with reference
   poses (the corrected logs), when the second half, aligned to the reference by the
   rigid transform that aligns the first half, is off by more than 1 m (RMS) beyond
   the single run's same figure; without them (Intel), when the transform is more
   than 1 m or 5 degrees from the single run's;
4. unless ``--no-pairs``: the second half of every log of another building mapped
   into this log's saved map, which must never join.

Printed: one row per log and seed, the different-building matrix, and the totals
(joins, wrong joins, false joins between buildings).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from data import se2
from data.relations import read_relations
from data.types import Trajectory
from evaluation.relations_metric import relations_metric
from evaluation.slam_input import load_input
from evaluation.trajectory_error import umeyama
from slam.config import PipelineConfig
from slam.pipeline import Mapper
from slam.session_file import read_saved_map, write_saved_map

CORRECTED = ("freiburg-101", "seattle", "orebro", "belgioioso", "intel-corrected",
             "freiburg-campus")
BUILDING = {"intel-corrected": "intel"}
"""Logs of one building (intel-corrected is the Intel log as GMapping corrected it)."""


def moved(scans: list, seed: int) -> tuple[list, np.ndarray]:
    """The scans with their odometry moved by a seeded random rigid transform."""
    rng = np.random.default_rng(seed)
    r, a = 50.0 * np.sqrt(rng.uniform()), rng.uniform(-np.pi, np.pi)
    move = np.array([r * np.cos(a), r * np.sin(a), rng.uniform(-np.pi, np.pi)])
    return [dataclasses.replace(s, odom=se2.compose(move, s.odom)) for s in scans], move


def aligned_error(poses: np.ndarray, reference: np.ndarray, fit: slice = slice(None),
                  judged: slice = slice(None)) -> float:
    """RMS position error [m] of the `judged` scans after the rigid alignment that best
    fits the `fit` scans to the reference (scans in the same order)."""
    p = np.column_stack([poses[:, :2], np.zeros(len(poses))])
    q = np.column_stack([reference[: len(poses), :2], np.zeros(len(poses))])
    rot, t, _ = umeyama(p[fit], q[fit])
    return float(np.sqrt(np.mean(np.sum((p[judged] @ rot.T + t - q[judged]) ** 2, axis=1))))


def ate(poses: np.ndarray, reference: np.ndarray) -> float:
    """RMS position error after the best rigid alignment [m] (scans in the same order)."""
    return aligned_error(poses, reference)


def relations_error(stamps: np.ndarray, poses: np.ndarray, relations: list) -> float:
    order = np.argsort(stamps, kind="stable")
    traj = Trajectory.from_xytheta(stamps[order], poses[order])
    lo, hi = stamps.min(), stamps.max()
    inside = [r for r in relations if lo <= min(r.t1, r.t2) and max(r.t1, r.t2) <= hi]
    return relations_metric(traj, inside).trans_abs_mean


class Log:
    """One log: its scans, its reference, its single run and its saved first half."""

    def __init__(self, name: str, path: Path, relations: Path | None) -> None:
        self.name = name
        data = load_input(path, odometry_noise=None if relations else 0)
        self.scans = data.scans
        self.reference = data.logged_poses
        self.relations = read_relations(relations) if relations else None
        self.half = len(self.scans) // 2
        start = time.process_time()
        single = Mapper(PipelineConfig(), name=name).run(self.scans)
        self.single_cpu = time.process_time() - start
        self.single_poses = single.scan_poses
        self.single = self.score(single.scan_stamps, single.scan_poses)
        first = Mapper(PipelineConfig(), name=f"{name} first half").run(self.scans[: self.half])
        self.saved_path = Path(tempfile.mkdtemp()) / "session.npz"
        write_saved_map(self.saved_path, first.saved_map)

    def placed_error(self, poses: np.ndarray) -> float:
        """RMS error [m] of the second half once the first half is aligned to the
        reference (how well the join placed it; reference poses needed)."""
        return aligned_error(poses, self.reference, slice(None, self.half),
                             slice(self.half, None))

    def score(self, stamps: np.ndarray, poses: np.ndarray) -> float:
        if self.relations is not None:
            return relations_error(stamps, poses, self.relations)
        return ate(poses, self.reference[: len(poses)])

    def second_half(self, seed: int) -> tuple[list, np.ndarray]:
        return moved(self.scans[self.half:], seed)


def join(saved_path: Path, scans: list, name: str) -> tuple[Mapper, object, float]:
    mapper = Mapper(PipelineConfig(), saved=read_saved_map(saved_path), name=name)
    start = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = mapper.run(scans)
    return mapper, result, time.process_time() - start


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2]
                    / "shared" / "data")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--logs", default="intel," + ",".join(CORRECTED))
    ap.add_argument("--no-pairs", action="store_true")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    logs: list[Log] = []
    for name in args.logs.split(","):
        if name == "intel":
            path, rel = args.data / "carmen/intel.clf.bz2", args.data / "carmen/intel.relations"
        else:
            stem = name if name.endswith("-corrected") else f"{name}-corrected"
            path, rel = args.data / f"carmen-corrected/{stem}.log.gz", None
        if not path.exists():
            print(f"skip {name}: {path} missing")
            continue
        logs.append(Log(name, path, rel))
        print(f"{name}: {len(logs[-1].scans)} scans, single run "
              f"{'relations' if rel else 'ATE'} {logs[-1].single:.4f} m "
              f"({logs[-1].single_cpu:.0f} s CPU)", flush=True)
    print("\nlog | seed | joined | at keyframe | after [m] | loops | transform error "
          "[m / deg] | error joined / single [m] | ratio | CPU [s]")
    joins = wrong = runs = 0
    for log in logs:
        for seed in seeds:
            scans, _ = log.second_half(seed)
            mapper, result, cpu = join(log.saved_path, scans, f"{log.name} second half")
            runs += 1
            s = result.sessions[-1]
            if not s.joined:
                print(f"{log.name} | {seed} | no | - | - | - | - | - | - | {cpu:.0f}", flush=True)
                continue
            joins += 1
            own = mapper.odometry_poses[0]
            truth = se2.compose(log.single_poses[log.half], se2.inverse(own))
            t = np.asarray(s.transform)
            dt = float(np.hypot(*(t[:2] - truth[:2])))
            da = float(np.degrees(abs(se2.wrap_angle(t[2] - truth[2]))))
            if log.relations is None:  # reference poses: where did the join put it?
                bad = log.placed_error(result.scan_poses) > log.placed_error(
                    log.single_poses) + 1.0
            else:
                bad = dt > 1.0 or da > 5.0
            wrong += bad
            err = log.score(result.scan_stamps, result.scan_poses)
            print(f"{log.name} | {seed} | {'WRONG' if bad else 'yes'} | "
                  f"{s.joined_at_keyframe} | {s.joined_after_m:.1f} | {s.loops} | "
                  f"{dt:.2f} / {da:.2f} | {err:.4f} / {log.single:.4f} | "
                  f"{err / log.single:.3f} | {cpu:.0f}", flush=True)
    false_joins = pairs = 0
    if not args.no_pairs and len(logs) > 1:
        print("\nmap \\ new session (second halves): joined?")
        for a in logs:
            row = []
            for b in logs:
                if BUILDING.get(a.name, a.name) == BUILDING.get(b.name, b.name):
                    row.append("-")
                    continue
                scans, _ = b.second_half(seeds[0])
                _, result, _ = join(a.saved_path, scans, f"{b.name} into {a.name}")
                pairs += 1
                joined = result.sessions[-1].joined
                false_joins += joined
                row.append("JOINED" if joined else "no")
            print(f"{a.name}: " + " ".join(f"{b.name}={v}" for b, v in zip(logs, row,
                                                                           strict=True)),
                  flush=True)
    print(f"\nsame log: {joins} of {runs} joined, {wrong} wrong joins; different "
          f"buildings: {false_joins} false joins in {pairs} pairs")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
