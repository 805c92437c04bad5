"""Benchmark of recognised objects as landmarks: recognition precision and ATE with / without.

Runs `slam.landmarks.run_landmarks` for one seed and scores it against the simulator's
ground truth:

- recognition precision = recognitions whose recognised library object is the object
  the cluster really is (identity, hence class too) / all accepted recognitions;
  ``None`` when nothing was recognised.  Class precision counts a recognition right
  when only the class matches.  Recall = correct recognitions / clusters of library
  objects.  The precision of the stripes alone (distance and ratio tests, no size
  verification) is the ablation.
- ATE (`evaluation.trajectory_error.trajectory_errors`, RMSE after rigid alignment)
  of the keyframe trajectory without landmarks (the wheel odometry, which is the
  optimum of the odometry-only graph) and with the landmark factors, against the
  true poses at the keyframe stamps.
- landmark position errors (estimate vs true object centre, both after the ATE
  alignment of the with-landmarks trajectory) and observation errors (measured
  range / bearing vs those of the true centre from the true keyframe pose).

Unit of work: one seed is one task (`LandmarksCell`, run by `landmarks_task`): the
experiment is simulated from its seed and configuration in the process that runs
it, which writes that seed's report when asked and returns its JSON figures.
`run_landmarks_cells` runs the seeds here in order or on a Dask cluster
(`evaluation.cluster`); the figures are the same either way, only the seconds differ.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data import se2
from data.types import Trajectory
from evaluation.trajectory_error import TrajectoryErrors, trajectory_errors
from slam.landmarks import LandmarkResult, LandmarkRunConfig, run_landmarks

Array = NDArray[np.float64]


def _precision(hits: int, total: int) -> float | None:
    return float(hits / total) if total else None


@dataclass(slots=True)
class LandmarksBenchmarkResult:
    """The experiment, its trajectory errors and wall time."""

    seed: int
    result: LandmarkResult
    ate_without: TrajectoryErrors
    ate_with: TrajectoryErrors
    seconds: float

    def landmark_errors(self) -> dict[str, float]:
        """Object name -> distance [m] of its landmark estimate from the true centre (after
        mapping the estimate through the with-landmarks trajectory's ATE alignment)."""
        res = self.result
        est = res.with_landmarks.landmarks
        if not est:
            return {}
        # Alignment used by the ATE: recover it from aligned vs estimated keyframe poses.
        p = res.with_landmarks.poses[:, :2]
        q = self.ate_with.aligned.xytheta()[:, :2]
        from evaluation.trajectory_error import umeyama

        rot, t, _ = umeyama(p, q)
        truth = {o.identity: o.pose[:2] for o in res.run.objects if o.identity >= 0}
        return {res.library.names[j]: float(np.linalg.norm(rot @ v + t - truth[j]))
                for j, v in est.items()}

    def observation_errors(self) -> tuple[Array, Array]:
        """Range [m] and bearing [rad] errors of every observation of a correctly
        recognised object, against the true centre seen from the true keyframe pose."""
        res = self.result
        dr, db = [], []
        for r in res.records:
            if r.observation is None or not r.correct:
                continue
            ob = r.observation
            pose = res.run.truth[res.keyframes[ob.keyframe]]
            centre = res.run.objects[r.truth].pose[:2]
            local = se2.transform_points(se2.inverse(pose), centre[None])[0]
            dr.append(ob.range - float(np.hypot(*local)))
            db.append(float(se2.wrap_angle(ob.bearing - np.arctan2(local[1], local[0]))))
        return np.array(dr), np.array(db)

    def to_json(self) -> dict[str, Any]:
        """The CLI's JSON (required keys first)."""
        res = self.result
        recs = res.records
        accepted = [r for r in recs if r.recognition.accepted]
        correct = [r for r in accepted if r.correct]
        class_ok = [r for r in accepted
                    if r.truth >= 0 and r.recognition.label == res.run.objects[r.truth].label]
        known = [r for r in recs if r.truth_identity >= 0]
        ng = [r for r in recs if r.recognition_stripes_only.accepted]
        ng_ok = [r for r in ng if r.recognition_stripes_only.identity == r.truth_identity]
        dr, db = self.observation_errors()
        lm_err = self.landmark_errors()
        sightings: dict[int, int] = {}
        for ob in res.observations:
            sightings[ob.landmark] = sightings.get(ob.landmark, 0) + 1
        return {
            "recognitions": len(accepted),
            "recognition_precision": _precision(len(correct), len(accepted)),
            "ate_without_m": self.ate_without.ate_rmse,
            "ate_with_m": self.ate_with.ate_rmse,
            "landmarks": len(res.with_landmarks.landmarks),
            "seed": self.seed,
            "clusters": len(recs),
            "clusters_of_library_objects": len(known),
            "clusters_of_unknown_objects": sum(1 for r in recs if r.truth >= 0
                                               and r.truth_identity < 0),
            "correct_recognitions": len(correct),
            "class_precision": _precision(len(class_ok), len(accepted)),
            "recognition_recall": float(len(correct) / len(known)) if known else 0.0,
            "ablation_stripes_only": {
                "recognitions": len(ng),
                "recognition_precision": _precision(len(ng_ok), len(ng)),
            },
            "vetoed_by_size": sum(1 for r in recs if r.recognition_stripes_only.accepted
                                  and r.recognition.size_verified is False),
            "object_loop_closures": int(sum(max(n - 1, 0) for n in sightings.values())),
            "sightings_per_landmark": {res.library.names[j]: n for j, n in sightings.items()},
            "landmark_error_m": lm_err,
            "observation_range_error_rms_m": float(np.sqrt(np.mean(dr**2))) if len(dr) else None,
            "observation_bearing_error_rms_rad": (float(np.sqrt(np.mean(db**2)))
                                                  if len(db) else None),
            "ate_without": self.ate_without.to_json(),
            "ate_with": self.ate_with.to_json(),
            "keyframes": len(res.keyframes),
            "scans": len(res.run.stamps),
            "scans_near_objects": len(res.run.scan_ids),
            "path_length_m": float(np.linalg.norm(np.diff(res.run.truth[:, :2], axis=0),
                                                  axis=1).sum()),
            "rejected_tracks": [t.rejected for t in res.rejected_tracks],
            "objects": [{"name": o.name, "class": o.label, "identity": o.identity,
                         "pose": o.pose.tolist()} for o in res.run.objects],
            "recognition_log": [
                {"truth": res.run.objects[r.truth].name if r.truth >= 0 else None,
                 "recognised": r.recognition.name or None,
                 "distance": r.recognition.distance if np.isfinite(r.recognition.distance)
                 else None,
                 "ratio": r.recognition.ratio, "accepted": r.recognition.accepted,
                 "stripes": len(r.cluster.scans)}
                for r in recs
            ],
            "seconds": self.seconds,
            "graph_error": {"initial": res.with_landmarks.initial_error,
                            "final": res.with_landmarks.final_error,
                            "iterations": res.with_landmarks.iterations},
            "config": res.config.to_json(),
        }


@dataclass(frozen=True, slots=True)
class LandmarksCell:
    """One task: the experiment for `seed` with `config`, its report written into
    `out` (`write_landmarks_report`) when given."""

    seed: int
    config: LandmarkRunConfig
    out: str | None = None


_PROGRESS: list[Callable[[str, int, int], None]] = []
"""The progress callback of the cells run in this process (none on a worker)."""


def landmarks_task(cell: LandmarksCell) -> dict[str, Any]:
    """One seed (`LandmarksCell`): its JSON figures (`LandmarksBenchmarkResult.to_json`),
    with ``outputs`` (the files written) when it has an output folder."""
    bench = run_landmarks_benchmark(cell.seed, cell.config, _PROGRESS[-1] if _PROGRESS else None)
    js = bench.to_json()
    if cell.out is not None:
        js["outputs"] = {k: str(v) for k, v in write_landmarks_report(bench, cell.out).items()}
    return js


def run_landmarks_cells(
    cells: list[LandmarksCell],
    *,
    cluster: str | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> list[dict[str, Any]]:
    """Every cell's figures, in order, here (with `progress`) or on `cluster`.

    Raises:
        UserError: a cell failed (its seed and error line).
    """
    from evaluation.cluster import map_tasks

    if progress is not None:
        _PROGRESS.append(progress)
    try:
        docs = []
        for o in map_tasks(landmarks_task, cells, cluster=cluster, retries=0,
                           description="bench landmarks", progress=cluster is not None):
            docs.append(o.result(f"bench landmarks, seed {o.item.seed}"))
    finally:
        if progress is not None:
            _PROGRESS.pop()
    return docs


def run_landmarks_benchmark(
    seed: int = 0,
    config: LandmarkRunConfig | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> LandmarksBenchmarkResult:
    """Run the landmark experiment for `seed` and compute the trajectory errors."""
    t0 = time.perf_counter()
    res = run_landmarks(seed, config, progress)
    stamps = res.run.stamps[res.keyframes]
    truth = Trajectory.from_xytheta(stamps, res.run.truth[res.keyframes])
    without = trajectory_errors(Trajectory.from_xytheta(stamps, res.without), truth)
    with_lm = trajectory_errors(Trajectory.from_xytheta(stamps, res.with_landmarks.poses), truth)
    return LandmarksBenchmarkResult(seed, res, without, with_lm, time.perf_counter() - t0)


def _plot_map(bench: LandmarksBenchmarkResult, path: Path) -> Path:
    """World, true / odometry / with-landmarks trajectories, objects and landmark estimates."""
    from evaluation.plots import plt, save_figure

    res = bench.result
    fig, ax = plt.subplots(figsize=(9, 7))
    for seg in res.run.world.segments:
        ax.plot(seg[:, 0], seg[:, 1], color="0.6", lw=0.6)
    truth = res.run.truth[res.keyframes]
    ax.plot(truth[:, 0], truth[:, 1], color="k", lw=1.0, label="ground truth")
    ax.plot(res.without[:, 0], res.without[:, 1], color="tab:orange", lw=0.9,
            label=f"odometry (ATE {bench.ate_without.ate_rmse:.2f} m)")
    ax.plot(res.with_landmarks.poses[:, 0], res.with_landmarks.poses[:, 1], color="tab:blue",
            lw=0.9, label=f"with landmarks (ATE {bench.ate_with.ate_rmse:.2f} m)")
    for o in res.run.objects:
        known = o.identity >= 0
        ax.plot(*o.pose[:2], marker="o" if known else "x", ms=6,
                color="tab:green" if known else "tab:red")
        ax.annotate(o.name, o.pose[:2], fontsize=6, xytext=(3, 3), textcoords="offset points")
    for j, p in res.with_landmarks.landmarks.items():
        ax.plot(*p, marker="+", ms=9, color="tab:blue")
        ax.annotate(res.library.names[j], p, fontsize=6, color="tab:blue", xytext=(3, -8),
                    textcoords="offset points")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("objects: o known, x unknown; + landmark estimates")
    ax.legend(fontsize=8, loc="best")
    ax.grid(True, lw=0.3)
    return save_figure(fig, path)


def _plot_stripes(bench: LandmarksBenchmarkResult, path: Path) -> Path:
    """Stripes of each correctly recognised object's first cluster beside its library entry."""
    from evaluation.plots import plt, save_figure
    from slam.landmarks.segmentation import cluster_stripes

    res = bench.result
    firsts: dict[int, Any] = {}
    for r in res.records:
        if r.correct and r.recognition.identity not in firsts:
            firsts[r.recognition.identity] = r
    n = max(len(firsts), 1)
    fig, axes = plt.subplots(1, n, figsize=(2.4 * n, 3.2), squeeze=False)
    for ax, (j, r) in zip(axes[0], sorted(firsts.items()), strict=False):
        for k, s in enumerate(cluster_stripes(r.cluster, res.library.resolution)):
            ax.plot(s[:, 0], -s[:, 1] + k, lw=0.5, color="tab:red")
        ax.set_title(f"{res.library.names[j]}\n{len(r.cluster.scans)} stripes, "
                     f"d={r.recognition.distance:.3f}", fontsize=8)
        ax.set_aspect("equal", adjustable="datalim")
        ax.axis("off")
    fig.suptitle("recognised clusters: push-broom stripes (lateral vs height, 2 mm units)",
                 fontsize=9)
    return save_figure(fig, path)


def write_landmarks_report(bench: LandmarksBenchmarkResult, out: str | Path) -> dict[str, Path]:
    """``report.md``, ``results.json``, ``map.png``, ``stripes.png`` in `out`."""
    from data.atomic_write import output_dir
    from evaluation.report import image, key_values, table, write_report
    from slam.json_io import write_json

    out_dir = output_dir(out)
    js = bench.to_json()
    paths = {
        "results": out_dir / "results.json",
        "map": _plot_map(bench, out_dir / "map.png"),
        "stripes": _plot_stripes(bench, out_dir / "stripes.png"),
    }
    write_json(paths["results"], js)
    headline = key_values({
        "seed": bench.seed,
        "path length [m]": js["path_length_m"],
        "object clusters": js["clusters"],
        "of library objects / unknown objects": (
            f"{js['clusters_of_library_objects']} / {js['clusters_of_unknown_objects']}"),
        "recognitions (accepted)": js["recognitions"],
        "recognition precision (identity and class)": js["recognition_precision"],
        "class precision": js["class_precision"],
        "recall (correct / clusters of library objects)": js["recognition_recall"],
        "precision of the stripes alone, no size verification (ablation)":
            js["ablation_stripes_only"]["recognition_precision"],
        "stripe matches vetoed by the size verification": js["vetoed_by_size"],
        "landmarks": js["landmarks"],
        "object-level loop closures (repeat sightings)": js["object_loop_closures"],
        "ATE without landmarks [m]": js["ate_without_m"],
        "ATE with landmarks [m]": js["ate_with_m"],
        "observation range error RMS [m]": js["observation_range_error_rms_m"],
        "observation bearing error RMS [rad]": js["observation_bearing_error_rms_rad"],
        "wall time [s]": js["seconds"],
    })
    log = table(["true object", "recognised", "distance", "ratio", "accepted", "stripes"],
                [[x["truth"], x["recognised"], x["distance"], x["ratio"], x["accepted"],
                  x["stripes"]] for x in js["recognition_log"]])
    lm = table(["object", "sightings", "landmark error [m]"],
               [[n, js["sightings_per_landmark"].get(n, 0), e]
                for n, e in js["landmark_error_m"].items()])
    sections = [
        ("Figures", headline),
        ("Recognitions", log),
        ("Landmarks", lm),
        ("Map", image(paths["map"], out_dir, "map") + "\n\n"
         + image(paths["stripes"], out_dir, "stripes")),
    ]
    paths["report"] = write_report(out_dir / "report.md", "Objects as landmarks", sections)
    return paths
