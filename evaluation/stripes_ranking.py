"""The stripes benchmark's retrieval figures of the stripes, the profile and the fused rows.

Each row's distance matrix (`evaluation.stripes_tasks.MatcherRows`) scored by
`evaluation.stripes_retrieval.evaluate` with the options it reports; a fused row's
matrix is the fusion of its parts' (`loopclosure.stripes.fuse`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence

from evaluation.stripes_config import StripesBenchmarkConfig
from evaluation.stripes_objects import ScannedSet
from evaluation.stripes_retrieval import MethodResult, evaluate
from evaluation.stripes_tasks import MatcherRows
from loopclosure.stripes import fuse


def _rank_with_stripes(
    scanned: ScannedSet, cfg: StripesBenchmarkConfig, rows: MatcherRows
) -> MethodResult:
    """The retrieval figures of the stripes' distance matrix of the scans."""
    d, secs = rows.distances, rows.seconds
    return evaluate("stripes", d, scanned.labels, scanned.objects, secs, cfg.k,
                    {"weights": [0.6, 0.3, 0.1], "stripe_count": cfg.descriptor.stripe_count,
                     "scale_free": cfg.descriptor.scale_free})


def _rank_with_profile(
    scanned: ScannedSet, cfg: StripesBenchmarkConfig, rows: MatcherRows
) -> MethodResult:
    """The retrieval figures of the stripe profiles' distance matrix of the scans."""
    d, secs = rows.distances, rows.seconds
    return evaluate("profile", d, scanned.labels, scanned.objects, secs, cfg.k,
                    {"samples": cfg.profile.samples, "features": ["l", "d", "e"],
                     "normalisation": "per-query median per feature"})


def _fused(
    scanned: ScannedSet, stripe_side: Sequence[MethodResult], ranked: dict[str, MethodResult],
    cfg: StripesBenchmarkConfig, verifiers: Sequence[str], name: str = "fused",
    scaling: str = "median", mean: str = "arithmetic",
) -> MethodResult:
    """A fused matcher's figures from the matrices of its stripe-side parts (the profile,
    and the relief, surface context and canonical profile when given) and of the
    `verifiers`, each made unitless by `scaling` and averaged by `mean`
    (`loopclosure.stripes.fuse`)."""
    t0 = time.perf_counter()
    d = fuse([*(r.distances for r in stripe_side), *(ranked[n].distances for n in verifiers)],
             scaling=scaling, neighbour=cfg.neighbour, mean=mean)
    secs = (sum(r.seconds for r in stripe_side) + sum(ranked[n].seconds for n in verifiers)
            + time.perf_counter() - t0)
    return evaluate(name, d, scanned.labels, scanned.objects, secs, cfg.k,
                    {"verifiers": list(verifiers),
                     "normalisation": ("local scaling, neighbour "
                                       f"{cfg.neighbour}" if scaling == "local"
                                       else "per-query median"),
                     "mean": mean,
                     "stripes": " + ".join(r.name for r in stripe_side),
                     "samples": cfg.profile.samples})
