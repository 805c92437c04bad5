"""Benchmark: a whole run with the front end's worker, CPU per stage in each process.

Run from the repository root (the code on ``PYTHONPATH`` is measured)::

    python benchmarks/worker_split.py LOG [loopclosure run options ...]

e.g. ``python benchmarks/worker_split.py ../shared/data/carmen/intel.clf.bz2 --out
/tmp/split --no-map``.  Runs ``loopclosure run`` in this process with the forked
front-end worker (`slam.front_end_worker`) and the CPU timers of
`benchmarks/loop_time_split.py` around every stage; the worker inherits the timers
and sends its totals back before it exits.  Prints, for the mapper (main) process and
the worker side by side, each stage's CPU seconds and calls, each process's whole
CPU time, and the mapper's waits for the worker: the wall and CPU seconds it spent
in the worker's generator (blocked on its inbox) and how many keyframes' place
queries the worker made (it makes them only while it is ahead).  From the per-scan
CPU costs of both processes it also simulates the loop's wall time on two idle cores
(`simulate`) with the place queries where the pipeline puts them, always in the
worker, and always in the mapper; with ``WORKER_SPLIT_SAVE=FILE`` in the environment
the per-scan costs are written to FILE (JSON) for other policies.

On an idle 2-core machine the run's wall time is about the mapper's CPU time plus
its wait for the worker: the worker's CPU time matters only where the mapper waits.
On a loaded machine the waits are inflated; the CPU figures are not.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
import types
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import loop_time_split as split

WAIT = {"wall": 0.0, "cpu": 0.0, "calls": 0}
STEPS = {"keyframes": 0, "matches_in_worker": 0}
#: Per scan, CPU seconds [s]: the worker's step without the place query, the place
#: query (wherever it was made; 0 without one), the mapper's step without it.
WORKER: list[float] = []
QUERY: dict[int, float] = {}
MAPPER: list[float] = []
_QUERY_NOW = [0.0]


def _install_worker_dump(path: Path) -> None:
    """The worker writes its stage totals and CPU time to `path` before ``os._exit``."""
    import slam.front_end_worker as few

    def _exit(code: int) -> None:
        totals = {"stages": dict(split.TOTAL), "calls": dict(split.CALLS),
                  "cpu": time.process_time(), "steps": WORKER,
                  "queries": {str(k): v for k, v in QUERY.items()}}
        path.write_text(json.dumps(totals))
        os._exit(code)

    few.os = types.SimpleNamespace(_exit=_exit)


def _install_step_timers() -> None:
    """Per-scan CPU seconds of the worker's and the mapper's steps, the place
    database's query apart (`WORKER`, `MAPPER`, `QUERY`)."""
    import loopclosure.keyframe_store as store
    import slam.pipeline as pipeline

    query = store.KeyframeStore.query_places

    def timed_query(self, *args, **kwargs):
        start = time.process_time()
        try:
            return query(self, *args, **kwargs)
        finally:
            _QUERY_NOW[0] += time.process_time() - start

    store.KeyframeStore.query_places = timed_query
    worker_step = pipeline.Mapper._worker_step
    after = pipeline.Mapper._after_odometry

    def timed_worker_step(self, scan, ahead):
        _QUERY_NOW[0] = 0.0
        start = time.process_time()
        out = worker_step(self, scan, ahead)
        q = _QUERY_NOW[0]
        if q:
            QUERY[len(WORKER)] = q
        WORKER.append(time.process_time() - start - q)
        return out

    def timed_after(self, *args, **kwargs):
        _QUERY_NOW[0] = 0.0
        start = time.process_time()
        after(self, *args, **kwargs)
        q = _QUERY_NOW[0]
        if q:
            QUERY[len(MAPPER)] = q
        MAPPER.append(time.process_time() - start - q)

    pipeline.Mapper._worker_step = timed_worker_step
    pipeline.Mapper._after_odometry = timed_after


def simulate(worker: list[float], mapper: list[float], query: dict[int, float],
             policy: str, threshold: int | None = None, batch: int | None = None
             ) -> tuple[float, float, int]:
    """The loop's wall time [s] on two idle cores, from the per-scan CPU costs [s]:
    the worker sends batches of `BATCH` scans, the mapper takes scan i once its batch
    has arrived (the worker's limit of `AHEAD` unread batches is left out: the mapper
    is then the slower one anyway).  A keyframe's place query runs in the worker
    under `policy` ``ahead`` (the pipeline's rule: the worker has sent at least a
    batch more than the mapper has taken), ``worker`` (always) or ``mapper`` (never),
    else in the mapper; `threshold` (scans; default the pipeline's `LEAD`, or one
    batch in code without it) is the rule's lead, `batch` (default `BATCH`) the scans
    per message.  Returns (wall, the mapper's waits, queries in the worker)."""
    import slam.front_end_worker as few

    size = few.BATCH if batch is None else batch
    lead = getattr(few, "LEAD", few.BATCH) if threshold is None else threshold
    n = len(worker)
    arrive: list[float] = []  # when each batch reaches the mapper
    done: list[float] = []  # when the mapper finished each scan
    in_worker: set[int] = set()
    w_clock = m_clock = wait = 0.0
    i_w = i_m = 0
    while i_m < n:
        mapper_blocked = i_m // size >= len(arrive)
        if i_w < n and (w_clock <= m_clock or mapper_blocked):
            consumed = i_m if m_clock <= w_clock else i_m - (done[-1] > w_clock if done else 0)
            q = query.get(i_w, 0.0)
            if q and (policy == "worker"
                      or (policy == "ahead" and len(arrive) * size - consumed >= lead)):
                in_worker.add(i_w)
                w_clock += q
            w_clock += worker[i_w]
            i_w += 1
            if i_w % size == 0 or i_w == n:
                arrive.append(w_clock)
            continue
        begin = max(m_clock, arrive[i_m // size])
        wait += begin - m_clock
        m_clock = begin + mapper[i_m] + (0.0 if i_m in in_worker else query.get(i_m, 0.0))
        done.append(m_clock)
        i_m += 1
    return m_clock, wait, len(in_worker)


def _install_wait_timer() -> None:
    """The mapper's time inside the worker's result generator (its waits)."""
    import slam.pipeline as pipeline

    original = pipeline.map_in_worker

    def timed_map(step, scans, stats=None):
        inner = original(step, scans, stats)

        def gen():
            try:
                while True:
                    w, c = time.perf_counter(), time.process_time()
                    try:
                        item = next(inner)
                    except StopIteration:
                        return
                    finally:
                        WAIT["wall"] += time.perf_counter() - w
                        WAIT["cpu"] += time.process_time() - c
                        WAIT["calls"] += 1
                    place, matches = item[1][2], item[1][3]
                    STEPS["keyframes"] += place is not None
                    STEPS["matches_in_worker"] += matches is not None
                    yield item
            finally:
                inner.close()

        return gen()

    pipeline.map_in_worker = timed_map


def main() -> None:
    if len(sys.argv) < 2 or sys.argv[1] in ("-h", "--help"):
        sys.exit(__doc__)
    split.install()
    with tempfile.TemporaryDirectory() as tmp:
        dump = Path(tmp) / "worker.json"
        _install_worker_dump(dump)
        _install_wait_timer()
        _install_step_timers()
        sys.argv = ["loopclosure", "run", *sys.argv[1:]]
        from slam.cli.main import main as cli

        wall, cpu = time.perf_counter(), time.process_time()
        cli()
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        worker = json.loads(dump.read_text()) if dump.exists() else {
            "stages": {}, "calls": {}, "cpu": 0.0}
    print(f"wall {wall:.1f} s; mapper CPU {cpu:.1f} s; worker CPU {worker['cpu']:.1f} s; "
          f"mapper waited {WAIT['wall']:.1f} s wall ({WAIT['cpu']:.1f} s CPU) in "
          f"{WAIT['calls']} scans; keyframes {STEPS['keyframes']}, place queries made "
          f"in the worker {STEPS['matches_in_worker']}")
    steps = worker.get("steps", [])
    if len(steps) == len(MAPPER):
        queries = {int(k): v for k, v in worker.get("queries", {}).items()} | QUERY
        print(f"loop CPU: worker {sum(steps):.1f} s, mapper {sum(MAPPER):.1f} s, place "
              f"queries {sum(queries.values()):.1f} s ({len(queries)})")
        for policy in ("ahead", "worker", "mapper"):
            wall_s, wait_s, n_w = simulate(steps, MAPPER, queries, policy)
            print(f"simulated loop on 2 idle cores, queries {policy}: wall {wall_s:.1f} s, "
                  f"mapper waits {wait_s:.1f} s, queries in the worker {n_w}")
        save = os.environ.get("WORKER_SPLIT_SAVE")
        if save:  # the per-scan costs, for other policies offline
            Path(save).write_text(json.dumps({"worker": steps, "mapper": MAPPER,
                                              "queries": {str(k): v for k, v in queries.items()}}))
    rows: defaultdict[str, list[float]] = defaultdict(lambda: [0.0, 0, 0.0, 0])
    for label, t in split.TOTAL.items():
        rows[label][0:2] = [t, split.CALLS[label]]
    for label, t in worker["stages"].items():
        rows[label][2:4] = [t, worker["calls"][label]]
    print(f"{'stage':26s} {'mapper s':>9s} {'calls':>7s} {'worker s':>9s} {'calls':>7s}")
    for label in sorted(rows, key=lambda k: -(rows[k][0] + rows[k][2])):
        m, mc, w, wc = rows[label]
        print(f"{label:26s} {m:9.2f} {mc:7d} {w:9.2f} {wc:7d}")


if __name__ == "__main__":
    main()
