"""Optimising a `PoseGraph` in one batch solve: Levenberg-Marquardt, GNC, gtsam's GNC.

`optimize(graph, kernel, method)` is the one-shot batch solve (``method="lm"``
with a robust kernel on loop factors; ``method="gnc"``: the truncated-least-squares
loss of Yang et al. 2020 with odometry and priors known inliers, solved by our
warm-started GNC (`gnc_warm`) or, with ``gnc_start="incremental"``, by time-ordered
admission (`slam.consistency`), the one that survives half the loops being false,
whose candidates are compared under calibrated odometry and whose final loops are
re-checked under odometry calibrated per segment of consecutive poses
(`slam.segment_recheck`);
``method="gnc-gtsam"``: gtsam's own GncLMOptimizer).

This module is the batch solve's front door and its driver (`optimize`, which reads
as the list of its stages); each stage is a module of its own, whose public names it
re-exports:

* `slam.initial_poses`: `initial_guess` (the given poses, the odometry chain, LAGO).
* `slam.optimization_result`: `OptimizationResult` and `default_outlier_residual`
  (loop classification: a loop is an outlier when GNC gives it a weight below 0.5,
  or, other methods, when its whitened residual under the solution exceeds
  `outlier_residual`, by default sqrt of the chi-square 99% quantile: 3.37 for 3
  degrees of freedom, 4.20 for 6).
* `slam.clean_optimum`: the incremental admission's fast path (`_clean_optimum`).
* `slam.rechecked`: the admission's decisions re-checked and the stated graph
  re-solved (`_rechecked`, `_segment_rechecked`).
* `slam.gnc_warm`: `gnc_warm`, GNC-TLS warm-started from the last solution.

The smoothers a mapper feeds as keyframes and loops arrive (`Smoother`,
`BatchSmoother`, `IncrementalSmoother`) live in `slam.smoothers`.
"""

from __future__ import annotations

import time
from functools import partial

import gtsam
import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from slam.clean_optimum import _clean_optimum
from slam.consistency import ODOMETRY_LADDER, incremental_tls, polish
from slam.gnc_warm import WARM_STARTS, gnc_warm
from slam.initial_poses import INITIALISATIONS, initial_guess
from slam.least_squares import lm_params, solve
from slam.offer_back import choose_and_offer_back
from slam.optimization_result import OptimizationResult, default_outlier_residual
from slam.pose_graph import PoseGraph, RobustKernel, poses_from_values, whitened_residual
from slam.rechecked import POLISH_ROUNDS, _rechecked, _segment_rechecked
from slam.swap import swap_search

__all__ = [
    "GNC_STARTS",
    "INITIALISATIONS",
    "METHODS",
    "POLISH_ROUNDS",
    "WARM_STARTS",
    "OptimizationResult",
    "default_outlier_residual",
    "gnc_warm",
    "initial_guess",
    "optimize",
]

Array = NDArray[np.float64]
METHODS = ("lm", "gnc", "gnc-gtsam")
GNC_STARTS = (*WARM_STARTS, "incremental")


def optimize(
    graph: PoseGraph,
    kernel: str | RobustKernel = "cauchy",
    method: str = "lm",
    *,
    initial: dict[int, Array] | None = None,
    init: str = "given",
    max_iterations: int = 100,
    gnc_probability: float = 0.99,
    outlier_residual: float | None = None,
    gnc_start: str = "given",
    odometry_ladder: tuple[float, ...] = ODOMETRY_LADDER,
    calibrated: bool = True,
    recheck: bool = False,
    segments: bool = True,
    groups: bool = True,
    fast_path: bool = True,
    swap: bool = False,
    defer: str = "off",
    regroup: bool | None = None,
    undo: bool = True,
    screen: bool = False,
    confirm: bool | str = True,
    stall: bool = True,
) -> OptimizationResult:
    """Batch-optimise `graph` from `initial`, or else from `initial_guess(graph, init)`.

    ``method="lm"``: Levenberg-Marquardt with `kernel` on loop factors.
    ``method="gnc"``: GNC-TLS over Gaussian loop factors (`kernel` ignored); a loop is
    an inlier when its factor error stays below the chi-square `gnc_probability`
    quantile of its dof.  `gnc_start`: ``"given"`` or ``"least-squares"``, `gnc_warm`'s
    `start` (``"given"``, the default, is fast and right when the start is already good
    and outliers are few, as after a mapper's iSAM2), or ``"incremental"`` (time-ordered TLS
    admission from the odometry chain; minutes on a few thousand poses, but
    robust to most loops being false: `slam.consistency`).  `odometry_ladder`: the
    odometry information factors the incremental admission decides at
    (`slam.consistency.incremental_tls`; ``(1.0,)`` decides at the stated information only).
    `calibrated`: the incremental admission picks among its candidates by TLS cost under
    calibrated odometry (`slam.calibrated_choice.calibrated_choice`) instead of the stated cost.
    `recheck`: its decisions are then re-checked under calibrated odometry
    (`slam.loop_recheck.recheck_loops`) and, where that changes them, the stated graph
    re-solved (off by default: it changed no decision the choice had not already made on
    the cases measured, and costs a solve per accepted loop and round).
    `segments`: the incremental admission's loops are finally re-checked under odometry
    calibrated per segment of consecutive poses (`slam.segment_recheck.segment_recheck`); loops
    it removes are barred and the stated graph re-decided (`slam.consistency.refine_tls`)
    and polished (`slam.consistency.polish`).  `groups`: the segment re-check also tests
    groups of loops that agree with one another as a whole (`slam.group_recheck.group_recheck`).
    `fast_path`: with ``gnc_start="incremental"`` and `segments`, the plain least-squares
    optimum is returned when every loop passes its chi-square test there and the segment
    re-check removes none (`_clean_optimum`; solver ``"least-squares-clean"``).
    `swap`: the incremental admission's result goes through `slam.swap.swap_search`
    (groups of rejected loops admitted together) before the segment re-check; off by
    default: on Intel with loosened odometry it let false groups in.
    `defer`: the incremental admission's deferral of loops whose innovation test has no
    power (`slam.consistency.incremental_tls`, `slam.deferral`): ``"off"`` (the default),
    ``"bounded"`` (waits one loop-bearing block for the consensus of the loops that
    arrive, then the plain gate decides), ``"both"`` (each rung without and with it, the
    choice among all), ``"all"`` and ``"candidate"`` as there.
    `regroup` (None: `slam.consistency.REGROUP`, off): before its bar search the incremental
    admission re-decides early lone admitted loops against a later return of rejected,
    mutually agreeing loops that contradicts them, kept only when the TLS objective drops
    (`slam.regroup`).
    `undo` (on by default): the incremental admission's passes undo earlier admissions
    that a later block's loops contradict when the TLS objective of the decided part says
    so, and compare each kept hypothesis again with the pass without it after the next
    loop-bearing blocks (`slam.admission_undo`): an early false return no longer bends
    the prefix that every later loop is judged against, and a consistent false group that
    looks cheaper when it arrives is reverted once the following returns contradict it.
    `screen`: the fast path is skipped when a few solver iterations at the stiffest rung
    leave most loops above ``c`` (`slam.fast_path_screen`); off by default, since on a
    consistent graph whose solve from the odometry chain converges slowly it skips a
    fast path that holds.
    `confirm` (on by default): the admission passes turn back an innovation-gate
    admission whose actual cost of being kept is above ``c``
    (`slam.admission.AdmissionPass`): the linearised cost the gate judges by can fall
    below ``c`` while the prefix re-solved without the loop says otherwise;
    ``confirm="screen"`` first clears the loops whose linearised leave-one-out cost is
    at most half of ``c`` (not exact, `slam.innovation.removal_costs`).
    `stall` (on by default): the fast path's first solve (stiffest rung) is given up when
    an LM step lowers the error by under a relative `slam.fast_path_screen.STALL_DECREASE`
    at low damping while most loops are above ``c``, or, where LM fails and dogleg goes on,
    when `slam.fast_path_screen.STALL_WINDOW` dogleg iterations bring no new least number of
    loops above ``c`` while most are above it (`slam.fast_path_screen.stalled_solve`);
    otherwise its result is `solve`'s bit for bit.  A measured rule, not a proof that the
    fast path would fail: on every graph and odometry scaling measured it gave up only
    solves whose result failed the fast path's check as well, and it saves most of that
    solve where many false loops make it the dearest of the back end.
    """
    if method not in METHODS:
        raise UserError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    if gnc_start not in GNC_STARTS:
        raise UserError(f"unknown GNC start {gnc_start!r}; choose one of {', '.join(GNC_STARTS)}")
    if not graph.initial:
        raise UserError("the pose graph has no poses")
    kernel = RobustKernel(kernel) if isinstance(kernel, str) else kernel
    threshold = outlier_residual or default_outlier_residual(graph.dim)
    values = graph.gtsam_values(initial if initial is not None else initial_guess(graph, init))
    start = time.perf_counter()
    weights = None
    if method == "gnc":
        factors, loop_index = graph.factor_graph(RobustKernel("none"))
        clean = None
        if fast_path and gnc_start == "incremental" and segments and len(graph.loops):
            clean = _clean_optimum(graph, factors, loop_index, values, gnc_probability,
                                   max_iterations, groups, tuple(odometry_ladder), screen,
                                   stall)
        if clean is not None:
            result, iterations = clean
            weights = np.ones(len(graph.loops))
            solver = "least-squares-clean"
        elif gnc_start == "incremental":
            factor: list[float] = []  # the chosen candidate's odometry factor, if any
            admission = incremental_tls(
                graph, values, probability=gnc_probability, ladder=odometry_ladder,
                choose=partial(choose_and_offer_back, factor=factor) if calibrated else None,
                defer=defer, regroup=regroup, undo=undo, confirm=confirm,
            )
            if swap and len(graph.loops):
                swapped = swap_search(graph, admission, values, probability=gnc_probability,
                                      factors=(factors, loop_index))
                if swapped.kept:
                    admission = swapped.admission
                    admission.values = polish((factors, loop_index), admission.weights,
                                              admission.values)
            result, weights, iterations = admission.values, admission.weights, admission.blocks
            solver = f"tls-incremental-{admission.gate}"
            if recheck and len(graph.loops):
                result, weights, solver = _rechecked(graph, factors, loop_index, result,
                                                     weights, gnc_probability, solver,
                                                     factor[-1] if factor else 1.0)
            if segments and len(graph.loops):
                result, weights, solver = _segment_rechecked(
                    graph, factors, loop_index, result, weights, gnc_probability, solver,
                    groups)
        else:
            result, weights, iterations = gnc_warm(
                graph, values, probability=gnc_probability, start=gnc_start
            )
            solver = "gnc-tls-warm"
    elif method == "gnc-gtsam":
        factors, loop_index = graph.factor_graph(RobustKernel("none"))
        # GNC's first step is the plain least-squares solution; solving it robustly
        # first (see `slam.least_squares`) gives GncLMOptimizer a start its LM can work from.
        values, iterations, solver = solve(factors, values, max_iterations)
        # Graphs that needed the QR fallback break GNC's inner Cholesky LM as well.
        inner = "MULTIFRONTAL_QR" if solver == "dogleg-qr" else "MULTIFRONTAL_CHOLESKY"
        params = gtsam.GncLMParams(lm_params(max_iterations, inner))
        params.setLossType(gtsam.GncLossType.TLS)
        known = sorted(set(range(factors.size())) - set(loop_index))
        params.setKnownInliers(known)
        optimizer = gtsam.GncLMOptimizer(factors, values, params)
        optimizer.setInlierCostThresholdsAtProbability(gnc_probability)
        result = optimizer.optimize()
        weights = np.asarray(optimizer.getWeights())[loop_index] if loop_index else np.zeros(0)
        solver = "gnc-tls"
    else:
        factors, loop_index = graph.factor_graph(kernel)
        result, iterations, solver = solve(factors, values, max_iterations)
    seconds = time.perf_counter() - start
    poses = poses_from_values(result, graph.dim)
    residuals = np.array([whitened_residual(c, poses, graph.dim) for c in graph.loops])
    if weights is not None:
        outliers = [int(i) for i in np.flatnonzero(weights < 0.5)]
    else:
        outliers = [int(i) for i in np.flatnonzero(residuals > threshold)]
    return OptimizationResult(
        poses=poses,
        initial_error=float(factors.error(values)),
        final_error=float(factors.error(result)),
        iterations=int(iterations),
        seconds=seconds,
        loop_residuals=residuals,
        loop_outliers=outliers,
        loop_weights=weights,
        solver=solver,
    )
