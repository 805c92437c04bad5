"""The all-pairs distance matrix of the place benchmark, in one process or several, CPU-timed.

``D[i] = distances(describe(shape i), stack(all descriptors))`` for every query i:
the full ``(M, M)`` matrix (self-distances included), one batched query per row.
With ``workers > 1`` the rows are split into chunks computed by a
`concurrent.futures.ProcessPoolExecutor` (``forkserver`` start on POSIX, so no worker
is forked from a process running the progress bar's thread); each worker builds its
own matcher and stack from the descriptors once (pool initializer) and reports the
CPU time of its rows, so the compare time is CPU time whatever the number of
workers.  The matrix is the same as with one worker.  (As with any non-fork start
method, a script that calls this with ``workers > 1`` must guard its entry point
with ``if __name__ == "__main__"``; the ``loopclosure`` console script does.)

`single_compare_ms` times one unbatched ``distance(a, b)`` call, as the paper
compared one pair at a time.

Unit of work
------------
Without a process pool, the matrix is computed as independent tasks, one matcher x
data set block of rows each (`RowBlock`, run by `block_task`): the process that runs
a block describes every shape and stacks the descriptors once per matcher and data
set (the blocks run here share that), computes its rows, and returns them with their
CPU seconds (`BlockRows`); the block of row 0 also times the unbatched compares.
`matrix_by_blocks` runs the blocks here in order, or on a Dask cluster
(`evaluation.cluster`), where each worker loads the data set itself from a
`PlaceSource`, and assembles the matrix: the same rows bit for bit, since every row
is the same call on the same descriptors.
"""

from __future__ import annotations

import math
import multiprocessing
import time
import uuid
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from evaluation.places_methods import build_matcher
from loopclosure.matchers import Matcher
from loopclosure.polygon import Polygon

Array = NDArray[np.float64]
Progress = Callable[[str, int, int], None]


def all_pairs_matrix(
    name: str, matcher: Matcher, overrides: dict[str, Any], descriptors: list[Any],
    workers: int, progress: Progress, label: str,
) -> tuple[Array, float]:
    """The ``(M, M)`` matrix of `descriptors` and its CPU seconds (stack included).

    `matcher` computes it in this process when ``workers == 1``; otherwise each of the
    `workers` processes builds its own from `name` and `overrides`.
    """
    if workers > 1:
        return _matrix_parallel(name, overrides, descriptors, workers, progress, label)
    return _matrix_serial(matcher, descriptors, progress, label)


_WORKER: dict[str, Any] = {}


def _init_worker(name: str, overrides: dict[str, Any], descriptors: list[Any]) -> None:
    """Pool initializer: this worker's own matcher and stack (timed once)."""
    matcher = build_matcher(name, overrides)
    t0 = time.process_time()
    stacked = matcher.stack(descriptors)
    _WORKER.update(matcher=matcher, stacked=stacked, descriptors=descriptors,
                   stack_s=time.process_time() - t0, stack_reported=False)


def _worker_rows(start: int, stop: int) -> tuple[int, Array, float, float]:
    """Rows ``start:stop`` of the distance matrix, their CPU seconds, and the stack's once."""
    m, stacked, descs = _WORKER["matcher"], _WORKER["stacked"], _WORKER["descriptors"]
    t0 = time.process_time()
    block = np.stack([np.asarray(m.distances(descs[i], stacked), dtype=float)
                      for i in range(start, stop)])
    cpu = time.process_time() - t0
    stack_s = 0.0 if _WORKER["stack_reported"] else _WORKER["stack_s"]
    _WORKER["stack_reported"] = True
    return start, block, cpu, stack_s


def _pool_context() -> multiprocessing.context.BaseContext:
    """``forkserver`` (POSIX) with this module preloaded, so workers fork ready-imported."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["__main__", __name__])
    return ctx


def _matrix_parallel(
    name: str, overrides: dict[str, Any], descriptors: list[Any], workers: int,
    progress: Progress, label: str,
) -> tuple[Array, float]:
    """All-pairs matrix over `workers` processes; CPU seconds summed over the workers.

    The stack time is counted once per worker that reported rows, divided by the
    number of such workers (each builds the same stack).
    """
    m = len(descriptors)
    size = max(1, math.ceil(m / (workers * 8)))
    chunks = [(a, min(a + size, m)) for a in range(0, m, size)]
    out = np.empty((m, m))
    cpu, stack_total, stacks = 0.0, 0.0, 0
    done = 0
    with ProcessPoolExecutor(max_workers=workers, mp_context=_pool_context(),
                             initializer=_init_worker,
                             initargs=(name, overrides, descriptors)) as pool:
        futures = [pool.submit(_worker_rows, a, b) for a, b in chunks]
        for fut in as_completed(futures):
            start, block, c, s = fut.result()
            out[start:start + len(block)] = block
            cpu += c
            if s > 0:
                stack_total += s
                stacks += 1
            done += len(block)
            progress(label, done, m)
    return out, cpu + (stack_total / stacks if stacks else 0.0)


def _matrix_serial(
    matcher: Matcher, descriptors: list[Any], progress: Progress, label: str
) -> tuple[Array, float]:
    """All-pairs matrix in this process, and its CPU seconds (stack included)."""
    m = len(descriptors)
    out = np.empty((m, m))
    t0 = time.process_time()
    stacked = matcher.stack(descriptors)
    cpu = time.process_time() - t0
    step = max(1, m // 50)
    for i, d in enumerate(descriptors):  # one batched query per row (the protocol)
        t0 = time.process_time()
        out[i] = matcher.distances(d, stacked)
        cpu += time.process_time() - t0
        if (i + 1) % step == 0 or i + 1 == m:
            progress(label, i + 1, m)
    return out, cpu


def single_compare_ms(
    matcher: Matcher, descriptors: list[Any], seed: int, pairs: int = 50
) -> float:
    """Mean CPU [ms] of one unbatched ``distance(a, b)`` over random pairs ``a != b``."""
    m = len(descriptors)
    rng = np.random.default_rng(seed)
    i = rng.integers(0, m, size=pairs)
    j = (i + rng.integers(1, m, size=pairs)) % m
    t0 = time.process_time()
    for a, b in zip(i, j, strict=True):  # deliberately unbatched: one pair at a time
        matcher.distance(descriptors[a], descriptors[b])
    return 1e3 * (time.process_time() - t0) / pairs


def describe_all(
    name: str, matcher: Matcher, polygons: Sequence[Polygon], progress: Progress
) -> tuple[list[Any], float]:
    """Every polygon's descriptor and the CPU seconds of describing them all."""
    m = len(polygons)
    descriptors: list[Any] = []
    describe_s = 0.0
    step = max(1, m // 20)
    for start in range(0, m, step):  # timed in slices so the progress bar moves
        t0 = time.process_time()
        descriptors += [matcher.describe(p) for p in polygons[start:start + step]]
        describe_s += time.process_time() - t0
        progress(f"{name}: describe", len(descriptors), m)
    return descriptors, describe_s


BLOCKS_PER_MATRIX = 16
"""Row blocks (tasks) the matrix of one matcher on one data set is split into."""


@dataclass(frozen=True, slots=True)
class PlaceSource:
    """A data set as a worker loads it: `evaluation.place_datasets.load_dataset` of
    `spec` with `seed` (and a robot set's `range_cap`); a relative folder in `spec` is
    taken from `folder` (the caller's working folder)."""

    spec: str
    seed: int = 0
    folder: str = "."
    range_cap: float | None = None

    def polygons(self) -> list[Polygon]:
        from evaluation.place_datasets import RobotPlacesConfig, load_dataset

        kind, _, arg = self.spec.partition(":")
        spec = f"{kind}:{Path(self.folder) / arg.strip()}" if arg.strip() else self.spec
        robot = RobotPlacesConfig(range_cap=self.range_cap)
        return list(load_dataset(spec, seed=self.seed, robot=robot).polygons)


@dataclass(frozen=True, slots=True)
class RowBlock:
    """One task: rows ``start:stop`` of the matrix of matcher `method` (built with
    `overrides`) on the data set `source` names (a `PlaceSource`, or the key of a
    set held in this process's memory); row 0's block also times single compares
    (`single_compare_ms` with `seed`)."""

    source: PlaceSource | str
    method: str
    overrides: dict[str, Any]
    start: int
    stop: int
    size: int
    seed: int = 0


@dataclass(slots=True)
class BlockRows:
    """What one `RowBlock` returns: its rows ``(stop - start, M)``, their CPU seconds,
    the CPU seconds of describing and stacking (once per process), and the single-
    compare time [ms] (row 0's block only, else None)."""

    start: int
    rows: Array
    cpu_s: float
    describe_s: float
    stack_s: float
    single_ms: float | None


class BlockFailed(Exception):
    """A block of rows failed; the message is its error line."""


_SETS: dict[PlaceSource | str, tuple[list[Polygon], Progress]] = {}
"""The data sets this process holds, by the `RowBlock.source` that names them."""
_DESCRIBED: dict[tuple[Any, str, str], tuple[Matcher, list[Any], float, Any, float]] = {}
"""(matcher, descriptors, describe CPU s, stack, stack CPU s) per set and matcher."""


def _no_progress(stage: str, done: int, total: int) -> None:
    return None


def _described(block: RowBlock) -> tuple[Matcher, list[Any], float, Any, float]:
    """The matcher, descriptors and stack of `block`'s set, made once per process."""
    key = (block.source, block.method, repr(sorted(block.overrides.items())))
    if key not in _DESCRIBED:
        if block.source not in _SETS:
            if not isinstance(block.source, PlaceSource):
                raise UserError("bench places: this worker does not hold the shapes in memory; "
                                "give the data set as a PlaceSource")
            _SETS.clear()  # a worker holds one data set at a time
            _SETS[block.source] = (block.source.polygons(), _no_progress)
        polygons, progress = _SETS[block.source]
        matcher = build_matcher(block.method, dict(block.overrides))
        descriptors, describe_s = describe_all(block.method, matcher, polygons, progress)
        t0 = time.process_time()
        stacked = matcher.stack(descriptors)
        stack_s = time.process_time() - t0
        _DESCRIBED.clear()  # one matcher at a time
        _DESCRIBED[key] = (matcher, descriptors, describe_s, stacked, stack_s)
    return _DESCRIBED[key]


def block_task(block: RowBlock) -> BlockRows:
    """One block of rows of the all-pairs matrix (`RowBlock`)."""
    matcher, descriptors, describe_s, stacked, stack_s = _described(block)
    m = len(descriptors)
    rows = np.empty((block.stop - block.start, m))
    t0 = time.process_time()
    for n, i in enumerate(range(block.start, block.stop)):  # one batched query per row
        rows[n] = matcher.distances(descriptors[i], stacked)
    cpu = time.process_time() - t0
    single = single_compare_ms(matcher, descriptors, block.seed) if block.start == 0 else None
    if block.source in _SETS:
        _SETS[block.source][1](f"{block.method}: all pairs", block.stop, m)
    return BlockRows(block.start, rows, cpu, describe_s, stack_s, single)


def matrix_by_blocks(
    name: str, overrides: dict[str, Any], polygons: Sequence[Polygon], *, seed: int = 0,
    progress: Progress = _no_progress, source: PlaceSource | None = None,
    cluster: str | None = None,
) -> tuple[Array, float, float, float]:
    """The ``(M, M)`` matrix of matcher `name` on `polygons`, one `RowBlock` task per
    block of rows, here or on `cluster` (whose workers load `source`: required).

    Returns the matrix, the describe CPU seconds, the compare CPU seconds (stack once
    plus every row) and the single-compare time [ms].  Raises `BlockFailed` when a
    block fails (its error line).
    """
    from evaluation.cluster import map_tasks

    if cluster is not None and source is None:
        raise UserError("a cluster run needs the data set as a PlaceSource, not shapes in "
                        "memory")
    m = len(polygons)
    key: PlaceSource | str = source if source is not None else f"memory-{uuid.uuid4().hex}"
    size = max(1, math.ceil(m / BLOCKS_PER_MATRIX))
    blocks = [RowBlock(key, name, dict(overrides), a, min(a + size, m), m, seed)
              for a in range(0, m, size)]
    out = np.empty((m, m))
    cpu = describe_s = stack_s = single = 0.0
    _SETS[key] = (list(polygons), progress)
    try:
        for o in map_tasks(block_task, blocks, cluster=cluster, retries=0,
                           description=f"{name}: all pairs", progress=cluster is not None):
            if o.status == "interrupted":
                raise KeyboardInterrupt
            if o.status != "done":
                raise BlockFailed(o.error)
            rows: BlockRows = o.value
            out[rows.start:rows.start + len(rows.rows)] = rows.rows
            cpu += rows.cpu_s
            if rows.single_ms is not None:  # row 0's block: its process's describe, stack
                describe_s, stack_s, single = rows.describe_s, rows.stack_s, rows.single_ms
    finally:
        _SETS.pop(key, None)
        for k in [k for k in _DESCRIBED if k[0] == key]:
            del _DESCRIBED[k]
    return out, describe_s, stack_s + cpu, single
