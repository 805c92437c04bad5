"""Undo hypotheses of the time-ordered admission, each re-examined over a look-ahead.

`slam.admission.AdmissionPass` with ``undo``: after a block, `test_hypotheses` asks
whether loops admitted in the last `UNDO_BLOCKS` loop-bearing blocks are what made this
block's loops fail, and replaces the block's outcome by the hypothesis "they were wrong"
when the TLS objective of the part decided so far drops (`AdmissionPass._decided_cost`:
anchors, odometry and every loop ending among the poses added, each at ``min(e_k, c)``,
``c`` = `slam.innovation.tls_threshold`).

That comparison sees only the loops that have arrived.  A group of loops between the
same two places with one consistent wrong transform (perceptual aliasing) costs almost
nothing on a loose prefix once the loop it contradicts is taken out, so the hypothesis
"the group is right" can be cheaper on the decided part although the returns that
follow contradict it.  So a kept hypothesis is provisional: `open_window` keeps the
pass as it stood without it (its *rival*, a copy that adds the same blocks with the
plain rules and no hypotheses of its own) for `LOOKAHEAD` more loop-bearing blocks;
`settle` then compares the two on the same decided part (each prefix re-solved by the
same batch solver) and goes back to the rival when it is cheaper.  A hypothesis kept
while a window is open extends it; the rival stays the pass before the first.

With `BY_ISAM` (on by default) a pass whose prefix is kept by iSAM2 solves its hypotheses
on a copy of that iSAM2: the undone loops taken out (gtsam's ``removeFactorIndices``), the
re-decided ones added back by updates, and both the block's outcome and the hypothesis
compared at iSAM2's estimates (the same tolerance on both sides); a kept hypothesis's
copy becomes the pass's prefix.  A copy whose updates stop converging hands that
hypothesis to the batch solves.
"""

from __future__ import annotations

import copy
from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

from slam.innovation import InnovationTest, greedy_admission
from slam.isam_prefix import IsamPrefix, isam_or_batch
from slam.pose_graph import to_gtsam_pose

AdmissionPass = Any  # a `slam.admission.AdmissionPass` (that module imports this one)

UNDO_BLOCKS = 2  # an undo hypothesis re-decides loops admitted this many loop-bearing blocks back
UNDO_SUPPORT = 2  # rejected loops near an admitted one's two ends that open a hypothesis
UNDO_TRIES = 2  # undo hypotheses tested per block
LOOKAHEAD = 2  # loop-bearing blocks after a kept hypothesis before it is compared again
# Hypotheses solved by a copy of the pass's iSAM2 prefix (loops taken out by their tags)
# instead of batch solves of the whole prefix (False: batch solves).
BY_ISAM = True
# A block's hypotheses that take out the same loops share their first iSAM2 solve (the
# prefix of the loops kept): while no hypothesis of the block has been kept, every one
# re-decides the same recent admissions, so that solve repeats on an identical copy of
# the pass's iSAM2 (False: each hypothesis solves it again).
SHARE_FIRST_SOLVE = True


def with_loops(
    fixed: gtsam.NonlinearFactorGraph, factors: list, indices: NDArray[np.int64]
) -> gtsam.NonlinearFactorGraph:
    """A copy of `fixed` plus ``factors[k]`` for every k in `indices`."""
    graph = gtsam.NonlinearFactorGraph(fixed)
    for k in indices:
        graph.add(factors[k])
    return graph


def pose_of(values: gtsam.Values, key: int, dim: int) -> NDArray[np.float64]:
    """Pose `key` of `values` as (x, y, theta) or a 4x4 matrix."""
    if dim == 2:
        p = values.atPose2(key)
        return np.array([p.x(), p.y(), p.theta()])
    return values.atPose3(key).matrix()


def test_hypotheses(run: AdmissionPass, arrived: NDArray[np.int64], prefix: list[int]) -> None:
    """Undo hypotheses after a block: were loops admitted in the last `UNDO_BLOCKS`
    loop-bearing blocks what made this block's loops fail?

    A hypothesis opens for an admitted recent loop ``a`` when at least `UNDO_SUPPORT`
    loops of this block that were rejected lie near it (both ends within `UNDO_BLOCKS`
    blocks of ``a``'s: the same return to the same place; its *support*) and outnumber
    the recent admitted loops near it (its *cluster*, ``a`` included). The hypothesis
    removes every loop admitted in the last `UNDO_BLOCKS` loop-bearing blocks (``a`` and
    whatever else bent the prefix since) and this block's admissions from the accepted
    prefix, re-solves it, decides the support first (as if it had arrived first), then
    this block's other loops and the removed ones, by the same rules as the block
    (`plain_rounds`). It replaces the block's outcome when its TLS objective over every
    loop decided so far is lower (the same candidate set for both), and the pass before
    it is kept as the rival of a look-ahead (`open_window`). At most `UNDO_TRIES`
    hypotheses a block, those whose support most outnumbers its cluster first.
    """
    w = run.weights
    rejected = arrived[w[arrived] < 0.5]
    if len(rejected) < UNDO_SUPPORT:
        return
    recent = np.flatnonzero((w > 0.5) & (run._admitted_at >= run.blocks - UNDO_BLOCKS))
    lo, hi, reach = run.loop_start, run.loop_end, UNDO_BLOCKS * run._block

    def near(k: int, others: NDArray[np.int64]) -> NDArray[np.int64]:
        return others[(np.abs(lo[others] - lo[k]) <= reach)
                      & (np.abs(hi[others] - hi[k]) <= reach)]

    hypotheses: dict[tuple[int, ...], int] = {}
    for a in recent:
        support, cluster = near(int(a), rejected), near(int(a), recent)
        if len(support) >= UNDO_SUPPORT and len(support) > len(cluster):
            hypotheses.setdefault(tuple(support), len(support) - len(cluster))
    ranked = sorted(hypotheses.items(), key=lambda h: -h[1])[:UNDO_TRIES]
    shared = _SharedSolve()
    for support_key, _ in ranked:
        support = np.array(support_key, dtype=np.int64)
        if (run.weights[support] > 0.5).any():  # an earlier hypothesis admitted it
            continue
        # Every recent admission is re-decided: the one the support contradicts and
        # any other that bent the prefix since.
        undone = np.flatnonzero(
            (run.weights > 0.5) & (run._admitted_at >= run.blocks - UNDO_BLOCKS))
        admitted = np.flatnonzero(run.weights > 0.5)
        keep = np.setdiff1d(admitted, np.union1d(undone, arrived))
        trial = _trial_prefix(run, np.setdiff1d(admitted, keep))
        # The block's outcome solved as the hypothesis will be (an iSAM2 estimate stops
        # at another tolerance than a batch solve), so the costs compare decisions.
        try:
            before = run._decided_cost(
                run.current if trial is not None else run._solve(run._fixed, run.current))
        except RuntimeError:
            return
        run.tried += 1
        try:
            if trial is not None:
                values, trial = shared.solved(run, trial, keep)
            else:
                values = run._solve(with_loops(run._base, run.unit, keep), run.current)
            first, values, trial = plain_rounds(run, support, keep, values, prefix, trial)
            keep = np.union1d(keep, first)
            rest = np.setdiff1d(np.union1d(arrived, undone), first)
            then, values, trial = plain_rounds(run, rest, keep, values, prefix, trial)
        except RuntimeError:  # singular information or a failed solve: no hypothesis
            continue
        weights = run.weights.copy()
        weights[np.union1d(arrived, undone)] = 0.0
        weights[np.union1d(first, then).astype(np.int64)] = 1.0
        if not run._decided_cost(values) < before * (1.0 - 1e-9):
            continue
        if LOOKAHEAD > 0:  # 0: every kept hypothesis is final
            open_window(run)
        newly = np.flatnonzero((weights > 0.5) & (run.weights < 0.5))
        run._admitted_at[weights < 0.5] = -1
        run._admitted_at[newly] = run.blocks
        run.weights = weights
        run._fixed = with_loops(run._base, run.unit, np.flatnonzero(weights > 0.5))
        run.current = values
        run.undone += 1
        shared = _SharedSolve()  # the pass's prefix changed: nothing to share from here
        if run.gate == "stated" and run.calibrated_step is None:
            # a calibrated pass resumed after this block would not have tested it
            run.calibrated_step = run._step
        if trial is not None:
            run._isam = trial
        elif run._isam is not None:
            isam = IsamPrefix()
            for n in range(run._base.size()):
                isam.add(run._base.at(n))
            for k in np.flatnonzero(weights > 0.5):  # tagged: a later hypothesis removes them
                isam.add(run.unit[k], int(k))
            for k in prefix:
                isam.insert(k, to_gtsam_pose(pose_of(values, k, run.graph.dim), run.graph.dim))
            # A rebuilt iSAM2 that does not converge hands over to batch solves; the
            # pass is not marked folded (its admitted loops are the hypothesis's).
            run.current, run._isam = isam_or_batch(isam, run._solve, run._fixed, values)


def _trial_prefix(run: AdmissionPass, out: NDArray[np.int64]) -> IsamPrefix | None:
    """With `BY_ISAM`: a copy of the pass's iSAM2 prefix with the admitted loops `out`
    taken out (at its next solve); None (batch solves) without `BY_ISAM`, without an
    iSAM2 prefix, or when one of them is not held by its tag."""
    if not BY_ISAM or run._isam is None or not run._isam.holds(int(k) for k in out):
        return None
    trial = run._isam.copy()
    trial.remove(int(k) for k in out)
    return trial


class _SharedSolve:
    """The first solve of a block's undo hypotheses (`test_hypotheses`), kept for the next
    hypothesis that takes out the same loops from the same iSAM2 prefix (`SHARE_FIRST_SOLVE`).

    Only a converged iSAM2 solve is kept (a batch fallback is solved again); a later
    hypothesis gets the kept estimate and a copy of the solved iSAM2, which continues
    bit for bit as the original would (`IsamPrefix.copy`).  The caller makes a new one
    whenever the pass's prefix changes (a hypothesis kept)."""

    def __init__(self) -> None:
        self._keep: NDArray[np.int64] | None = None
        self._values: gtsam.Values | None = None
        self._isam: IsamPrefix | None = None
        self.hits = 0

    def solved(
        self, run: AdmissionPass, trial: IsamPrefix, keep: NDArray[np.int64]
    ) -> tuple[gtsam.Values, IsamPrefix | None]:
        """The prefix of the admitted loops `keep` solved by `trial` (a copy of the pass's
        iSAM2 with every other admitted loop taken out) from the pass's solution, or the
        kept result of an earlier hypothesis of the block with the same `keep`."""
        if (SHARE_FIRST_SOLVE and self._isam is not None and self._keep is not None
                and np.array_equal(self._keep, keep)):
            self.hits += 1
            return gtsam.Values(self._values), self._isam.copy()
        values, solved = _isam_solved(run, trial, with_loops(run._base, run.unit, keep),
                                      run.current)
        if SHARE_FIRST_SOLVE and solved is not None:
            self._keep, self._values, self._isam = keep.copy(), gtsam.Values(values), solved.copy()
        return values, solved


def _isam_solved(
    run: AdmissionPass, trial: IsamPrefix, factors: gtsam.NonlinearFactorGraph,
    current: gtsam.Values,
) -> tuple[gtsam.Values, IsamPrefix | None]:
    """`factors` (what `trial` holds) solved by `trial`, or by the pass's batch solver
    when its updates stop converging (`isam_or_batch`; None: batch from then on)."""
    return isam_or_batch(trial, run._solve, factors, current)


def plain_rounds(
    run: AdmissionPass, pending: NDArray[np.int64], accepted: NDArray[np.int64],
    current: gtsam.Values, prefix: list[int], trial: IsamPrefix | None = None,
) -> tuple[NDArray[np.int64], gtsam.Values, IsamPrefix | None]:
    """The block's rounds (residual rule, then the greedy innovation gate; no deferral)
    deciding `pending` against the prefix of the loops `accepted`, solved at `current`;
    the loops of `pending` admitted, the solution and the iSAM2 left.  Each round's
    admissions are added to the iSAM2 `trial` (which holds the prefix of `accepted`),
    else batch solves."""
    unit, c = run.unit, run._c
    taken = np.zeros(len(pending), dtype=bool)
    factors = with_loops(run._base, unit, accepted)
    for _ in range(run._max_rounds):
        errors = np.array([unit[k].error(current) for k in pending])
        newly = ~taken & (errors <= c)
        if not newly.any():
            rest = np.flatnonzero(~taken)
            if len(rest) == 0:
                break
            limit = run._gate_limit(factors, current, len(prefix), c)
            test = InnovationTest(factors, current, prefix, run._d)
            gains = test.gains([unit[pending[q]] for q in rest])
            chosen, _ = greedy_admission(gains, limit)
            if not chosen:
                break
            newly = np.zeros(len(pending), dtype=bool)
            newly[rest[chosen]] = True
        taken |= newly
        factors = with_loops(run._base, unit, np.union1d(accepted, pending[taken]))
        if trial is not None:
            for k in pending[newly]:
                trial.add(unit[k], int(k))
            current, trial = _isam_solved(run, trial, factors, current)
        else:
            current = run._solve(factors, current)
    return pending[taken], current, trial


def open_window(run: AdmissionPass) -> None:
    """Before a hypothesis is kept: keep the pass as it stands as the rival of a
    look-ahead of `LOOKAHEAD` loop-bearing blocks (`settle`), or extend the open one."""
    run._rival_until = run.blocks + LOOKAHEAD
    if run._rival is not None:
        return
    rival = copy.copy(run)  # graph, factors and positions shared, never mutated
    rival.undo, rival.snapshots, rival._rival = False, None, None
    rival.current = gtsam.Values(run.current)
    rival.weights = run.weights.copy()
    rival._fixed = gtsam.NonlinearFactorGraph(run._fixed)
    rival._base = gtsam.NonlinearFactorGraph(run._base)
    rival._isam = None if run._isam is None else run._isam.copy()
    rival.deferred, rival._since = run.deferred.copy(), run._since.copy()
    rival._admitted_at = run._admitted_at.copy()
    run._rival = rival


def settle(run: AdmissionPass) -> None:
    """After a block that the rival added too: at the end of the window (or of the
    pass), go back to the rival when the TLS objective of the part decided so far,
    each prefix re-solved by the same batch solver, is lower there."""
    rival = run._rival
    if rival is None or (run.blocks < run._rival_until and not run.done):
        return
    run._rival = None
    run.examined += 1
    try:
        ours = run._solve(run._fixed, run.current)
        theirs = rival._solve(rival._fixed, rival.current)
    except RuntimeError:
        return
    if not rival._decided_cost(theirs) < run._decided_cost(ours) * (1.0 - 1e-9):
        return
    run.reverted += 1
    run.current, run.weights, run._fixed = rival.current, rival.weights, rival._fixed
    run._base, run._isam, run._admitted_at = rival._base, rival._isam, rival._admitted_at
    run.folded = run.folded or rival.folded
