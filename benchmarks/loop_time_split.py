"""Benchmark: where a whole run's loop detection spends its CPU time, stage by stage.

Run from the repository root (the code on ``PYTHONPATH`` is measured)::

    python benchmarks/loop_time_split.py LOG [loopclosure run options ...]

e.g. ``python benchmarks/loop_time_split.py ../shared/data/carmen/intel.clf.bz2
--out /tmp/split --no-map --set front_end_worker=false``.  Runs ``loopclosure run``
in this process with a CPU timer (``time.process_time``: the process's user +
system seconds, so a loaded machine inflates it far less than wall time) around
each stage of loop detection, and prints per stage its total CPU seconds and its
calls: the keyframes' place descriptions (``describe_keyframe``, of which FLIRT's
``flirt_describe``), the place database's queries (``query_places``, of which
FLIRT's RANSAC ``flirt_distances``), the checks from a prior (``check_prior``: the
pose gate's candidates and the appearance candidates inside it) and without one
(``check_global``, of which the correlative search ``match_prior_free`` and its
lattices ``pf_two_level``, and ``nearer_place``), the multi-start ICP of the
checks (``register_multi``, which the front end's recovery search calls too), the
overlap screen, and the submaps' registration targets (``target``); besides loop
detection, the front end, keyframe selection, the submaps' points, the graph's
updates and the final pass, and within the place database its describe (the pair
histogram, the polar grid, the virtual scans, the wide view) and its query parts
(the screen, the grid similarity, ``query_stored``).  Stages nest:
a stage's time includes the stages it calls.  Run it with the old and the new code
at the same time to compare stages; `benchmarks/run_speed.py` compares whole runs.
"""

from __future__ import annotations

import functools
import importlib
import sys
import time
from collections import defaultdict

TOTAL: defaultdict[str, float] = defaultdict(float)
CALLS: defaultdict[str, int] = defaultdict(int)

#: (module, class or None, function, label) of the timed stages.
STAGES = [
    ("loopclosure.keyframe_store", "KeyframeStore", "describe_keyframe", "describe_keyframe"),
    ("loopclosure.keyframe_store", "KeyframeStore", "query_places", "query_places"),
    ("loopclosure.candidate_checks", "CandidateChecks", "_check_prior", "check_prior"),
    ("loopclosure.candidate_checks", "CandidateChecks", "_check_global", "check_global"),
    ("loopclosure.candidate_checks", "CandidateChecks", "_nearer_place", "nearer_place"),
    ("loopclosure.keyframe_store", "KeyframeStore", "_target", "target"),
    ("loopclosure.loop_detector", "LoopClosureDetector", "detect", "detect"),
    ("loopclosure.matchers.flirt", "FlirtMatcher", "describe", "flirt_describe"),
    ("loopclosure.matchers.flirt", "FlirtMatcher", "distances", "flirt_distances"),
    ("loopclosure.fast_icp", None, "overlap_screen", "overlap_screen"),
    ("slam.pipeline", "Mapper", "_add_keyframe", "add_keyframe (all of it)"),
    ("slam.pipeline", "Mapper", "_update", "graph update"),
    ("slam.pipeline", "Mapper", "finish", "finish (final pass)"),
    ("slam.submap_cache", "SubmapCache", "local_points", "submap points"),
    ("slam.odometry.icp2d", "Icp2dOdometry", "process", "front end"),
    ("slam.keyframes", "KeyframeSelector", "push", "keyframe selection"),
    ("loopclosure.keyframe_store", "KeyframeStore", "_describe_wide", "describe wide view"),
    ("loopclosure.place_database", "PlaceDatabase", "describe", "database describe"),
    ("loopclosure.place_database", "PlaceDatabase", "_grid", "polar grid"),
    ("loopclosure.place_database", "PlaceDatabase", "_grid_similarity", "grid similarity"),
    ("loopclosure.place_database", "PlaceDatabase", "_screen", "screen"),
    ("loopclosure.place_database", "PlaceDatabase", "query_stored", "query_stored"),
    ("loopclosure.matchers.pair_histogram", "PairHistogramMatcher", "describe", "pairs_describe"),
]
#: Functions imported by name into another module: (module, name, its origin, label).
IMPORTED = [
    ("loopclosure.geometric_check", "register_multi", "loopclosure.multi_start",
     "register_multi"),
    ("loopclosure.geometric_check", "match_prior_free", "loopclosure.prior_free",
     "match_prior_free"),
    ("loopclosure.prior_free", "_two_level", "loopclosure.prior_free", "pf_two_level"),
    ("loopclosure.keyframe_store", "virtual_scan", "loopclosure.virtual_scan", "virtual_scan"),
]


def timed(function, label: str):
    """`function` with its CPU seconds and calls added to `label`'s totals."""
    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        start = time.process_time()
        try:
            return function(*args, **kwargs)
        finally:
            TOTAL[label] += time.process_time() - start
            CALLS[label] += 1
    return wrapper


def install() -> None:
    """Wrap every stage (`STAGES`, `IMPORTED`) with its timer."""
    for module, owner, name, label in STAGES:
        mod = importlib.import_module(module)
        where = getattr(mod, owner) if owner else mod
        if not hasattr(where, name):  # a stage the code no longer has
            print(f"not timed (no {module}.{owner or ''}.{name})", file=sys.stderr)
            continue
        setattr(where, name, timed(getattr(where, name), label))
    for module, name, origin, label in IMPORTED:
        wrapped = timed(getattr(importlib.import_module(origin), name), label)
        setattr(importlib.import_module(module), name, wrapped)
        setattr(importlib.import_module(origin), name, wrapped)


def main() -> None:
    if len(sys.argv) < 2 or sys.argv[1] in ("-h", "--help"):
        sys.exit(__doc__)
    install()
    sys.argv = ["loopclosure", "run", *sys.argv[1:]]
    from slam.cli.main import main as cli

    start = time.process_time()
    try:
        cli()
    finally:
        print(f"whole run: {time.process_time() - start:.2f} s CPU", file=sys.stderr)
        for label in sorted(TOTAL, key=lambda k: -TOTAL[k]):
            print(f"{label:26s} {TOTAL[label]:8.2f} s  {CALLS[label]:7d} calls", file=sys.stderr)


if __name__ == "__main__":
    main()
