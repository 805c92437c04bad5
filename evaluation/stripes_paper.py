"""The stripes paper's own figures, which the benchmark's report sets beside ours.

Paper: "Stripes-based Object Matching" (``papers/stripes-object-matching.txt``),
Section VI.B-C: Table I (retrieval counts), Table II (class accuracy) and the run times.
"""

from __future__ import annotations

#: The paper's Table I (counts at positions 1..10 over its 100 queries).
PAPER_TABLE_I: dict[str, list[int]] = {
    "SC [41]": [100, 79, 84, 71, 75, 74, 64, 67, 58, 48],
    "ID [42]": [100, 80, 77, 70, 68, 68, 64, 66, 54, 41],
    "PS [18]": [100, 81, 79, 78, 76, 71, 65, 60, 55, 53],
    "HF [43]": [100, 80, 71, 67, 64, 54, 52, 43, 49, 51],
    "Our": [100, 95, 91, 89, 86, 77, 73, 72, 66, 63],
}
#: The paper's Table II (mean accuracy [%] per class, classes in `DAILY_CLASSES` order).
PAPER_TABLE_II: dict[str, list[int]] = {
    "SC [41]": [46, 100, 79, 73, 87, 77, 51, 79, 100, 28],
    "HF [43]": [53, 82, 48, 61, 51, 43, 54, 97, 100, 30],
    "Our": [100, 78, 48, 100, 100, 96, 84, 100, 42, 64],
}
#: The paper's run times (Section VI.C, Matlab R2015a, Core i7 2.2 GHz) [s].
PAPER_SECONDS: dict[str, float] = {"stripes": 0.0375 * 3600.0, "shape-context": 1.6223 * 3600.0}
