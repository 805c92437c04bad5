"""Where independent tasks run: in this process one after the other, or on a Dask cluster.

``--cluster ADDRESS`` (`ClusterOption`) chooses the engine:

* not given: every task runs here, serially, in input order;
* ``local``: a Dask `LocalCluster` on this machine, one single-threaded worker
  process per core (the cores this process may use);
* ``local:N``: the same with N worker processes;
* a scheduler address (``tcp://HOST:8786``, ``tls://...``, or ``HOST:PORT``): an
  existing Dask scheduler, whatever runs its workers (``dask worker``, Kubernetes,
  Slurm through dask-jobqueue).

`Engine.map(fn, items)` runs ``fn(item)`` for every item and yields one `Outcome` per
item **in input order**, whatever the order of completion, so a table built from
the outcomes never depends on the schedule.  The serial engine and a cluster run
the same function on the same items.

Contract for a task
-------------------
* `fn` is a module-level function of an installed package (workers import it by
  name: they need the project installed, the same version);
* an item is small (paths, a config object): inputs are files that the workers
  read themselves, so on a real cluster every worker must see the same paths (a
  shared file system, or the same files at the same paths on every node);
* the returned value is small too (a summary, file paths).

Faults
------
* A `data.errors.UserError` raised by a task (bad input: the error names the file
  and what is wrong) is that item's failure, with its message as the error line;
  it is deterministic and not retried.
* Any other exception is retried `retries` times (Dask ``retries=``; the serial
  engine retries in the same way), then is the item's failure with
  ``"<ExceptionType>: <message>"`` as the error line.
* A worker process that dies while it runs a task (killed, out of memory) does not
  fail the task: the scheduler runs it again on another (or the restarted)
  worker; only after ``distributed.scheduler.allowed-failures`` such deaths (Dask's
  default 3; a `LocalCluster` here uses `ALLOWED_WORKER_DEATHS`) does the item fail
  with ``KilledWorker``.
* One failed item never stops the others.
* Ctrl-C cancels every task not yet finished; the items already finished are
  yielded as they are, the others as ``interrupted``, and the map then ends.

Progress: one rich progress bar on stderr (done / failed / running, elapsed time)
while the tasks run; a cluster engine prints its dashboard address on stderr when
it starts.
"""

from __future__ import annotations

import logging
import os
import re
import signal
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Annotated, Any

import typer

from data.errors import UserError

ClusterOption = Annotated[
    str | None,
    typer.Option("--cluster", help="Run the tasks on Dask: 'local' (one worker per core), "
                 "'local:N' or a scheduler address (tcp://HOST:8786). Default: in-process."),
]

DEFAULT_RETRIES = 1
"""Extra attempts of a task that raised an exception other than a `UserError`."""
ALLOWED_WORKER_DEATHS = 3
"""Worker deaths a task survives on a `LocalCluster` started here (it is then failed)."""

_SCHEDULER = re.compile(r"^(tcp|tls|inproc|ucx|ws|wss)://.+|^[\w.\-]+:\d+$")


@dataclass(frozen=True, slots=True)
class Outcome:
    """What became of one item: ``status`` is ``done``, ``failed`` or ``interrupted``.

    `value` is the task's return value (``done`` only); `error` the one-line reason
    (``failed``: the error line; ``interrupted``: ``"interrupted"``), else None.
    """

    index: int
    item: Any
    status: str
    value: Any = None
    error: str | None = None

    def result(self, label: str) -> Any:
        """`value` of a ``done`` item; an interrupted one raises `KeyboardInterrupt`, a
        failed one a `UserError` ``"<label>: <error>"`` (for sweeps that stop at the
        first failure)."""
        if self.status == "interrupted":
            raise KeyboardInterrupt
        if self.status != "done":
            raise UserError(f"{label}: {self.error}")
        return self.value


@dataclass(frozen=True, slots=True)
class ClusterSpec:
    """A parsed ``--cluster`` value: `kind` is ``serial``, ``local`` or ``scheduler``."""

    kind: str
    workers: int | None = None
    address: str | None = None

    def describe(self) -> str:
        if self.kind == "serial":
            return "in-process (serial)"
        if self.kind == "local":
            return f"local Dask cluster of {self.workers} worker processes"
        return f"Dask scheduler {self.address}"


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity where the OS tells it)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def parse_cluster(address: str | None) -> ClusterSpec:
    """The engine that ``--cluster ADDRESS`` names (module docstring); `UserError` if none."""
    if address is None:
        return ClusterSpec("serial")
    text = address.strip()
    if text == "local":
        return ClusterSpec("local", workers=available_cores())
    if text.startswith("local:"):
        count = text.removeprefix("local:")
        if not count.isdigit() or int(count) < 1:
            raise UserError(f"--cluster {address}: local:N needs a worker count N >= 1")
        return ClusterSpec("local", workers=int(count))
    if _SCHEDULER.match(text):
        return ClusterSpec("scheduler", address=text)
    raise UserError(
        f"--cluster {address}: expected 'local', 'local:N' or a scheduler address "
        "such as tcp://HOST:8786"
    )


def _attempt(fn: Callable[[Any], Any], item: Any) -> tuple[str, Any]:
    """``("done", fn(item))``, or ``("failed", message)`` for a `UserError` (not retried)."""
    try:
        return "done", fn(item)
    except UserError as exc:
        return "failed", str(exc)


def _error_line(exc: BaseException) -> str:
    if type(exc).__name__ == "KilledWorker":
        return ("KilledWorker: every worker that ran this task died (out of memory? "
                "killed?), more often than the scheduler's allowed-failures")
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


@contextmanager
def _interrupts_ignored() -> Iterator[None]:
    """SIGINT ignored in this process meanwhile, so that the worker processes started
    meanwhile inherit that: Ctrl-C in a terminal reaches every process of its group,
    and the workers of a `LocalCluster` are to be shut down by the client instead."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _ignore_interrupts_plugin() -> Any:
    """A worker plugin that ignores SIGINT in each worker, restarted ones included."""
    from distributed.diagnostics.plugin import WorkerPlugin

    class IgnoreInterrupts(WorkerPlugin):
        def setup(self, worker: Any) -> None:
            if threading.current_thread() is threading.main_thread():
                signal.signal(signal.SIGINT, signal.SIG_IGN)

    return IgnoreInterrupts()


class Engine:
    """An open engine (module docstring); use as a context manager.

    ``with Engine("local:2") as engine: for o in engine.map(fn, items): ...``
    starts the cluster on entry and shuts it down on exit; ``Engine(None)`` runs
    every task in this process.
    """

    def __init__(self, address: str | None, *, echo: Callable[[str], None] | None = None) -> None:
        self.spec = parse_cluster(address)
        self.echo = echo or (lambda line: print(line, file=sys.stderr))
        self.client: Any = None
        self._cluster: Any = None

    # -- lifetime ----------------------------------------------------------------------

    def __enter__(self) -> Engine:
        if self.spec.kind != "serial":
            self._connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _connect(self) -> None:
        try:
            import dask
            from distributed import Client, LocalCluster
        except ImportError as exc:
            raise UserError(f"--cluster needs the `distributed` package ({exc}): "
                            "pip install distributed") from None
        if self.spec.kind == "local":
            with dask.config.set({"distributed.scheduler.allowed-failures":
                                  ALLOWED_WORKER_DEATHS}), _interrupts_ignored():
                self._cluster = LocalCluster(
                    n_workers=self.spec.workers, threads_per_worker=1, processes=True,
                    host="127.0.0.1", scheduler_port=0, dashboard_address="127.0.0.1:0",
                    silence_logs=logging.CRITICAL,
                )
            self.client = Client(self._cluster)
            self.client.register_plugin(_ignore_interrupts_plugin(), name="ignore-ctrl-c")
        else:
            try:
                self.client = Client(self.spec.address, timeout="10s")
            except OSError as exc:
                raise UserError(f"--cluster {self.spec.address}: cannot reach the scheduler "
                                f"({exc})") from None
        link = self.client.dashboard_link if self._has_dashboard() else None
        self.echo(f"{self.spec.describe()}, {self.workers} workers; dashboard: "
                  f"{link or 'not served (pip install bokeh)'}")

    def _has_dashboard(self) -> bool:
        services = self.client.scheduler_info().get("services", {})
        return "dashboard" in services

    def close(self) -> None:
        """Disconnect, and shut down the `LocalCluster` this engine started."""
        if self.client is not None:
            self.client.close()
            self.client = None
        if self._cluster is not None:
            self._cluster.close()
            self._cluster = None

    @property
    def workers(self) -> int:
        """Worker threads the tasks can use (1 for the serial engine)."""
        if self.client is None:
            return 1
        info = self.client.scheduler_info().get("workers", {})
        return sum(w.get("nthreads", 1) for w in info.values())

    # -- the map -----------------------------------------------------------------------

    def map(
        self,
        fn: Callable[[Any], Any],
        items: Iterable[Any],
        *,
        retries: int = DEFAULT_RETRIES,
        description: str = "tasks",
        progress: bool = True,
    ) -> Iterator[Outcome]:
        """``fn(item)`` for every item; yields one `Outcome` per item, in input order."""
        items = list(items)
        with _Bar(description, len(items), progress) as bar:
            if self.client is None:
                yield from self._map_serial(fn, items, retries, bar)
            else:
                yield from self._map_cluster(fn, items, retries, bar)

    def _map_serial(
        self, fn: Callable[[Any], Any], items: list[Any], retries: int, bar: _Bar
    ) -> Iterator[Outcome]:
        for index, item in enumerate(items):
            bar.show(running=1)
            try:
                outcome = self._run_here(fn, index, item, retries)
            except KeyboardInterrupt:
                for rest in range(index, len(items)):
                    yield Outcome(rest, items[rest], "interrupted", error="interrupted")
                return
            bar.count(outcome)
            yield outcome

    @staticmethod
    def _run_here(fn: Callable[[Any], Any], index: int, item: Any, retries: int) -> Outcome:
        for attempt in range(retries + 1):
            try:
                status, value = _attempt(fn, item)
            except Exception as exc:
                if attempt == retries:
                    return Outcome(index, item, "failed", error=_error_line(exc))
                continue
            if status == "done":
                return Outcome(index, item, "done", value=value)
            return Outcome(index, item, "failed", error=value)
        raise AssertionError("unreachable")

    def _map_cluster(
        self, fn: Callable[[Any], Any], items: list[Any], retries: int, bar: _Bar
    ) -> Iterator[Outcome]:
        from distributed import wait

        tag = f"{getattr(fn, '__name__', 'task')}-{uuid.uuid4().hex[:8]}"
        futures = [
            self.client.submit(_attempt, fn, item, key=f"{tag}-{i}", pure=False,
                               retries=retries)
            for i, item in enumerate(items)
        ]
        index_of = {f.key: i for i, f in enumerate(futures)}
        finished: dict[int, Outcome] = {}
        pending = set(futures)
        following = 0
        try:
            while pending:
                bar.show(running=self._running(tag))
                try:
                    done, _ = wait(pending, timeout=0.5, return_when="FIRST_COMPLETED")
                except TimeoutError:
                    continue
                for future in done:
                    i = index_of[future.key]
                    finished[i] = self._outcome(future, i, items[i])
                    bar.count(finished[i])
                    future.release()
                pending -= done
                while following in finished:
                    yield finished.pop(following)
                    following += 1
        except KeyboardInterrupt:
            self.client.cancel(list(pending))
            for i in range(following, len(items)):
                yield finished.get(i) or Outcome(i, items[i], "interrupted", error="interrupted")

    def _running(self, tag: str) -> int:
        """Tasks of this map that a worker is running now."""
        processing = self.client.processing()
        return sum(1 for keys in processing.values() for k in keys if str(k).startswith(tag))

    @staticmethod
    def _outcome(future: Any, index: int, item: Any) -> Outcome:
        if future.status == "error":
            return Outcome(index, item, "failed", error=_error_line(future.exception()))
        if future.status == "cancelled":
            return Outcome(index, item, "interrupted", error="interrupted")
        status, value = future.result()
        if status == "done":
            return Outcome(index, item, "done", value=value)
        return Outcome(index, item, "failed", error=value)


def map_tasks(
    fn: Callable[[Any], Any],
    items: Iterable[Any],
    *,
    cluster: str | None = None,
    retries: int = DEFAULT_RETRIES,
    description: str = "tasks",
    progress: bool = True,
) -> Iterator[Outcome]:
    """`Engine.map` on an engine opened for this one map (``cluster``: ``--cluster``)."""
    with Engine(cluster) as engine:
        yield from engine.map(fn, items, retries=retries, description=description,
                              progress=progress)


class _Bar:
    """The progress bar of one map on stderr: done / failed / running of the total."""

    def __init__(self, description: str, total: int, enabled: bool) -> None:
        self.enabled = enabled
        self.done = self.failed = self.running = 0
        self.description = description
        self.total = total
        self._progress: Any = None
        self._task: Any = None
        self._start = time.perf_counter()

    def __enter__(self) -> _Bar:
        if self.enabled:
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
            )

            self._progress = Progress(
                TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                TextColumn("done {task.fields[done]}  failed {task.fields[failed]}  "
                           "running {task.fields[running]}"),
                TimeElapsedColumn(), console=Console(stderr=True), transient=True,
            )
            self._progress.start()
            self._task = self._progress.add_task(self.description, total=self.total, done=0,
                                                 failed=0, running=0)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._progress is not None:
            self._progress.stop()

    def show(self, running: int) -> None:
        self.running = running
        self._update()

    def count(self, outcome: Outcome) -> None:
        if outcome.status == "done":
            self.done += 1
        elif outcome.status == "failed":
            self.failed += 1
        self._update()

    def _update(self) -> None:
        if self._progress is not None:
            self._progress.update(self._task, completed=self.done + self.failed,
                                  done=self.done, failed=self.failed, running=self.running)
