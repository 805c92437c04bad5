"""Benchmark: stages sped up without changing a bit of their output, old code against
new, in one process.

Run from the repository root (the working tree's code on ``PYTHONPATH``)::

    python benchmarks/exact_stage_speed.py --baseline REV [--data DIR]
        [--log carmen/intel.clf.bz2] [--graph g2o/input_INTEL_g2o.g2o] [--repeat R]

Revision REV's versions of the files concerned (``git show``) are loaded beside the
working tree's, on the working tree's other modules, and both run the same work on
real data, R alternate passes each (CPU seconds, ``time.process_time``, best pass):

* ``scan points``: the ``icp2d`` front end's `Icp2dOdometry.scan_points` of every
  scan of the log;
* ``submap points``: `Mapper._local_points` of every keyframe's submap (keyframes
  ``k - 10 .. k + 10``), the keyframes every 6th scan of the log at its odometry
  poses (about the default pipeline's keyframe rate on Intel);
* ``factor graphs``: `PoseGraph.factor_graph` built three times on a fresh graph of
  the g2o file (the final pass builds the whole graph about that often), Gaussian
  and with the Cauchy kernel;
* ``loops.csv``: `write_loops_csv` of 3,000 candidates.

Per stage it prints the best CPU milliseconds of either code, their ratio (baseline /
now: above 1 is faster now) and whether the outputs are bit-identical (the points'
bytes; the graphs' errors at the initial values, factor by factor; the files' bytes).
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

ROOT = Path(__file__).resolve().parents[1]
FILES = {"icp2d": "slam/odometry/icp2d.py", "pipeline": "slam/pipeline.py",
         "pose_graph": "slam/pose_graph.py", "outputs": "slam/outputs.py"}


def load_revision(rev: str, path: str, folder: Path):
    """Revision `rev`'s file `path` as a module of its own (``<stem>_baseline``)."""
    text = subprocess.run(["git", "show", f"{rev}:{path}"], cwd=ROOT, check=True,
                          capture_output=True, text=True).stdout
    name = Path(path).stem + "_baseline"
    file = folder / f"{name}.py"
    file.write_text(text)
    spec = importlib.util.spec_from_file_location(name, file)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def best_of(repeat: int, work: dict[str, Callable[[], object]]) -> dict[str, float]:
    """Best CPU seconds of each of `work`'s calls over `repeat` alternate passes."""
    best = dict.fromkeys(work, np.inf)
    for r in range(repeat):
        for label in (list(work) if r % 2 == 0 else list(work)[::-1]):
            t0 = time.process_time()
            work[label]()
            best[label] = min(best[label], time.process_time() - t0)
    return best


def same_arrays(a: list, b: list) -> bool:
    return len(a) == len(b) and all(x.shape == y.shape and x.tobytes() == y.tobytes()
                                    for x, y in zip(a, b, strict=True))


def scan_points(old, scans, repeat):
    from slam.odometry.icp2d import Icp2dOdometry

    new_odo, old_odo = Icp2dOdometry(), old.Icp2dOdometry()
    same = same_arrays([old_odo.scan_points(s) for s in scans],
                       [new_odo.scan_points(s) for s in scans])
    best = best_of(repeat, {"baseline": lambda: [old_odo.scan_points(s) for s in scans],
                            "now": lambda: [new_odo.scan_points(s) for s in scans]})
    return best, same


def submap_points(old, scans, repeat):
    from slam.keyframes import Keyframe
    from slam.pipeline import Mapper

    mapper = Mapper()
    for n, scan in enumerate(s for s in scans[::6] if s.odom is not None):
        mapper.keyframes.keyframes.append(Keyframe(
            n, scan.stamp, scan.index, np.asarray(scan.odom, float), scan, scan.points()))
    count = len(mapper.keyframes.keyframes)
    calls = [(k, max(0, k - 10), min(count - 1, k + 10)) for k in range(count)]

    def run(local_points):
        return [local_points(mapper, *c) for c in calls]

    same = same_arrays(run(old.Mapper._local_points), run(Mapper._local_points))
    best = best_of(repeat, {"baseline": lambda: run(old.Mapper._local_points),
                            "now": lambda: run(Mapper._local_points)})
    return best, same


def factor_graphs(old, data, repeat):
    from slam.pose_graph import PoseGraph, RobustKernel

    kernels = (RobustKernel("none"), RobustKernel("cauchy"))

    def build(cls):
        graph = cls.from_g2o(data)
        return [graph.factor_graph(k)[0] for k in kernels for _ in range(3)]

    values = PoseGraph.from_g2o(data).gtsam_values()

    def errors(graphs):
        return [np.array([g.at(i).error(values) for i in range(g.size())]) for g in graphs]

    same = same_arrays(errors(build(old.PoseGraph)), errors(build(PoseGraph)))
    best = best_of(repeat, {"baseline": lambda: build(old.PoseGraph),
                            "now": lambda: build(PoseGraph)})
    return best, same


def loops_csv(old, folder, repeat):
    from slam.outputs import LoopRecord, write_loops_csv

    rng = np.random.default_rng(0)
    records = [LoopRecord(int(a), int(a) + 50, float(a), float(a) + 9.5, "place",
                          bool(a % 3), "ok" if a % 3 else "rejected", float(rng.random()),
                          int(a % 7), float(rng.random()), float(rng.random()),
                          relative=rng.normal(size=3), prior=bool(a % 2))
               for a in range(3000)]
    old_path, new_path = folder / "old.csv", folder / "new.csv"
    best = best_of(repeat, {"baseline": lambda: old.write_loops_csv(old_path, records),
                            "now": lambda: write_loops_csv(new_path, records)})
    return best, old_path.read_bytes() == new_path.read_bytes()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--baseline", required=True, help="a revision")
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--log", default="carmen/intel.clf.bz2", help="under --data")
    parser.add_argument("--graph", default="g2o/input_INTEL_g2o.g2o", help="under --data")
    parser.add_argument("--repeat", type=int, default=3, help="timed passes per code")
    args = parser.parse_args()
    from data.g2o import read_g2o
    from data.sources import open_source

    scans = list(open_source(args.data / args.log))
    data = read_g2o(args.data / args.graph)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        old = {key: load_revision(args.baseline, path, folder) for key, path in FILES.items()}
        stages = {
            "scan points": lambda: scan_points(old["icp2d"], scans, args.repeat),
            "submap points": lambda: submap_points(old["pipeline"], scans, args.repeat),
            "factor graphs": lambda: factor_graphs(old["pose_graph"], data, args.repeat),
            "loops.csv": lambda: loops_csv(old["outputs"], folder, args.repeat),
        }
        print(f"{'stage':<15} {'old ms':>9} {'new ms':>9} {'ratio':>6}  output")
        for name, stage in stages.items():
            best, same = stage()
            old_s, new_s = best["baseline"], best["now"]
            print(f"{name:<15} {1e3 * old_s:9.1f} {1e3 * new_s:9.1f} {old_s / new_s:6.2f}  "
                  f"{'identical' if same else 'DIFFER'}", flush=True)


if __name__ == "__main__":
    main()
