"""Time-ordered admission of loop closures under the truncated-least-squares loss.

The truncated-least-squares (TLS) objective of a pose graph with loop constraints
``k`` is (gtsam error units, ``e = 0.5 r^T I r``)::

    J(x, w) = sum_odometry e(x) + sum_k [ w_k e_k(x) + (1 - w_k) c ],   w_k in {0, 1}

with ``c = 0.5 chi2_dof^-1(p)`` (`tls_threshold`): a loop is worth keeping when it
costs less than ``c``.  Graduated non-convexity (Yang, Antonante, Tzoumas &
Carlone, "Graduated Non-Convexity for Robust Spatial Perception", RA-L 2020)
approaches this optimum through a convex surrogate; at small ``mu`` that
surrogate is close to an L1 loss, in which every loop pulls with the same force
whatever its residual.  With half the loops false (plausible measurements between
random poses) those pulls fold a graph such as M3500 before the surrogate turns
robust: GNC can fail on M3500 at 50% false loops from every start, including the
outlier-free optimum itself.

This module reaches the TLS optimum the way a mapper meets its loops: in time
order.  Poses are added in blocks of `block` ids (odometry composed onto the
solved prefix); every loop whose later end falls in the block is then decided
against the solved prefix, which earlier decisions already made consistent:

1. *Residual admission*: a loop whose error at the current solution is at most
   ``c`` is an inlier (the GNC-TLS weight rule in its limit ``mu -> inf``); the
   prefix is re-solved and the rule re-applied until nothing changes.
2. *Innovation admission* for the rest.  Adding loop ``k`` (whitened Jacobian ``B``,
   whitened residual ``b`` at the solution ``x*`` of the accepted graph, whose
   information is ``H = A^T A``) raises the least-squares cost, to first order, by
   the innovation (Schur complement) form::

       delta_k = 0.5 b^T (I + B H^-1 B^T)^-1 b

   the individual-compatibility test of Neira & Tardós (IEEE T-RA 2001), here the
   exact linearised TLS criterion: admitting ``k`` lowers ``J`` iff ``delta_k < c``.
   Candidates are admitted greedily, smallest ``delta`` first; after each
   admission the others' ``delta`` are updated exactly by the rank-``dof``
   (Sherman-Morrison-Woodbury) update of ``H^-1``, so two loops that contradict
   each other are never both admitted on the strength of the same slack.
   ``H`` is factorised once per round (sparse LU of the whitened normal equations).
   A candidate whose test has no power against a wrong place of the map (the prefix
   ties its poses only through a long, loosely stated odometry chain, so the gate
   would admit almost any measurement) is not admitted in its own block but deferred
   and decided by consensus with the loops that arrive later (`slam.deferral`).
3. Decisions are final for the incremental pass; `refine_tls` then re-decides every
   loop on the whole graph by the residual rule until the weights are stable.

`incremental_tls` wraps the pass in two local searches on the stated TLS objective:

* an *odometry ladder*: the pass decides on the graph with its odometry information
  multiplied by 1, 10 and 100 (a loose stated odometry makes the solved prefix floppy,
  and early false loops bend it onto themselves), each result refined under the
  stated covariances, the lowest stated `tls_cost` kept;
* a *bar search* (`bar_search`): the pass is repeated with the most strained
  accepted loop barred, kept when the stated cost drops (a false loop admitted early
  can fold a graph with few loops beyond what any residual rule recovers).

The innovation gate is where the noise model matters.  ``delta`` measures a loop
against the uncertainty the graph's own covariances claim; when they are far
more pessimistic than the data (M3500: the a-posteriori variance factor of the
outlier-free solution is 0.024), a stretch of trajectory tied to the map only
by a long odometry chain can be bent onto any false loop at a cost below ``c``.
`admit_incrementally` therefore has two gates: ``"stated"`` (``c``) and
``"calibrated"``, ``c`` times the a-posteriori variance factor of the accepted
prefix, ``s0^2 = 2 J_accepted / (m - n)`` (the estimated variance of unit weight
of least-squares adjustment, e.g. Förstner & Wrobel, *Photogrammetric Computer
Vision*, 2016), capped at 1 and used once the prefix has a redundancy ``m - n`` of
at least `MIN_REDUNDANCY_LOOPS` loops' worth.  Heavy-tailed graphs (Intel: a few
true loops with innovations near ``c`` although ``s0^2 = 0.2``) need the stated
gate; `incremental_tls` runs both and keeps the solution with the lower TLS
objective `tls_cost` (under the stated covariances), a plain two-start local
search.  Limitation: judged by the stated covariances, bending a loose tail onto
a lone false loop can be cheaper than rejecting it; when the stated run makes
no other mistake it then wins the comparison and keeps that loop (see
``test_calibrated_gate_refuses_a_false_loop_on_a_loose_tail``).

Related: pairwise consistency maximisation (PCM, Mangelson, Dominic, Eustice &
Vasudevan, ICRA 2018) tests pairs of loops through odometry chains; with
covariances as pessimistic as M3500's those chains are uninformative, which is
why the test here is against the solved prefix, as incremental robust back ends
do (riSAM, McGann, Rogers & Kaess, ICRA 2023; IPC, arXiv 2405.08503), here in
batch form.

Cost: a factorisation and ``dof`` sparse solves per candidate and round, and a
prefix solve per admission round.  The prefix solves are updates of one iSAM2 per
pass, which re-eliminate only what the new factors touch, until iSAM2's undamped
updates stop converging (admitted false loops folded the prefix); the pass then
goes on with batch solves (LM, dogleg-QR where LM fails), whose damping copes
(`admit_incrementally`'s ``prefix_solver``; ``benchmarks/tls_speed.py`` measures
the passes against an earlier revision).  Passes that share their first blocks share
their work: the calibrated pass is the stated one on the same graph until the first
block in which the calibrated gate admits less, and a `bar_search` trial is the pass it
improves on until the block that decides its barred loop; each resumes a snapshot of
the other (`AdmissionPass.resumed`; the same computation, bit for bit).

Modules: the innovation test and `greedy_admission` are `slam.innovation` (marginal
covariances from `slam.selected_inverse`), one pass (steps 1-3, `AdmissionPass`,
`admit_incrementally`, `tls_cost`) is `slam.admission`, its iSAM2 prefix
`slam.isam_prefix`; this module holds the searches over passes (`incremental_tls`,
`bar_search`) and `polish` (`refine_tls` is `slam.tls_refine`), and re-exports the
names it always exported.

Requirements: the smallest pose id is an anchor and every later pose is reached by
odometry from an earlier one (the odometry spine of a mapper or a g2o file);
`incremental_tls` raises `UserError` otherwise.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from slam.admission import (
    GATES,
    Admission,
    AdmissionPass,
    StatedFactors,
    admit_incrementally,
    has_odometry_spine,
    tls_cost,
)
from slam.innovation import InnovationTest, admission_costs, greedy_admission, tls_threshold
from slam.least_squares import StickySolver
from slam.pose_graph import (
    Constraint,
    PoseGraph,
    RobustKernel,
)
from slam.regroup import regroup as redecide
from slam.tls_refine import refine_tls, stated_with_loops
from slam.warm_starts import WarmStarts

__all__ = [
    "BAR_TRIES", "DEFER_MODES", "LM_BUDGET", "ODOMETRY_LADDER", "POLISH_TOLERANCE",
    "Admission", "AdmissionPass", "InnovationTest", "StatedFactors", "admission_costs",
    "admit_incrementally", "bar_search", "greedy_admission", "has_odometry_spine",
    "incremental_tls", "needs_qr", "polish", "refine_tls", "stated_with_loops", "tls_cost",
    "tls_threshold",
]

Array = NDArray[np.float64]
ODOMETRY_LADDER = (1.0, 10.0, 100.0)  # odometry information factors `incremental_tls` decides at
BAR_TRIES = 5  # at most this many trials of `incremental_tls`'s `bar_search`
LM_BUDGET = 25  # LM iterations of a warm-started solve before dogleg (`StickySolver`)
POLISH_TOLERANCE = 1e-10  # `polish` stops below this relative decrease of the error
BOUNDED_WAIT = 1  # loop-bearing blocks a deferred loop waits under ``defer="bounded"``
# `incremental_tls`'s deferral of powerless tests
DEFER_MODES = ("off", "candidate", "all", "bounded", "both")
# `incremental_tls`'s `refine_tls` solves start from the solution already found (any run,
# any loops) that is cheapest on the graph to solve (`slam.warm_starts.WarmStarts`);
# False: each from the run's own solution.
WARM_STARTS = True
# `incremental_tls`'s `regroup` when not given: re-decide an early admitted loop against a
# later group of rejected loops that contradicts it (`slam.regroup`).
REGROUP = False
# `incremental_tls` climbs its odometry ladder no further once a rung's finished pass,
# refined, decides every loop as a finished pass of the rung below did (False: every rung).
LADDER_STOP = False
# `incremental_tls` skips its bar search when a finished pass decided on another rung's
# graph, refined, keeps exactly the winner's loops (False: the bar search always runs).
BAR_AGREE = False


def needs_qr(graph: PoseGraph, values: gtsam.Values) -> bool:
    """True when sparse Cholesky cannot eliminate the anchors and odometry of `graph`
    linearised at `values` (Intel's near-singular information matrices; milliseconds)."""
    factors = gtsam.NonlinearFactorGraph()
    for k in graph.anchor_keys():
        factors.add(graph.prior_factor(k))
    for o in graph.odometry:
        factors.add(graph.between_factor(o))
    try:
        factors.linearize(values).eliminateMultifrontal()  # Cholesky
    except RuntimeError:  # gtsam IndeterminateLinearSystemException
        return True
    return False


def bar_search(
    graph: PoseGraph,
    decide: PoseGraph,
    values: gtsam.Values,
    best: Admission,
    *,
    probability: float = 0.99,
    block: int = 50,
    tries: int = 3,
    solver: StickySolver | None = None,
    prefix_solver: str = "auto",
    unit: list[gtsam.NonlinearFactor] | None = None,
    factors: StatedFactors | None = None,
    gate: str = "stated",
    source: AdmissionPass | None = None,
    defer: bool = False,
    wait: int | None = None,
    undo: bool = False,
    confirm: bool = False,
    starts: WarmStarts | None = None,
) -> Admission:
    """Local search on the TLS objective: re-run the admission without one accepted loop.

    A false loop admitted early can fold the map so far that the true loops it
    contradicts sit at errors of ``1e6 c``: neither `refine_tls` nor a solve without the
    false loop leaves that basin (the map stays folded).  A trial bars one accepted
    loop and repeats the time-ordered admission of the winning run (on `decide`, the
    graph it decided on, with its `gate`) from `values`, then `refine_tls` on `graph`
    with the loop still barred.  Trials take the accepted loops in decreasing order of
    factor error at the solution of `best` (the false loop of a fold is the most
    strained): a trial that lowers `tls_cost` (stated covariances) is kept, its loop
    stays barred and the ranking is redone at the new solution; the search ends at the
    first trial that does not, or after `tries` (one extra admission run when there is
    nothing to fix).  A trial whose prefix folds (`AdmissionPass`) and whose decided
    part already costs more than `best` on the same part has failed, and stops there.
    `factors`: as in `tls_cost`.  `source`: the pass (made with ``record=True``) that
    gave `best`, on `decide` with `gate`: a trial resumes it from before the block that
    decides its barred loop (`AdmissionPass.resumed`), as is the next trial from a kept
    one, instead of deciding every block again.  `starts`: `refine_tls`'s.
    """
    solve = solver or StickySolver()
    factors = factors or graph.factor_graph(RobustKernel("none"))
    if unit is None:
        unit = [factors[0].at(k) for k in factors[1]]
    barred: list[int] = []
    done: set[int] = set()
    while len(done) < tries:
        errors = np.array([f.error(best.values) for f in unit])
        accepted = [int(k) for k in np.argsort(-errors) if best.weights[k] > 0.5
                    and int(k) not in done]
        if not accepted:
            break
        k = accepted[0]
        done.add(k)
        trial = [*barred, k]
        if source is not None and source.snapshots is not None:
            run = source.resumed(source.block_of(k), barred=trial)
        else:
            run = AdmissionPass(decide, values, probability=probability, block=block,
                                gate=gate, solver=solve, barred=trial,
                                prefix_solver=prefix_solver, unit=unit, defer=defer,
                                wait=wait, undo=undo, confirm=confirm)
        if not _finish_unless_behind(run, best, factors, probability):
            break
        refined, weights = refine_tls(graph, run.current, run.weights,
                                      probability=probability, solver=solve, barred=trial,
                                      solved=decide is graph, factors=factors, starts=starts)
        cost = tls_cost(graph, refined, probability, factors)
        if not cost < best.tls_cost * (1.0 - 1e-9):
            break
        barred, source = trial, run
        best = Admission(refined, weights, cost, run.blocks, f"{_gate_of(best)}-barred")
    return best


def _gate_of(admission: Admission) -> str:
    """The innovation gate of an `incremental_tls` run from its label (``"calibrated"``,
    ``"stated-odometry-x10"``, ``"stated-barred"`` ...)."""
    return admission.gate.split("-")[0]


def _finish_unless_behind(
    run: AdmissionPass, best: Admission | None, factors: StatedFactors, probability: float
) -> bool:
    """Advance `run` to its end, unless, once its prefix has folded, its decided part
    costs more than `best` on the same part (`AdmissionPass.prefix_cost`, checked after
    every block); True when it finished.

    Why: a pass whose admitted loops folded its prefix goes on with damped batch solves
    (several times the cost of the iSAM2 updates), and the time-ordered pass's decisions
    are final, so a folded pass that trails the best finished run on the poses it has
    decided is not worth finishing."""
    if not run.folded:
        run.advance(until_fold=True)
    while not run.done:
        if best is not None and (run.prefix_cost(run.current, factors, probability)
                                 > run.prefix_cost(best.values, factors, probability)):
            return False
        run.advance(blocks=1)
    return True


def incremental_tls(
    graph: PoseGraph,
    values: gtsam.Values,
    *,
    probability: float = 0.99,
    block: int = 50,
    ladder: Sequence[float] = ODOMETRY_LADDER,
    tries: int = BAR_TRIES,
    prefix_solver: str = "auto",
    choose: Callable[..., int | tuple[int, Array | None]] | None = None,
    defer: str = "off",
    undo: bool = False,
    confirm: bool = False,
    regroup: bool | None = None,
) -> Admission:
    """TLS solution by time-ordered admission over an odometry ladder, then `refine_tls`.

    For every factor ``m`` of `ladder` the loops are *decided* by `admit_incrementally`
    on the graph whose odometry information is multiplied by ``m`` (both gates at
    ``m = 1``, the stated gate elsewhere: above 1 the calibrated gate's variance factor
    is mostly capped and it repeats the stated run), and the decisions are refined by
    `refine_tls` on the graph *as stated*; the run with the lowest stated `tls_cost`
    is returned (the module docstring's local search, over ``len(ladder) + 1`` starts;
    every rung is run, since the costs along the ladder need not be monotone; with
    `LADDER_STOP` the climb ends after a rung whose finished pass, refined, keeps exactly
    the loops of a finished pass of the rung below, `_rung_agrees`).

    Why: the TLS objective under the stated covariances is the criterion, but deciding
    loops under odometry covariances that are far more pessimistic than the data
    lets early false loops bend the solved prefix onto themselves (step 2's gate is
    only as sharp as the prefix is stiff).  A rung ``m`` decides as if the odometry
    were ``m`` times more precise; the stated refinement re-admits every loop the
    stated model accepts at that solution (``e_k <= c``), so at 0% outliers every rung
    ends at the plain optimum and ties keep the first.  A run whose iSAM2 prefix folds
    (`AdmissionPass`) stops at the fold and is finished after the others only if the
    part it has decided is still cheaper than the best finished run's on the same
    part.  The best run is then improved by `bar_search` with `tries` trials (0: none),
    which repeats the winning run's graph and gate (with `BAR_AGREE`, not when a
    candidate of another rung keeps exactly the winner's loops, `_other_rung_agrees`).

    `defer` (`DEFER_MODES`): ``"bounded"``: every run defers the loops whose
    innovation test has no power (`slam.deferral`), for `BOUNDED_WAIT` loop-bearing blocks:
    they are offered to the consensus of the loops that arrive meanwhile, and a loop still
    deferred then is decided by the plain gate against the prefix as those loops left it
    (every one still deferred at the last block, too).  ``"off"`` (the default) decides
    every loop in its own block; ``"all"``: deferred loops wait to the end of the pass, and
    those still deferred there are rejected; ``"candidate"``: one more run, on the graph as
    stated with the stated gate, defers as ``"all"`` does (label ``"stated-deferred"``) and
    replaces the chosen run (`choose`, or the lowest stated cost) when it dominates it: a
    lower stated `tls_cost` with more loops admitted (under ``"all"`` any run may dominate
    so); ``"both"``: every rung is run without and with the bounded deferral (labels of the
    latter end in ``"-bounded"``), and `choose` (or the lowest stated cost) picks among all.

    Why a bounded wait: the first loop back to a place after a long stretch of odometry is
    decided against a prefix that ties its two poses only through that stretch, so a false
    one passes the gate, bends the map onto itself and makes the true loops of the same
    return, arriving a block later, fail it; waiting one block lets those true loops, which
    agree with one another, be admitted first (their consensus), and the false one is then
    judged against the map they made.  Waiting longer, or to the end (``"all"``), rejects
    true loops that have no consensus to wait for on a graph of few, far-apart loops, and
    ``"candidate"`` lets false loops that lower the stated objective in.  Not the default:
    the consensus admits a group of false loops that agree with one another as readily as
    the true loops of a return (false loops in groups, `benchmarks/robust_bounded.md`), and
    on Intel with its odometry information x0.1 the bounded run ends in a worse TLS
    objective (random, seed 0); with ``"both"`` the calibrated choice still picks the
    false group on MITb.

    `choose`: picks the winner among the refined runs instead of the lowest stated cost,
    called as ``choose(graph, [(values, weights, stated cost), ...], probability=...,
    solver=..., unit=...)`` and returning an index, or -1 to keep the lowest stated cost
    (`slam.calibrated_choice.calibrated_choice`); or ``(index, weights)``, weights (or None) that
    replace the chosen run's loop decisions (`slam.offer_back.choose_and_offer_back`),
    the stated graph re-solved with them.

    `undo`: every pass tests, after each block, whether loops it admitted in the last
    blocks made the block's loops fail, and undoes them when the decided loops' TLS
    objective drops (`slam.admission_undo`); off by default.

    `confirm`: every pass turns back an admission by the innovation gate whose actual
    cost (the accepted prefix's error less its error re-solved without the loop) is above
    ``c`` (`AdmissionPass.confirm`); off by default.

    `regroup` (None: `REGROUP`): before the bar search, the chosen run's admitted loops
    that a later group of rejected, mutually agreeing loops contradicts are re-decided
    against that group (`slam.regroup.regroup`: the group in, they out, kept only when
    the stated `tls_cost` drops).
    """
    if not ladder:
        raise UserError("the odometry ladder needs at least one factor")
    if defer not in DEFER_MODES:
        raise UserError(f"unknown deferral {defer!r}; use {', '.join(DEFER_MODES)}")
    best: Admission | None = None
    decided: PoseGraph | None = None
    # Dogleg-QR from the start where the odometry needs QR (Intel: LM runs out its
    # iterations there without raising); elsewhere an LM that does not converge hands only
    # that solve to dogleg (M3500: one bad start made every later solve dogleg, 2-4x
    # slower).
    solver = StickySolver(lm_budget=LM_BUDGET, sticky=False)
    solver.dogleg = needs_qr(graph, values)
    stated = graph.factor_graph(RobustKernel("none"))  # built once for every run below
    base, loop_index = stated
    unit = [base.at(k) for k in loop_index]  # the loops' factors, the same on every rung
    runs = []
    # (defers, wait) of the passes run at every rung: "both" runs each rung without and
    # with the bounded deferral, and the choice compares all of them.
    variants = {"off": [(False, None)], "candidate": [(False, None)], "all": [(True, None)],
                "bounded": [(True, BOUNDED_WAIT)],
                "both": [(False, None), (True, BOUNDED_WAIT)]}[defer]
    refined_of: dict[int, tuple[gtsam.Values, Array, float]] = {}  # id(run) -> refined
    starts = WarmStarts() if WARM_STARTS else None  # every refined solution, as starts

    def refined(decide: PoseGraph, run: AdmissionPass) -> tuple[gtsam.Values, Array, float]:
        """`run` (finished) refined on the stated graph, and its stated `tls_cost`."""
        if id(run) not in refined_of:
            values_, weights_ = refine_tls(
                graph, run.current, run.weights, probability=probability, solver=solver,
                solved=decide is graph, factors=stated, starts=starts,
            )
            refined_of[id(run)] = (values_, weights_,
                                   tls_cost(graph, values_, probability, stated))
        return refined_of[id(run)]

    rungs: list[list[tuple[PoseGraph, AdmissionPass]]] = []  # the finished passes per rung
    for factor in ladder:
        if LADDER_STOP and len(rungs) >= 2 and _rung_agrees(rungs[-1], rungs[-2], refined):
            break
        rungs.append([])
        decide = graph if factor == 1.0 else _odometry_scaled(graph, factor)
        for defers, wait in variants:
            for gate in GATES if factor == 1.0 else GATES[:1]:
                label = gate if factor == 1.0 else f"{gate}-odometry-x{factor:g}"
                label += "-bounded" if wait is not None and defer == "both" else ""
                if gate == "calibrated" and runs and runs[-1][1] is decide:
                    # The same as the stated pass on this graph up to the first block in
                    # which the calibrated gate admits less (`AdmissionPass.calibrated_step`).
                    stated_run = runs[-1][2]
                    step = stated_run.calibrated_step
                    run = stated_run.resumed(stated_run._step if step is None else step,
                                             gate=gate)
                else:
                    run = AdmissionPass(decide, values, probability=probability, block=block,
                                        gate=gate, solver=solver, prefix_solver=prefix_solver,
                                        unit=unit, record=tries > 0 or gate == "stated",
                                        defer=defers, wait=wait, undo=undo,
                                        confirm=confirm)
                run.advance(until_fold=True)
                if run.done:
                    run.release_prefix()
                    rungs[-1].append((decide, run))
                runs.append((label, decide, run))
    if defer == "candidate":
        run = AdmissionPass(graph, values, probability=probability, block=block,
                            solver=solver, prefix_solver=prefix_solver, unit=unit,
                            record=True, defer=True)
        run.advance(until_fold=True)
        if run.done:
            run.release_prefix()
        runs.append(("stated-deferred", graph, run))
    # Finished runs first, then the folded ones in ladder order, each only if still ahead.
    finished: list[tuple[Admission, PoseGraph, AdmissionPass]] = []
    source: AdmissionPass | None = None
    for label, decide, run in sorted(runs, key=lambda r: not r[2].done):
        finishes = _finish_unless_behind(run, best, stated, probability)
        run.release_prefix()  # decided: the pass is never advanced again
        if not finishes:
            continue
        solution, weights, cost = refined(decide, run)
        finished.append((Admission(solution, weights, cost, run.blocks, label), decide, run))
        if best is None or cost < best.tls_cost * (1.0 - 1e-9):
            best, decided, source = finished[-1]
    assert best is not None and decided is not None
    if choose is not None and len(finished) > 1:
        pick = choose(graph, [(a.values, a.weights, a.tls_cost) for a, _, _ in finished],
                      probability=probability, solver=solver, unit=unit)
        pick, offered = pick if isinstance(pick, tuple) else (pick, None)
        if pick >= 0:
            best, decided, source = finished[pick]
        if pick >= 0 and offered is not None:
            kept = stated_with_loops(stated, offered)
            refined = solver(kept, best.values)
            best = Admission(refined, np.asarray(offered, dtype=float),
                             tls_cost(graph, refined, probability, stated), best.blocks,
                             f"{best.gate}-offered")
    for admission, graph_of, run in finished:
        # The deferred run dominates a choice that explains fewer loops at a higher cost.
        if (run.defer and defer in ("all", "candidate") and admission.tls_cost < best.tls_cost
                and admission.weights.sum() > best.weights.sum()):
            best, decided, source = admission, graph_of, run
    if REGROUP if regroup is None else regroup:

        regrouped = redecide(graph, best, values, probability=probability, solver=solver,
                             factors=stated)
        best = regrouped.admission
    if tries and not (BAR_AGREE and _other_rung_agrees(best, decided, finished)):
        best = bar_search(graph, decided, values, best, probability=probability, block=block,
                          tries=tries, solver=solver, prefix_solver=prefix_solver, unit=unit,
                          factors=stated, gate=_gate_of(best), source=source,
                          defer=source is not None and source.defer,
                          wait=None if source is None else source.wait, undo=undo,
                          confirm=confirm, starts=starts)
    # The winner may be an unpolished admission (refine_tls's `solved`): one batch solve
    # with its weights, by dogleg-QR, which stops closer to the optimum along M3500's flat
    # directions than LM at the same tolerance (0% outliers: 0.9 mm from the plain optimum
    # with LM).
    polished = polish(stated, best.weights, best.values, solver.max_iterations)
    return Admission(polished, best.weights, tls_cost(graph, polished, probability, stated),
                     best.blocks, best.gate)


def _rung_agrees(
    rung: list[tuple[PoseGraph, AdmissionPass]],
    below: list[tuple[PoseGraph, AdmissionPass]],
    refined: Callable[[PoseGraph, AdmissionPass], tuple[gtsam.Values, Array, float]],
) -> bool:
    """True when a finished pass of `rung` (pairs of the graph it decided on and the pass),
    refined by `refined`, keeps exactly the loops (weights above 0.5) of a finished pass
    of the rung `below`, refined: the stiffer odometry changed no decision.

    Why the ladder may stop there: a rung exists to reject early false loops that bend a
    floppy prefix onto themselves; when multiplying the odometry information by the
    rung's factor leaves every refined decision as it was, the decisions are not bent
    by the prefix's floppiness, and a stiffer rung would only reject true loops that the
    stated refinement then re-admits (at 0% outliers every rung ends at the plain
    optimum).  A measured rule, not a proof: the stiffer rung is not run to check it."""
    # the rung below refined first: the refinements run in the order they would without
    # the test (`refine_tls`'s warm starts are the solutions refined before)
    kept_below = [refined(decide, run)[1] > 0.5 for decide, run in below]
    return any(any(np.array_equal(refined(decide, run)[1] > 0.5, kept) for kept in kept_below)
               for decide, run in rung)


def _other_rung_agrees(
    best: Admission, decided: PoseGraph,
    finished: Sequence[tuple[Admission, PoseGraph, AdmissionPass]],
) -> bool:
    """True when a finished candidate decided on another graph than `decided` (another
    rung of the odometry ladder) keeps exactly the loops of `best` (weights above 0.5).

    Why the bar search may be skipped then: it looks for an early false loop that folded
    the winner's prefix beyond what the residual rule recovers; a fold comes from a prefix
    too floppy for the false loop's pull, and a pass on odometry ten times stiffer that
    ends with the same loops was not bent by it.  A measured rule, not a proof."""
    kept = best.weights > 0.5
    return any(graph is not decided and np.array_equal(kept, admission.weights > 0.5)
               for admission, graph, _ in finished)


def polish(
    factors: StatedFactors, weights: Array, values: gtsam.Values, max_iterations: int = 100
) -> gtsam.Values:
    """The stated graph `factors` with the loops of ``weights > 0.5`` solved from `values`
    by Powell's dogleg with multifrontal QR, until an iteration lowers the error by less
    than `POLISH_TOLERANCE` of it (relative decrease ``(E_old - E_new) / E_old``; no
    absolute criterion, so a graph whose error is small in gtsam units, as one with
    loosely stated information, is solved as far as one with a large error).

    Why so tight: along the flat directions of a loosely stated graph a solve that stops
    at ``1e-6``, or at gtsam's default absolute decrease of ``1e-5``, can end visibly
    short of the optimum (MITb with odometry information scaled by 0.01: decimetres).
    """
    kept = stated_with_loops(factors, weights)
    params = gtsam.DoglegParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(POLISH_TOLERANCE)
    params.setAbsoluteErrorTol(0.0)
    params.setLinearSolverType("MULTIFRONTAL_QR")
    return gtsam.DoglegOptimizer(kept, values, params).optimize()


def _odometry_scaled(graph: PoseGraph, factor: float) -> PoseGraph:
    """A copy of `graph` with every odometry information matrix multiplied by `factor`."""
    odometry = [Constraint(c.i, c.j, c.measurement, c.information * factor)
                for c in graph.odometry]
    return PoseGraph(graph.dim, dict(graph.initial), odometry, list(graph.loops),
                     set(graph.fixed))
