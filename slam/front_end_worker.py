"""The front of the mapper in a worker process, a batch of scans ahead of the rest.

The front end needs nothing from the back end: scan ``i``'s odometry depends only
on the scans before it, and so do the choice of keyframes and the description of
their places (`slam.pipeline`).  So while the mapper checks loops and updates the
graph for scan ``i``, a forked worker process can already register scans ``i + 1,
i + 2, ...`` and describe their places; on 2 cores that work leaves the mapper's
critical path.

`map_in_worker(step, scans)` yields ``(scan, step(scan, ahead))`` in input order,
exactly what calling ``step`` (the mapper's `_worker_step`) here would have returned.
``ahead`` tells the step whether the worker is ahead of the mapper (results waiting
unread) and so has time for work the mapper would otherwise do itself.  The
worker is a ``fork`` of this process: it inherits the front end and the scan
iterator as they are (nothing is pickled on the way in) and sends the results back
in batches through a pipe.  A reader thread here empties the pipe into an inbox of
up to `AHEAD` batches, so the worker blocks only when it is that far ahead (a pipe's
own buffer holds a batch or two: the worker used to wait there, idle, while the
mapper was the slower process, and the mapper then waited for it where the worker
was slower).  An exception
in the worker (a malformed log under ``--strict``) is raised again here.  Where
``fork`` is missing (Windows), or in a daemon process or a thread other than the
main one (a cluster's task), `worker_available` is False and the mapper runs the
front end in its own process.

The mapper still reports the front end's time (measured in the worker), so the stage
timings of a run add up to more than its wall time.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
import threading
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from slam.memory import peak_rss_mb

__all__ = ["AHEAD", "BATCH", "LEAD", "map_in_worker", "worker_available"]

BATCH = 16
"""Scans per message: one pipe round trip per batch, not per scan."""

AHEAD = 64
"""Batches the worker may run ahead of the mapper (1,024 scans: a few tens of MB of
scans, estimates and place descriptions waiting)."""

LEAD = 2 * BATCH
"""Results waiting unread (scans) from which the worker counts as ahead of the mapper
and takes on the mapper's movable work (`map_in_worker`'s ``ahead``).  One batch
gave the work to the worker while the mapper was about to catch up with it (the
results in flight are a batch or so); two keep it with the mapper there, and the
two processes wait less for each other (`benchmarks/worker_split.py`)."""

_DONE = "done"
_ERROR = "error"
_ITEMS = "items"
_GONE = "gone"  # the pipe closed without a last message


def worker_available() -> bool:
    """True where a forked worker can run the front end: POSIX with ``fork``, from the
    main thread of a process that may have children.  Not in a daemon process, nor
    in a task thread of a cluster worker (a fork copies only the calling thread, and
    the cluster already keeps the cores busy)."""
    return ("fork" in mp.get_all_start_methods() and not mp.current_process().daemon
            and threading.current_thread() is threading.main_thread())


def _work(step: Callable[[Any, int], Any], scans: Iterable[Any], conn: Any,
          consumed: Any) -> None:
    """The worker: `step` of every scan, sent back in batches, then _DONE."""
    batch: list[tuple[Any, Any]] = []
    sent = 0
    try:
        for scan in scans:
            batch.append((scan, step(scan, sent - consumed.value)))
            if len(batch) == BATCH:
                conn.send((_ITEMS, batch))
                sent += len(batch)
                batch = []
        if batch:
            conn.send((_ITEMS, batch))
        conn.send((_DONE, peak_rss_mb()))
    except KeyboardInterrupt:  # Ctrl-C reaches the whole process group: the mapper
        pass  # stops the run itself
    except BaseException as exc:
        try:
            conn.send((_ERROR, exc))
        except Exception:  # an exception that does not pickle
            conn.send((_ERROR, RuntimeError(f"front end worker: {exc!r}")))
    finally:
        conn.close()
        os._exit(0)  # no atexit handlers, no flushing of the parent's inherited buffers


def map_in_worker(
    step: Callable[[Any, int], Any], scans: Iterable[Any], stats: dict[str, float] | None = None
) -> Iterator[tuple[Any, Any]]:
    """``(scan, step(scan, ahead))`` of every scan, computed in a forked worker (module
    docstring).  ``ahead`` is how many results the worker has sent that the caller
    has not yet taken: at least `BATCH` when the caller is the slower of the two, so
    `step` may then take on work the caller would otherwise do (from `LEAD`).  Closing the
    generator early (an interrupted run) stops the worker.  At the end `stats` gets
    ``peak_rss_mb``, the worker's peak resident memory [MB] (with the pages it shares
    with this process since the fork)."""
    ctx = mp.get_context("fork")
    receive, send = ctx.Pipe(duplex=False)
    consumed = ctx.RawValue("q", 0)  # written here only, read by the worker
    worker = ctx.Process(target=_work, args=(step, scans, send, consumed), daemon=True,
                         name="loopclosure-front-end")
    worker.start()
    send.close()  # the worker holds the only writing end: EOF when it is gone
    inbox: queue.Queue[tuple[str, Any]] = queue.Queue(maxsize=AHEAD)
    stop = threading.Event()
    reader = threading.Thread(target=_read, args=(receive, inbox, stop), daemon=True,
                              name="loopclosure-front-end-reader")
    reader.start()
    try:
        while True:
            kind, payload = inbox.get()
            if kind == _ITEMS:
                for item in payload:
                    yield item
                    consumed.value += 1
            elif kind == _ERROR:
                raise payload
            elif kind == _GONE:
                raise RuntimeError(
                    f"the front end worker stopped without a result (exit code "
                    f"{worker.exitcode})")
            else:
                if stats is not None:
                    stats["peak_rss_mb"] = payload
                return
    finally:
        stop.set()
        if worker.is_alive():
            worker.terminate()
        worker.join()
        reader.join()  # the worker's end is closed: the reader's recv returns
        receive.close()


def _read(receive: Any, inbox: queue.Queue, stop: threading.Event) -> None:
    """The reader thread: every message of the pipe into `inbox` (blocking while it
    holds `AHEAD` batches), until the last one, the pipe's end, or `stop`."""
    while not stop.is_set():
        try:
            message = receive.recv()
        except (EOFError, OSError):
            message = (_GONE, None)
        while not stop.is_set():
            try:
                inbox.put(message, timeout=0.1)
                break
            except queue.Full:
                continue
        if message[0] != _ITEMS:
            return
