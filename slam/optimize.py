"""Optimising a `PoseGraph`: batch Levenberg-Marquardt, GNC, and incremental iSAM2.

`optimize(graph, kernel, method)` is the one-shot batch solve (``method="lm"``
with a robust kernel on loop factors; ``method="gnc"``: the truncated-least-squares
loss of Yang et al. 2020 with odometry and priors known inliers, solved by our
warm-started GNC (`gnc_warm`) or, with ``gnc_start="incremental"``, by time-ordered
admission (`slam.consistency`), the one that survives half the loops being false,
whose candidates are compared under calibrated odometry and whose final loops are
re-checked under odometry calibrated per segment of consecutive poses
(`slam.segment_recheck`);
``method="gnc-gtsam"``: gtsam's own GncLMOptimizer).

`Smoother` is the interface a mapper uses as keyframes and loops arrive:
``add_pose``, ``add_odometry``, ``add_loop``, ``update``, ``estimate``,
``marginal_covariance``.  `BatchSmoother` re-solves the whole graph with LM on each
update; `IncrementalSmoother` feeds gtsam.ISAM2 only what is new.

Loop classification: a loop constraint is reported as an outlier when GNC gives
it a weight below 0.5, or (other methods) when its whitened residual under the
solution exceeds `outlier_residual` (default sqrt of the chi-square 99% quantile:
3.37 for 3 degrees of freedom, 4.20 for 6).
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from functools import partial

import gtsam
import numpy as np
from numpy.typing import NDArray

from data.errors import UserError, warn
from slam.consistency import (
    LM_BUDGET,
    ODOMETRY_LADDER,
    incremental_tls,
    needs_qr,
    polish,
    refine_tls,
    tls_threshold,
)
from slam.fast_path_screen import majority_fails, stalled_solve
from slam.least_squares import StickySolver, conditioning, dogleg_qr, lm_params, solve
from slam.loop_recheck import recheck_loops
from slam.offer_back import choose_and_offer_back
from slam.pose_graph import (
    Constraint,
    PoseGraph,
    RobustKernel,
    chi2_quantile,
    pose_dof,
    poses_from_values,
    relative_compose,
    to_gtsam_pose,
    whitened_residual,
)
from slam.segment_recheck import segment_recheck
from slam.swap import swap_search
from slam.variance_components import with_information_scaled

Array = NDArray[np.float64]
METHODS = ("lm", "gnc", "gnc-gtsam")
INITIALISATIONS = ("given", "odometry", "lago")
WARM_STARTS = ("given", "least-squares")
GNC_STARTS = (*WARM_STARTS, "incremental")
POLISH_ROUNDS = 5  # re-decisions at the polished solution after the segment re-check


def default_outlier_residual(dim: int, probability: float = 0.99) -> float:
    """Whitened-residual threshold of a loop factor: sqrt(chi2 quantile) for its dof."""
    return float(np.sqrt(chi2_quantile(probability, pose_dof(dim))))


@dataclass(slots=True)
class OptimizationResult:
    """Outcome of a batch solve.

    Attributes:
        poses: id -> optimised pose ((3,) planar or 4x4).
        initial_error, final_error: gtsam graph error (0.5 * sum of squared whitened
            residuals, robust-weighted) before and after.
        iterations: optimiser iterations (GNC: those of its least-squares warm start).
        seconds: wall time of the solve.
        loop_residuals: whitened residual of every loop constraint under `poses`.
        loop_outliers: indices into `graph.loops` classified as outliers.
        loop_weights: GNC weights per loop (1 inlier, 0 outlier); None for LM.
        solver: "lm", "dogleg-qr" (LM fallback, see `slam.least_squares`), "gnc-tls-warm",
            "tls-incremental-<gate>" (``gnc_start="incremental"``; "...-segments" when
            the segment re-check removed loops), "least-squares-clean" (the incremental
            admission's fast path: the plain optimum was its decision) or "gnc-tls" (gtsam).
    """

    poses: dict[int, Array]
    initial_error: float
    final_error: float
    iterations: int
    seconds: float
    loop_residuals: Array
    loop_outliers: list[int]
    loop_weights: Array | None = None
    solver: str = "lm"


def initial_guess(graph: PoseGraph, init: str = "given") -> dict[int, Array]:
    """Initial poses for a batch solve.

    ``given``: the graph's own initial guesses (g2o vertices, mapper estimates).
    ``odometry``: the anchor pose composed along odometry constraints (breadth-first;
    poses no odometry reaches keep their given guess).
    ``lago``: gtsam's LAGO (Carlone et al. 2014) linear approximation over every
    constraint, 2D only, with the diagonal of each information matrix (LAGO accepts
    diagonal noise only).  Far better than odometry on long loops, but it trusts
    every loop, so it is a poor start when false loops are present.
    """
    if init not in INITIALISATIONS:
        raise UserError(f"unknown initialisation {init!r}; use {', '.join(INITIALISATIONS)}")
    if init == "given":
        return dict(graph.initial)
    if init == "odometry":
        poses = dict(graph.initial)
        children: dict[int, list] = {}
        for c in graph.odometry:
            children.setdefault(c.i, []).append(c)
        frontier = list(graph.anchor_keys())
        seen = set(frontier)
        while frontier:
            key = frontier.pop()
            for c in children.get(key, []):
                if c.j not in seen:
                    poses[c.j] = relative_compose(poses[key], c.measurement, graph.dim)
                    seen.add(c.j)
                    frontier.append(c.j)
        return poses
    if graph.dim != 2:
        raise UserError("LAGO initialisation is for 2D graphs only")
    factors = gtsam.NonlinearFactorGraph()
    for key in graph.anchor_keys():
        factors.add(graph.prior_factor(key))
    for c in graph.odometry + graph.loops:
        noise = gtsam.noiseModel.Diagonal.Precisions(np.maximum(np.diag(c.information), 1e-12))
        factors.add(gtsam.BetweenFactorPose2(c.i, c.j, to_gtsam_pose(c.measurement, 2), noise))
    return poses_from_values(gtsam.lago.initialize(factors), 2)


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
                defer=defer, undo=undo, confirm=confirm,
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


def _clean_optimum(
    graph: PoseGraph, factors: gtsam.NonlinearFactorGraph, loop_index: list[int],
    values: gtsam.Values, probability: float, max_iterations: int, groups: bool,
    ladder: tuple[float, ...] = ODOMETRY_LADDER, screen: bool = False, stall: bool = False,
) -> tuple[gtsam.Values, int] | None:
    """The plain least-squares optimum over every loop (polished as the admission's
    result is, `slam.consistency.polish`) and its iterations, when it is also the TLS
    decision: at every rung of the odometry `ladder` (the graph with its odometry
    information multiplied by the rung's factor, solved stiffest first, each from the
    solution of the one before, the stated graph last) every loop's factor error is at
    most ``c`` (`tls_threshold`, the chi-square test of its dof at `probability`), and
    the segment re-check (`slam.segment_recheck.segment_recheck`, with its group test when
    `groups`) removes none of the loops at the stated graph's optimum; else None.

    Why every rung: under loosely stated odometry the least-squares map bends onto
    every false loop at an error below ``c`` (MITb with its odometry information x0.01
    and half its loops false: all of them), where the stiffer rungs, as the admission's
    ladder decides, see them; and solved from the odometry chain alone such a graph's
    least squares can stop in a poor local minimum that the stiff rungs' solutions,
    as starts, avoid.

    Why: the residual rule of the time-ordered admission (``w_k = [e_k <= c]``) holds at
    that optimum for every loop, so it is a fixed point of `refine_tls` with every loop
    in, and the re-check the admission's result would go through finds nothing; on a
    graph without false loops (the common case of a mapper's final pass) the admission
    and its ladder, choice and bar search would cost many solves to arrive there.  One
    false loop bends the least-squares map so that some loop fails the test (or the
    re-check removes it), and the whole admission runs: the extra cost is one solve.
    `screen`: that solve is not started at all when a few iterations of it at the
    stiffest rung leave most loops above ``c`` (`slam.fast_path_screen.majority_fails`):
    with many false loops it is the dearest solve of the robust back end.
    `stall`: that first solve is abandoned at an LM stall with most loops above ``c``
    (`slam.fast_path_screen.stalled_solve`).
    """
    c = tls_threshold(graph.dim, probability)
    result, iterations = values, 0
    for n, factor in enumerate(sorted(ladder, reverse=True)):
        rung = factors if factor == 1.0 else with_information_scaled(
            graph, factor).factor_graph(RobustKernel("none"))[0]
        if screen and n == 0 and majority_fails(rung, loop_index, result, c):
            return None
        if stall and n == 0:
            solved = stalled_solve(rung, result, max_iterations, loop_index, c)
            if solved is None:
                return None
        else:
            solved = solve(rung, result, max_iterations)
        result, used_iterations, used = solved
        iterations += used_iterations
        # The loops' factors are the same on every rung (only odometry is scaled).
        if any(factors.at(k).error(result) > c for k in loop_index):
            return None
    check_solver = StickySolver(lm_budget=LM_BUDGET, sticky=False)
    check_solver.dogleg = used == "dogleg-qr" or needs_qr(graph, result)
    weights = np.ones(len(loop_index))
    unit = [factors.at(k) for k in loop_index]
    check = segment_recheck(graph, result, weights, probability=probability,
                            solver=check_solver, unit=unit, groups=groups)
    if check.removed:
        return None
    return polish((factors, loop_index), weights, result, max_iterations), iterations


def _rechecked(
    graph: PoseGraph, factors: gtsam.NonlinearFactorGraph, loop_index: list[int],
    values: gtsam.Values, weights: Array, probability: float, solver: str, start: float,
) -> tuple[gtsam.Values, Array, str]:
    """`slam.loop_recheck.recheck_loops` on an admission; the stated graph re-solved with the
    re-checked loops when they differ (dogleg-QR, as `incremental_tls` polishes)."""
    unit = [factors.at(k) for k in loop_index]
    new, _ = recheck_loops(graph, values, weights, probability=probability, unit=unit,
                           start=start)
    if np.array_equal(new > 0.5, np.asarray(weights) > 0.5):
        return values, weights, solver
    kept = gtsam.NonlinearFactorGraph()
    loops = set(loop_index)
    for k in range(factors.size()):
        if k not in loops:
            kept.add(factors.at(k))
    for k in np.flatnonzero(new > 0.5):
        kept.add(unit[k])
    return dogleg_qr(kept, values, 100).optimize(), new, f"{solver}-rechecked"


def _segment_rechecked(
    graph: PoseGraph, factors: gtsam.NonlinearFactorGraph, loop_index: list[int],
    values: gtsam.Values, weights: Array, probability: float, solver: str,
    groups: bool = True,
) -> tuple[gtsam.Values, Array, str]:
    """`slam.segment_recheck.segment_recheck` on a TLS solution (`groups`: with its group test);
    when it removes loops or offers rejected ones back (`slam.group_recheck.group_recheck`'s
    readmitted loops, weight 1 from here on), the removed ones are barred, the rest
    re-decided on the stated graph by
    `slam.consistency.refine_tls` and the result polished (`slam.consistency.polish`), as
    is the odometry chain with the same loops; the solution of lower stated error is kept
    (the map the false loops bent can hold the polish in a local minimum the chain is
    free of).  The decisions are then re-made at the polished solution
    (``w_k = [e_k <= c]``, barred loops out) and re-polished until they hold (at most
    `POLISH_ROUNDS` times): on a loosely stated graph `refine_tls`'s solves can stop short
    of the optimum, where a true loop that a group of false ones had kept out still shows
    an error above ``c``."""
    unit = [factors.at(k) for k in loop_index]
    solve = StickySolver(lm_budget=LM_BUDGET, sticky=False)
    solve.dogleg = needs_qr(graph, values)
    check = segment_recheck(graph, values, weights, probability=probability, solver=solve,
                            unit=unit, groups=groups)
    if not check.removed and not (check.groups is not None and check.groups.readmitted):
        return values, weights, solver
    stated = (factors, loop_index)
    if check.groups is not None and check.groups.readmitted:
        weights = np.asarray(weights, dtype=float).copy()
        weights[check.groups.readmitted] = 1.0
    refined, new = refine_tls(graph, values, weights, probability=probability, solver=solve,
                              barred=check.removed, factors=stated)
    c = tls_threshold(graph.dim, probability)
    result = polish(stated, new, refined, solve.max_iterations)
    chain = polish(stated, new, graph.gtsam_values(initial_guess(graph, "odometry")),
                   solve.max_iterations)
    if _stated_error(stated, new, chain) < _stated_error(stated, new, result):
        result = chain
    for _ in range(POLISH_ROUNDS):
        again = np.array([unit[k].error(result) <= c for k in range(len(unit))], dtype=float)
        again[check.removed] = 0.0
        if np.array_equal(again, new):
            break
        new = again
        result = polish(stated, new, result, solve.max_iterations)
    return result, new, f"{solver}-segments"


def _stated_error(factors: tuple[gtsam.NonlinearFactorGraph, list[int]], weights: Array,
                  values: gtsam.Values) -> float:
    """Error (gtsam units) of the stated graph `factors` with the loops of ``weights > 0.5``
    at `values`."""
    base, loop_index = factors
    loops = set(loop_index)
    fixed = sum(base.at(k).error(values) for k in range(base.size()) if k not in loops)
    return float(fixed + sum(base.at(loop_index[k]).error(values)
                             for k in np.flatnonzero(np.asarray(weights) > 0.5)))


def _gnc_tls_weights(error: Array, barc: Array, mu: float) -> Array:
    """TLS weights of Yang et al. (2020), Eq. (14), in gtsam's error units (0.5 r^2)."""
    lower = mu / (mu + 1.0) * barc
    upper = (mu + 1.0) / mu * barc
    mid = np.sqrt(barc * mu * (mu + 1.0) / np.maximum(error, 1e-300)) - mu
    return np.where(error <= lower, 1.0, np.where(error >= upper, 0.0, np.clip(mid, 0.0, 1.0)))


def gnc_warm(
    graph: PoseGraph,
    values: gtsam.Values,
    *,
    probability: float = 0.99,
    mu_step: float = 1.4,
    max_outer: int = 100,
    inner_iterations: int = 10,
    weights_tol: float = 1e-4,
    start: str = "given",
) -> tuple[gtsam.Values, Array, int]:
    """GNC with the TLS loss whose every step starts from the previous solution.

    The algorithm of gtsam's GncOptimizer (Yang, Antonante, Tzoumas & Carlone 2020:
    mu initialised by their Remark 5, TLS weights by their Eq. (14), mu grown by
    `mu_step` until the weights are binary), with one difference: gtsam restarts
    every weighted least-squares step from the *initial* values, which on a
    corrupted graph costs a full solve per step; here each step continues from
    the last solution with at most `inner_iterations` LM iterations.  Odometry and
    priors are known inliers.  Returns (solution, loop weights, outer iterations).

    `start`: ``"least-squares"`` begins, as the paper does, from the plain
    least-squares solution over every loop; ``"given"`` begins from `values`
    (typically the odometry chain).  With plausible-looking false loops the
    least-squares solution is a crumpled map in which true and false loops are
    equally inconsistent, while from odometry the surrogate's first, nearly
    convex steps (every loop weighted almost 0) stay near odometry and admit the
    loops consistent with it first.  (Graduation from any start can fold M3500
    with half its loops false, because at small ``mu`` the surrogate is close to L1
    and every false loop pulls as hard as a true one: `optimize`'s
    ``gnc_start="incremental"`` uses `slam.consistency.incremental_tls` instead.)
    """
    if start not in WARM_STARTS:
        raise UserError(f"unknown GNC start {start!r}; choose one of {', '.join(WARM_STARTS)}")
    barc = tls_threshold(graph.dim, probability)
    base, _ = graph.factor_graph(RobustKernel("none"))
    n_fixed = base.size() - len(graph.loops)
    loop_factors = [base.at(n_fixed + k) for k in range(len(graph.loops))]

    def weighted_graph(w: Array) -> gtsam.NonlinearFactorGraph:
        g = gtsam.NonlinearFactorGraph()
        for k in range(n_fixed):
            g.add(base.at(k))
        for k, c in enumerate(graph.loops):
            if w[k] > 1e-8:
                g.add(graph.between_factor(
                    Constraint(c.i, c.j, c.measurement, w[k] * c.information)))
        return g

    def loop_errors(v: gtsam.Values) -> Array:
        return np.array([f.error(v) for f in loop_factors])

    weights = np.ones(len(graph.loops))
    if start == "least-squares":
        result, _, used = solve(base, values, 100)
    else:
        result, used = values, conditioning(base, values)
    # Graphs that needed the QR fallback break a Cholesky LM as well.
    linear = "MULTIFRONTAL_QR" if used == "dogleg-qr" else "MULTIFRONTAL_CHOLESKY"

    def refine(w: Array, start: gtsam.Values, iterations: int) -> gtsam.Values:
        g = weighted_graph(w)
        try:
            return gtsam.LevenbergMarquardtOptimizer(
                g, start, lm_params(iterations, linear)).optimize()
        except RuntimeError:  # indeterminate system: retry with QR
            return gtsam.LevenbergMarquardtOptimizer(
                g, start, lm_params(iterations, "MULTIFRONTAL_QR")).optimize()

    errors = loop_errors(result)
    excess = 2.0 * errors - barc
    if len(errors) == 0 or np.all(excess <= 0):
        return result, weights, 0
    mu = max(float(np.min(barc / excess[excess > 0])), 1e-6)
    outer = 0
    for outer in range(1, max_outer + 1):  # noqa: B007 - the count is returned
        new_weights = _gnc_tls_weights(errors, barc, mu)
        result = refine(new_weights, result, inner_iterations)
        errors = loop_errors(result)
        # Binary weights only mean convergence once the surrogate is close to TLS: at
        # small mu every weight of a large residual is ~0 without being decided.
        binary = np.all(np.abs(new_weights - np.round(new_weights)) < weights_tol)
        weights = new_weights
        if binary and mu >= 1.0:
            break
        mu *= mu_step
    weights = np.round(_gnc_tls_weights(errors, barc, mu))
    return refine(weights, result, 100), weights, outer


class Smoother(ABC):
    """What a mapper needs from a back end, batch or incremental alike."""

    def __init__(self, dim: int = 2, kernel: str | RobustKernel = "cauchy") -> None:
        self.graph = PoseGraph(dim=dim)
        self.kernel = RobustKernel(kernel) if isinstance(kernel, str) else kernel

    @property
    def dim(self) -> int:
        return self.graph.dim

    def add_pose(self, key: int, guess: Array) -> None:
        """A new pose with its initial guess (e.g. the odometry-composed pose)."""
        self.graph.add_pose(key, guess)
        self._on_pose(key, guess)

    def add_odometry(self, i: int, j: int, measurement: Array, information: Array) -> None:
        """An odometry constraint (Gaussian)."""
        self.graph.add_odometry(i, j, measurement, information)
        self._on_factor(self.graph.between_factor(self.graph.odometry[-1]), is_loop=False)

    def add_loop(self, i: int, j: int, measurement: Array, information: Array) -> int:
        """A loop-closure constraint with the smoother's robust kernel; returns its index."""
        index = self.graph.add_loop(i, j, measurement, information)
        self._on_factor(
            self.graph.between_factor(self.graph.loops[index], self.kernel), is_loop=True
        )
        return index

    @abstractmethod
    def _on_pose(self, key: int, guess: Array) -> None: ...

    @abstractmethod
    def _on_factor(self, factor: gtsam.NonlinearFactor, is_loop: bool) -> None: ...

    @abstractmethod
    def update(self) -> None:
        """Bring the estimate up to date with everything added so far."""

    @abstractmethod
    def estimate(self) -> dict[int, Array]:
        """Current id -> pose estimate (of every pose added so far)."""

    def estimate_rows(self) -> tuple[NDArray[np.int64], Array]:
        """The current estimate as arrays: ids ascending ``(N,)`` and their poses
        (``(N, 3)`` in 2-D, ``(N, 4, 4)`` in 3-D), for a caller that wants them all."""
        est = self.estimate()
        keys = np.array(sorted(est), dtype=np.int64)
        shape = (0, 3) if self.dim == 2 else (0, 4, 4)
        poses = np.array([est[k] for k in keys]) if len(keys) else np.empty(shape)
        return keys, poses

    @abstractmethod
    def marginal_covariance(self, key: int) -> Array:
        """Marginal covariance of pose `key` (gtsam tangent order) at the current estimate."""


class BatchSmoother(Smoother):
    """Re-solves the whole graph with Levenberg-Marquardt at every `update`."""

    def __init__(self, dim: int = 2, kernel: str | RobustKernel = "cauchy") -> None:
        super().__init__(dim, kernel)
        self._poses: dict[int, Array] = {}
        self._marginals: gtsam.Marginals | None = None

    def _on_pose(self, key: int, guess: Array) -> None:
        self._poses[key] = np.asarray(guess, dtype=float)
        self._marginals = None

    def _on_factor(self, factor: gtsam.NonlinearFactor, is_loop: bool) -> None:
        self._marginals = None

    def update(self) -> None:
        result = optimize(self.graph, self.kernel, "lm", initial=self._poses)
        self._poses = result.poses

    def estimate(self) -> dict[int, Array]:
        return dict(self._poses)

    def marginal_covariance(self, key: int) -> Array:
        if self._marginals is None:
            factors, _ = self.graph.factor_graph(self.kernel)
            self._marginals = gtsam.Marginals(factors, self.graph.gtsam_values(self._poses))
        return np.asarray(self._marginals.marginalCovariance(key))


class IncrementalSmoother(Smoother):
    """gtsam.ISAM2: each `update` folds in only the poses and factors added since the last.

    Args:
        relinearize_threshold: iSAM2 relinearisation threshold (tangent units).
        extra_iterations: further ``update()`` calls without new factors after a loop
            closure, so iSAM2's single Gauss-Newton step converges on large corrections.

    Factorisation: Cholesky, the fast one.  When it gives up on an ill-conditioned
    system (gtsam's "indeterminate linear system": e.g. an odometry step whose
    covariance says the front end is lost, 10 m and pi rad, next to millimetre-level
    steps), iSAM2 is rebuilt once from the whole graph with QR factorisation, about
    1.4x slower but stable, for the rest of the run (one warning).
    """

    def __init__(
        self,
        dim: int = 2,
        kernel: str | RobustKernel = "cauchy",
        relinearize_threshold: float = 0.01,
        extra_iterations: int = 2,
    ) -> None:
        super().__init__(dim, kernel)
        self._relinearize_threshold = relinearize_threshold
        self._factorization = "CHOLESKY"
        self._isam = self._new_isam()
        self._new_factors = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()
        self._anchored = False
        self._loop_pending = False
        self._extra_iterations = extra_iterations
        self._estimate: gtsam.Values | None = None

    def _on_pose(self, key: int, guess: Array) -> None:
        self._new_values.insert(key, to_gtsam_pose(guess, self.dim))
        if not self._anchored:
            self._new_factors.add(self.graph.prior_factor(key, guess))
            self._anchored = True

    def _on_factor(self, factor: gtsam.NonlinearFactor, is_loop: bool) -> None:
        self._new_factors.add(factor)
        self._loop_pending |= is_loop

    def _new_isam(self) -> gtsam.ISAM2:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(self._relinearize_threshold)
        params.relinearizeSkip = 1
        params.setFactorization(self._factorization)
        return gtsam.ISAM2(params)

    def _restart_with_qr(self) -> None:
        """Rebuild iSAM2 with QR from every factor and the latest estimate (class doc)."""
        warn("iSAM2: Cholesky found the pose graph ill-conditioned; continuing with QR "
             "factorisation (slower)")
        self._factorization = "QR"
        self._isam = self._new_isam()
        factors, _ = self.graph.factor_graph(self.kernel)
        current = self.estimate()
        values = gtsam.Values()
        for key, guess in self.graph.initial.items():
            values.insert(key, to_gtsam_pose(current.get(key, guess), self.dim))
        self._isam.update(factors, values)

    def update(self) -> None:
        if self._new_factors.size() == 0 and self._new_values.size() == 0:
            return
        try:
            self._isam.update(self._new_factors, self._new_values)
        except RuntimeError:
            if self._factorization == "QR":
                raise
            self._restart_with_qr()
        if self._loop_pending:
            for _ in range(self._extra_iterations):
                self._isam.update()
        self._new_factors = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()
        self._loop_pending = False
        self._estimate = self._isam.calculateEstimate()

    def estimate(self) -> dict[int, Array]:
        if self._estimate is None:
            return {}
        return poses_from_values(self._estimate, self.dim)

    def estimate_rows(self) -> tuple[NDArray[np.int64], Array]:
        if self._estimate is None or self.dim != 2:
            return super().estimate_rows()
        keys = np.asarray(self._estimate.keys(), dtype=np.int64)  # ascending
        return keys, gtsam.utilities.extractPose2(self._estimate)  # rows in key order

    def marginal_covariance(self, key: int) -> Array:
        return np.asarray(self._isam.marginalCovariance(key))
