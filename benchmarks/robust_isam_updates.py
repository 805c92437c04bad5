"""Diagnosis: the robust back end's solves on one corrupted pose graph by purpose, and
what its iSAM2 prefix updates cost by how many poses they relinearise.

Run from the repository root::

    python benchmarks/robust_isam_updates.py input_M3500_g2o.g2o [--data DIR] [--scale 1]
        [--policy random] [--ratio 50] [--seed 0] [--cache DIR] [--cap S]

Runs `slam.optimize.optimize` (``gnc``, incremental, from the odometry chain) with
`slam.isam_prefix.IsamPrefix` and `slam.least_squares.StickySolver` wrapped (their
results unchanged).  Prints

* every iSAM2 prefix solve (`IsamPrefix.solve`) by the `slam` function that asked for it
  (the admission's prefix after a round, the leave-one-out check's copy, an undo
  hypothesis's copy, ...): solves, ``ISAM2.update`` calls and their CPU seconds;
* every batch solve (`StickySolver` call, memo hits apart) by the chain of its two
  innermost `slam` callers: solves and CPU seconds;
* the CPU seconds of every admission pass's `AdmissionPass.advance` calls (bar search's
  passes included), by the pass's gate and its first odometry factor's information
  ``I[0, 0]`` (which tells the ladder's rungs apart), with the iSAM2 solves (and by which
  caller) and updates made while it advanced, and its updates that relinearised over
  1000 poses;
* the updates split by the poses they relinearised (gtsam's ``variablesRelinearized``,
  which counts the poses of new factors too): the update that hands new factors over,
  then the others in bands of 0, 1-10, 11-100, 101-1000 and over 1000 poses, with their
  CPU seconds and mean poses re-eliminated.

``--cap S`` stops the run after S seconds of process CPU (`benchmarks.robust_cell.cpu_cap`;
the counts up to there are printed).
"""

from __future__ import annotations

import sys
import time
import traceback
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import slam.admission as admission
import slam.isam_prefix as isam_prefix
import slam.least_squares as least_squares
from benchmarks.robust_cell import capped_gnc, cell_parser, read_cell

# (new factors, relinearised, re-eliminated, CPU s) of every update
UPDATES: list[tuple[bool, int, int, float]] = []
PREFIX: dict[str, list[float]] = defaultdict(lambda: [0, 0, 0.0])  # solves, updates, CPU s
BATCH: dict[str, list[float]] = defaultdict(lambda: [0, 0, 0.0])  # solves, memo hits, CPU s
_converge = isam_prefix.IsamPrefix._converge
_solve = isam_prefix.IsamPrefix.solve
_call = least_squares.StickySolver.__call__
_inner = least_squares.StickySolver._solve
_SOLVED = [False]
_advance = admission.AdmissionPass.advance
# id of the pass -> [gate, odometry I[0, 0], advance calls, CPU s, iSAM2 solves, updates,
# whole-prefix updates (over 1000 poses relinearised), their CPU s, {caller: solves}]
PASSES: dict[int, list] = {}
_RUNNING: list[list] = []  # the entry of the pass being advanced (innermost last)


def _callers(depth: int) -> str:
    frames = [f for f in traceback.extract_stack()[:-2] if "/slam/" in f.filename]
    names = [f"{Path(f.filename).stem}.{f.name}" for f in frames]
    return " > ".join(names[-depth:])


class _TimedIsam:
    """An ISAM2 whose ``update`` calls are timed into `UPDATES` (all else passed on)."""

    def __init__(self, isam) -> None:  # type: ignore[no-untyped-def]
        self._isam = isam

    def __getattr__(self, name: str):  # type: ignore[no-untyped-def]
        return getattr(self._isam, name)

    def update(self, *args):  # type: ignore[no-untyped-def]
        start = time.process_time()
        result = self._isam.update(*args)
        UPDATES.append((len(args) > 0 and args[0].size() > 0,
                        result.getVariablesRelinearized(), result.getVariablesReeliminated(),
                        time.process_time() - start))
        return result


def _timed_converge(self, *args):  # type: ignore[no-untyped-def]
    isam = self._isam
    self._isam = _TimedIsam(isam)
    try:
        return _converge(self, *args)
    finally:
        self._isam = isam


def _counted_solve(self):  # type: ignore[no-untyped-def]
    caller = _callers(2)
    entry = PREFIX[caller]
    before, start = len(UPDATES), time.process_time()
    try:
        return _solve(self)
    finally:
        entry[0] += 1
        entry[1] += len(UPDATES) - before
        entry[2] += time.process_time() - start
        if _RUNNING:
            done = UPDATES[before:]
            whole = [u for u in done if not u[0] and u[1] > 1000]
            _RUNNING[-1][4:8] = [_RUNNING[-1][4] + 1, _RUNNING[-1][5] + len(done),
                                 _RUNNING[-1][6] + len(whole),
                                 _RUNNING[-1][7] + sum(u[3] for u in whole)]
            by_caller = _RUNNING[-1][8]
            by_caller[caller] = by_caller.get(caller, 0) + 1


def _counted_call(self, factors, values):  # type: ignore[no-untyped-def]
    _SOLVED[0] = False
    start = time.process_time()
    result = _call(self, factors, values)
    entry = BATCH[_callers(2)]
    entry[0 if _SOLVED[0] else 1] += 1
    entry[2] += time.process_time() - start
    return result


def _counted_inner(self, factors, values):  # type: ignore[no-untyped-def]
    _SOLVED[0] = True
    return _inner(self, factors, values)


def _timed_advance(self, *args, **kwargs):  # type: ignore[no-untyped-def]
    info = float(self.graph.odometry[0].information[0, 0])
    entry = PASSES.setdefault(id(self), [self.gate, info, 0, 0.0, 0, 0, 0, 0.0, {}])
    start = time.process_time()
    _RUNNING.append(entry)
    try:
        return _advance(self, *args, **kwargs)
    finally:
        _RUNNING.pop()
        entry[2] += 1
        entry[3] += time.process_time() - start


_WRAPPED = (
    (admission.AdmissionPass, "advance", _timed_advance),
    (isam_prefix.IsamPrefix, "_converge", _timed_converge),
    (isam_prefix.IsamPrefix, "solve", _counted_solve),
    (least_squares.StickySolver, "__call__", _counted_call),
    (least_squares.StickySolver, "_solve", _counted_inner),
)


def install() -> list[object]:
    """Wrap the counted methods (results unchanged) and clear the counts; returns the
    originals for `restore`."""
    for table in (UPDATES, PREFIX, BATCH, PASSES):
        table.clear()
    originals = [getattr(cls, name) for cls, name, _ in _WRAPPED]
    for cls, name, wrapper in _WRAPPED:
        setattr(cls, name, wrapper)
    return originals


def restore(originals: list[object]) -> None:
    """Put back the methods `install` wrapped."""
    for (cls, name, _), original in zip(_WRAPPED, originals, strict=True):
        setattr(cls, name, original)


BANDS = ((0, 0), (1, 10), (11, 100), (101, 1000), (1001, 10**12))


def band_rows(updates: list[tuple[bool, int, int, float]]) -> list[tuple[str, int, float, float]]:
    """``(label, updates, CPU s, mean poses re-eliminated)`` of the updates that handed new
    factors over, then of the others by the poses they relinearised (`BANDS`)."""
    if not updates:
        return []
    new, relin, reelim, cpu = np.array(updates, dtype=float).T
    first = new > 0
    masks = [("with new factors", first)] + [
        (f"relinearised {lo}-{hi if hi < BANDS[-1][1] else 'more'}",
         ~first & (relin >= lo) & (relin <= hi)) for lo, hi in BANDS]
    return [(label, int(m.sum()), float(cpu[m].sum()),
             float(reelim[m].mean()) if m.any() else 0.0) for label, m in masks]


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--cap", type=float, default=0.0)
    args = parser.parse_args()
    _, _, corrupted, _ = read_cell(args)
    install()
    start = time.process_time()
    if capped_gnc(corrupted, args.cap) is None:
        print(f"capped at {args.cap:g} s CPU")
    print(f"{args.graph} x{args.scale:g} {args.policy} {args.ratio:g}% seed {args.seed}: "
          f"{time.process_time() - start:.1f} s CPU")
    print("admission passes (gate, odometry I[0, 0]; in order of their first advance):")
    for gate, info, calls, cpu, solves, updates, whole, whole_cpu, by in PASSES.values():
        print(f"  {gate:10s} {info:10.4g} {calls:3d} advance calls {cpu:7.2f} s: {solves:4d} "
              f"iSAM2 solves, {updates:5d} updates, {whole:4d} over 1000 poses "
              f"({whole_cpu:.2f} s)")
        for caller, n in sorted(by.items(), key=lambda kv: -kv[1]):
            print(f"      {n:4d} solves by {caller}")
    print("iSAM2 prefix solves by caller:")
    for name, (n, updates, cpu) in sorted(PREFIX.items(), key=lambda kv: -kv[1][2]):
        print(f"  {n:5d} solves {updates:6d} updates {cpu:7.2f} s  {name}")
    print("batch solves by caller:")
    for name, (n, hits, cpu) in sorted(BATCH.items(), key=lambda kv: -kv[1][2]):
        print(f"  {n:5d} solves {hits:3d} memo hits {cpu:7.2f} s  {name}")
    print(f"iSAM2 updates: {len(UPDATES)}, {sum(u[3] for u in UPDATES):.2f} s CPU")
    for label, n, cpu, reelim in band_rows(UPDATES):
        print(f"  {label:26s} {n:5d} updates {cpu:7.2f} s, mean re-eliminated {reelim:.0f}")

if __name__ == "__main__":
    main()
