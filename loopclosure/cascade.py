"""The cascade matcher: prefilter -> verifier -> fused score, behind the `Matcher` interface.

The cascade is the place database (`loopclosure.place_database`) seen as one
matcher, so the all-pairs benchmark (Bull's eye, ROC, F-score) scores it like any
other:

- ``describe(polygon)``: the descriptors of every stage (a dict stage -> descriptor).
- ``stack(descriptors)``: a `PlaceDatabase` holding them (keys 0..M-1); its stage
  scales (median distance of random stored pairs, per stage) are estimated there.
- ``distances(query, stacked)``: the prefilter's combined normalised distance p(j)
  over all M entries, the verifiers on the K best, the fused score s(j) in [0, 1]
  of those K, and the final distance

      D(j) = 1 - s(j) + 1e-12 r(j)     for the K verified entries (r = prefilter rank)
      D(j) = 1 + 1e-9 + p(j)           for all others

  so the K verified entries come first, ordered by fused score (ties by prefilter
  rank), and all others follow in prefilter order.  On laser places (``anchored``:
  fusion "auto", not scale invariant, the ``anchor`` verifier, FLIRT, among the
  verifiers) the verified entries are instead ordered by the anchor:

      D(j) = 1 - exp(-d_a(j) / scale_a) + 1e-12 f(j) / K   (f = rank by fused score)

  a monotone map of the anchor's distance by its database scale, the fused score
  only breaking exact ties.  D >= 0 and finite; with
  logistic fusion 1 - s is the calibrated probability that the pair is NOT the same
  place, comparable across queries (ROC / F-score thresholds).  A shape against
  itself gets D ~ 1e-17, not exactly 0 (the logistic never reaches 1).

The cascade distance is relative to the database it is stacked with (scales, ranks,
the top K), so ``distance(a, b)`` (= ``distances(a, stack([b]))[0]``, as for every
matcher) is only meaningful inside a database.

Parameters (`CascadeConfig`: the `PlaceDatabaseConfig` fields, with these defaults):
    prefilter = ("fft", "ring") with their matchers' full sizes (fft_harmonics 16,
    ring_rings 32: the benchmark's databases are small, speed is not the issue,
    recall is); verifiers = ("mrm", "flirt", "shape-context"); top_k K = 128;
    verify_all_up_to = 1024 (a database of M <= 1024 entries is verified in full,
    K = M: `CascadeConfig.k_for`); anchor = "flirt"; fusion = "auto";
    n_headings = 0 (the benchmark needs no heading); scale_invariant passed down to
    every stage (True for MPEG-7).

Why K = M on small databases and the FLIRT anchor on places: on real scans the
FFT + ring prefilter, near perfect on the simulated sets, loses a part of the
same-place scans of a query beyond any affordable K, and FLIRT re-ranking only the
top K then falls below FLIRT over all pairs; the MRM, ring and FFT stages the
Box-calibrated logistic trusts are weak on real scans, so on real places every other
stage only adds noise to FLIRT's order (even a logistic fitted on real pairs does
not beat FLIRT alone).  Hence: verify everything when that is affordable (the
prefilter is a speed device, not a quality one), and on places let FLIRT order the
verified candidates; the calibrated fusion is kept for ties, for the place database
(`PlaceDatabaseConfig`, untouched) and for explicit ``fusion`` modes.  On
scale-invariant shape sets the anchor is off and rank fusion orders (FLIRT is the
weakest verifier on MPEG-7).  The anchored cascade therefore equals FLIRT's ranking
when K = M, i.e. it cannot fall below FLIRT on Bull's eye; it beats FLIRT only where
FLIRT has exact ties.  K matters for the benchmark: Bull's eye counts the 2n nearest
(n = class size), so re-ranking can only change it when K > 2n; and the prefilter
must keep every same-class shape within K (recall@K = 1).

Which stages the place benchmark runs.  The defaults above are the paper's stages.
On laser places (every data set that is not scale invariant) the benchmark runs the
cascade as the SLAM pipeline's place database is configured
(`place_database_stages`): the surface-pair prefilter
(`loopclosure.matchers.pair_histogram`, not one of the paper's eight), FLIRT, and
their logistic fusion, verified over the whole (small) database.  The benchmark's
cascade row is then the product's own cascade, and on real places it ranks far
above the paper's stages and FLIRT alone, since the pair histogram, unlike the FFT
and ring descriptors, does not depend on a reference point that moves with what the
sensor happens to see.
MPEG-7 and other scale-invariant shape sets keep the paper's stages with rank fusion.

Fusion "auto" = logistic for places (not scale invariant), reciprocal rank fusion for
scale-invariant shape sets (`PlaceDatabaseConfig.resolved_fusion`).  The logistic is
calibrated on laser places, where FLIRT separates places almost perfectly and gets
the largest weight; on MPEG-7 silhouettes FLIRT is the weakest verifier, and the
Box-calibrated logistic falls below MRM alone there, while rank fusion, which needs
no calibration, does not.

Calibration of the logistic fusion (`calibrate_logistic`): every shape of a labelled
set queries the database of all the others (leave one out); the K prefilter
candidates give (stage distances, same place?) pairs; features
log(d_s / scale_s + 1e-3); ridge-penalised Newton fit (`loopclosure.fusion`).
`CASCADE_LOGISTIC` was fitted on the simulated Box set, seed 0.  Refit, without any
CLI::

    python -c "
    from data.sim import place_dataset
    from loopclosure.polygon import polygon_from_scan
    from loopclosure.cascade import CascadeConfig, calibrate_logistic
    ds = place_dataset('box', seed=0)
    print(calibrate_logistic([polygon_from_scan(s) for _, s in ds], [l for l, _ in ds],
                             CascadeConfig(fusion='rank')))"

and paste the printed `LogisticFusion` into `CASCADE_LOGISTIC` (or into the
``logistic`` section of a config file).  The place database's `PAPER_LOGISTIC`
(its stages before the surface-pair prefilter) was fitted the same way with
``PlaceDatabaseConfig(fusion='rank')`` and ``top_k=50``; its `DEFAULT_LOGISTIC` is
fitted on bench-loops candidates of real logs (`loopclosure.place_config`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError
from loopclosure.fusion import LogisticFusion, fit_logistic, log_features
from loopclosure.matchers.base import Matcher
from loopclosure.place_config import PlaceDatabaseConfig
from loopclosure.place_database import PlaceDatabase
from loopclosure.place_match import Descriptors
from loopclosure.polygon import Polygon

Array = NDArray[np.float64]

# Fitted by `calibrate_logistic(polygons, labels, CascadeConfig(fusion="rank"))` on the
# simulated Box set (seed 0; 231 scans x K = 128 leave-one-out candidate pairs, ridge 1).
# Shape context gets a small positive weight: it is collinear with MRM on these pairs.
CASCADE_LOGISTIC = LogisticFusion(
    names=("fft", "ring", "mrm", "flirt", "shape-context"),
    coefficients=(-1.060, -2.998, -4.261, -13.93, 0.5568),
    intercept=-8.528,
)


def place_database_stages() -> dict[str, Any]:
    """`CascadeConfig` overrides that make the cascade the SLAM pipeline's place
    database: its prefilter, verifiers and logistic fusion (`PlaceDatabaseConfig`
    defaults: the surface-pair prefilter, FLIRT, `DEFAULT_LOGISTIC`), no anchor.

    What the place benchmark runs as ``cascade`` on laser places (module docstring,
    "Which stages").
    """
    base = PlaceDatabaseConfig()
    return {"prefilter": base.prefilter, "verifiers": base.verifiers, "fusion": "logistic",
            "logistic": base.logistic, "anchor": None}


@dataclass(slots=True, frozen=True)
class CascadeConfig(PlaceDatabaseConfig):
    """Parameters of the cascade matcher: `PlaceDatabaseConfig` with benchmark defaults."""

    prefilter: tuple[str, ...] = ("fft", "ring")
    verifiers: tuple[str, ...] = ("mrm", "flirt", "shape-context")
    top_k: int = 128
    fusion: str = "auto"
    logistic: LogisticFusion = field(default_factory=lambda: CASCADE_LOGISTIC)
    n_headings: int = 0
    grid_extra: int = 0  # K means K here: the benchmark's rows count the verified K
    fft_harmonics: int = 16
    ring_rings: int = 32
    verify_all_up_to: int = 1024
    anchor: str | None = "flirt"

    def __post_init__(self) -> None:
        PlaceDatabaseConfig.__post_init__(self)
        if self.verify_all_up_to < 0:
            raise UserError(
                f"cascade: verify_all_up_to must be >= 0, got {self.verify_all_up_to}"
            )

    @property
    def anchored(self) -> bool:
        """True when the anchor verifier orders the verified candidates: the anchor is
        one of the verifiers, fusion is "auto" and the set is not scale invariant
        (laser places).  Otherwise the database's fused score orders them."""
        return (
            self.anchor in self.verifiers and self.fusion == "auto" and not self.scale_invariant
        )

    def k_for(self, m: int) -> int:
        """Candidates verified in a database of `m` entries: all of them when
        ``m <= verify_all_up_to``, else ``top_k`` (at most m)."""
        return m if m <= self.verify_all_up_to else min(self.top_k, m)


@dataclass(slots=True, frozen=True)
class CascadeStack:
    """Stacked cascade descriptors: a place database keyed 0..M-1."""

    database: PlaceDatabase

    def __len__(self) -> int:
        return len(self.database)


class CascadeMatcher(Matcher):
    """Prefilter over all, verify the top K, fuse (see module docstring)."""

    name = "cascade"
    rotation_invariant = True

    def __init__(
        self,
        config: CascadeConfig | None = None,
        *,
        matchers: dict[str, Matcher] | None = None,
        **overrides: Any,
    ) -> None:
        cfg = config or CascadeConfig()
        if overrides:
            known = {f.name for f in fields(CascadeConfig)}
            unknown = set(overrides) - known
            if unknown:
                raise UserError(f"unknown CascadeConfig fields: {', '.join(sorted(unknown))}")
            cfg = replace(cfg, **overrides)
        self.config = cfg
        self._template = PlaceDatabase(cfg, matchers=matchers)
        self.matchers = self._template.matchers
        self.rotation_invariant = all(m.rotation_invariant for m in self.matchers.values())

    def describe(self, polygon: Polygon) -> Descriptors:
        """Descriptors of every stage of one polygon (sensor frame [m])."""
        return self._template.describe(polygon)

    def stack(self, descriptors: Sequence[Descriptors]) -> CascadeStack:
        """A place database holding the descriptors under keys 0..M-1."""
        db = PlaceDatabase(self.config, matchers=self.matchers)
        for i, d in enumerate(descriptors):
            db.add_descriptors(i, d)
        return CascadeStack(db)

    def distances(self, query: Descriptors, stacked: CascadeStack) -> Array:
        """``(M,)`` cascade distances (module docstring): verified first, by fused score."""
        db = stacked.database
        m = len(db)
        if m == 0:
            return np.zeros(0)
        cfg = self.config
        c = db.candidates(query, keep_prefilter=True, top_k=cfg.k_for(m))
        assert c.prefilter_all is not None
        out = c.prefilter_all + (1.0 + 1e-9)
        k = len(c.indices)
        if cfg.anchored:
            assert cfg.anchor is not None
            a = cfg.stages.index(cfg.anchor)
            scale = db.scales[cfg.anchor]
            fused_rank = np.empty(k)
            fused_rank[c.order()] = np.arange(k)
            out[c.indices] = -np.expm1(-c.distances[a] / scale) + 1e-12 * fused_rank / max(k, 1)
        else:
            out[c.indices] = 1.0 - c.scores + 1e-12 * np.arange(k)
        out = np.where(np.isfinite(out), out, np.finfo(float).max)
        return np.maximum(out, 0.0)

    def distance(self, a: Descriptors, b: Descriptors) -> float:
        """Cascade distance of `b` as the only entry of a database queried by `a`."""
        return float(self.distances(a, self.stack([b]))[0])


def candidate_pairs(
    shapes: Sequence[Polygon | Descriptors],
    labels: ArrayLike,
    config: PlaceDatabaseConfig | None = None,
    *,
    matchers: dict[str, Matcher] | None = None,
    top_k: int | None = None,
) -> tuple[Array, NDArray[np.bool_], tuple[str, ...], Array]:
    """Leave-one-out candidate pairs of a labelled set, as the cascade sees them.

    Every shape queries the database of all the others; its K prefilter candidates
    give one pair each.

    Returns:
        ``(distances, same, stages, scales)``: ``(n_pairs, S)`` raw stage distances,
        ``(n_pairs,)`` True for same-label pairs, the stage names, and the ``(S,)``
        database scales used to normalise them.
    """
    lab = np.asarray(labels)
    if len(lab) != len(shapes):
        raise UserError(f"candidate_pairs: {len(lab)} labels for {len(shapes)} shapes")
    cfg = config or CascadeConfig()
    db = PlaceDatabase(cfg, matchers=matchers)
    descs = [s if isinstance(s, dict) else db.describe(s) for s in shapes]
    for i, d in enumerate(descs):
        db.add_descriptors(i, d)
    scales = np.asarray(list(db.scales.values()))
    rows: list[Array] = []
    same: list[NDArray[np.bool_]] = []
    for i, d in enumerate(descs):
        c = db.candidates(d, exclude_keys=[i], top_k=top_k)
        rows.append(c.distances.T)
        same.append(lab[c.indices] == lab[i])
    return np.concatenate(rows), np.concatenate(same), cfg.stages, scales


def calibrate_logistic(
    shapes: Sequence[Polygon | Descriptors],
    labels: ArrayLike,
    config: PlaceDatabaseConfig | None = None,
    *,
    matchers: dict[str, Matcher] | None = None,
    top_k: int | None = None,
    ridge: float = 1.0,
) -> LogisticFusion:
    """Fit the logistic fusion of `config`'s stages on a labelled set (module docstring).

    Args:
        shapes: polygons (sensor frame [m]) or their `describe` dicts.
        labels: place (class) label of each shape.
        config: the cascade / database config whose stages are fused.
        matchers: prebuilt matchers by stage name.
        top_k: K candidates per query (default the config's).
        ridge: penalty of `loopclosure.fusion.fit_logistic`.
    """
    cfg = config or CascadeConfig()
    dist, same, stages, scales = candidate_pairs(
        shapes, labels, replace(cfg, fusion="rank"), matchers=matchers, top_k=top_k
    )
    feats = log_features(dist, scales, cfg.logistic.eps)
    return fit_logistic(feats, same, names=stages, ridge=ridge, eps=cfg.logistic.eps)


__all__ = [
    "CASCADE_LOGISTIC",
    "CascadeConfig",
    "CascadeMatcher",
    "CascadeStack",
    "calibrate_logistic",
    "candidate_pairs",
    "place_database_stages",
]
