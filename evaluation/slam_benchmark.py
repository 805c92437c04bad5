"""`loopclosure bench slam`: our pipeline, wheel odometry and KISS-ICP on one log, side by side.

Methods (`METHODS`), each run over the same scans, read once into memory before any
timing (`load_input`; ``limit`` keeps the first N scans and stops reading there):

* ``pipeline``: `slam.pipeline.Mapper` with the given `PipelineConfig` (front end,
  keyframes, loop closure, iSAM2, final GNC); its per-scan poses are
  `MappingResult.scan_poses`.
* ``wheel``: the logged odometry alone (``make_odometry("wheel", config.wheel)``):
  one pose per scan, no loop closure.
* ``kiss-icp``: KISS-ICP alone on the scans lifted to z = 0
  (``make_odometry("kiss-icp", config.kiss_icp)``, seeded with the wheel increment
  when the scans carry odometry), no loop closure.

All three report poses of the sensor in the odometry frame of the first scan
(``(x, y, theta)`` [m, m, rad]), one per scan, so they are directly comparable.
Per method: wall seconds of the run (reading excluded) and milliseconds per scan.
A method that raises (a bug, e.g. a solver failure; not bad input) is reported as
failed, with a warning and its error in its row, and the other methods still run.

Measures
--------
* **Relations metric** (`evaluation.relations_metric`, Kümmerle et al. 2009) of the
  per-scan trajectory, over the relations whose two stamps are both among the scans
  read (within 1 ms); ``relations_total`` counts those, the file's count is in the
  document's ``relations`` section.  Duplicate stamps keep their first scan.
* **ATE / RPE** (`evaluation.trajectory_error`) against a reference trajectory
  (``reference``: a TUM file, or ``reference_from_log``: the poses logged in the
  input, for GMapping-corrected logs).  Trajectories are stamped as `loopclosure
  run` stamps its output (`slam.outputs.output_stamps`): the scan stamps when they
  are unique, else the scan index (0, 1, ...), so a reference written from such a
  log must use the scan index too.
* **Loop closures** of the pipeline (`evaluation.loop_metrics.evaluate_loops`,
  default tolerances: 2 m, 0.2 m, 2 deg): counts (proposed = every candidate
  verified, accepted = kept after the final GNC, rejected by the check, rejected
  by GNC) and precision / recall against each reference available, for the final
  loops and for the loops the geometric check accepted (``before_gnc``); with an
  output folder, every candidate's verdict and error against each reference in
  ``pipeline/loops_vs_reference.csv`` / ``loops_vs_relations.csv`` (`loop_verdicts`).  Loops are
  evaluated in scan-index time: every keyframe is stamped with its scan index and
  the reference pose of a keyframe is looked up at its scan's (output) stamp, so a
  log whose clock runs backwards (Intel) still orders queries correctly.

Reference poses from the relations (`relations_reference`)
-------------------------------------------------------------
Relations are between scan stamps, rarely at keyframes, so the reference is a
small pose graph solved with Levenberg-Marquardt (`slam.optimize.optimize`, LAGO
start, Gaussian factors):

* nodes: every scan that is an end of a relation (stamp within 1 ms, first scan of
  a duplicated stamp) and every keyframe of the pipeline between the first and
  the last such scan (in scan order); node key = scan index;
* relation edges: the relation's planar delta, standard deviations
  `RELATION_SIGMA` (1 cm, 1 cm, 0.25 deg): tight;
* gap edges between consecutive nodes (scan order): the *gap odometry* increment,
  with the `slam.odometry.MotionNoise` default wheel model applied to the path
  length and the summed turning along the gap (weak: 10 cm after 1 m);
* the first node is held at its gap-odometry pose.

The gap odometry is the pipeline's front-end odometry (``odometry_poses``: scan-to-map
ICP by default, computed before and independently of any loop closure).  A keyframe
has a reference pose when it is a relation node or when the two relation nodes
around it are at most `max_gap_m` (2 m) of gap-odometry path apart; loops touching
any other keyframe are *unverifiable* (counted).

Why not the logged wheel odometry: on Intel the robot often turns in place between
two relation nodes (140-220 degrees with under 0.5 m of path), and the wheel
odometry's heading over such a turn is several degrees off even after the
relations pin both ends.  Measured on the first 3,000 Intel scans: with wheel gaps,
48 of 189 verifiable accepted loops came out "false" by 2-7 degrees; checking
every third of them (16) against the two raw scans alone, the scans overlapped
better at the loop's relative pose than at the reference's in all 16 (share of
points within 5 cm of the other scan 0.26-0.83 against 0.02-0.45), and a plain
scan-to-scan ICP started from the reference's pose converged to the loop's pose
in 14; with front-end
gaps none is false.  The relations themselves are not exact either: over the
in-place turn between Intel scans 202 and 244 the hand-verified relation differs
from raw scan-to-scan ICP by 8 cm and 1.4 degrees, so the reference is good to
roughly 0.1 m / 1 degree there, inside the 0.2 m / 2 degree tolerance of a true loop.

Independence: nothing of the pipeline's loop closures enters this graph.  Its
only long-range constraints are the hand-verified relations; the gap odometry
fills at most `max_gap_m` of path between two relation nodes (on Intel: a median
of 6 scans, 0.35 m) and comes from the front end, which runs before the loop
detector and never receives anything from it or from the back end.  The
pipeline's keyframes choose *where* the reference is read, never its values.  The
reference's own fit to the relations is reported (``fit_trans_mean_m``,
``fit_rot_mean_deg``).

GMapping-corrected logs carry the corrected poses in their odometry fields: the
wheel row would be the reference itself.  ``odometry_noise=SEED`` replaces every
scan's odometry with the simulator's drifting wheel-odometry model
(`data.sim.motion.wheel_odometry`, default `OdometryNoise`, generator seeded with
SEED) applied to the logged poses, as ``benchmarks/odometry.py`` does; the logged
poses stay available as the reference (``reference_from_log``), which therefore
requires ``odometry_noise``.
"""

from __future__ import annotations

import dataclasses
import itertools
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data import se2
from data.errors import DataWarning, UserError, warn
from data.types import PointCloud, Relation, Scan, Trajectory
from evaluation.loop_metrics import LoopMetrics, LoopProposal, evaluate_loops
from evaluation.relations_metric import lookup, relations_metric
from evaluation.trajectory_error import associate, trajectory_errors, umeyama
from slam.config import PipelineConfig
from slam.odometry import MotionNoise, make_odometry, scan_odometry
from slam.pipeline import Mapper, MappingResult

Array = NDArray[np.float64]
Progress = Callable[[str, int, int], None]
"""``progress(stage, done, total)``: called while loading and running each method."""

METHODS: tuple[str, ...] = ("pipeline", "wheel", "kiss-icp")
RELATION_SIGMA: tuple[float, float, float] = (0.01, 0.01, float(np.radians(0.25)))
"""Standard deviations (x [m], y [m], theta [rad]) of a relation edge of the reference."""
RELATION_TOLERANCE = 1e-3
"""Relation stamps match scan stamps within this [s] (as `relations_metric`)."""


def _noop(stage: str, done: int, total: int) -> None:
    return None


def parse_methods(text: str) -> list[str]:
    """Comma-separated method names (`METHODS`, or ``all``), in the given order, unique."""
    names = [n.strip().lower() for n in text.split(",") if n.strip()]
    names = ["kiss-icp" if n in ("kiss", "kissicp", "kiss_icp") else n for n in names]
    if names == ["all"]:
        return list(METHODS)
    if not names:
        raise UserError(f"--methods needs at least one of {', '.join(METHODS)}")
    unknown = [n for n in names if n not in METHODS]
    if unknown:
        raise UserError(
            f"unknown method(s) {', '.join(unknown)}; choose from {', '.join(METHODS)} or all"
        )
    return list(dict.fromkeys(names))


# ------------------------------------------------------------------------------ input


@dataclass(slots=True)
class SlamInput:
    """The scans every method maps, in source order (``scan.index`` = position).

    Attributes:
        name: the source as shown in reports (its path).
        scans: the scans (odometry replaced when `odometry_noise` is set).
        read_s: seconds spent reading them.
        logged_poses: ``(N, 3)`` odometry poses as logged (before any replacement), or
            None when some scan has none.
        odometry_noise: seed of the synthetic wheel odometry, or None (logged odometry).
    """

    name: str
    scans: list[Scan | PointCloud]
    read_s: float
    logged_poses: Array | None
    odometry_noise: int | None = None

    @property
    def stamps(self) -> Array:
        """``(N,)`` scan stamps [s] as logged."""
        return np.array([float(s.stamp) for s in self.scans])


def load_input(
    path: Path,
    *,
    limit: int | None = None,
    odometry_noise: int | None = None,
    topic: str | None = None,
    odom_topic: str | None = None,
    strict: bool = False,
    progress: Progress = _noop,
) -> SlamInput:
    """Read the first `limit` scans (all when None) of a log or bag into memory.

    Raises:
        UserError / DataError: missing or unreadable input, `limit` < 2, fewer than two
            scans, `odometry_noise` on input without odometry or on point clouds.
    """
    from data.sources import open_source

    if limit is not None and limit < 2:
        raise UserError(f"--limit must be at least 2 scans, got {limit}")
    if odometry_noise is not None and odometry_noise < 0:
        raise UserError(f"--odometry-noise must be a seed >= 0, got {odometry_noise}")
    source = open_source(path, topic=topic, odom_topic=odom_topic, strict=strict)
    start = time.perf_counter()
    total = limit or 0
    scans: list[Any] = []
    for n, scan in enumerate(itertools.islice(iter(source), limit), 1):
        scans.append(scan if scan.index == n - 1 else dataclasses.replace(scan, index=n - 1))
        if n % 100 == 0:
            progress("reading", n, max(total, n))
    progress("reading", len(scans), len(scans))
    read_s = time.perf_counter() - start
    if len(scans) < 2:
        raise UserError(f"{path}: {len(scans)} scan(s) read; the benchmark needs at least 2")
    odom = [scan_odometry(s) for s in scans]
    logged = np.array(odom) if all(o is not None for o in odom) else None
    if odometry_noise is not None:
        if logged is None or any(isinstance(s, PointCloud) for s in scans):
            missing = sum(o is None for o in odom)
            raise UserError(
                f"{path}: --odometry-noise needs planar scans that all carry odometry "
                f"({missing} of {len(scans)} have none)"
            )
        scans = synthetic_odometry(scans, logged, odometry_noise)
    return SlamInput(str(path), scans, read_s, logged, odometry_noise)


def synthetic_odometry(scans: Sequence[Scan], poses: Array, seed: int) -> list[Scan]:
    """`scans` with ``odom`` replaced by drifting wheel odometry of the true `poses` ``(N, 3)``.

    The simulator's model (`data.sim.motion.wheel_odometry`, default `OdometryNoise`,
    ``numpy.random.default_rng(seed)``); the first odometry pose equals the first pose.
    """
    from data.sim.motion import OdometryNoise, wheel_odometry

    noisy = wheel_odometry(np.asarray(poses, float), OdometryNoise(), np.random.default_rng(seed))
    return [dataclasses.replace(s, odom=o) for s, o in zip(scans, noisy, strict=True)]


def evaluation_stamps(stamps: Array) -> tuple[Array, str]:
    """Stamps of the evaluated trajectories: the scan stamps if unique, else the scan index.

    The rule of `slam.outputs.output_stamps` (without its warning).
    """
    stamps = np.asarray(stamps, dtype=float)
    if len(np.unique(stamps)) == len(stamps):
        return stamps, "scan stamps"
    return np.arange(len(stamps), dtype=float), "scan index"


# ---------------------------------------------------------------------------- methods


@dataclass(slots=True)
class MethodRun:
    """One method's per-scan trajectory and cost.

    Attributes:
        method: a name of `METHODS`.
        poses: ``(N, 3)`` sensor pose of every scan (x [m], y [m], theta [rad]); None
            when the method failed.
        wall_s: wall seconds of the run (scans already in memory; until the failure).
        statuses: front-end status counts.
        result: the pipeline's full result (``pipeline`` only).
        error: ``"ExceptionType: first line of its message"`` when the method failed.
    """

    method: str
    poses: Array | None
    wall_s: float
    statuses: dict[str, int] = field(default_factory=dict)
    result: MappingResult | None = None
    error: str | None = None


def run_pipeline(
    scans: Sequence[Scan | PointCloud], config: PipelineConfig, progress: Progress = _noop
) -> MethodRun:
    """Map `scans` with `Mapper(config)`; Ctrl-C propagates (a partial run is no result)."""
    total = len(scans)
    start = time.perf_counter()
    mapper = Mapper(config)

    def step(n: int, keyframes: int, loops: int) -> None:
        if n % 10 == 0 or n == total:
            progress("pipeline", n, total)

    result = mapper.run(scans, progress=step)
    wall = time.perf_counter() - start
    if result.interrupted:
        raise KeyboardInterrupt
    return MethodRun("pipeline", result.scan_poses, wall, dict(result.odometry_status), result)


def run_odometry(
    name: str,
    scans: Sequence[Scan | PointCloud],
    config: PipelineConfig,
    progress: Progress = _noop,
) -> MethodRun:
    """One front end alone over `scans` (``wheel`` or ``kiss-icp``, config from `config`)."""
    section = {"wheel": config.wheel, "kiss-icp": config.kiss_icp}[name]
    total = len(scans)
    poses = np.zeros((total, 3))
    statuses: dict[str, int] = {}
    start = time.perf_counter()
    odometry = make_odometry(name, section)
    for n, scan in enumerate(scans):
        estimate = odometry.process(scan)
        poses[n] = estimate.pose
        statuses[estimate.status] = statuses.get(estimate.status, 0) + 1
        if (n + 1) % 10 == 0 or n + 1 == total:
            progress(name, n + 1, total)
    return MethodRun(name, poses, time.perf_counter() - start, statuses)


# ----------------------------------------------------------------------- references


def relations_in_range(relations: Sequence[Relation], stamps: Array) -> list[Relation]:
    """The relations whose two stamps are both scan stamps (within `RELATION_TOLERANCE`)."""
    if not relations:
        return []
    t1 = np.array([r.t1 for r in relations])
    t2 = np.array([r.t2 for r in relations])
    ok = (lookup(stamps, t1, RELATION_TOLERANCE) >= 0) & (
        lookup(stamps, t2, RELATION_TOLERANCE) >= 0
    )
    return [r for r, keep in zip(relations, ok, strict=True) if keep]


def _first_of_duplicates(stamps: Array) -> tuple[Array, NDArray[np.intp]]:
    """Sorted unique stamps and the index of the first scan of each."""
    order = np.argsort(stamps, kind="stable")
    uniq, first = np.unique(stamps[order], return_index=True)
    return uniq, order[first]


def trajectory_at_stamps(stamps: Array, poses: Array) -> Trajectory:
    """Per-scan poses as a trajectory sorted by stamp, first scan of a duplicated stamp."""
    uniq, idx = _first_of_duplicates(np.asarray(stamps, float))
    return Trajectory.from_xytheta(uniq, np.asarray(poses, float)[idx])


@dataclass(slots=True)
class RelationsReference:
    """Reference poses of keyframes solved from the relations (module docstring).

    Attributes:
        scan_index: ``(K,)`` scan index of every keyframe that has a reference pose.
        poses: ``(K, 3)`` their reference poses (frame of the gap odometry).
        nodes: poses in the graph; relations: relation edges used.
        keyframes: keyframes asked for; gap_odometry: which odometry filled the gaps.
        fit_trans_mean_m, fit_rot_mean_deg: relations metric of the solved nodes.
        node_index, node_poses: every node (scan index, pose), for plots.
    """

    scan_index: NDArray[np.intp]
    poses: Array
    nodes: int
    relations: int
    keyframes: int
    gap_odometry: str
    fit_trans_mean_m: float
    fit_rot_mean_deg: float
    node_index: NDArray[np.intp]
    node_poses: Array

    def trajectory(self) -> Trajectory:
        """The keyframe reference in scan-index time (stamp = scan index)."""
        return Trajectory.from_xytheta(self.scan_index.astype(float), self.poses)

    def to_json(self) -> dict[str, Any]:
        """Summary figures."""
        return {
            "nodes": self.nodes,
            "relations": self.relations,
            "keyframes": self.keyframes,
            "keyframes_with_reference": len(self.scan_index),
            "gap_odometry": self.gap_odometry,
            "fit_trans_mean_m": self.fit_trans_mean_m,
            "fit_rot_mean_deg": self.fit_rot_mean_deg,
        }


def _gap_information(odometry: Array, a: NDArray[np.intp], b: NDArray[np.intp]) -> Array:
    """``(M, 3, 3)`` information of the gap edges ``a[m] -> b[m]`` (module docstring)."""
    step = se2.between(odometry[:-1], odometry[1:])
    path = np.concatenate([[0.0], np.cumsum(np.hypot(step[:, 0], step[:, 1]))])
    turn = np.concatenate([[0.0], np.cumsum(np.abs(step[:, 2]))])
    dist, rot = path[b] - path[a], turn[b] - turn[a]
    m = MotionNoise()
    var = np.column_stack([
        m.along_per_m**2 * dist + m.along_per_rad**2 * rot + m.min_sigma_xy**2,
        m.lateral_per_m**2 * dist + m.lateral_per_rad**2 * rot + m.min_sigma_xy**2,
        m.rot_per_m**2 * dist + m.rot_per_rad**2 * rot + m.min_sigma_theta**2,
    ])
    info = np.zeros((len(a), 3, 3))
    info[:, [0, 1, 2], [0, 1, 2]] = 1.0 / var
    return info


def relations_reference(
    stamps: Array,
    relations: Sequence[Relation],
    keyframe_index: Sequence[int],
    odometry: Array,
    *,
    gap_odometry: str = "front end",
    max_gap_m: float = 2.0,
) -> RelationsReference:
    """Reference poses of the keyframes from `relations` (module docstring).

    Args:
        stamps: ``(N,)`` scan stamps [s] (as logged).
        relations: relations (those with a stamp not among `stamps` are ignored).
        keyframe_index: scan index of every keyframe.
        odometry: ``(N, 3)`` gap odometry, one pose per scan.
        gap_odometry: its name, for the report.
        max_gap_m: longest gap-odometry path between two relation nodes over which a
            keyframe still gets a reference pose [m].
    """
    from slam.optimize import optimize
    from slam.pose_graph import PoseGraph

    stamps = np.asarray(stamps, float)
    odometry = np.asarray(odometry, float).reshape(-1, 3)
    uniq, first = _first_of_duplicates(stamps)
    rels = relations_in_range(relations, stamps)
    t1 = np.array([r.t1 for r in rels])
    t2 = np.array([r.t2 for r in rels])
    i1 = first[lookup(uniq, t1, RELATION_TOLERANCE)] if rels else np.zeros(0, np.intp)
    i2 = first[lookup(uniq, t2, RELATION_TOLERANCE)] if rels else np.zeros(0, np.intp)
    keep = i1 != i2
    i1, i2 = i1[keep], i2[keep]
    rels = [r for r, k in zip(rels, keep, strict=True) if k]
    deltas = [se2.from_matrix(r.delta) for r in rels]
    kf = np.asarray(keyframe_index, dtype=np.intp)
    empty = RelationsReference(np.zeros(0, np.intp), np.zeros((0, 3)), 0, 0, len(kf),
                               gap_odometry, float("nan"), float("nan"),
                               np.zeros(0, np.intp), np.zeros((0, 3)))
    if len(i1) == 0:
        return empty
    rel_nodes = np.unique(np.concatenate([i1, i2]))
    lo, hi = rel_nodes[0], rel_nodes[-1]
    nodes = np.unique(np.concatenate([rel_nodes, kf[(kf >= lo) & (kf <= hi)]]))

    # Graph keys are node positions 0..M-1 (gtsam's LAGO wants consecutive keys).
    graph = PoseGraph(dim=2)
    for key, scan in enumerate(nodes):
        graph.add_pose(key, odometry[scan])
    graph.fixed = {0}
    a, b = nodes[:-1], nodes[1:]
    gap_delta = se2.between(odometry[a], odometry[b])
    for k, (d, info) in enumerate(zip(gap_delta, _gap_information(odometry, a, b), strict=True)):
        graph.add_odometry(k, k + 1, d, info)
    rel_info = np.diag(1.0 / np.square(RELATION_SIGMA))
    for i, j, d in zip(np.searchsorted(nodes, i1), np.searchsorted(nodes, i2), deltas,
                       strict=True):
        graph.add_loop(int(i), int(j), d, rel_info)
    solved = optimize(graph, kernel="none", method="lm", init="lago").poses
    node_poses = np.array([solved[k] for k in range(len(nodes))])

    at_rel = np.searchsorted(nodes, rel_nodes)
    fit = relations_metric(Trajectory.from_xytheta(stamps[rel_nodes], node_poses[at_rel]), rels,
                           RELATION_TOLERANCE)
    # Keyframes covered: relation nodes, or bracketed by relation nodes close in path.
    step = se2.between(odometry[:-1], odometry[1:])
    path = np.concatenate([[0.0], np.cumsum(np.hypot(step[:, 0], step[:, 1]))])
    inside = kf[(kf >= lo) & (kf <= hi)]
    after = np.searchsorted(rel_nodes, inside, side="left")
    before = np.searchsorted(rel_nodes, inside, side="right") - 1
    on_node = rel_nodes[np.minimum(after, len(rel_nodes) - 1)] == inside
    gap = path[rel_nodes[np.minimum(after, len(rel_nodes) - 1)]] - path[rel_nodes[before]]
    covered = np.unique(inside[on_node | (gap <= max_gap_m)])
    pos = np.searchsorted(nodes, covered)
    return RelationsReference(
        scan_index=covered,
        poses=node_poses[pos],
        nodes=len(nodes),
        relations=len(i1),
        keyframes=len(kf),
        gap_odometry=gap_odometry,
        fit_trans_mean_m=fit.trans_abs_mean,
        fit_rot_mean_deg=fit.rot_abs_mean_deg,
        node_index=nodes,
        node_poses=node_poses,
    )


def keyframe_reference(
    reference: Trajectory, eval_stamps: Array, keyframe_index: Sequence[int],
    max_diff: float = 0.01,
) -> Trajectory:
    """A reference trajectory's poses at the keyframes, re-stamped with their scan index.

    Keyframes whose (evaluation) stamp the reference lacks (within `max_diff` s) are left
    out; their loops become unverifiable.
    """
    kf = np.asarray(keyframe_index, dtype=np.intp)
    hit = lookup(reference.stamps, np.asarray(eval_stamps, float)[kf], max_diff)
    ok = hit >= 0
    return Trajectory(kf[ok].astype(float), reference.poses[hit[ok]])


def loop_proposals(result: MappingResult, *, after_gnc: bool = True) -> list[LoopProposal]:
    """The pipeline's loop candidates as proposals in scan-index time (stamp = scan index).

    `relative` is the query keyframe's pose in the match keyframe's frame; the score is
    the geometric check's fitness (as `loopclosure run`'s demo report); accepted means
    kept after the final GNC (`after_gnc`) or accepted by the check.
    """
    kfs = result.keyframes
    out = []
    for e in result.loops:
        c = e.candidate
        accepted = c.accepted and not (after_gnc and e.rejected_by_gnc)
        out.append(LoopProposal(
            float(kfs[c.match].scan_index), float(kfs[c.query].scan_index),
            np.asarray(c.relative, float),
            c.verification.fitness if c.verification else 0.0, accepted,
        ))
    return out


def loop_evaluation(result: MappingResult, reference: Trajectory) -> dict[str, Any]:
    """Precision / recall of the pipeline's loops against a keyframe reference (scan-index
    time, see `keyframe_reference`), final loops and ``before_gnc``."""
    kf_index = np.array([k.scan_index for k in result.keyframes], dtype=float)
    final = evaluate_loops(loop_proposals(result), reference, kf_index)
    before: LoopMetrics = evaluate_loops(loop_proposals(result, after_gnc=False), reference,
                                         kf_index)
    doc: dict[str, Any] = final.to_json()
    doc["verifiable"] = final.proposals - final.unverifiable
    doc["keyframes_with_reference"] = len(reference)
    doc["before_gnc"] = {k: before.to_json()[k] for k in
                         ("accepted", "true_positives", "false_positives", "precision", "recall")}
    return doc


LOOP_VERDICT_COLUMNS = (
    "scan_a", "scan_b", "stage", "accepted", "rejected_by_gnc", "fitness",
    "reference_distance_m", "error_m", "error_deg", "verdict",
)


def loop_verdicts(result: MappingResult, reference: Trajectory) -> list[dict[str, Any]]:
    """Every loop candidate of a run judged against a keyframe reference, one row each.

    Columns `LOOP_VERDICT_COLUMNS`: the two keyframes' scan indices (older first), the
    search stage, whether the check accepted it and GNC then dropped it, the check's
    fitness, the reference distance of the two poses and the error of the candidate's
    relative pose against the reference; ``verdict`` is ``true`` / ``false`` (by
    `evaluate_loops`' rule, for every candidate, accepted or not) or ``unverifiable``.
    What a user reads to see *which* loops a method let through, and by how much.
    """
    kf_index = np.array([k.scan_index for k in result.keyframes], dtype=float)
    proposals = loop_proposals(result, after_gnc=False)
    metrics = evaluate_loops(proposals, reference, kf_index)
    rows = []
    for e, p, true, err in zip(result.loops, proposals, metrics.is_true, metrics.errors,
                               strict=True):
        verifiable = bool(np.isfinite(err[0]))
        rows.append({
            "scan_a": int(p.stamp_a), "scan_b": int(p.stamp_b), "stage": e.candidate.source,
            "accepted": int(e.candidate.accepted), "rejected_by_gnc": int(e.rejected_by_gnc),
            "fitness": p.score, "reference_distance_m": err[0], "error_m": err[1],
            "error_deg": err[2],
            "verdict": ("true" if true else "false") if verifiable else "unverifiable",
        })
    return rows


def write_loop_verdicts(path: Path, rows: Sequence[dict[str, Any]]) -> Path:
    """`loop_verdicts` rows as CSV (floats with 6 decimals, NaN as empty)."""
    import csv

    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, LOOP_VERDICT_COLUMNS, lineterminator="\n")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (("" if np.isnan(v) else f"{v:.6f}") if isinstance(v, float)
                                 else v) for k, v in row.items()})
    return path


def loop_counts(result: MappingResult) -> dict[str, Any]:
    """Keyframes and loop-candidate counts of a pipeline run."""
    checked = [e for e in result.loops if e.candidate.accepted]
    gnc = sum(e.rejected_by_gnc for e in checked)
    return {
        "keyframes": len(result.keyframes),
        "proposed": len(result.loops),
        "accepted": len(checked) - gnc,
        "rejected_by_check": len(result.loops) - len(checked),
        "rejected_by_gnc": gnc,
        "by_stage": {s: sum(1 for e in checked if e.candidate.source == s
                            and not e.rejected_by_gnc) for s in ("local", "global")},
    }


# --------------------------------------------------------------------------- the run


@dataclass(slots=True)
class SlamBenchmark:
    """Everything one `run_slam_benchmark` produced.

    Attributes:
        input: the scans; eval_stamps, stamp_rule: `evaluation_stamps` of them.
        runs: one `MethodRun` per method, in the order asked; reports: their measures
            (the ``methods`` entries of `json_document`).
        config: the pipeline's parameters.
        relations_file, relations_in_file, relations_used: the relations given, their
            count in the file, and those with both stamps among the scans.
        reference_name, reference: the reference trajectory (eval-stamped), if any.
        relations_ref: keyframe reference poses solved from the relations, if any.
    """

    input: SlamInput
    eval_stamps: Array
    stamp_rule: str
    runs: list[MethodRun]
    reports: list[dict[str, Any]]
    config: PipelineConfig
    relations_file: str | None = None
    relations_in_file: int = 0
    relations_used: list[Relation] = field(default_factory=list)
    reference_name: str | None = None
    reference: Trajectory | None = None
    relations_ref: RelationsReference | None = None

    def run_of(self, method: str) -> MethodRun | None:
        """The run of `method`, if it ran."""
        return next((r for r in self.runs if r.method == method), None)


def _check_reference(reference: Trajectory, eval_stamps: Array, rule: str, name: str) -> None:
    i_est, _ = associate(np.sort(eval_stamps), reference.stamps)
    if len(i_est) < 2:
        raise UserError(
            f"{name}: only {len(i_est)} of its {len(reference)} stamps match the stamps of the "
            f"{len(eval_stamps)} scans (within 0.01 s; the scans are stamped by {rule})"
        )


def run_slam_benchmark(
    data: SlamInput,
    methods: Sequence[str],
    config: PipelineConfig,
    *,
    relations: Sequence[Relation] | None = None,
    relations_file: str | None = None,
    reference: Trajectory | None = None,
    reference_name: str | None = None,
    progress: Progress = _noop,
) -> SlamBenchmark:
    """Run every method on `data`, then measure each (module docstring).

    `reference` is stamped like the evaluated trajectories (`evaluation_stamps`).
    Inputs are checked before the (slow) runs: relations with no pair of stamps among
    the scans, or a reference sharing fewer than two stamps with them, raise `UserError`.
    """
    stamps = data.stamps
    eval_stamps, rule = evaluation_stamps(stamps)
    used: list[Relation] = []
    if relations is not None:
        used = relations_in_range(relations, stamps)
        if not used:
            raise UserError(
                f"{relations_file or 'relations'}: none of its {len(relations)} relations has "
                f"both stamps among the {len(stamps)} scans read (stamps {stamps.min():.3f} .. "
                f"{stamps.max():.3f} s, matched within {RELATION_TOLERANCE * 1e3:g} ms)"
            )
    if reference is not None:
        _check_reference(reference, eval_stamps, rule, reference_name or "reference")
    runs = [_run_method(name, data, config, progress) for name in methods]

    bench = SlamBenchmark(
        data, eval_stamps, rule, runs, [], config, relations_file,
        len(relations) if relations is not None else 0, used, reference_name, reference,
    )
    pipeline = bench.run_of("pipeline")
    if pipeline is not None and pipeline.result is not None and used:
        result = pipeline.result
        gap, gap_name = result.odometry_poses, f"front end ({config.odometry})"
        bench.relations_ref = relations_reference(
            stamps, used, [k.scan_index for k in result.keyframes], gap, gap_odometry=gap_name
        )
    bench.reports = [_method_report(bench, run) for run in runs]
    return bench


def _run_method(
    name: str, data: SlamInput, config: PipelineConfig, progress: Progress
) -> MethodRun:
    """One method; a method that raises (other than bad usage or Ctrl-C) is reported as
    failed, with a warning, and the others still run."""
    start = time.perf_counter()
    try:
        if name == "pipeline":
            return run_pipeline(data.scans, config, progress)
        return run_odometry(name, data.scans, config, progress)
    except (UserError, KeyboardInterrupt):
        raise
    except Exception as exc:  # one method's failure must not lose the others
        first = (str(exc).strip().splitlines() or [""])[0]
        message = f"{type(exc).__name__}: {first}".rstrip(": ")
        warn(f"{name} failed on {data.name}: {message}")
        return MethodRun(name, None, time.perf_counter() - start, error=message)


def _method_report(bench: SlamBenchmark, run: MethodRun) -> dict[str, Any]:
    n = len(bench.input.scans)
    doc: dict[str, Any] = {
        "method": run.method,
        "wall_s": run.wall_s,
        "ms_per_scan": 1000.0 * run.wall_s / n,
        "relations": None,
        "ate": None,
        "loops": None,
        "odometry_status": run.statuses,
        "error": run.error,
    }
    if run.poses is None:
        return doc
    if bench.relations_used:
        traj = trajectory_at_stamps(bench.input.stamps, run.poses)
        doc["relations"] = relations_metric(traj, bench.relations_used,
                                            RELATION_TOLERANCE).to_json()
    if bench.reference is not None:
        est = trajectory_at_stamps(bench.eval_stamps, run.poses)
        doc["ate"] = trajectory_errors(est, bench.reference).to_json()
    if run.result is not None:
        loops = loop_counts(run.result)
        against: dict[str, Any] = {}
        kf_index = [k.scan_index for k in run.result.keyframes]
        if bench.reference is not None:
            against["reference"] = loop_evaluation(
                run.result, keyframe_reference(bench.reference, bench.eval_stamps, kf_index))
        if bench.relations_ref is not None:
            against["relations"] = loop_evaluation(run.result, bench.relations_ref.trajectory())
        primary = "reference" if "reference" in against else (
            "relations" if "relations" in against else None)
        loops["precision"] = against[primary]["precision"] if primary else None
        loops["recall"] = against[primary]["recall"] if primary else None
        loops["evaluated_against"] = primary
        loops["against"] = against
        doc["loops"] = loops
    return doc


# -------------------------------------------------------------------------- outputs


def json_document(bench: SlamBenchmark) -> dict[str, Any]:
    """The ``--json`` document: ``{"input", "scans", "methods": [...], ...}``."""
    rel = None
    if bench.relations_file is not None:
        rel = {"file": bench.relations_file, "in_file": bench.relations_in_file,
               "in_range": len(bench.relations_used)}
    return {
        "input": bench.input.name,
        "scans": len(bench.input.scans),
        "read_s": bench.input.read_s,
        "trajectory_stamps": bench.stamp_rule,
        "odometry_noise": bench.input.odometry_noise,
        "relations": rel,
        "reference": bench.reference_name,
        "relations_reference": bench.relations_ref.to_json() if bench.relations_ref else None,
        "methods": bench.reports,
    }


def _pm(mean: float | None, std: float | None, digits: int) -> str:
    if mean is None or not np.isfinite(mean):
        return "-"
    return f"{mean:.{digits}f} ± {std:.{digits}f}"


def _num(value: Any, fmt: str) -> str:
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "-"
    return format(value, fmt)


def _loop_cells(reps: list[dict[str, Any]], ref: str) -> list[list[str]]:
    """Precision / recall / verifiable rows of the loops evaluated against `ref`."""
    def ev(r: dict[str, Any]) -> dict[str, Any] | None:
        return r["loops"]["against"].get(ref) if r["loops"] else None

    def ratio(e: dict[str, Any] | None, value: str, num: int, den: int) -> str:
        return "-" if e is None else f"{e[value]:.3f} ({num}/{den})"

    rows = [[f"loop precision ({ref})"], [f"loop recall ({ref})"],
            [f"loops verifiable ({ref})"], [f"loop precision before GNC ({ref})"]]
    for r in reps:
        e = ev(r)
        b = e["before_gnc"] if e else None
        rows[0].append(ratio(e, "precision", *(
            (e["true_positives"], e["true_positives"] + e["false_positives"]) if e else (0, 0))))
        rows[1].append(ratio(e, "recall", *(
            (e["queries_recalled"], e["queries_with_loop"]) if e else (0, 0))))
        rows[2].append(f"{e['verifiable']}/{e['proposals']}" if e else "-")
        rows[3].append(ratio(b, "precision", *(
            (b["true_positives"], b["true_positives"] + b["false_positives"]) if b else (0, 0))))
    return rows


def table_rows(bench: SlamBenchmark) -> tuple[list[str], list[list[str]]]:
    """Headers (``measure``, then one column per method) and rows of the side-by-side table."""
    reps = bench.reports

    def row(label: str, cell: Callable[[dict[str, Any]], str]) -> list[str]:
        return [label, *[cell(r) for r in reps]]

    def sub(key: str, cell: Callable[[dict[str, Any]], str]) -> Callable[[dict[str, Any]], str]:
        return lambda r: cell(r[key]) if r[key] else "-"

    headers = ["measure", *[r["method"] for r in reps]]
    rows: list[list[str]] = []
    if any(r["error"] for r in reps):
        rows.append(row("status", lambda r: f"failed ({r['error'].split(':')[0]})"
                        if r["error"] else "ok"))
    rows += [row("wall [s]", lambda r: _num(r["wall_s"], ".2f")),
             row("ms / scan", lambda r: _num(r["ms_per_scan"], ".2f"))]
    if bench.relations_used:
        rows += [
            row("relations trans [m]", sub("relations", lambda m: _pm(
                m["trans_abs_mean"], m["trans_abs_std"], 4))),
            row("relations rot [deg]", sub("relations", lambda m: _pm(
                m["rot_abs_mean_deg"], m["rot_abs_std_deg"], 3))),
            row("relations used", sub("relations", lambda m: (
                f"{m['relations_used']}/{m['relations_total']}"))),
        ]
    if bench.reference is not None:
        rows += [
            row("ATE rmse [m]", sub("ate", lambda a: _num(a["ate_rmse"], ".4f"))),
            row("RPE rmse [m / deg]", sub("ate", lambda a: (
                f"{_num(a['rpe_trans_rmse'], '.4f')} / {_num(a['rpe_rot_rmse_deg'], '.3f')}"))),
        ]
    if any(r["loops"] for r in reps):
        for label, key in (("keyframes", "keyframes"), ("loops proposed", "proposed"),
                           ("loops accepted", "accepted"),
                           ("rejected by check", "rejected_by_check"),
                           ("rejected by GNC", "rejected_by_gnc")):
            rows.append(row(label, sub("loops", lambda m, key=key: str(m[key]))))
        for ref in ("reference", "relations"):
            if any(r["loops"] and ref in r["loops"]["against"] for r in reps):
                rows += _loop_cells(reps, ref)
    return headers, rows


def summary_lines(bench: SlamBenchmark) -> list[str]:
    """Plain-text lines about the inputs and references (printed under the table)."""
    data = bench.input
    lines = [f"{data.name}: {len(data.scans)} scans read in {data.read_s:.1f} s; "
             f"trajectories stamped by {bench.stamp_rule}"]
    if data.odometry_noise is not None:
        lines.append(f"odometry replaced by the simulator's drifting model (seed "
                     f"{data.odometry_noise}) of the logged poses")
    if bench.relations_file:
        lines.append(f"relations {bench.relations_file}: {len(bench.relations_used)} of "
                     f"{bench.relations_in_file} have both stamps among the scans")
    if bench.relations_ref is not None:
        r = bench.relations_ref
        lines.append(
            f"reference from relations: {r.nodes} nodes, {r.relations} relations, gap odometry "
            f"{r.gap_odometry}; fits the relations to {r.fit_trans_mean_m:.4f} m / "
            f"{r.fit_rot_mean_deg:.3f} deg; {len(r.scan_index)} of {r.keyframes} keyframes "
            "have a reference pose"
        )
    if bench.reference_name:
        lines.append(f"reference trajectory: {bench.reference_name}")
    return lines


def _plot(bench: SlamBenchmark, out: Path) -> Path:
    """Every method's trajectory (first-scan odometry frame) and the references, aligned."""
    from evaluation.plots import plot_trajectories

    done = [r for r in bench.runs if r.poses is not None]
    curves: dict[str, Array] = {r.method: r.poses[:, :2] for r in done}
    base = done[0] if done else None
    if bench.reference is not None and base is not None:
        est = trajectory_at_stamps(bench.eval_stamps, base.poses)
        i_est, i_ref = associate(est.stamps, bench.reference.stamps)
        ref_xy = bench.reference.poses[:, :3, 3]
        rot, t, _ = umeyama(ref_xy[i_ref], est.poses[i_est, :3, 3])
        curves["reference"] = (ref_xy @ rot.T + t)[:, :2]
    if bench.relations_ref is not None and bench.relations_ref.nodes:
        curves["reference (relations)"] = bench.relations_ref.node_poses[:, :2]
    loops = []
    pipeline = bench.run_of("pipeline")
    if pipeline is not None and pipeline.result is not None:
        res = pipeline.result
        for e in res.accepted_loops:
            a = res.keyframes[e.candidate.match].scan_index
            b = res.keyframes[e.candidate.query].scan_index
            loops.append((pipeline.poses[a, :2], pipeline.poses[b, :2]))
    return plot_trajectories(out / "trajectories.png", curves,
                             f"{Path(bench.input.name).name}: {len(bench.input.scans)} scans",
                             loops=loops)


def write_outputs(bench: SlamBenchmark, out: Path, *, write_map: bool = True) -> dict[str, Path]:
    """``report.md``, ``results.json``, ``trajectories.png``, ``<method>.tum`` and the
    pipeline's usual outputs in ``pipeline/`` (`slam.results.write_results`)."""
    from data.trajectory_io import write_tum
    from evaluation.report import image, table, write_report
    from slam.cli.common import write_json
    from slam.config_io import dump_config

    out.mkdir(parents=True, exist_ok=True)
    paths: dict[str, Path] = {}
    for run in bench.runs:
        if run.poses is None:
            continue
        path = out / f"{run.method}.tum"
        write_tum(path, trajectory_at_stamps(bench.eval_stamps, run.poses))
        paths[f"{run.method}_tum"] = path
    pipeline = bench.run_of("pipeline")
    if pipeline is not None and pipeline.result is not None:
        from slam.results import write_results

        folder = out / "pipeline"
        folder.mkdir(parents=True, exist_ok=True)
        dump_config(bench.config, folder / "config.yaml")
        with warnings.catch_warnings():  # the stamp rule is reported once, by us
            warnings.simplefilter("ignore", DataWarning)
            write_results(folder, pipeline.result, bench.input.name, wall_s=pipeline.wall_s,
                          write_map=write_map, map_config=bench.config.map)
        paths["pipeline"] = folder
        kf_index = [k.scan_index for k in pipeline.result.keyframes]
        if bench.reference is not None:
            ref = keyframe_reference(bench.reference, bench.eval_stamps, kf_index)
            paths["loops_vs_reference"] = write_loop_verdicts(
                folder / "loops_vs_reference.csv", loop_verdicts(pipeline.result, ref))
        if bench.relations_ref is not None:
            paths["loops_vs_relations"] = write_loop_verdicts(
                folder / "loops_vs_relations.csv",
                loop_verdicts(pipeline.result, bench.relations_ref.trajectory()))
    if bench.reference is not None and bench.reference_name == "logged poses":
        paths["reference_tum"] = out / "reference_logged.tum"
        write_tum(paths["reference_tum"], bench.reference)
    paths["plot"] = _plot(bench, out)
    doc = json_document(bench)
    write_json(out / "results.json", doc)
    paths["results"] = out / "results.json"
    headers, rows = table_rows(bench)
    paths["report"] = write_report(out / "report.md", "SLAM benchmark", [
        ("Inputs", "\n".join(f"- {line}" for line in summary_lines(bench))),
        ("Results", table(headers, rows)),
        ("Protocol", "Relations metric (Kümmerle et al. 2009) of each method's per-scan "
         "trajectory; ATE/RPE against the reference after SE(2) alignment; loop precision "
         "and recall of the pipeline's loops (2 m, 0.2 m, 2 deg) against the reference poses "
         "(see `evaluation/slam_benchmark.py`). Wall time excludes reading the log."),
        ("Trajectories", image(paths["plot"], out)),
    ])
    return paths


def logged_reference(data: SlamInput) -> Trajectory:
    """The poses logged in the input (GMapping-corrected logs) as a reference trajectory,
    stamped by `evaluation_stamps` and sorted."""
    if data.logged_poses is None:
        raise UserError(f"{data.name}: --reference-from-log needs odometry poses on every scan")
    if data.odometry_noise is None:
        raise UserError(
            "--reference-from-log needs --odometry-noise SEED: without it the logged poses "
            "are both the odometry every method starts from and the reference"
        )
    stamps, _ = evaluation_stamps(data.stamps)
    return trajectory_at_stamps(stamps, data.logged_poses)


def warn_without_odometry(data: SlamInput, methods: Sequence[str]) -> None:
    """One warning when the wheel method runs on scans without odometry."""
    if "wheel" in methods and data.logged_poses is None:
        missing = sum(scan_odometry(s) is None for s in data.scans)
        warn(f"{data.name}: {missing} of {len(data.scans)} scans have no odometry: the wheel "
             "row holds its last pose there")
