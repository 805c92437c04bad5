"""Files a run writes into its output folder, each written atomically.

- ``trajectory.tum``: one pose per input scan at the scan's stamp, sorted by stamp
  (TUM and evo need increasing stamps; a log whose clock went backwards keeps
  every pose, just in time order).  Logs whose stamps are not unique (some
  corrected Radish logs give every scan the same stamp) use the scan index as the
  time stamp instead, with a warning; `output_stamps` says which rule applied.
- ``trajectory_kitti.txt``: the same poses as KITTI rows (in the same order),
  ``trajectory_kitti_times.txt`` their stamps.
- ``graph.g2o``: keyframe poses and every odometry and accepted loop constraint.
- ``loops.csv``: one row per loop candidate (accepted or rejected, and why).
- ``summary.json``, ``config.yaml``: what happened and with which parameters.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.atomic_write import write_text_atomic
from data.errors import warn
from data.trajectory_io import write_kitti, write_tum
from data.types import Trajectory

Array = NDArray[np.float64]


def output_stamps(stamps: Array, source: str) -> tuple[Array, str]:
    """Stamps for the trajectory files: the scan stamps when unique, else the scan index."""
    stamps = np.asarray(stamps, dtype=float)
    if len(np.unique(stamps)) == len(stamps):
        return stamps, "scan stamps"
    warn(
        f"{source}: scan stamps are not unique ({len(stamps) - len(np.unique(stamps))} "
        "duplicates): trajectory files use the scan index as the time stamp"
    )
    return np.arange(len(stamps), dtype=float), "scan index"


def write_trajectories(out: Path, stamps: Array, poses: Array) -> dict[str, Path]:
    """``trajectory.tum`` (sorted by stamp) and the KITTI pair, from planar poses ``(N, 3)``."""
    order = np.argsort(stamps, kind="stable")
    traj = Trajectory.from_xytheta(np.asarray(stamps)[order], np.asarray(poses)[order])
    paths = {
        "tum": out / "trajectory.tum",
        "kitti": out / "trajectory_kitti.txt",
        "kitti_times": out / "trajectory_kitti_times.txt",
    }
    write_tum(paths["tum"], traj)
    write_kitti(paths["kitti"], traj)
    write_text_atomic(paths["kitti_times"], "".join(f"{t:.6f}\n" for t in traj.stamps))
    return paths


@dataclass(slots=True)
class LoopRecord:
    """One loop-closure candidate as reported in ``loops.csv``.

    `relative` is the pose of keyframe `b` in the frame of keyframe `a` (x, y, theta),
    from the geometric check (NaN when the check did not produce one).  `consistency`
    is the free-space consistency of the two submaps in [0, 1], from a check without a
    pose prior (NaN for the others).
    """

    keyframe_a: int
    keyframe_b: int
    stamp_a: float
    stamp_b: float
    search: str
    accepted: bool
    reason: str
    prefilter_distance: float = float("nan")
    prefilter_rank: int = -1
    verifier_distance: float = float("nan")
    score: float = float("nan")
    fitness: float = float("nan")
    rms: float = float("nan")
    inlier_ratio: float = float("nan")
    consistency: float = float("nan")
    relative: Array = field(default_factory=lambda: np.full(3, np.nan))
    rejected_by_gnc: bool = False
    prior: bool = False


LOOP_COLUMNS = (
    "keyframe_a", "keyframe_b", "stamp_a", "stamp_b", "search", "prior", "accepted",
    "rejected_by_gnc", "reason", "prefilter_distance", "prefilter_rank", "verifier_distance",
    "score", "fitness", "rms", "inlier_ratio", "consistency", "dx", "dy", "dtheta",
)


def write_loops_csv(path: Path, records: Sequence[LoopRecord]) -> Path:
    """``loops.csv``: one row per candidate, columns `LOOP_COLUMNS`."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(LOOP_COLUMNS)
    fields = LOOP_COLUMNS[:-3]
    for r in records:
        # The attributes themselves (`dataclasses.asdict` would deep-copy each record
        # first, most of the time this took on thousands of candidates).
        row = [getattr(r, c) for c in fields] + list(np.asarray(r.relative, dtype=float))
        writer.writerow(
            [f"{v:.6f}" if isinstance(v, float) else int(v) if isinstance(v, bool) else v
             for v in row]
        )
    write_text_atomic(path, buf.getvalue())
    return path


def read_loops_csv(path: Path) -> list[dict[str, Any]]:
    """Rows of a ``loops.csv`` as dicts (numbers parsed), for evaluation tools."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    out = []
    for row in rows:
        parsed: dict[str, Any] = {}
        for k, v in row.items():
            if k in ("search", "reason"):
                parsed[k] = v
            elif k in ("accepted", "prior", "rejected_by_gnc", "keyframe_a", "keyframe_b",
                       "prefilter_rank"):
                parsed[k] = int(v)
            else:
                parsed[k] = float(v)
        out.append(parsed)
    return out
