"""The input of `loopclosure bench loops`: scans and the reference poses of their keyframes.

`LoopSource` names the input the way a worker can read it itself: a CARMEN log or
ROS bag (`evaluation.slam_input.load_input`) with its reference (relations, a TUM
trajectory, or the log's own poses with synthetic odometry), or a simulated world
of the embedded demo (its ground truth is the reference).  `LoopSource.open` reads
it into a `LoopInput`: the label shown in reports, the scans, and the reference
callback of `evaluation.loop_bench.run_loop_bench` (keyframe reference poses
``(K, 3)`` [m, m, rad], NaN rows for keyframes without one; a relations reference
also tells its own uncertainty, `relations_reference_fn`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from data.errors import UserError

Progress = Callable[[str, int, int], None]


def _no_progress(stage: str, done: int, total: int) -> None:
    return None


def relations_reference_fn(data: Any, relations: Path, name: str | None = None) -> Any:
    """Reference of the keyframes from relations (`relations_reference`; NaN = none).

    `name`: the relations file as reported (default `relations`).  The callback has a
    second one, ``reference.sigmas(result, pairs)``: ``(n, 3)`` standard deviations
    (x, y [m], theta [rad]) of the reference's relative pose of keyframe pairs
    ``(match, query)`` (`relative_sigmas`; NaN where a keyframe has no reference)."""
    from data.relations import read_relations
    from evaluation.slam_reference import (
        relations_in_range,
        relations_reference,
        relative_sigmas,
    )

    rels = read_relations(relations)
    used = relations_in_range(rels, data.stamps)
    if not used:
        raise UserError(f"{name or relations}: none of its {len(rels)} relations has both "
                        f"stamps among the {len(data.scans)} scans read")
    solved: dict[int, Any] = {}  # id(result) -> (result, its RelationsReference)

    def _solved(result: Any) -> Any:
        if id(result) not in solved:
            kf = [k.scan_index for k in result.keyframes]
            solved.clear()
            solved[id(result)] = (result, relations_reference(data.stamps, used, kf,
                                                              result.odometry_poses))
        return solved[id(result)][1]

    def reference(result: Any) -> np.ndarray:
        kf = [k.scan_index for k in result.keyframes]
        ref = _solved(result)
        out = np.full((len(kf), 3), np.nan)
        pos = {int(s): i for i, s in enumerate(ref.scan_index)}
        for i, s in enumerate(kf):
            if s in pos:
                out[i] = ref.poses[pos[s]]
        return out

    def sigmas(result: Any, pairs: Any) -> np.ndarray:
        kf = np.array([k.scan_index for k in result.keyframes], np.intp)
        scans = kf[np.asarray(pairs, np.intp).reshape(-1, 2)]
        ref = _solved(result)
        out = np.full((len(scans), 3), np.nan)
        known = np.isin(scans, ref.scan_index).all(axis=1)
        if known.any():
            out[known] = relative_sigmas(ref.graph, ref.node_poses, scans[known])
        return out

    reference.sigmas = sigmas  # type: ignore[attr-defined]
    return reference


def trajectory_reference_fn(data: Any, trajectory: Any) -> Any:
    """Reference of the keyframes from a trajectory stamped like the scans."""
    from evaluation.slam_input import evaluation_stamps
    from evaluation.slam_reference import keyframe_reference

    stamps, _ = evaluation_stamps(data.stamps)

    def reference(result: Any) -> np.ndarray:
        kf = [k.scan_index for k in result.keyframes]
        ref = keyframe_reference(trajectory, stamps, kf)
        out = np.full((len(kf), 3), np.nan)
        pos = {int(s): i for i, s in enumerate(ref.stamps.astype(int))}
        xyt = ref.xytheta()
        for i, s in enumerate(kf):
            if s in pos:
                out[i] = xyt[pos[s]]
        return out

    moves: dict[int, tuple[Any, np.ndarray, np.ndarray]] = {}  # id(result) -> its moves

    def sigmas(result: Any, pairs: Any) -> np.ndarray:
        """The reference's relative-pose sigmas of keyframe pairs ``(match, query)``
        from its disagreement with its own scans (`evaluation.loop_bench_scan_truth`)."""
        from evaluation.loop_bench_scan_truth import disagreement_sigmas, scan_disagreement

        if id(result) not in moves:
            moves.clear()
            n = len(result.keyframes)
            moves[id(result)] = (result, reference(result), np.full((n, 2), np.nan))
        _, poses, mv = moves[id(result)]
        pr = np.asarray(pairs, np.intp).reshape(-1, 2)
        points = [k.points for k in result.keyframes]
        for key in np.unique(pr):
            if np.isnan(mv[key]).all():
                mv[key] = scan_disagreement(points, poses, int(key))
        return disagreement_sigmas(mv, pr)

    reference.sigmas = sigmas  # type: ignore[attr-defined]
    return reference


@dataclass(slots=True)
class LoopInput:
    """An opened input: `label` for reports, the `scans`, the `reference` callback."""

    label: str
    scans: Sequence[Any]
    reference: Callable[[Any], np.ndarray]


@dataclass(frozen=True, slots=True)
class LoopSource:
    """Where the input of ``bench loops`` is read from (module docstring).

    `path` None: the simulated `world` (``box`` / ``surface``) with `seed`.  Else the
    log or bag at `path` with one reference: `relations`, `reference` (TUM) or
    `reference_from_log`.  Relative paths are taken from `folder` (the caller's
    working folder, so that a worker started elsewhere finds them) and reported as
    given.
    """

    path: str | None = None
    world: str | None = None
    seed: int = 0
    limit: int | None = None
    odometry_noise: int | None = None
    topic: str | None = None
    relations: str | None = None
    reference: str | None = None
    reference_from_log: bool = False
    folder: str = "."

    def open(self, progress: Progress = _no_progress) -> LoopInput:
        """Read the scans and build the reference; `UserError` / `DataError`."""
        if self.path is None:
            return self._simulated()
        from data.trajectory_io import read_tum
        from evaluation.slam_input import load_input
        from evaluation.slam_reference import logged_reference

        here = Path(self.folder)
        data = load_input(here / self.path, limit=self.limit,
                          odometry_noise=self.odometry_noise, topic=self.topic,
                          progress=progress)
        if self.relations is not None:
            ref_fn = relations_reference_fn(data, here / self.relations, self.relations)
        elif self.reference is not None:
            ref_fn = trajectory_reference_fn(data, read_tum(here / self.reference))
        else:
            ref_fn = trajectory_reference_fn(data, logged_reference(data))
        return LoopInput(self.path, data.scans, ref_fn)

    def _simulated(self) -> LoopInput:
        from data.sim import simulate_run
        from data.sim.run import check_world
        from slam.cli.run_command import DEMO_SENSOR

        name = check_world(self.world or "box")
        run = simulate_run(name, seed=self.seed, **DEMO_SENSOR)
        truth = run.ground_truth.xytheta()
        scans: list[Any] = run.scans[: self.limit] if self.limit else run.scans

        def reference(result: Any) -> np.ndarray:
            return truth[[k.scan_index for k in result.keyframes]]

        return LoopInput(f"simulated {name} world (seed {self.seed})", scans, reference)
