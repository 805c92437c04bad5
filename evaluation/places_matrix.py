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
"""

from __future__ import annotations

import math
import multiprocessing
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any

import numpy as np
from numpy.typing import NDArray

from evaluation.places_methods import build_matcher
from loopclosure.matchers import Matcher

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
