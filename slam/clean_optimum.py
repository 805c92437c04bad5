"""The robust back end's fast path: the plain least-squares optimum when it is the TLS decision.

`slam.optimize.optimize` (``method="gnc"``, ``gnc_start="incremental"``) first tries
`_clean_optimum`; only when a loop fails its chi-square test there (or the segment
re-check removes one) does the time-ordered admission (`slam.consistency`) run.
"""

from __future__ import annotations

import gtsam
import numpy as np

from slam.consistency import LM_BUDGET, ODOMETRY_LADDER, needs_qr, polish, tls_threshold
from slam.fast_path_screen import majority_fails, stalled_solve
from slam.least_squares import StickySolver, solve
from slam.pose_graph import Constraint, PoseGraph, RobustKernel
from slam.segment_recheck import segment_recheck
from slam.variance_components import with_information_scaled


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
        rung = factors if factor == 1.0 else _rung_factors(graph, factors, loop_index, factor)
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


def _rung_factors(
    graph: PoseGraph, factors: gtsam.NonlinearFactorGraph, loop_index: list[int],
    factor: float,
) -> gtsam.NonlinearFactorGraph:
    """The factor graph of `graph` with its odometry information multiplied by `factor`:
    ``with_information_scaled(graph, factor).factor_graph(RobustKernel("none"))[0]``,
    factor for factor (priors, odometry, loops, in that order), but the priors and
    the loops, which do not depend on the odometry's scale, are the very factors of
    `factors` (the stated graph's `PoseGraph.factor_graph`, loops at `loop_index`):
    only the odometry factors are made anew.  Information in the units of
    `graph`'s (its inverse covariances in g2o order)."""
    priors = len(graph.anchor_keys())
    if list(loop_index) != list(range(priors + len(graph.odometry), factors.size())):
        # not laid out as `factor_graph` lays a graph out: build it whole
        return with_information_scaled(graph, factor).factor_graph(RobustKernel("none"))[0]
    rung = gtsam.NonlinearFactorGraph()
    for k in range(priors):
        rung.add(factors.at(k))
    for c in graph.odometry:
        rung.add(graph.between_factor(
            Constraint(c.i, c.j, c.measurement, c.information * factor)))
    for k in loop_index:
        rung.add(factors.at(k))
    return rung
