"""Benchmark: the graph updates and final pass of recorded runs, old code against new in
one process, interleaved.

Run from the repository root (the working tree on ``PYTHONPATH``)::

    python benchmarks/back_end_ab.py FILE[,FILE2...] --baseline REV [--repeat R]

FILE is a recording of `benchmarks/back_end_replay.py` ``record``.  The baseline is the
working tree with the back-end functions this work changed taken from revision REV's
source (`SWAPPED`: the incremental smoother, the pose graph's factor builders, the final
pass's fast path), so both codes run in the same process, alternately, R times each:
the machine's load then weighs on both alike.  Prints per recording and code the
least and median CPU seconds (``time.process_time``) of the graph's updates (the
mapper's "graph update" stage), of its additions and of the final pass, the ratios of
the least (baseline / now: above 1 is faster now), and whether the estimates after
every update and the final result are the same bit for bit.
"""

from __future__ import annotations

import argparse
import importlib
import statistics
import subprocess
import sys
import types
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from back_end_replay import replay

ROOT = Path(__file__).resolve().parent.parent
#: (module, dotted attribute, module of the baseline's source, its dotted attribute):
#: the live attribute set to the baseline's for the baseline's replays.
SWAPPED = [
    ("slam.smoothers", "IncrementalSmoother", "slam.smoothers", "IncrementalSmoother"),
    ("slam.pose_graph", "PoseGraph.between_factor", "slam.pose_graph", "PoseGraph.between_factor"),
    ("slam.pose_graph", "PoseGraph._own_factor", "slam.pose_graph", "PoseGraph._own_factor"),
    ("slam.optimize", "_clean_optimum", "slam.clean_optimum", "_clean_optimum"),
]


def _source_module(name: str, rev: str) -> types.ModuleType:
    """Module `name` executed from revision `rev`'s source (a copy under another name)."""
    path = name.replace(".", "/") + ".py"
    source = subprocess.run(["git", "show", f"{rev}:{path}"], cwd=ROOT, check=True,
                            capture_output=True, text=True).stdout
    module = types.ModuleType(f"_baseline_{name.replace('.', '_')}")
    module.__file__ = str(ROOT / path)
    sys.modules[module.__name__] = module  # dataclasses look their module up
    exec(compile(source, str(ROOT / path), "exec"), module.__dict__)
    return module


def _get(obj, dotted: str) -> tuple[object, str, object]:
    """(owner, attribute name, its value as stored: a class's function unbound)."""
    *parents, last = dotted.split(".")
    for p in parents:
        obj = getattr(obj, p)
    value = obj.__dict__[last] if isinstance(obj, type) else getattr(obj, last)
    return obj, last, value


def _variants(rev: str) -> dict[str, list[tuple[object, str, object]]]:
    """Per code, the (owner, attribute, value) to set before a replay."""
    sources: dict[str, types.ModuleType] = {}
    out: dict[str, list] = {"baseline": [], "now": []}
    for module, dotted, origin, origin_dotted in SWAPPED:
        if origin not in sources:
            sources[origin] = _source_module(origin, rev)
        owner, attr, value = _get(importlib.import_module(module), dotted)
        out["now"].append((owner, attr, value))
        out["baseline"].append((owner, attr, _get(sources[origin], origin_dotted)[2]))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("files", help="comma-separated recordings")
    parser.add_argument("--baseline", required=True)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    from slam.kernel_warm_up import warm_up

    warm_up()
    variants = _variants(args.baseline)
    for path in map(Path, args.files.split(",")):
        runs: dict[str, list[dict]] = {"baseline": [], "now": []}
        for r in range(args.repeat):
            for label in ("baseline", "now") if r % 2 == 0 else ("now", "baseline"):
                for owner, attr, value in variants[label]:
                    setattr(owner, attr, value)
                runs[label].append(replay(path))
        for owner, attr, value in variants["now"]:
            setattr(owner, attr, value)
        parts = []
        for k in ("update", "add", "final"):
            old = [run[k] for run in runs["baseline"]]
            new = [run[k] for run in runs["now"]]
            parts.append(f"{k} {min(old):.2f} -> {min(new):.2f} s (x{min(old) / min(new):.2f}; "
                         f"medians {statistics.median(old):.2f} -> {statistics.median(new):.2f})")
        same = {k: len({run[k] for rs in runs.values() for run in rs}) == 1
                for k in ("updates", "final_digest")}
        print(f"{path.name}: " + "; ".join(parts)
              + f"; estimates after every update {'identical' if same['updates'] else 'DIFFER'}"
              f", final pass {'identical' if same['final_digest'] else 'DIFFERS'}; as in the "
              f"recorded run: {all(run['same_as_run'] for rs in runs.values() for run in rs)}",
              flush=True)


if __name__ == "__main__":
    main()
