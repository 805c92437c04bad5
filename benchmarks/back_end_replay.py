"""Benchmark: the mapper's graph updates and final pass replayed, old code against new.

Run from the repository root::

    python benchmarks/back_end_replay.py record LOG FILE [loopclosure run options ...]
    python benchmarks/back_end_replay.py compare FILE[,FILE2...] --baseline REV [--repeat R]

``record`` runs ``loopclosure run LOG`` (with the code on ``PYTHONPATH``) and writes to
FILE (pickle of plain numbers) every call the mapper made on its incremental smoother
(`slam.smoothers.IncrementalSmoother`: ``add_pose``, ``add_odometry``, ``add_loop``,
``update``), the poses and options the final pass (`slam.optimize.optimize`) was given,
and that pass's result.

``compare`` replays each recording with the code of revision REV (``git archive``) and
with the working tree, each in a fresh process, R times each, alternately: a fresh
`IncrementalSmoother` fed the same calls, then the final pass on its graph.  Per code
it prints the least CPU seconds (``time.process_time``) of the graph's additions
(``add_*``), of its updates (``update`` + ``estimate_rows``: the mapper's "graph
update" stage) and of the final pass, their ratios (baseline / now: above 1 is faster
now), and whether both codes gave the same estimate after every update and the same
final poses and rejected loops, bit for bit.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def record(log: str, path: Path, options: list[str]) -> None:
    """Run the pipeline on `log`, recording the smoother's calls and the final pass."""
    import slam.pipeline as pipeline
    import slam.smoothers as smoothers

    ops: list[tuple] = []
    final: dict = {}
    cls = smoothers.IncrementalSmoother
    add_pose, add_odometry, add_loop, update = (
        cls.add_pose, cls.add_odometry, cls.add_loop, cls.update)

    def rec_pose(self, key, guess):
        ops.append(("p", int(key), np.array(guess, dtype=float)))
        return add_pose(self, key, guess)

    def rec_odometry(self, i, j, z, info):
        ops.append(("o", int(i), int(j), np.array(z, dtype=float), np.array(info, dtype=float)))
        return add_odometry(self, i, j, z, info)

    def rec_loop(self, i, j, z, info):
        ops.append(("l", int(i), int(j), np.array(z, dtype=float), np.array(info, dtype=float)))
        return add_loop(self, i, j, z, info)

    def rec_update(self):
        ops.append(("u",))
        return update(self)

    cls.add_pose, cls.add_odometry, cls.add_loop, cls.update = (
        rec_pose, rec_odometry, rec_loop, rec_update)
    optimize = pipeline.optimize

    def rec_optimize(graph, **kwargs):
        final["initial"] = {int(k): np.array(v, dtype=float) for k, v in kwargs["initial"].items()}
        final["kwargs"] = {k: v for k, v in kwargs.items() if k != "initial"}
        result = optimize(graph, **kwargs)
        final["poses"] = {int(k): np.array(v) for k, v in result.poses.items()}
        final["outliers"] = sorted(int(k) for k in result.loop_outliers)
        return result

    pipeline.optimize = rec_optimize
    sys.argv = ["loopclosure", "run", log, *options]
    from slam.cli.main import main as cli

    cli()
    path.write_bytes(pickle.dumps({"ops": ops, "final": final}))


def replay(path: Path) -> dict:
    """CPU seconds of one replay of a recording with the code on ``PYTHONPATH``, and
    digests of its estimates and final result."""
    from slam.optimize import optimize
    from slam.smoothers import IncrementalSmoother

    data = pickle.loads(path.read_bytes())
    smoother = IncrementalSmoother()
    add = upd = 0.0
    digest = hashlib.sha256()
    for op in data["ops"]:
        start = time.process_time()
        if op[0] == "u":
            smoother.update()
            keys, poses = smoother.estimate_rows()
            upd += time.process_time() - start
            digest.update(np.ascontiguousarray(keys).tobytes())
            digest.update(np.ascontiguousarray(poses).tobytes())
            continue
        if op[0] == "p":
            smoother.add_pose(op[1], op[2])
        elif op[0] == "o":
            smoother.add_odometry(*op[1:])
        else:
            smoother.add_loop(*op[1:])
        add += time.process_time() - start
    final = data["final"]
    start = time.process_time()
    result = optimize(smoother.graph, initial=final["initial"], **final["kwargs"])
    fin = time.process_time() - start
    poses = np.array([result.poses[k] for k in sorted(result.poses)])
    recorded = np.array([final["poses"][k] for k in sorted(final["poses"])])
    same_as_run = (np.array_equal(poses, recorded)
                   and sorted(result.loop_outliers) == final["outliers"])
    return {"add": add, "update": upd, "final": fin, "updates": digest.hexdigest(),
            "final_digest": hashlib.sha256(poses.tobytes()).hexdigest()
            + str(sorted(result.loop_outliers)), "same_as_run": same_as_run}


def _child(code: Path, path: Path) -> dict:
    out = subprocess.run(
        [sys.executable, str(Path(__file__).resolve()), "child", str(path)],
        env={"PYTHONPATH": str(code), "PATH": "/usr/bin:/bin"}, cwd=code, check=True,
        capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def compare(paths: list[Path], baseline: str, repeat: int) -> None:
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from run_speed import checkout

    with tempfile.TemporaryDirectory() as tmp:
        codes = [("baseline", checkout(baseline, Path(tmp) / "baseline")), ("now", ROOT)]
        for path in paths:
            runs: dict[str, list[dict]] = {"baseline": [], "now": []}
            for r in range(repeat):
                for label, code in codes if r % 2 == 0 else codes[::-1]:
                    runs[label].append(_child(code, path))
            best = {label: {k: min(run[k] for run in rs) for k in ("add", "update", "final")}
                    for label, rs in runs.items()}
            same = {k: len({run[k] for rs in runs.values() for run in rs}) == 1
                    for k in ("updates", "final_digest")}
            print(f"{path.name}: " + "; ".join(
                f"{k} {best['baseline'][k]:.2f} -> {best['now'][k]:.2f} s "
                f"(x{best['baseline'][k] / max(best['now'][k], 1e-9):.2f})"
                for k in ("add", "update", "final"))
                + f"; estimates after every update {'identical' if same['updates'] else 'DIFFER'}"
                f", final pass {'identical' if same['final_digest'] else 'DIFFERS'}; "
                f"as in the recorded run: "
                f"{all(run['same_as_run'] for rs in runs.values() for run in rs)}",
                flush=True)


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "record":
        if len(sys.argv) < 4:
            sys.exit(__doc__)
        record(sys.argv[2], Path(sys.argv[3]), sys.argv[4:])
        return
    if len(sys.argv) > 1 and sys.argv[1] == "child":
        from slam.kernel_warm_up import warm_up

        warm_up()
        print(json.dumps(replay(Path(sys.argv[2]))))
        return
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("command", choices=["compare"])
    parser.add_argument("files", help="comma-separated recordings")
    parser.add_argument("--baseline", required=True)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    compare([Path(p) for p in args.files.split(",")], args.baseline, args.repeat)


if __name__ == "__main__":
    main()
