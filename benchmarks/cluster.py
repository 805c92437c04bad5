"""Benchmark: two sweeps serial vs on a local Dask cluster, and the per-task overhead.

Run from the repository root::

    python benchmarks/cluster.py [--data DIR] [--limit N] [--workers N] [--tasks M] [--no-map]
        [--kernels none,huber,...] [--ratios 0,10,...] [--skip-batch] [--skip-robustness]

**Robustness sweep.** The cells of ``loopclosure eval robustness`` (one task per kernel x
outlier ratio, `evaluation.robustness.robustness_task`) on the INTEL pose graph
(``DATA/g2o/input_INTEL_g2o.g2o``; by default the six kernels ``none, huber, cauchy, dcs,
gemanmcclure, gnc`` x the six ratios ``0, 10, 20, 30, 40, 50`` %, fewer with
``--kernels`` / ``--ratios`` for a quick run), in-process then on the cluster: the wall
time of each, the speed-up, and whether the two tables are identical (every figure but
the seconds), with the CPU seconds the cells used and the cores they kept busy on
average (a machine shared with other work shows here: fewer than the worker count).
The clean optimum is computed once, before either timed sweep, as the command does.

**Batch sweep.** It maps the six GMapping-corrected logs (``DATA/carmen-corrected/*.log.gz``,
``--limit N``: only their first N scans, for a quick run) twice with the code of
`loopclosure batch` (`evaluation.batch.map_input` on `evaluation.cluster.Engine`):
in-process, serially, then on a `LocalCluster` of ``--workers`` (default 2) worker
processes, and prints

* the wall time of each [s] (the cluster's with and without its start-up), and the
  speed-up serial / cluster; the ideal is the worker count, as long as there are at
  least that many logs of similar length (the longest log bounds the cluster's time);
* whether the two tables are identical (every row field except wall time, memory
  and output folder);
* the scheduler overhead per task [ms], from ``--tasks`` (default 200) trivial tasks
  on the same cluster: the round trip of one task at a time (median of 20: submit,
  run, result), and the wall time of all of them at once divided by their count
  (amortised over the workers).

Every process compiles the numba ICP on its first log (a few seconds) and imports
the pipeline: before the timed maps the serial process and every worker
(``Client.run``) map the first ``WARM_UP_SCANS`` scans of one log once, so that the
times compare the mapping itself; that warm-up is printed on its own (a real batch
pays it once per process, in its first task).
Output goes to a temporary folder removed at exit.  The goal: a speed-up of at
least 1.8 on 2 workers, and an overhead per task under 50 ms.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

# One BLAS thread here, as in every Dask worker (its nanny sets it): the serial sweep
# must not use more cores than one worker has.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evaluation.batch import expand_inputs, make_jobs, map_input  # noqa: E402
from evaluation.cluster import Engine  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402

VARYING = ("wall_s", "peak_rss_mb")
WARM_UP_SCANS = 20
INTEL = "input_INTEL_g2o.g2o"
KERNELS = "none,huber,cauchy,dcs,gemanmcclure,gnc"
RATIOS = "0,10,20,30,40,50"


def noop(n: int) -> int:
    """A trivial task: the scheduler's overhead is all its cost."""
    return n


def rows(outcomes) -> list[dict]:
    """Comparable rows: status, error and every figure that does not vary by machine."""
    table = []
    for o in outcomes:
        value = {k: v for k, v in (o.value or {}).items() if k not in VARYING}
        table.append({"name": o.item.name, "status": o.status, "error": o.error, **value})
    return table


def warm_up(job) -> float:
    """Map `job` (imports, numba compilation) in this process; its wall time [s]."""
    start = time.perf_counter()
    map_input(job)
    return time.perf_counter() - start


def timed_map(engine: Engine, jobs, label: str) -> tuple[float, list[dict]]:
    start = time.perf_counter()
    outcomes = list(engine.map(map_input, jobs, description=label))
    return time.perf_counter() - start, rows(outcomes)


def overhead_ms(engine: Engine, tasks: int) -> tuple[float, float]:
    """(median round trip of one trivial task, wall of `tasks` at once / tasks) [ms]."""
    list(engine.map(noop, range(engine.workers), progress=False))  # workers warm
    trips = []
    for n in range(20):
        start = time.perf_counter()
        list(engine.map(noop, [n], progress=False))
        trips.append(time.perf_counter() - start)
    start = time.perf_counter()
    list(engine.map(noop, range(tasks), progress=False))
    return 1e3 * statistics.median(trips), 1e3 * (time.perf_counter() - start) / tasks


def timed_cell(cell):
    """`robustness_task` of `cell` and the CPU seconds of its process meanwhile."""
    from evaluation.robustness import robustness_task

    start = time.process_time()
    result = robustness_task(cell)
    return result, time.process_time() - start


def robustness_figures(outcomes) -> list[dict]:
    """Comparable robustness rows: status, error and every figure but the seconds."""
    return [{"status": o.status, "error": o.error,
             **{k: v for k, v in (o.value[0].to_json() if o.value else {}).items()
                if k != "seconds"}} for o in outcomes]


def robustness_sweep(g2o: Path, kernels: str, ratios: str, engines) -> list[str]:
    """The INTEL cells on every engine of `engines` ((label, Engine) pairs); report lines."""
    from data.g2o import read_g2o
    from evaluation.robustness import robustness_cells
    from slam.pose_graph import PoseGraph

    names = [k for k in kernels.split(",") if k]
    fractions = [float(r) / 100 for r in ratios.split(",") if r]
    start = time.perf_counter()
    cells = robustness_cells(str(g2o), PoseGraph.from_g2o(read_g2o(g2o)), fractions, names)
    lines = [f"robustness sweep on {g2o.name}: {len(names)} kernels x {len(fractions)} "
             f"ratios = {len(cells)} cells (clean optimum {time.perf_counter() - start:.1f} s, "
             "not in the times below)"]
    times, tables = [], []
    for label, engine in engines:
        # every process imports the solver and reads the graph before the timed sweep
        list(engine.map(timed_cell, [cells[0]] * engine.workers, progress=False))
        start = time.perf_counter()
        outcomes = list(engine.map(timed_cell, cells, description=label))
        times.append(time.perf_counter() - start)
        tables.append(robustness_figures(outcomes))
        failed = sum(o.status != "done" for o in outcomes)
        cpu = sum(o.value[1] for o in outcomes if o.value)
        lines.append(f"  {label:<16}{times[-1]:8.1f} s wall  ({len(cells) - failed} of "
                     f"{len(cells)} cells done; {cpu:.1f} CPU s in the cells, "
                     f"{cpu / times[-1]:.2f} cores busy on average)")
    for (label, engine), wall in zip(engines[1:], times[1:], strict=True):
        lines.append(f"  speed-up {label:<7}{times[0] / wall:8.2f} x  (ideal "
                     f"{min(engine.workers, len(cells))})")
    same = all(t == tables[0] for t in tables[1:])
    lines.append(f"  identical tables {'yes' if same else 'NO'}")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--limit", type=int, default=None, help="Scans per log (default all).")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--tasks", type=int, default=200, help="Trivial tasks for the overhead.")
    parser.add_argument("--no-map", action="store_true", help="Skip the occupancy maps.")
    parser.add_argument("--kernels", default=KERNELS, help="Robustness sweep: kernels.")
    parser.add_argument("--ratios", default=RATIOS, help="Robustness sweep: false loops [%%].")
    parser.add_argument("--skip-batch", action="store_true", help="Only the robustness sweep.")
    parser.add_argument("--skip-robustness", action="store_true", help="Only the batch sweep.")
    args = parser.parse_args()
    if not args.skip_robustness:
        g2o = args.data / "g2o" / INTEL
        if not g2o.is_file():
            print(f"no data: {g2o} not found", file=sys.stderr)
            return 2
        with Engine(None) as serial, Engine(f"local:{args.workers}") as cluster:
            for line in robustness_sweep(g2o, args.kernels, args.ratios,
                                         [("serial", serial),
                                          (f"local:{args.workers}", cluster)]):
                print(line, flush=True)
    if args.skip_batch:
        return 0
    logs = args.data / "carmen-corrected"
    if not logs.is_dir():
        print(f"no data: {logs} not found (needs ../shared beside the checkout)", file=sys.stderr)
        return 2
    inputs = expand_inputs([str(logs / "*.log.gz")])
    out = Path(tempfile.mkdtemp(prefix="bench-cluster-"))
    try:
        def jobs(sub: str):
            return make_jobs(inputs, out / sub, PipelineConfig(), write_map=not args.no_map,
                             limit=args.limit)

        scans = "all scans" if args.limit is None else f"first {args.limit} scans"
        print(f"batch over {len(inputs)} logs ({scans} each), maps "
              f"{'off' if args.no_map else 'on'}")
        warm = make_jobs(inputs[:1], out / "warm-up", PipelineConfig(), write_map=False,
                         limit=WARM_UP_SCANS)[0]
        with Engine(None) as serial:
            serial_warm_s = warm_up(warm)
            serial_s, serial_rows = timed_map(serial, jobs("serial"), "serial")
        start = time.perf_counter()
        with Engine(f"local:{args.workers}") as cluster:
            startup_s = time.perf_counter() - start
            worker_warm_s = max(cluster.client.run(warm_up, warm).values())
            cluster_s, cluster_rows = timed_map(cluster, jobs("cluster"), f"local:{args.workers}")
            trip_ms, amortised_ms = overhead_ms(cluster, args.tasks)
        mapped = sum(r["status"] == "done" for r in serial_rows)
        print(f"serial            {serial_s:8.1f} s  ({mapped} of {len(inputs)} logs mapped)")
        print(f"local:{args.workers}           {cluster_s:8.1f} s  "
              f"(+ {startup_s:.1f} s cluster start-up)")
        print(f"warm-up           {serial_warm_s:8.1f} s serial, {worker_warm_s:.1f} s the "
              f"slowest worker (imports, numba; not in the times above)")
        print(f"speed-up          {serial_s / cluster_s:8.2f} x  without start-up, "
              f"{serial_s / (cluster_s + startup_s):.2f} x with it "
              f"(ideal {min(args.workers, len(inputs))})")
        print(f"identical tables  {'yes' if serial_rows == cluster_rows else 'NO'}")
        print(f"overhead per task {trip_ms:8.1f} ms round trip of one trivial task (median of "
              f"20), {amortised_ms:.2f} ms amortised over {args.tasks} at once")
        for r in serial_rows:
            if r["status"] != "done":
                print(f"  {r['name']}: {r['status']}: {r['error']}")
    finally:
        import shutil

        shutil.rmtree(out, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
