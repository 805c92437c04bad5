"""Benchmark: the machine code of the compiled ICP's top kernels, a revision's against
the working tree's, in one process.

Run from the repository root (the working tree's code on ``PYTHONPATH``), with an
empty numba cache so that both sides are compiled here::

    NUMBA_CACHE_DIR=$(mktemp -d) python benchmarks/kernel_code_compare.py --baseline REV

Revision REV's compiled ICP is loaded as `benchmarks.register_speed` loads it (its
modules of ``CHAIN``), both sides make the warm-up's calls on the synthetic room
(`loopclosure.warm_up.room_scan`), and for `_register_kernel`, `_screen_kernel` and
`_bound_kernel` the script prints the instruction counts of either, the calls among
them, and whether the instructions are the same once symbol names (which carry the
module's name), local labels and the names of pickled constants (an exception's
arguments with its source location, named by their hash) are renamed.  Equal code
runs at equal speed: a reorganisation of the modules that leaves the code equal
costs nothing, whatever a timing on a loaded machine says.
"""

from __future__ import annotations

import argparse
import difflib
import re
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.register_speed import load_chain

KERNELS = {"_register_kernel": "loopclosure.icp_kernel",
           "_screen_kernel": "loopclosure.grid_overlap",
           "_bound_kernel": "loopclosure.grid_overlap"}


def exercise(module) -> None:
    """The warm-up's calls of the compiled ICP through `module` (a `fast_icp`)."""
    from loopclosure.registration import RegistrationTarget
    from loopclosure.warm_up import room_scan

    points = [room_scan(-1.0, -0.5).points(), room_scan(-0.8, -0.4).points()]
    grid = module.GridTarget(module.voxel_downsample_fast(points[0], 0.05))
    module.register_fast(points[1], grid, (0.2, 0.1, 0.0))
    check = RegistrationTarget(points[0], normals=module.estimate_normals_fast)
    grid = module.GridTarget.from_target(check, module.TARGET_GRID_CELL)
    guesses = np.array([[0.2, 0.1, 0.0], [-0.3, 0.0, 0.2]])
    module.overlap_screen(points[1], grid, guesses, 1.0, 0.55)
    module.overlap_bound(points[1], grid, guesses, 0.55)


def instructions(asm: str) -> list[str]:
    """The instructions of an assembly listing, symbols (``_ZN...``), local labels
    (``.L...``) and pickled constants (``.const.picklebuf.<hash>``) renamed,
    directives, labels and comments dropped."""
    out = []
    for line in asm.splitlines():
        line = line.split("#")[0].strip()
        if not line or line.startswith(".") or line.endswith(":"):
            continue
        line = re.sub(r"\.const\.picklebuf\.[0-9a-f]+", "PICKLED", line)
        out.append(re.sub(r"\.L\w+", "LABEL", re.sub(r"_ZN\w+", "SYMBOL", line)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--baseline", required=True, help="a revision")
    args = parser.parse_args()
    import importlib

    import loopclosure.fast_icp as now

    with tempfile.TemporaryDirectory() as tmp:
        old = load_chain(args.baseline, Path(tmp))
        exercise(old)
        exercise(now)
        for name, home in KERNELS.items():
            # the revision's kernel: in its fast_icp.py, or in its module of the chain
            a = getattr(old, name, None) or getattr(sys.modules[home.split(".")[-1]
                                                                + "_baseline"], name)
            b = getattr(importlib.import_module(home), name)
            ia = instructions(a.inspect_asm(a.signatures[0]))
            ib = instructions(b.inspect_asm(b.signatures[0]))
            differ = [line for line in difflib.unified_diff(ia, ib, lineterm="", n=0)
                      if line[:1] in "+-" and line[:3] not in ("+++", "---")]
            calls = [sum(x.startswith("call") for x in i) for i in (ia, ib)]
            print(f"{name}: {len(ia)} -> {len(ib)} instructions, calls {calls[0]} -> "
                  f"{calls[1]}; {len(differ) // 2} differ after renaming"
                  + "".join(f"\n    {line}" for line in differ[:6]))


if __name__ == "__main__":
    main()
