"""The command line of the robustness diagnoses that study one corrupted pose graph.

`cell_parser` gives their common arguments (graph file name, data folder, odometry
scaling, outlier policy, ratio [%], seed, and optionally a cache folder); `read_cell`
reads the cell they name (`evaluation.robustness.corrupted_graph`), keeping the clean
optimum of each graph and scaling in the cache folder between runs (minutes on
M3500a).
"""

from __future__ import annotations

import argparse
import contextlib
import pickle
import signal
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evaluation.robustness import (
    aligned_position_error,
    consistent_with_clean,
    corrupted_graph,
)
from slam.consistency import ODOMETRY_LADDER, tls_cost
from slam.innovation import tls_threshold
from slam.optimize import default_outlier_residual, initial_guess, optimize
from slam.pose_graph import RobustKernel, whitened_residual
from slam.variance_components import with_information_scaled


def cell_parser(description: str, seed: int = 0, cache: bool = True) -> argparse.ArgumentParser:
    """An argument parser with the arguments that name one cell."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("graph")
    parser.add_argument("--data", default="../shared/data/g2o")
    parser.add_argument("--scale", type=float, default=1.0)
    parser.add_argument("--policy", default="random")
    parser.add_argument("--ratio", type=float, default=50.0)
    parser.add_argument("--seed", type=int, default=seed)
    if cache:
        parser.add_argument("--cache", type=Path, default=None)
    return parser


def read_cell(args: argparse.Namespace):
    """``(graph, reference, corrupted, is_false)`` of the cell `args` name
    (`evaluation.robustness.corrupted_graph`), the clean optimum from ``args.cache``
    when it holds it (and stored there when it does not)."""
    folder = getattr(args, "cache", None)
    cached = folder / f"{args.graph}-x{args.scale:g}.pkl" if folder else None
    known = (pickle.loads(cached.read_bytes()) if cached is not None and cached.exists()
             else None)
    cell = corrupted_graph(str(Path(args.data) / args.graph), args.scale, args.ratio / 100,
                           args.policy, args.seed, reference=known)
    if cached is not None and known is None:
        cached.parent.mkdir(parents=True, exist_ok=True)
        cached.write_bytes(pickle.dumps(cell[1]))
    return cell


@dataclass(frozen=True)
class CellOutcome:
    """What a robust solution of one cell did: `obeyed` per loop (whitened residual at
    most the default outlier residual), the false loops obeyed, how many of those the
    clean optimum also satisfies (`consistent`), the true loops rejected, the TLS cost
    above the clean optimum's (`gap`) and the aligned position error [m]."""

    obeyed: np.ndarray
    false_obeyed: np.ndarray
    consistent: int
    true_rejected: int
    gap: float
    ate: float


def fast_path_problem(corrupted):  # type: ignore[no-untyped-def]
    """What the fast path's first solve is given: ``(c, factors, loop_index, values)``,
    the TLS threshold, the stiffest odometry rung's factor graph without a kernel, the
    indices of its loop factors, and the odometry initial guess."""
    c = tls_threshold(corrupted.dim)
    factors, loop_index = with_information_scaled(corrupted, max(ODOMETRY_LADDER)).factor_graph(
        RobustKernel("none"))
    return c, factors, loop_index, corrupted.gtsam_values(initial_guess(corrupted, "odometry"))


def cell_outcome(graph, reference, corrupted, is_false: np.ndarray, poses) -> CellOutcome:
    """`CellOutcome` of `poses` on the cell ``(graph, reference, corrupted, is_false)``
    that `read_cell` returns."""
    threshold = default_outlier_residual(graph.dim)
    residuals = np.array([whitened_residual(c, poses, graph.dim) for c in corrupted.loops])
    obeyed = residuals <= threshold
    false_obeyed = np.flatnonzero(obeyed & is_false)
    consistent = consistent_with_clean(graph, reference,
                                       [corrupted.loops[k] for k in false_obeyed])
    gap = (tls_cost(corrupted, corrupted.gtsam_values(poses))
           - tls_cost(corrupted, corrupted.gtsam_values(reference)))
    return CellOutcome(obeyed, false_obeyed, consistent, int((~obeyed & ~is_false).sum()),
                       gap, aligned_position_error(poses, reference, graph.dim))


class CpuCapped(Exception):
    """Raised inside `cpu_cap`'s block when its CPU budget is spent."""


def _capped(*_) -> None:  # type: ignore[no-untyped-def]
    raise CpuCapped()


@contextlib.contextmanager
def cpu_cap(seconds: float):
    """Raise `CpuCapped` in the block once it has used `seconds` of process CPU time
    (``ITIMER_PROF``; no cap when `seconds` <= 0); the timer is cleared on leaving."""
    if seconds > 0:
        signal.signal(signal.SIGPROF, _capped)
        signal.setitimer(signal.ITIMER_PROF, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_PROF, 0)


def capped_gnc(corrupted, cap: float, **options):  # type: ignore[no-untyped-def]
    """The default robust mode on `corrupted` (``optimize(..., "none", "gnc",
    init="odometry", gnc_start="incremental", **options)``) within `cap` seconds of
    process CPU (`cpu_cap`): its result, or None when the cap was reached."""
    try:
        with cpu_cap(cap):
            return optimize(corrupted, "none", "gnc", init="odometry",
                            gnc_start="incremental", **options)
    except CpuCapped:
        return None
