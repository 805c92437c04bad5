"""Query by query, how two passes of `scan_origins_bench.py --npz` differ.

Run from the repository root::

    python benchmarks/scan_passes_diff.py A.npz B.npz

Prints the queries whose correct detection A has and B lacks (lost), the reverse
(gained), B's incorrect accepted detections that A lacks, each with its match, fused
score and the fit's distance from the reference [m, deg].
"""

from __future__ import annotations

import argparse

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("a")
    ap.add_argument("b")
    args = ap.parse_args()
    a, b = np.load(args.a), np.load(args.b)
    assert np.array_equal(a["keys"], b["keys"]), "the passes ran different queries"

    def show(label, sel, src):
        idx = np.flatnonzero(sel)
        print(f"{label}: {len(idx)}")
        err = src["error"] if "error" in src else np.full((len(src["keys"]), 2), np.nan)
        for i in idx:
            print(f"  {int(src['keys'][i])} -> {int(src['match'][i])} score "
                  f"{float(src['score'][i]):.3f} off {err[i][0]:.3f} m {err[i][1]:.2f} deg")

    same = a["match"] == b["match"]
    show("lost (A correct, B not the same correct)", a["correct"] & ~(b["correct"] & same), a)
    show("gained (B correct, A not the same correct)", b["correct"] & ~(a["correct"] & same), b)
    show("B incorrect accepted, not in A", b["accepted"] & ~b["correct"]
         & ~(a["accepted"] & same), b)


if __name__ == "__main__":
    main()
