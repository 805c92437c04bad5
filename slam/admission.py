"""One time-ordered admission pass of loop closures under the TLS loss.

The pass of `slam.consistency` (its module docstring, steps 1-3): poses are added in
blocks of `block` ids (odometry composed onto the solved prefix); every loop whose later
end falls in the block is decided against the solved prefix, first by the residual rule
``e_k <= c`` (gtsam error units; ``c`` = `slam.innovation.tls_threshold`), then by the
innovation test (`slam.innovation`) under the ``"stated"`` gate ``c`` or the
``"calibrated"`` gate ``c min(1, s0^2)``, ``s0^2 = 2 J_accepted / (m - n)`` the
a-posteriori variance factor of the accepted prefix (used once the redundancy is at
least `MIN_REDUNDANCY_LOOPS` loops' worth).  The prefix is re-solved after every
admission round by one iSAM2 per pass (`slam.isam_prefix`) or by batch solves.

`AdmissionPass` holds the state of a pass so that it can stop after a fold, resume, and
be resumed from a snapshot by a pass that differs from a given block on
(`slam.consistency.incremental_tls`, `slam.consistency.bar_search`); `admit_incrementally`
runs one pass to its end.  `tls_cost` is the TLS objective every search compares.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import NDArray

from data import se2
from data.errors import UserError
from slam.admission_undo import pose_of, settle, test_hypotheses
from slam.admission_undo import with_loops as _with
from slam.deferral import (
    MIN_POWER,
    alternative_offsets,
    alternative_places,
    consensus,
    power,
    whitened_offsets,
)
from slam.innovation import (
    InnovationTest,
    admission_costs,
    greedy_admission,
    removal_costs,
    tls_threshold,
)
from slam.isam_prefix import IsamPrefix, isam_or_batch
from slam.least_squares import StickySolver
from slam.pose_graph import (
    PoseGraph,
    RobustKernel,
    pose_dof,
    poses_from_values,
    to_gtsam_pose,
)

Array = NDArray[np.float64]
GATES = ("stated", "calibrated")
MIN_REDUNDANCY_LOOPS = 10  # the calibrated gate needs this many loops' worth of redundancy
PREFIX_SOLVERS = ("auto", "batch", "isam2")  # `admit_incrementally`'s prefix_solver
SNAPSHOTS = 2  # at most this many snapshots of a recorded `AdmissionPass` (each an iSAM2 copy)
# A recorded stated pass also keeps the snapshot before the block that sets its
# `calibrated_step` (a snapshot is taken before every block until then and dropped after
# it), so the calibrated pass forks exactly there instead of re-deciding the blocks since
# the evenly spaced snapshot before it (False: evenly spaced snapshots only).
FORK_SNAPSHOT = True
CONFIRM_MODES = ("exact", "screen")  # `AdmissionPass`'s confirm (True is "exact")
# The screen (`confirm="screen"`) clears an admitted loop without its leave-one-out solve
# when its linearised leave-one-out cost is at most this fraction of ``c``.
SCREEN_FRACTION = 0.5
# The screen solves the loops it does not clear in decreasing ``rho`` and skips a loop
# whose ``rho / SCREEN_FRACTION`` is below the largest actual cost above ``c`` already
# solved in the same turn (it cannot be the costliest under the same margin); False: every
# loop not cleared is solved, in admission order.
SCREEN_SKIP = True
# A round whose nonlinear check turns loops back keeps, as the pass's iSAM2 prefix, the
# leave-one-out copy that already solved the prefix without them (the copy of the same
# iSAM2 with the same factors taken out: the same estimate, bit for bit) instead of
# taking them out of the prefix and solving it again (False: solved again).
ADOPT_LEAVE_ONE_OUT = True


@dataclass(slots=True)
class Admission:
    """Result of a TLS solve by time-ordered admission.

    Attributes:
        values: solution (gtsam Values of every pose).
        weights: 1 for loops kept, 0 for loops rejected (order of `graph.loops`).
        tls_cost: `tls_cost` of the solution under the graph's stated covariances.
        blocks: prefix solves of the incremental pass.
        gate: ``"stated"`` or ``"calibrated"`` (module docstring).
        prefix: how the prefix was solved, ``"batch"``, ``"isam2"`` or
            ``"isam2-then-batch"`` (iSAM2 until its updates stopped converging; see
            `slam.isam_prefix.IsamPrefix`).
    """

    values: gtsam.Values
    weights: Array
    tls_cost: float
    blocks: int
    gate: str
    prefix: str = "batch"


StatedFactors = tuple[gtsam.NonlinearFactorGraph, list[int]]  # `PoseGraph.factor_graph`'s result


def tls_cost(
    graph: PoseGraph, values: gtsam.Values, probability: float = 0.99,
    factors: StatedFactors | None = None,
) -> float:
    """TLS objective at `values`: odometry and prior error plus ``min(e_k, c)`` per loop.

    `factors`: ``graph.factor_graph(RobustKernel("none"))`` when the caller already built
    it (a few milliseconds per thousand constraints, which a search over many runs of the
    same graph would otherwise repeat).
    """
    base, loop_index = factors or graph.factor_graph(RobustKernel("none"))
    c = tls_threshold(graph.dim, probability)
    n_fixed = base.size() - len(loop_index)
    fixed = sum(base.at(k).error(values) for k in range(n_fixed))
    loops = sum(min(base.at(k).error(values), c) for k in loop_index)
    return float(fixed + loops)


def has_odometry_spine(graph: PoseGraph) -> bool:
    """The first pose is anchored and odometry reaches every other pose from an earlier
    one: what the time-ordered admission needs (a graph of two sessions joined by
    loops alone has no spine)."""
    try:
        _check_spine(graph)
    except UserError:
        return False
    return True


def _check_spine(graph: PoseGraph) -> list[int]:
    """Pose ids in order, after checking the anchor and the odometry spine."""
    keys = graph.keys
    if keys[0] not in graph.anchor_keys():
        raise UserError(f"time-ordered admission needs the first pose ({keys[0]}) anchored")
    reached = {max(o.i, o.j) for o in graph.odometry if o.i != o.j}
    missing = len(set(keys[1:]) - reached)
    if missing:
        raise UserError(
            f"time-ordered admission needs odometry from an earlier pose to every pose; "
            f"{missing} poses have none"
        )
    return keys


def _screen_order(rho: Array | None, count: int, ordered: bool) -> NDArray[np.int64]:
    """The order in which `AdmissionPass._unconfirmed` judges the `count` loops of one
    turn: decreasing linearised leave-one-out cost `rho` (gtsam error units; ``inf``
    first, ties in admission order) when `ordered` and there is a screen, else
    admission order."""
    if rho is None or not ordered:
        return np.arange(count, dtype=np.int64)
    return np.argsort(-np.asarray(rho), kind="stable").astype(np.int64)


def _extend(
    solved: dict[int, Array], given: dict[int, Array], ref: int | None, new: list[int], dim: int
) -> None:
    """New poses keep their given pose relative to `ref`, which moved to its solved pose."""
    if ref is None:
        solved.update((k, given[k]) for k in new)
        return
    if dim == 2:
        moved = se2.compose(solved[ref], se2.inverse(given[ref]))
        solved.update(zip(new, se2.compose(moved, np.array([given[k] for k in new])), strict=True))
    else:
        moved = solved[ref] @ np.linalg.inv(given[ref])
        solved.update((k, moved @ given[k]) for k in new)


def _variance_factor(
    factors: gtsam.NonlinearFactorGraph, values: gtsam.Values, poses: int, dof: int
) -> float | None:
    """A-posteriori variance of unit weight ``2 J / (m - n)``; None without enough redundancy."""
    redundancy = dof * factors.size() - dof * poses
    if redundancy < dof * MIN_REDUNDANCY_LOOPS:
        return None
    return 2.0 * factors.error(values) / redundancy


def admit_incrementally(
    graph: PoseGraph,
    values: gtsam.Values,
    *,
    probability: float = 0.99,
    block: int = 50,
    gate: str = "stated",
    max_rounds: int = 50,
    solver: StickySolver | None = None,
    barred: Sequence[int] = (),
    prefix_solver: str = "auto",
    unit: list[gtsam.NonlinearFactor] | None = None,
    defer: bool = False,
    wait: int | None = None,
    undo: bool = False,
) -> Admission:
    """One time-ordered TLS pass (`slam.consistency`'s module docstring, steps 1-3) from
    initial `values`.

    Args:
        graph: the pose graph (2D or 3D); its loops are the candidates.
        values: initial guess of every pose (e.g. the odometry chain); only the poses'
            relative placement within each new block is used.
        probability: chi-square probability of the TLS threshold ``c``.
        block: poses added per step (ids in increasing order).
        gate: ``"stated"`` or ``"calibrated"`` innovation gate.
        max_rounds: admission rounds per block (each ends with a prefix solve).
        solver: least-squares solver (shared by the calls of `slam.consistency.incremental_tls`).
        barred: loops never admitted (weight 0).
        prefix_solver: ``"batch"`` (`solver` on the whole accepted prefix after every
            admission round) or ``"isam2"`` (`IsamPrefix`, handing over to batch solves
            for the rest of the pass once its updates stop converging); ``"auto"`` is
            ``"isam2"``: on a prefix that stays consistent its updates cost a fraction
            of the batch solves, and a folded prefix costs about what batch does.
        unit: the Gaussian factor of every loop (computed when None).
        defer: loops whose innovation test has no power are deferred and decided by
            consensus (`slam.deferral`); loops still deferred at the end are rejected.
            False (the default) decides every loop in its own block.
        wait: with `defer`, a deferred loop waits at most this many loop-bearing blocks
            (blocks that bring loops) for a consensus; still deferred after the rounds of
            the last of them, or at the last block of the pass, it is decided by the
            plain gate against the prefix those rounds left.  None: it waits to the end
            and is rejected there.
        undo: after each block, test whether loops admitted in the last blocks are what
            made this block's loops fail, and undo them when the TLS objective of the
            decided loops says so; a kept hypothesis is compared again with the pass
            without it after the next loop-bearing blocks (`slam.admission_undo`).
    """
    run = AdmissionPass(graph, values, probability=probability, block=block, gate=gate,
                        max_rounds=max_rounds, solver=solver, barred=barred,
                        prefix_solver=prefix_solver, unit=unit, defer=defer, wait=wait,
                        undo=undo)
    run.advance()
    return run.result()


@dataclass(slots=True)
class _Snapshot:
    """The state of an `AdmissionPass` before block `step` (index into its block ends),
    taken while its prefix had not folded; never mutated (`AdmissionPass.resumed` copies
    it)."""

    step: int
    last: int
    blocks: int
    current: gtsam.Values
    weights: Array
    fixed: gtsam.NonlinearFactorGraph
    isam: IsamPrefix | None
    deferred: NDArray[np.int64]
    since: NDArray[np.int64]
    base: gtsam.NonlinearFactorGraph
    admitted_at: NDArray[np.int64]


class AdmissionPass:
    """The state of one `admit_incrementally` pass, which can stop after a fold.

    `advance` adds blocks until the end of the graph, or, with ``until_fold``, until the
    end of the block in which the iSAM2 prefix stopped converging (`IsamPrefix`: the
    admitted loops folded the prefix); `folded` then says so, and a later `advance`
    goes on with the batch solves the pass would have used anyway, so a resumed pass
    equals one that never stopped.  `slam.consistency.incremental_tls` uses this to finish
    a folded pass only when its decided prefix is still cheaper than the best finished pass's
    (`prefix_cost`).  Arguments as `admit_incrementally`.

    `record`: keep `SNAPSHOTS` snapshots of the state before evenly spaced blocks (while
    the prefix has not folded; with `FORK_SNAPSHOT` also the one before the block that
    sets `calibrated_step`), from which `resumed` starts a pass that differs from
    this one only from a given block on: one more barred loop
    (`slam.consistency.bar_search`: every block before the barred loop's is decided as
    here) or the calibrated gate (`calibrated_step`: a stated pass tracks the first block
    in which the calibrated gate would have admitted less).  A resumed pass computes what
    a new pass would, bit for bit.
    """

    def __init__(
        self, graph: PoseGraph, values: gtsam.Values, *, probability: float = 0.99,
        block: int = 50, gate: str = "stated", max_rounds: int = 50,
        solver: StickySolver | None = None, barred: Sequence[int] = (),
        prefix_solver: str = "auto", unit: list[gtsam.NonlinearFactor] | None = None,
        record: bool = False, defer: bool = False, wait: int | None = None,
        undo: bool = False, confirm: bool | str = False,
    ) -> None:
        if prefix_solver not in PREFIX_SOLVERS:
            raise UserError(f"unknown prefix solver {prefix_solver!r}; use "
                            f"{', '.join(PREFIX_SOLVERS)}")
        if gate not in GATES:
            raise UserError(f"unknown gate {gate!r}; use {', '.join(GATES)}")
        if undo and defer:
            raise UserError("the undo hypotheses and the deferral do not combine")
        if not isinstance(confirm, bool) and confirm not in CONFIRM_MODES:
            raise UserError(f"unknown confirm mode {confirm!r}; use True, False or "
                            f"{', '.join(CONFIRM_MODES)}")
        self.prefix_solver = "isam2" if prefix_solver == "auto" else prefix_solver
        self._isam = IsamPrefix() if self.prefix_solver == "isam2" else None
        self._solve = solver or StickySolver()
        self.graph, self.gate, self.barred = graph, gate, barred
        self._max_rounds = max_rounds
        self.keys = _check_spine(graph)
        self._d, self._c = pose_dof(graph.dim), tls_threshold(graph.dim, probability)
        self.position = {k: n for n, k in enumerate(self.keys)}
        self._given = poses_from_values(values, graph.dim)
        self.unit = unit if unit is not None else [graph.between_factor(lp) for lp in graph.loops]
        self.odometry_end = np.array([max(self.position[o.i], self.position[o.j])
                                      for o in graph.odometry], dtype=int)
        self.loop_end = np.array([max(self.position[lp.i], self.position[lp.j])
                                  for lp in graph.loops], dtype=int)
        self._anchors = set(graph.anchor_keys())
        self.weights = np.zeros(len(graph.loops))
        self.defer = defer
        self.deferred = np.zeros(0, dtype=np.int64)  # loops whose test had no power yet
        self.wait = wait  # loop-bearing blocks a deferred loop waits (None: to the end)
        # `blocks` when each loop was first deferred (-1: never)
        self._since = np.full(len(graph.loops), -1, dtype=np.int64)
        self._fixed = gtsam.NonlinearFactorGraph()
        self._base = gtsam.NonlinearFactorGraph()  # `_fixed` without its loops
        self.undo = undo
        self.confirm = bool(confirm)  # step-2 admissions re-checked by their nonlinear cost
        self.screen = confirm == "screen"  # ... after the linearised screen (`_unconfirmed`)
        self.refused = 0  # step-2 admissions the nonlinear check turned back
        self._held = False  # the last admission stopped the iSAM2 prefix converging
        # (loops turned back, the iSAM2 copy that solved the prefix without them or None)
        self._adoptable: tuple[tuple[int, ...], IsamPrefix | None] | None = None
        self._loo_isam: IsamPrefix | None = None  # see `_solved_without`
        self._block = block
        self.loop_start = np.array([min(self.position[lp.i], self.position[lp.j])
                                    for lp in graph.loops], dtype=int)
        # `blocks` when each loop was admitted (-1: not admitted)
        self._admitted_at = np.full(len(graph.loops), -1, dtype=np.int64)
        self.undone = 0  # undo hypotheses kept
        self.tried = 0  # undo hypotheses tested
        self.examined = self.reverted = 0  # look-ahead windows settled; of them, reverted
        self._rival: AdmissionPass | None = None  # the pass without the open window's hypotheses
        self._rival_until = 0  # `blocks` at which the open window is settled
        self.current = gtsam.Values()  # the solved prefix, then the new block composed onto it
        self.last, self.blocks = -1, 0  # position of the last pose added; blocks solved
        self._ends = [*range(block - 1, len(self.keys) - 1, block), len(self.keys) - 1]
        self._step = 0
        self.folded = False  # the iSAM2 prefix stopped converging (batch solves from then on)
        self._released = False  # the iSAM2 prefix dropped by `release_prefix` (not folded)
        self.snapshots: list[_Snapshot] | None = [] if record else None
        self._stride = max(1, -(-len(self._ends) // SNAPSHOTS))
        # A stated pass: the first block in which the calibrated gate would admit less.
        self.calibrated_step: int | None = None

    @property
    def done(self) -> bool:
        return self._step == len(self._ends)

    def release_prefix(self) -> None:
        """Drop the iSAM2 of the solved prefix (memory: one per pass, and
        `slam.consistency.incremental_tls` keeps several passes until it chooses among
        them); only for a pass that will not `advance` again."""
        self._rival = None
        self._adoptable = self._loo_isam = None
        if self._isam is not None:
            self._isam = None
            self._released = True

    def advance(self, until_fold: bool = False, blocks: int | None = None) -> None:
        """Add blocks to the end, or until the block that folded (`until_fold`), or
        `blocks` more blocks."""
        n = 0
        while not self.done and (blocks is None or n < blocks):
            fork = None  # the snapshot before this block, kept if it sets `calibrated_step`
            if self.snapshots is not None and not self.folded and self._rival is None:
                if (self._step % self._stride == 0
                        and (not self.snapshots or self.snapshots[-1].step < self._step)):
                    self.snapshots.append(self._snapshot())
                elif (FORK_SNAPSHOT and self.gate == "stated" and self.calibrated_step is None
                      and (not self.snapshots or self.snapshots[-1].step < self._step)):
                    fork = self._snapshot()
            rival = self._rival  # a look-ahead's rival adds the same block (`settle`)
            self._add_block(self._ends[self._step])
            if fork is not None and self.calibrated_step == self._step:
                self.snapshots.append(fork)
            if rival is not None:
                rival._add_block(self._ends[self._step])
                rival._step += 1
            self._step += 1
            settle(self)
            n += 1
            if until_fold and self.folded:
                return

    def _snapshot(self) -> _Snapshot:
        return _Snapshot(self._step, self.last, self.blocks, gtsam.Values(self.current),
                         self.weights.copy(), gtsam.NonlinearFactorGraph(self._fixed),
                         None if self._isam is None else self._isam.copy(),
                         self.deferred.copy(), self._since.copy(),
                         gtsam.NonlinearFactorGraph(self._base), self._admitted_at.copy())

    def block_of(self, loop: int) -> int:
        """Index of the block in which `loop` (index into `graph.loops`) is decided."""
        return int(np.searchsorted(self._ends, self.loop_end[loop]))

    def resumed(
        self, step: int, *, barred: Sequence[int] | None = None, gate: str | None = None
    ) -> AdmissionPass:
        """A new pass with `barred` (default this pass's) and `gate` (default this pass's),
        from this pass's latest snapshot before block `step` or earlier: right when the new
        pass decides every block before `step` as this one did.  It keeps the snapshots it
        shares with this pass and records its own."""
        if self.snapshots is None:
            raise ValueError("resumed() needs a pass made with record=True")
        earlier = [snap for snap in self.snapshots if snap.step <= step]
        run = copy.copy(self)  # the graph, factors and positions are shared, never mutated
        run.barred = self.barred if barred is None else barred
        run.gate = self.gate if gate is None else gate
        run.folded, run._released, run.calibrated_step = False, False, None
        run._rival = None  # snapshots are taken with no look-ahead open
        run.snapshots = earlier
        if not earlier:  # before the first block: a new pass
            run.last, run.blocks, run._step = -1, 0, 0
            run.current, run.weights = gtsam.Values(), np.zeros(len(self.graph.loops))
            run.deferred = np.zeros(0, dtype=np.int64)
            run._since = np.full(len(self.graph.loops), -1, dtype=np.int64)
            run._fixed = gtsam.NonlinearFactorGraph()
            run._base = gtsam.NonlinearFactorGraph()
            run._admitted_at = np.full(len(self.graph.loops), -1, dtype=np.int64)
            run.undone = run.tried = run.examined = run.reverted = 0
            run._isam = IsamPrefix() if self.prefix_solver == "isam2" else None
            return run
        snap = earlier[-1]
        run.last, run.blocks, run._step = snap.last, snap.blocks, snap.step
        run.current, run.weights = gtsam.Values(snap.current), snap.weights.copy()
        run.deferred = np.setdiff1d(snap.deferred, run.barred).astype(np.int64)
        run._since = snap.since.copy()
        run._fixed = gtsam.NonlinearFactorGraph(snap.fixed)
        run._base = gtsam.NonlinearFactorGraph(snap.base)
        run._admitted_at = snap.admitted_at.copy()
        run._isam = None if snap.isam is None else snap.isam.copy()
        return run

    def _add_block(self, end: int) -> None:
        graph, keys, unit, c = self.graph, self.keys, self.unit, self._c
        last, current, fixed, isam = self.last, self.current, self._fixed, self._isam
        new = keys[last + 1 : end + 1]
        ref = keys[last] if last >= 0 else None
        solved = {} if ref is None else {ref: pose_of(current, ref, graph.dim)}
        _extend(solved, self._given, ref, new, graph.dim)
        for k in new:
            pose = to_gtsam_pose(solved[k], graph.dim)
            current.insert(k, pose)
            if k in self._anchors:
                fixed.add(graph.prior_factor(k))
                self._base.add(fixed.at(fixed.size() - 1))
                if isam is not None:
                    isam.add(graph.prior_factor(k))
            if isam is not None:
                isam.insert(k, pose)
        for n in np.flatnonzero((self.odometry_end > last) & (self.odometry_end <= end)):
            fixed.add(graph.between_factor(graph.odometry[n]))
            self._base.add(fixed.at(fixed.size() - 1))
            if isam is not None:
                isam.add(fixed.at(fixed.size() - 1))
        arrived = np.setdiff1d(
            np.flatnonzero((self.loop_end > last) & (self.loop_end <= end)), self.barred)
        final = end == len(keys) - 1
        self.last = end
        # Deferred loops are re-tested with every block that brings loops, and at the end.
        if len(arrived) == 0 and not (final and len(self.deferred)):
            return
        pending = np.union1d(arrived, self.deferred).astype(np.int64)
        self.blocks += 1
        prefix = keys[: end + 1]
        accepted = np.zeros(len(pending), dtype=bool)
        waiting = np.zeros(0, dtype=np.int64)  # positions in `pending` deferred (`slam.deferral`)
        forced = np.zeros(len(pending), dtype=bool)  # waited `wait` blocks: the plain gate decides
        factors = fixed  # the accepted graph, whose solution is `current`
        refused = np.zeros(len(pending), dtype=bool)  # turned back by the nonlinear check
        for _ in range(self._max_rounds):
            errors = np.array([unit[k].error(current) for k in pending])
            newly = ~accepted & ~refused & (errors <= c)
            if newly.any():  # step 1
                accepted |= newly
                factors = _with(fixed, unit, pending[accepted])
                current, isam = self._prefix_solve(factors, current, pending[newly])
                continue
            rest = np.flatnonzero(~accepted & ~refused)
            waiting = np.zeros(0, dtype=np.int64)
            if len(rest) == 0:
                break
            # Step 2, at the solution of the accepted graph.
            limit = self._gate_limit(factors, current, len(prefix), c)
            try:
                test = InnovationTest(factors, current, prefix, self._d)
            except RuntimeError:  # singular information: no innovation test possible
                break
            gains = test.gains([unit[pending[q]] for q in rest])
            decide = np.arange(len(rest))
            weak = np.zeros(0, dtype=np.int64)
            white = None
            if self.defer:
                # The deferral's classes use the stated ``c`` whatever the gate, so a stated
                # and a calibrated pass defer alike until they admit differently.
                ends = [unit[pending[q]].keys()[1] for q in rest]
                white = whitened_offsets(gains, alternative_offsets(
                    current, ends, alternative_places(prefix), graph.dim))
                eye = np.eye(self._d)
                strong = (power(eye + gains.M, white, c) >= MIN_POWER) | forced[rest]
                weak = np.flatnonzero(~strong & (admission_costs(gains) < c))
                decide = np.flatnonzero(strong)
            costs: list[float] = []
            admitted: list[int] = []
            if len(decide):
                chosen, _ = greedy_admission(gains.subset(decide), limit, costs)
                admitted = [int(decide[q]) for q in chosen]
            if not admitted and len(weak):
                agreeing = consensus(gains.subset(weak), white[weak], c)
                if len(agreeing):
                    pick = weak[agreeing]
                    chosen, _ = greedy_admission(gains.subset(pick), limit, costs)
                    admitted = [int(pick[q]) for q in chosen]
            if self.gate == "stated" and self.calibrated_step is None and admitted:
                s0 = _variance_factor(factors, current, len(prefix), self._d)
                if s0 is not None and max(costs) >= c * min(1.0, s0):
                    self.calibrated_step = self._step
            if not admitted:
                expired = self._expired(pending[rest[weak]], final)
                if expired.any():  # decided now by the plain gate, after any consensus
                    forced[rest[weak[expired]]] = True
                    continue
                waiting = rest[weak] if not final else waiting
                break
            before = factors.error(current) if self.confirm else 0.0
            accepted[rest[admitted]] = True
            factors = _with(fixed, unit, pending[accepted])
            solved, isam = self._prefix_solve(factors, current, pending[rest[admitted]],
                                              hold=self.confirm)
            if self.confirm:
                held, self._held = self._held, False
                back = self._unconfirmed(fixed, pending, accepted, rest[admitted], solved,
                                         before, current)
                if len(back):
                    refused[back] = True
                    accepted[back] = False
                    self.refused += len(back)
                    factors = _with(fixed, unit, pending[accepted])
                    solved, isam = self._turned_back(factors, current, pending[back], held)
                elif held:
                    self.folded = True
            current = solved
        self.current = current
        self.weights[pending] = accepted
        self.deferred = pending[waiting[~accepted[waiting]]]
        self._since[self.deferred[self._since[self.deferred] < 0]] = self.blocks
        for q in np.flatnonzero(accepted):
            fixed.add(unit[pending[q]])
        self._admitted_at[pending[accepted]] = self.blocks
        if self.undo:
            test_hypotheses(self, arrived, prefix)

    def _unconfirmed(
        self, fixed: gtsam.NonlinearFactorGraph, pending: NDArray[np.int64],
        accepted: NDArray[np.bool_], admitted: NDArray[np.int64], current: gtsam.Values,
        before: float, start: gtsam.Values,
    ) -> NDArray[np.int64]:
        """Positions in `pending` among `admitted` (by the innovation gate) to turn back:
        the actual cost of keeping a loop is the accepted prefix's error at its solution
        `current` less the error of the prefix re-solved without it (gtsam error units);
        the TLS rule keeps a loop only when that cost is below ``c``, and the innovation
        ``delta`` is its linearisation at the prefix before the loop, which a loop that
        bends a long stretch of odometry can leave well below it.  The costliest loop
        above ``c`` is turned back and the rest judged again without it (two loops that
        contradict each other both cost more than ``c`` while both are kept).

        `before`: the error of the accepted prefix without the `admitted` loops at its
        solution (the prefix the gate decided against).  Taking factors out of a least
        squares problem can only lower its minimum, so no admitted loop costs more than
        the joint cost ``J(current) - before`` of all of them: when that is at most ``c``
        none is turned back, and a lone admitted loop's cost is exactly that.  Only
        rounds that admitted several loops at a joint cost above ``c`` re-solve the
        prefix without each (`_minimum`).

        With `screen` (not exact): those rounds first factorise the accepted prefix
        once at `current` and take every admitted loop's linearised leave-one-out cost
        ``rho_q = 0.5 b_q^T (I - M_q)^-1 b_q`` (`slam.innovation.removal_costs`), the
        Gauss-Newton approximation at the joint solution of the cost defined above; a
        loop with ``rho_q <= SCREEN_FRACTION c`` is cleared with ``rho_q`` as its cost,
        and only the others get the re-solve.  The screen is exact on a linear problem
        and errs only by the curvature of the cost between the joint solution and the
        solution without the loop: a loop that bends a long stretch of loose odometry
        through a large rotation can cost more than ``rho_q``, and a loop cleared
        whose actual cost is above ``c`` stays admitted where the exact check would
        turn it back.  The margin absorbs an actual cost up to ``1 / SCREEN_FRACTION``
        times ``rho_q``; nothing bounds the ratio beyond that.  Under the same margin the
        loops not cleared are solved in decreasing ``rho_q`` (`SCREEN_SKIP`), and once a
        solve has found a loop costing ``C > c`` a loop with ``rho_q < SCREEN_FRACTION C``
        cannot be the costliest: it keeps ``rho_q`` as its cost without its solve.  When
        a loop is turned back the prefix without it is the solution its re-solve already
        found (not solved again), and the loops left are screened again at it.
        """
        unit, accepted, left = self.unit, accepted.copy(), [int(q) for q in admitted]
        out: list[int] = []
        solutions: dict[int, gtsam.Values] = {}
        self._adoptable = None
        while left:
            kept = _with(fixed, unit, pending[accepted])
            total = kept.error(current)
            if not total - before > self._c:
                break
            costs = [total - before]
            if len(left) > 1:
                rho = self._screened(kept, current, pending[left]) if self.screen else None
                costs, solutions = [-np.inf] * len(left), {}
                copies: dict[int, IsamPrefix] = {}  # converged leave-one-out iSAM2 copies
                found = -np.inf  # the largest actual cost above ``c`` solved this turn
                for n in _screen_order(rho, len(left), SCREEN_SKIP):
                    q = left[n]
                    if rho is not None and (rho[n] <= SCREEN_FRACTION * self._c or (
                            SCREEN_SKIP and rho[n] < SCREEN_FRACTION * found)):
                        costs[n] = float(rho[n])
                        continue
                    others = accepted.copy()
                    others[q] = False
                    without = _with(fixed, unit, pending[others])
                    try:
                        if self.screen:
                            error, solutions[q] = self._solved_without(
                                without, current, start, pending[[*out, q]])
                            costs[n] = total - error
                        else:
                            costs[n] = total - self._minimum(without, current, start,
                                                             pending[[*out, q]])
                    except RuntimeError:  # a failed solve: the admission stands
                        continue
                    if self._loo_isam is not None:
                        copies[q] = self._loo_isam
                    if costs[n] > self._c:
                        found = max(found, costs[n])
            else:
                copies = {}
            worst = int(np.argmax(costs))
            if not costs[worst] > self._c:
                break
            q = left.pop(worst)
            out.append(q)
            # the prefix without every loop of `out`, solved by a copy of the pass's iSAM2
            self._adoptable = (tuple(int(k) for k in pending[out]), copies.get(q))
            accepted[q] = False
            if left and q in solutions:
                current = solutions[q]
            elif left:
                current = self._solve(_with(fixed, unit, pending[accepted]), current)
        self._loo_isam = None  # (memory: `_adoptable` keeps the copy `_turned_back` takes)
        return np.array(out, dtype=np.int64)

    def _screened(
        self, kept: gtsam.NonlinearFactorGraph, current: gtsam.Values,
        loops: NDArray[np.int64],
    ) -> Array | None:
        """Linearised leave-one-out cost (`slam.innovation.removal_costs`, gtsam error
        units) of each of `loops` (indices into `graph.loops`, all in `kept`) at
        `current`, the solution of `kept`; None when its information is singular."""
        try:
            test = InnovationTest(kept, current, list(current.keys()), self._d)
            b, gram = test.blocks([self.unit[k] for k in loops])
        except RuntimeError:
            return None
        return removal_costs(b, gram)

    def _minimum(
        self, without: gtsam.NonlinearFactorGraph, current: gtsam.Values,
        start: gtsam.Values, removed: NDArray[np.int64],
    ) -> float:
        """The error of `without` (the accepted prefix less the loops `removed`) at its
        solution: by a copy of the iSAM2 prefix (which holds the prefix with every loop
        of the round) with `removed` taken out, or, when there is none or its updates do
        not converge, by a batch solve from whichever of `current` (the solution with
        them) and `start` (the solution before the round's admissions) it is lower at: a
        false loop's removal undoes the bend it caused, so the solution before it is
        the nearer start."""
        return self._solved_without(without, current, start, removed)[0]

    def _solved_without(
        self, without: gtsam.NonlinearFactorGraph, current: gtsam.Values,
        start: gtsam.Values, removed: NDArray[np.int64],
    ) -> tuple[float, gtsam.Values]:
        """`_minimum` and the solution it is the error at; `_loo_isam` is then the
        converged iSAM2 copy that solved it (None: a batch solve did)."""
        self._loo_isam = None
        if self._isam is not None:
            trial = self._isam.copy()
            trial.remove(int(k) for k in removed)
            try:
                estimate = trial.solve()
            except RuntimeError:  # gtsam IndeterminateLinearSystemException
                estimate = None
            if estimate is not None and trial.converged:
                self._loo_isam = trial
                return float(without.error(estimate)), estimate
        x0 = start if without.error(start) < without.error(current) else current
        solved = self._solve(without, x0)
        return float(without.error(solved)), solved

    def _turned_back(
        self, factors: gtsam.NonlinearFactorGraph, current: gtsam.Values,
        removed: NDArray[np.int64], held: bool = False,
    ) -> tuple[gtsam.Values, IsamPrefix | None]:
        """The accepted prefix `factors` solved after the loops `removed` (indices into
        `graph.loops`, admitted by the last `_prefix_solve`) were turned back: they are
        taken out of the iSAM2 prefix, which goes on incrementally; when their admission
        had stopped its updates converging (`held`), a new iSAM2 is built from `factors`
        at `current`, the prefix's solution before they were admitted.  Batch solves
        from `current` when there is no iSAM2 prefix or its updates stop converging."""
        adoptable, self._adoptable = self._adoptable, None
        if held:
            self._isam = IsamPrefix.of(factors, current)
        elif self._isam is None:
            return self._solve(factors, current), None
        elif (ADOPT_LEAVE_ONE_OUT and adoptable is not None and adoptable[1] is not None
              and adoptable[0] == tuple(int(k) for k in removed)):
            # what the lines below would compute: the same removals from the same iSAM2
            self._isam = adoptable[1]
            return self._isam.estimate, self._isam
        else:
            self._isam.remove(int(k) for k in removed)
        current, self._isam = isam_or_batch(self._isam, self._solve, factors, current)
        if self._isam is None:
            self.folded = True
        return current, self._isam

    def _decided_cost(self, values: gtsam.Values) -> float:
        """TLS objective at `values` of the part decided so far: anchors and odometry of
        the poses added, and every loop ending among them that is not barred, each at
        ``min(e_k, c)`` whether the solution admitted it or not."""
        decided = np.setdiff1d(np.flatnonzero(self.loop_end <= self.last), self.barred)
        errors = np.array([self.unit[k].error(values) for k in decided])
        return float(self._base.error(values) + np.minimum(errors, self._c).sum())

    def _gate_limit(self, factors: gtsam.NonlinearFactorGraph, current: gtsam.Values,
                    n_poses: int, c: float) -> float:
        """The innovation gate's threshold: ``c`` (stated), or ``c * min(1, s)`` with
        the prefix's odometry variance factor ``s`` (``calibrated``)."""
        if self.gate != "calibrated":
            return c
        s0 = _variance_factor(factors, current, n_poses, self._d)
        return c * min(1.0, s0) if s0 is not None else c

    def _expired(self, loops: NDArray[np.int64], final: bool) -> NDArray[np.bool_]:
        """Which deferred `loops` have waited their `wait` loop-bearing blocks (every one at
        the `final` block); none when deferred loops wait to the end (`wait` None)."""
        if self.wait is None:
            return np.zeros(len(loops), dtype=bool)
        since = self._since[loops]
        return final | ((since >= 0) & (self.blocks - since >= self.wait))

    def _prefix_solve(
        self, factors: gtsam.NonlinearFactorGraph, current: gtsam.Values,
        added: NDArray[np.int64], hold: bool = False,
    ) -> tuple[gtsam.Values, IsamPrefix | None]:
        """The accepted prefix `factors` solved from `current` after the loops `added`.

        `hold`: when the iSAM2 prefix stops converging the pass is not marked folded yet
        (`_held` says so instead): the nonlinear check may turn the loops back."""
        if self._isam is None:
            return self._solve(factors, current), None
        for k in added:
            self._isam.add(self.unit[k], int(k))
        current, self._isam = isam_or_batch(self._isam, self._solve, factors, current)
        if self._isam is None:
            if hold:
                self._held = True
            else:
                self.folded = True
        return current, self._isam

    def prefix_cost(
        self, values: gtsam.Values, factors: StatedFactors, probability: float = 0.99
    ) -> float:
        """`tls_cost` at `values` of the part of `factors` (the stated graph of the same
        poses, odometry and loops) that this pass has decided: anchors and odometry
        among the poses added so far, and the loops that end among them."""
        base, loop_index = factors
        c = tls_threshold(self.graph.dim, probability)
        n_priors = base.size() - len(loop_index) - len(self.graph.odometry)
        seen = set(self.keys[: self.last + 1])
        cost = sum(base.at(k).error(values) for k in range(n_priors)
                   if base.at(k).keys()[0] in seen)
        n_odometry = np.flatnonzero(self.odometry_end <= self.last)
        cost += sum(base.at(n_priors + int(n)).error(values) for n in n_odometry)
        cost += sum(min(base.at(loop_index[k]).error(values), c)
                    for k in np.flatnonzero(self.loop_end <= self.last))
        return float(cost)

    def result(self) -> Admission:
        """The pass's `Admission` (after `advance` reached the end)."""
        errors = np.array([f.error(self.current) for f in self.unit])
        w = self.weights
        cost = self._fixed.error(self.current) - errors[w > 0.5].sum() + np.minimum(
            errors, self._c).sum()
        prefix = self.prefix_solver
        if prefix == "isam2" and self._isam is None and not self._released:
            prefix = "isam2-then-batch"
        return Admission(self.current, w, float(cost), self.blocks, self.gate, prefix)

