"""Benchmark: local precision and speed of the ``icp2d`` front end alone, variants in one run.

Run from the repository root::

    python benchmarks/front_end_precision.py [--data DIR] [--limit N] [--sim-scans N]
        [--no-intel] [--no-sim] [--corrected NAMES] [--log LOG:RELATIONS ...]
        [--variant NAME:key=value,key=value ...]

Each variant is the default `slam.config.PipelineConfig` with ``key=value``
overrides in the syntax of ``loopclosure run --set`` (keys under ``icp2d.``, e.g.
``icp2d.map_voxel=0.03`` or ``icp2d.icp.kernel=huber``); only its front end
(`Icp2dConfig`) is used.  Every variant processes the same scans, read once before
any timing; the first variant is the reference of the ratios printed at the end.

Intel (``carmen/intel.clf.bz2`` and ``carmen/intel.relations``): the front end's
per-scan poses (file order, wheel odometry in the scans; no loop closure) are
scored by the relations metric (Kümmerle et al. 2009, `evaluation.relations_metric`)
on the *short* relations, ``|t2 - t1| < SHORT_S`` (1 s): consecutive or nearly
consecutive scans, where the error is the registration's own, not drift.  Mean
absolute translational [m] and rotational [deg] error, and the front end's wall
seconds (``time.perf_counter``) and milliseconds per scan.  ``--log LOG:RELATIONS``
(repeatable) scores any other CARMEN log with reference relations the same way
(e.g. a building kept out of the repository, read where it lies).

Simulation (`data.sim.simulate_run`, exact ground truth): a robot drives half a
figure-eight (0.5 m/s, 5 Hz) through the ``box`` and the ``surface`` worlds with a
180-degree laser like a SICK LMS: 181 beams at 1 degree and 361 beams at 0.5
degree, Gaussian range noise 1 cm, 1 % dropout, 30 m maximum range (`SIM_LASERS`).
The error is the mean over consecutive scans ``(k, k+1)`` of the translation [m] and
rotation [deg] of ``E = (P_k^-1 P_k+1) (G_k^-1 G_k+1)^-1`` (estimate ``P``, ground
truth ``G``, as 2D poses), i.e. the relations metric on consecutive pairs.
Each simulated case also gets a ``noise floor`` row: every scan (its points as the
front end takes them, the first variant's `Icp2dConfig`) registered by the same
ICP, from its true pose, onto an exact map, the noise-free end points of a
7,200-beam 360-degree laser at that pose (1 cm voxels): the error a scan-to-map
registration of these beams and this noise cannot beat with a perfect map.

GMapping-corrected logs (``--corrected freiburg-101,seattle,intel-corrected``,
``carmen-corrected/<name>-corrected.log.gz``; a name may carry the suffix): their
pose fields are the reference; the front end gets the simulator's drifting wheel odometry of them
(`evaluation.slam_input.synthetic_odometry`, seed 0, as ``loopclosure bench
slam --odometry-noise 0`` does) and its trajectory alone (no loop closure) is
scored by the ATE RMSE [m] after SE(2) alignment (`evaluation.trajectory_errors`,
scans matched by index) in the "trans m" column, and the RPE rotation RMSE [deg]
between consecutive scans in the "rot deg" column.  These logs hold about one
scan per metre: a test of the defaults on other buildings and sparse maps.

Before any timing, every variant runs once on the first scans of the first case,
so numba's compilation (about a second in a cold process) is not counted in the
first variant's time.  Nothing is cached or written; the shared data is read in
place.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from data import se2  # noqa: E402
from data.carmen import CarmenLog  # noqa: E402
from data.raycast import LaserModel, cast  # noqa: E402
from data.relations import read_relations  # noqa: E402
from data.sim import MotionConfig, simulate_run  # noqa: E402
from data.types import Scan, Trajectory  # noqa: E402
from evaluation.relations_metric import relations_metric  # noqa: E402
from evaluation.slam_input import synthetic_odometry  # noqa: E402
from evaluation.trajectory_error import trajectory_errors  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402
from slam.config_io import apply_overrides  # noqa: E402
from slam.odometry.icp2d import Icp2dConfig, Icp2dOdometry  # noqa: E402

DEFAULT_DATA = ROOT.parent / "shared" / "data"
SHORT_S = 1.0
#: (name, field of view [deg], beams, range noise sigma [m]) of the simulated lasers.
SIM_LASERS = (("181@1deg", 180.0, 181, 0.01), ("361@0.5deg", 180.0, 361, 0.01))
SIM_WORLDS = ("box", "surface")
DEFAULT_VARIANTS = ("defaults:",)
#: The exact map of the noise floor: a noise-free 360-degree laser of this many beams.
FLOOR_BEAMS = 7200
FLOOR_VOXEL = 0.01
WARM_UP_SCANS = 30


def front_end(
    scans: list[Scan], config: Icp2dConfig
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Poses ``(N, 3)``, stamps ``(N,)``, wall and CPU seconds of the front end on `scans`."""
    odo = Icp2dOdometry(config)
    start, cpu = time.perf_counter(), time.process_time()
    estimates = [odo.process(s) for s in scans]
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    return (np.array([e.pose for e in estimates]), np.array([e.stamp for e in estimates]),
            wall, cpu)


def consecutive_error(poses: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Mean |translation| [m] and |rotation| [deg] of the consecutive relative-pose errors."""
    est = se2.between(poses[:-1], poses[1:])
    ref = se2.between(truth[:-1], truth[1:])
    err = se2.between(ref, est)
    return (float(np.mean(np.hypot(err[:, 0], err[:, 1]))),
            float(np.degrees(np.mean(np.abs(se2.wrap_angle(err[:, 2]))))))


def noise_floor(run, scans: list[Scan], config: Icp2dConfig) -> np.ndarray:
    """Poses ``(N, 3)`` of `scans` registered from their true poses onto exact maps.

    Each scan's points (`Icp2dOdometry.scan_points`) are registered by the front
    end's ICP (`loopclosure.fast_icp.register_fast`, `config.icp`, no prior) onto
    the noise-free end points of a `FLOOR_BEAMS`-beam 360-degree laser at the
    scan's true pose (sensor frame, voxelised to `FLOOR_VOXEL`): a perfect map, so
    the error left is the scan's own noise.
    """
    from loopclosure.fast_icp import GridTarget, register_fast, voxel_downsample_fast

    exact = LaserModel(fov_deg=360.0, beams=FLOOR_BEAMS, max_range=run.laser.max_range,
                       noise_sigma=0.0, dropout=0.0)
    truth = run.ground_truth.xytheta()[: len(scans)]
    ranges = cast(run.world, truth, exact)
    angles = exact.angles()
    odo = Icp2dOdometry(config)
    poses = []
    for scan, pose, r in zip(scans, truth, ranges, strict=True):
        hit = r < exact.max_range - 1e-6
        target = np.column_stack([r[hit] * np.cos(angles[hit]), r[hit] * np.sin(angles[hit])])
        grid = GridTarget(voxel_downsample_fast(target, FLOOR_VOXEL), config.icp)
        res = register_fast(odo.scan_points(scan), grid, np.zeros(3), config=config.icp)
        poses.append(se2.compose(pose, res.pose))
    return np.array(poses)


def intel_case(data: Path, limit: int | None):
    """The Intel scans and a scorer of a trajectory on its short relations, or None."""
    return relations_case(data / "carmen" / "intel.clf.bz2",
                          data / "carmen" / "intel.relations", limit, "Intel")


def relations_case(log: Path, rel_path: Path, limit: int | None, label: str):
    """A CARMEN log's scans and a scorer of a trajectory on its short relations, or None."""
    if not log.exists() or not rel_path.exists():
        print(f"skipped {label}: {log} or {rel_path} not found")
        return None
    scans = list(CarmenLog(log))[:limit]
    stamps = np.array([s.stamp for s in scans])
    short = [r for r in read_relations(rel_path)
             if abs(r.t2 - r.t1) < SHORT_S
             and min(r.t1, r.t2) >= stamps.min() and max(r.t1, r.t2) <= stamps.max()]
    print(f"{label}: {len(scans)} scans, {len(short)} relations < {SHORT_S:g} s apart")

    def score(poses: np.ndarray, st: np.ndarray) -> tuple[float, float]:
        order = np.argsort(st, kind="stable")
        uniq, first = np.unique(st[order], return_index=True)
        m = relations_metric(Trajectory.from_xytheta(uniq, poses[order][first]), short)
        return m.trans_abs_mean, m.rot_abs_mean_deg

    return scans, score


def sim_cases(n_scans: int):
    """``(name, scans, scorer)`` for every simulated world and laser."""
    cases = []
    motion = MotionConfig(speed=0.5, rate_hz=5.0, laps=0.5)
    for world in SIM_WORLDS:
        for name, fov, beams, sigma in SIM_LASERS:
            run = simulate_run(world, seed=3, fov_deg=fov, beams=beams, max_range=30.0,
                               noise_sigma=sigma, dropout=0.01, motion=motion)
            scans = run.scans[:n_scans]
            truth = run.ground_truth.xytheta()[: len(scans)]

            def score(poses: np.ndarray, _st: np.ndarray, truth=truth) -> tuple[float, float]:
                return consecutive_error(poses, truth)

            cases.append((f"sim {world} {name}", scans, score, run))
    return cases


def corrected_cases(data: Path, names: list[str]):
    """``(name, scans, scorer)`` for every GMapping-corrected log found."""
    cases = []
    for name in names:
        name = name.removesuffix("-corrected")
        path = data / "carmen-corrected" / f"{name}-corrected.log.gz"
        if not path.exists():
            print(f"skipped {name}: {path} not found")
            continue
        scans = list(CarmenLog(path))
        ref = np.array([s.odom for s in scans])
        scans = [dataclasses.replace(s, stamp=float(i))
                 for i, s in enumerate(synthetic_odometry(scans, ref, seed=0))]
        index = np.arange(len(scans), dtype=float)
        reference = Trajectory.from_xytheta(index, ref)

        def score(poses: np.ndarray, _st: np.ndarray, reference=reference, index=index):
            err = trajectory_errors(Trajectory.from_xytheta(index, poses), reference)
            return err.ate_rmse, err.rpe_rot_rmse_deg

        cases.append((f"{name} ATE", scans, score, None))
    return cases


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help="shared data folder")
    parser.add_argument("--limit", type=int, default=None, help="first N Intel scans only")
    parser.add_argument("--sim-scans", type=int, default=400, help="scans per simulated run")
    parser.add_argument("--no-intel", action="store_true", help="skip Intel")
    parser.add_argument("--no-sim", action="store_true", help="skip the simulated runs")
    parser.add_argument("--corrected", default="",
                        help="comma-separated GMapping-corrected logs, e.g. freiburg-101,seattle")
    parser.add_argument("--log", action="append", default=[],
                        help="LOG:RELATIONS, a CARMEN log scored on its short relations "
                        "(repeatable)")
    parser.add_argument("--variant", action="append", default=None,
                        help="NAME:key=value,key=value (repeatable; the first is the reference)")
    args = parser.parse_args()

    cases = []
    if not args.no_intel:
        intel = intel_case(args.data, args.limit)
        if intel is not None:
            cases.append(("Intel short", *intel, None))
    for spec in args.log:
        log, _, rel_path = spec.rpartition(":")
        if not log:
            parser.error(f"--log needs LOG:RELATIONS, got {spec!r}")
        case = relations_case(Path(log), Path(rel_path), args.limit, Path(log).name)
        if case is not None:
            cases.append((f"{Path(log).name.split('.')[0]} short", *case, None))
    if not args.no_sim:
        cases.extend(sim_cases(args.sim_scans))
    names = [n.strip() for n in args.corrected.split(",") if n.strip()]
    cases.extend(corrected_cases(args.data, names))
    variants = []
    for spec in args.variant or DEFAULT_VARIANTS:
        name, _, sets = spec.partition(":")
        overrides = [s for s in sets.split(",") if s]
        variants.append((name, apply_overrides(PipelineConfig(), overrides).icp2d, overrides))

    results: dict[str, dict[str, tuple[float, float, float, float]]] = {}
    header = (f"{'case':<22} {'variant':<16} {'trans m':>9} {'rot deg':>8} {'wall s':>7} "
              f"{'cpu s':>7} {'cpu ms/scan':>11}")
    if cases:
        for _, cfg, _ in variants:
            front_end(cases[0][1][:WARM_UP_SCANS], cfg)
    print(header)
    print("-" * len(header))
    for case, scans, score, run in cases:
        if run is not None:
            start, cpu = time.perf_counter(), time.process_time()
            te, re = score(noise_floor(run, scans, variants[0][1]), np.zeros(0))
            wall, cpu = time.perf_counter() - start, time.process_time() - cpu
            print(f"{case:<22} {'noise floor':<16} {te:9.5f} {re:8.4f} {wall:7.2f} "
                  f"{cpu:7.2f} {1000 * cpu / len(scans):11.2f}", flush=True)
        for name, cfg, _ in variants:
            poses, st, wall, cpu = front_end(scans, cfg)
            te, re = score(poses, st)
            results.setdefault(name, {})[case] = (te, re, wall, cpu)
            print(f"{case:<22} {name:<16} {te:9.5f} {re:8.4f} {wall:7.2f} {cpu:7.2f} "
                  f"{1000 * cpu / len(scans):11.2f}", flush=True)
    for name, _, overrides in variants:
        print(f"{name}: {', '.join(overrides) or 'defaults'}")
    if len(variants) > 1 and cases:
        ref = variants[0][0]
        print(f"\nratios against {ref!r} (error and time; lower is better)")
        print(f"{'case':<22} {'variant':<16} {'trans':>7} {'rot':>7} {'wall':>7} {'cpu':>7}")
        for case, *_ in cases:
            te0, re0, w0, c0 = results[ref][case]
            for name, _, _ in variants[1:]:
                te, re, w, c = results[name][case]
                print(f"{case:<22} {name:<16} {te / te0:7.3f} {re / max(re0, 1e-12):7.3f} "
                      f"{w / w0:7.3f} {c / c0:7.3f}")
        for k, what in ((2, "wall"), (3, "CPU")):
            total0 = sum(v[k] for v in results[ref].values())
            for name, _, _ in variants[1:]:
                total = sum(v[k] for v in results[name].values())
                print(f"total front-end {what} time {name}: {total:.1f} s vs {total0:.1f} s "
                      f"({total / total0:.3f})")


if __name__ == "__main__":
    main()

