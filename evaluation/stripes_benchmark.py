"""The stripes paper's object-retrieval benchmark: Table I, Table II, Bull's eye, timing.

Paper: "Stripes-based Object Matching" (``papers/stripes-object-matching.txt``),
Section VI.B-C.  `run_stripes_benchmark` scans an object set
(`evaluation.stripes_objects`), ranks every scan against all of them with each
method, and scores every distance matrix with the paper's retrieval figures
(`evaluation.stripes_retrieval`: Table I counts, Table II class accuracy, Bull's
eye, nearest-neighbour precision, each also without the query's sibling scans, the
"other objects" figures).  The YCB target (nearest-neighbour precision >= 0.9) is
reported both ways and the report (`evaluation.stripes_report`) says which is which.

Methods on the same scans:

- ``stripes``: `loopclosure.stripes` descriptors ``[l, d, o]`` (Eq. 1-3) and the
  vectorised `StripeDatabase` (Eq. 4-6, lambda = 0.6, 0.3, 0.1).
- Baselines on the object's silhouette (`evaluation.stripes_objects.silhouette_polygon`:
  the scanned footprint, `StripeScan.silhouette()`, made isotropic in millimetres,
  closed by one pixel, outer contour smoothed as the MPEG-7 rule of
  `data.mpeg7.contour_from_image`), compared by the place-recognition matchers of
  `loopclosure.matchers` with scale invariance switched on where the matcher has it
  (customary for object shapes).  The baseline list is a parameter; a registered
  matcher whose module is not importable yet is skipped with one warning.
- ``profile``: the same stripes as `loopclosure.stripes.StripeProfile`s (``[l, d, e]``
  resampled to 32 positions along the sweep, scale-free, order kept; see
  `loopclosure.stripes.profile`) and `ProfileDatabase`: the stripe matcher for object
  classes whose members differ in size.
- ``surface``: the same stripes' heights as 3D surface points in metres and
  `loopclosure.stripes.SurfaceDatabase`: the joint histogram of the distances
  (scale-free) and elevations of pairs of surface points, Eq. 1-2 over the whole
  object instead of within one stripe.
- ``canonical``: the same stripes' heights cut into virtual stripes along the
  footprint's long axis (`loopclosure.stripes.CanonicalDatabase`): a profile free of
  the scan direction and of the object's yaw.
- ``fused-stripes``: profile, relief, surface context and canonical profile combined
  by `loopclosure.stripes.fuse` (each method's distances locally scaled,
  ``D(q, j) / sqrt(s(q) s(j))`` with ``s`` the distance to the 5th nearest other
  object, `StripesBenchmarkConfig.scaling`; their geometric mean with equal weights,
  `StripesBenchmarkConfig.mean`): the matcher that reads nothing but the stripes.
- ``fused``: the default matcher (`loopclosure.stripes.FusedObjectDatabase`): profile,
  relief, surface context and the silhouette verifiers (default
  ``shape-context-50``), same rule; its time is the parts' times plus the fusion.
- ``fused-sc``: the same rule with shape context as the one verifier (the profile's
  distance and shape context's, each divided by its per-query median, equal
  weights); by default the ``shape-context-50`` preset of
  `loopclosure.stripes.fusion.VERIFIER_PRESETS` (50 boundary points, the compiled
  kernel, each unordered pair solved once).  The profile reads the object along the
  sweep (where along its length it is tall, round or flat) and is blind to the
  footprint's outline once resampled (a long box and a can are one profile); shape
  context reads the outline and is blind to height: the two miss different objects,
  so their sum verifies each other.  FFT and ring projection are global summaries of
  the outline and repeat much of what the profile's ``l`` already says.  Its time is
  the profile's plus shape context's (all pairs: quadratic in the set, shape
  context's point matching dominates).
- ``relief``: the same stripes' rows as heights above the table
  (`data.stripe_scanner.StripeScan.height_map`, the scanner's calibration) and
  `loopclosure.stripes.ReliefDatabase`: the mean depth below the object's top, in
  units of its size, in rings about the footprint's centre (yaw and scale free).
- ``fused-relief``: the ``fused-sc`` rule with the relief as a third part (profile,
  relief and shape context, each divided by its per-query median, equal weights).
  The relief says what the other two cannot: how deep the surface falls below the
  top (flat box tops against studded bricks, lids, domes and hollows); its time is
  the three parts' times.

With two or more scans per object every method also gets the different-pose figures
(`evaluation.stripes_retrieval.cross_pose`): first scans as queries against a
database of second scans, each scan from its own random pose.

Timing (`seconds`): representation + matching of the whole set (descriptors of every
object and the full distance matrix), wall clock in this process, against the paper's
0.0375 h (Matlab, stripes) and 1.6223 h (shape context).  Scanning is the simulator's
cost and is reported apart (`scan_seconds`).

Unit of work: one matcher's distance matrix on the scanned set
(`evaluation.stripes_tasks`: here, or on a cluster's workers).

This module is the benchmark's front door and its runner (`run_stripes_benchmark`,
which reads as the list of its steps); each step is a module of its own, whose public
names it re-exports:

* `evaluation.stripes_config`: `StripesBenchmarkConfig`, `DEFAULT_BASELINES`.
* `evaluation.stripes_methods`: every method's distance matrix (`stripes_distances`,
  `profile_distances`, `relief_distances`, `surface_distances`,
  `canonical_distances`, `baseline_matcher`, `baseline_distances`).
* `evaluation.stripes_tasks`: `StripesSource`, `MatcherTask`, `MatcherRows`,
  `matcher_task`.
* `evaluation.stripes_ranking`: the retrieval figures of the stripes, profile and fused
  rows.
* `evaluation.stripes_result`: `StripesBenchmarkResult` and its JSON.
* `evaluation.stripes_paper`: the paper's figures (`PAPER_TABLE_I`, `PAPER_TABLE_II`,
  `PAPER_SECONDS`).
"""

from __future__ import annotations

import uuid
from dataclasses import asdict

from data.errors import UserError
from evaluation.stripes_config import DEFAULT_BASELINES, StripesBenchmarkConfig
from evaluation.stripes_methods import (
    Array,
    Progress,
    _available_baselines,
    baseline_distances,
    baseline_matcher,
    canonical_distances,
    profile_distances,
    relief_distances,
    stripes_distances,
    surface_distances,
)
from evaluation.stripes_objects import ObjectSet, scan_objects
from evaluation.stripes_paper import PAPER_SECONDS, PAPER_TABLE_I, PAPER_TABLE_II
from evaluation.stripes_ranking import _fused, _rank_with_profile, _rank_with_stripes
from evaluation.stripes_result import StripesBenchmarkResult
from evaluation.stripes_retrieval import evaluate
from evaluation.stripes_tasks import (
    _SCANNED,
    _SILHOUETTES,
    MatcherRows,
    MatcherTask,
    StripesSource,
    _scan_key,
    matcher_task,
)

__all__ = [
    "DEFAULT_BASELINES",
    "PAPER_SECONDS",
    "PAPER_TABLE_I",
    "PAPER_TABLE_II",
    "Array",
    "MatcherRows",
    "MatcherTask",
    "Progress",
    "StripesBenchmarkConfig",
    "StripesBenchmarkResult",
    "StripesSource",
    "baseline_distances",
    "baseline_matcher",
    "canonical_distances",
    "matcher_task",
    "profile_distances",
    "relief_distances",
    "run_stripes_benchmark",
    "stripes_distances",
    "surface_distances",
]


def run_stripes_benchmark(
    objects: ObjectSet,
    config: StripesBenchmarkConfig | None = None,
    progress: Progress | None = None,
    *,
    source: StripesSource | None = None,
    cluster: str | None = None,
) -> StripesBenchmarkResult:
    """Scan `objects`, rank them with stripes and with every available baseline.

    One `MatcherTask` per matcher, here in order or, with `cluster` (an
    `evaluation.cluster` address), on Dask, the workers rebuilding the objects from
    `source` (the source `objects` came from: required).

    Raises:
        UserError: bad parameters, unknown baseline name, nothing scanned, a matcher's
            task that failed.
    """
    from evaluation.cluster import map_tasks

    cfg = config or StripesBenchmarkConfig()
    if cfg.k < 2:
        raise UserError(f"k must be at least 2, got {cfg.k}")
    if cluster is not None and source is None:
        raise UserError("a cluster run needs the objects as a StripesSource, not meshes in "
                        "memory")
    available, skipped = _available_baselines(cfg.baselines)
    scanned = scan_objects(objects, cfg.scanner, cfg.seed, cfg.scans_per_object, progress)
    verifiers = list(dict.fromkeys(n for n in (*cfg.fused, *cfg.fused_sc, *cfg.fused_relief)
                                   if n not in available))
    for name in verifiers:
        baseline_matcher(name)  # unknown verifier names fail before any silhouette work
    key: StripesSource | str = source if source is not None else f"memory-{uuid.uuid4().hex}"
    tasks = [MatcherTask(key, cfg, m)
             for m in ("stripes", "profile", "relief", "surface", "canonical", *available,
                       *verifiers)]
    _SCANNED[_scan_key(key, cfg)] = (scanned, progress)
    try:
        rows = {}
        for o in map_tasks(matcher_task, tasks, cluster=cluster, retries=0,
                           description="bench stripes", progress=cluster is not None):
            rows[o.item.method] = o.result(f"bench stripes, {o.item.method}")
    finally:
        _SCANNED.pop(_scan_key(key, cfg), None)
        _SILHOUETTES.pop(_scan_key(key, cfg), None)
    stripes = _rank_with_stripes(scanned, cfg, rows.pop("stripes"))
    profile = _rank_with_profile(scanned, cfg, rows.pop("profile"))
    relief_rows = rows.pop("relief")
    relief = evaluate("relief", relief_rows.distances, scanned.labels, scanned.objects,
                      relief_rows.seconds, cfg.k, asdict(cfg.relief))
    surface_rows = rows.pop("surface")
    surface = evaluate("surface", surface_rows.distances, scanned.labels, scanned.objects,
                       surface_rows.seconds, cfg.k, asdict(cfg.surface))
    canonical_rows = rows.pop("canonical")
    canonical = evaluate("canonical", canonical_rows.distances, scanned.labels,
                         scanned.objects, canonical_rows.seconds, cfg.k, asdict(cfg.canonical))
    ranked = {n: evaluate(n, r.distances, scanned.labels, scanned.objects, r.seconds, cfg.k,
                          r.options) for n, r in rows.items()}
    silhouette_seconds = next((r.silhouette_seconds for r in rows.values()), 0.0)
    three = [profile, relief, surface]
    fused_stripes = _fused(scanned, [*three, canonical], ranked, cfg, (), "fused-stripes",
                           cfg.scaling, cfg.mean)
    fused = (_fused(scanned, three, ranked, cfg, cfg.fused, "fused", cfg.scaling, cfg.mean)
             if cfg.fused else None)
    fused_sc = (_fused(scanned, [profile], ranked, cfg, cfg.fused_sc, "fused-sc")
                if cfg.fused_sc else None)
    fused_relief = (_fused(scanned, [profile, relief], ranked, cfg, cfg.fused_relief,
                           "fused-relief") if cfg.fused_relief else None)
    baselines = {n: r for n, r in ranked.items() if n in available}
    return StripesBenchmarkResult(objects.name, cfg, objects, scanned, stripes, profile,
                                  baselines, fused, skipped, silhouette_seconds, fused_sc,
                                  relief, fused_relief, surface, fused_stripes, canonical)
