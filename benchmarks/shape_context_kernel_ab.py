"""Benchmark: the compiled shape-context distances, a revision's kernel module against the
working tree's, in one process, on MPEG-7 silhouettes.

Run from the repository root (the working tree's code on ``PYTHONPATH``)::

    python benchmarks/shape_context_kernel_ab.py --baseline REV --data DIR [--shapes N]
        [--repeat R]

Revision REV's `loopclosure/matchers/shape_context_kernel.py` (``git show``) is loaded
under another module name from a temporary folder; both sides compute
`shape_context_kernel.all_pairs` of the first `--shapes` silhouettes of
``DIR/mpeg7-subset`` (described by `ShapeContextMatcher` with ``kernel="numba"``) and
`distances` of each of them against all.  The script prints whether the matrices are
equal to the bit, and the best-of-R CPU seconds (``time.process_time``) of either side,
run alternately, with their ratio (baseline / now: above 1 is faster now).
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from data.mpeg7 import load_silhouettes
from loopclosure.matchers import shape_context_kernel
from loopclosure.matchers.shape_context import ShapeContextMatcher
from loopclosure.polygon import Polygon

ROOT = Path(__file__).resolve().parents[1]
PATH = "loopclosure/matchers/shape_context_kernel.py"


def load_revision(rev: str, folder: Path, path: str = PATH):  # type: ignore[no-untyped-def]
    """Revision `rev`'s module at `path` (one that imports no module of the project),
    imported under a name of its own from `folder`."""
    text = subprocess.run(["git", "show", f"{rev}:{path}"], cwd=ROOT, check=True,
                          capture_output=True, text=True).stdout
    name = f"{Path(path).stem}_" + "".join(c if c.isalnum() else "_" for c in rev)
    file = folder / f"{name}.py"
    file.write_text(text)
    spec = importlib.util.spec_from_file_location(name, file)
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules[name] = module
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def run(module, counts, table, n_dummy, cost):  # type: ignore[no-untyped-def]
    """`all_pairs` and every row by `distances` through `module`."""
    pairs = module.all_pairs(counts, table, n_dummy, cost)
    rows = np.stack([module.distances(counts[i], counts, table, n_dummy, cost)
                     for i in range(len(counts))])
    return pairs, rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--baseline", required=True)
    parser.add_argument("--data", default="../shared/data")
    parser.add_argument("--shapes", type=int, default=40)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    shapes = load_silhouettes(Path(args.data) / "mpeg7-subset")[: args.shapes]
    matcher = ShapeContextMatcher(kernel="numba")
    counts = matcher.stack([matcher.describe(Polygon(s.contour)) for s in shapes]).counts
    table = shape_context_kernel.harmonic_table(matcher.config.n_points - 1)
    n_dummy = round(matcher.config.dummy_fraction * matcher.config.n_points)
    cost = float(matcher.config.dummy_cost)
    with tempfile.TemporaryDirectory() as folder:
        old = load_revision(args.baseline, Path(folder))
        sides = {"baseline": old, "now": shape_context_kernel}
        outputs = {name: run(m, counts, table, n_dummy, cost) for name, m in sides.items()}
        best = {name: np.inf for name in sides}
        for _ in range(args.repeat):
            for name, module in sides.items():
                start = time.process_time()
                run(module, counts, table, n_dummy, cost)
                best[name] = min(best[name], time.process_time() - start)
    same = all(np.array_equal(a, b) for a, b in zip(outputs["baseline"], outputs["now"],
                                                    strict=True))
    print(f"{len(shapes)} shapes: all_pairs and distances {'identical' if same else 'DIFFER'}; "
          f"CPU best of {args.repeat}: {best['baseline']:.3f} s ({args.baseline}) -> "
          f"{best['now']:.3f} s (now), ratio {best['baseline'] / best['now']:.3f}")


if __name__ == "__main__":
    main()
