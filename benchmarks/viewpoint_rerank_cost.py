"""Benchmark: a place query's CPU time with viewpoints re-ranking a pool against the
full screen over every pair of descriptions and against no viewpoints, in one process.

Run from the repository root::

    python benchmarks/viewpoint_rerank_cost.py [--scans N] [--sizes 2000,10000]
        [--queries Q] [--viewpoints V] [--repeat R]

The measurement of `place_query_scaling.measure` (Intel places, the default
`PlaceDatabaseConfig`, `PlaceDatabase.query` without headings, CPU ms per query) for
four configurations, R times each, interleaved in this one process so that the
machine's load falls on all of them alike: no viewpoints; V stored viewpoints per
entry and V on the query's side screened over every pair (``viewpoint_order="min"``,
``query_viewpoints``); the same viewpoints ranking only the pool of the own
descriptions' smallest distances again (``viewpoint_order="rerank"``, the pool
of 128 and of 256).  Printed per
size: the best of the R runs of each and its ratio to the one without viewpoints.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import viewpoint_query_cost  # noqa: E402

CONFIGS = {
    "none": dict(viewpoints=0),
    "both min": dict(query_viewpoints=True, viewpoint_order="min"),
    "both rerank": dict(query_viewpoints=True, viewpoint_order="rerank"),
    "both rerank 256": dict(query_viewpoints=True, viewpoint_order="rerank", viewpoint_pool=256),
}


if __name__ == "__main__":
    viewpoint_query_cost.main(CONFIGS, __doc__)
