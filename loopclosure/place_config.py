"""Parameters of the place database (`loopclosure.place_database`) in one frozen object.

`PlaceDatabaseConfig` names the stages (prefilter vectors screening every keyframe,
verifiers run on the K candidates), the fusion of their distances into one score,
the heading hypotheses and the descriptor sizes; `__post_init__` rejects a bad
combination with a `UserError` naming the field.  `DEFAULT_LOGISTIC` is the
calibrated logistic fusion of the default stages.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from data.errors import UserError
from loopclosure.fusion import DEFAULT_RANK_CONSTANT, LogisticFusion
from loopclosure.matchers import MATCHER_NAMES, get_matcher
from loopclosure.matchers.base import Matcher

NEAR_FFT = "fft-near"
"""Prefilter stage name of the near+far FFT descriptor: `loopclosure.matchers.fft`
with ``near_radius`` and ``far_weight`` (`PlaceDatabaseConfig.fft_near_radius`,
``fft_far_weight``, ``fft_near_harmonics``), a stage of its own so that the ``fft``
stage and the heading hypotheses' range functions stay the whole polygon's."""

NEAR_PAIRS = "pairs-near"
"""Prefilter stage name of the near-field surface-pair histogram: the pair histogram
(`loopclosure.matchers.pair_histogram`) of the polygon's surfaces within
`PlaceDatabaseConfig.pairs_near_radius` of the sensor (farther vertices are open
space, `PairHistogramConfig.max_range`), a stage of its own beside ``pairs`` (the
whole view's).  Added to ``pairs`` with a small weight it lets the surfaces near the
robot outvote the far ones, which differ most between two passes (another heading,
the range cap, a half-circle laser) and which put far-away places ahead of a true
one."""

PREFILTER_STAGES = ("fft", "ring", "pairs", NEAR_FFT, NEAR_PAIRS)
"""Matchers whose descriptors are Euclidean vectors, usable as prefilter stages
(``pairs``: `loopclosure.matchers.pair_histogram`, the default)."""

FUSION_MODES = ("logistic", "rank", "verifier", "prefilter", "auto")

VIEWPOINT_ORDERS = ("min", "interleave", "rerank")
"""How a query's viewpoints rank the stored keyframes (`PlaceDatabaseConfig`)."""

VOTE_MODES = ("off", "fuse")
"""Whether the keypoint-pair vote picks candidates (`PlaceDatabaseConfig.vote`)."""

# Default logistic model of the place database (stages "pairs" and "flirt"): fitted by
# `loopclosure.fusion.fit_logistic` (ridge 1) on the 10 prefilter candidates of every
# query (no pose prior; same place = within 2 m) of the simulated Box world (seed 0)
# and three GMapping-corrected real logs (freiburg-101, seattle, orebro), with the
# features log(d / scale + 1e-3) of `loopclosure.fusion`; the Intel log was held out.
# Fitted on Intel and the others with one of the five left out, the weights range over
# -2.3 .. -4.5 (pairs) and -1.5 .. -2.9 (FLIRT): both matter and neither dominates, so
# the fused top-1 ranks at or above the better of its two members on most logs, where
# the paper stages' model (FLIRT -13.5, calibrated on the Box only) ranked below FLIRT.
DEFAULT_LOGISTIC = LogisticFusion(
    names=("pairs", "flirt"),
    coefficients=(-2.32, -2.88),
    intercept=-2.48,
)

# The logistic model of the same stages for the loop detector's wide view (a keyframe
# described from the map of its last keyframes, in a database of its own): fitted the
# same way as `DEFAULT_LOGISTIC` (`benchmarks/view_calibration.py`: `fit_logistic`,
# ridge 1, the 10 prefilter candidates of every query, same place = within 2 m) on the
# wide views of the same three real logs (freiburg-101, seattle, orebro; the simulated
# Box world's laser covers the full circle and has no wide view), Intel and the other
# corrected logs held out.  A wide view's FLIRT distance of a true place is larger
# against its database's scale than an own view's, so the own view's model scores a
# wide view's true places low and a merge by score keeps the own view's answer; with a
# model per view the scores of both views are probabilities of the same event.  Used
# with `LoopClosureConfig.view_calibration` "per-view", not the default: which view
# carries a revisit differs between logs more than this model can tell
# (benchmarks/view_calibration.md).
WIDE_LOGISTIC = LogisticFusion(
    names=("pairs", "flirt"),
    coefficients=(-3.22, -1.29),
    intercept=-4.22,
)

# The logistic model of the surface-pair and near+far FFT prefilter with the FLIRT
# verifier (``prefilter=("pairs", "fft-near")``, ``prefilter_weights=(1, 0.1)``):
# fitted as `DEFAULT_LOGISTIC` (`benchmarks/view_calibration.py`: `fit_logistic`,
# ridge 1, the 10 prefilter candidates of every query of the own view, same place =
# within 2 m) on freiburg-101, seattle and orebro; Intel and the other corrected logs
# held out.  Among candidates the combined prefilter already chose, the near+far FFT
# distance adds little beyond the pair histogram's (its weight is small).
NEAR_FFT_LOGISTIC = LogisticFusion(
    names=("pairs", NEAR_FFT, "flirt"),
    coefficients=(-2.09, -0.10, -2.27),
    intercept=-3.04,
)

# The logistic model of the whole and near-field surface-pair prefilter with the FLIRT
# verifier (``prefilter=("pairs", "pairs-near")``): `DEFAULT_LOGISTIC` with weight 0 on
# the near-field histogram, not refitted: the fused score of a candidate is the
# default's, and the near field only changes which keyframes become candidates.
NEAR_PAIRS_LOGISTIC = LogisticFusion(
    names=("pairs", NEAR_PAIRS, "flirt"),
    coefficients=(DEFAULT_LOGISTIC.coefficients[0], 0.0, DEFAULT_LOGISTIC.coefficients[1]),
    intercept=DEFAULT_LOGISTIC.intercept,
)

FITTED_LOGISTIC = (DEFAULT_LOGISTIC, NEAR_FFT_LOGISTIC, NEAR_PAIRS_LOGISTIC)
"""The fitted logistic models by stage set: a config whose ``logistic`` is left at
`DEFAULT_LOGISTIC` uses the one of its stages (`PlaceDatabaseConfig.logistic`)."""

# The logistic model of the paper's stages (FFT and ring prefilter, FLIRT and MRM
# verifiers), fitted by `loopclosure.cascade.calibrate_logistic` on the simulated Box
# set (seed 0, 231 scans, leave-one-out candidate pairs, K = 50); the default of the
# place database before the surface-pair prefilter.
PAPER_LOGISTIC = LogisticFusion(
    names=("fft", "ring", "flirt", "mrm"),
    coefficients=(-0.5891, -1.344, -13.52, -5.142),
    intercept=-7.119,
)


@dataclass(slots=True, frozen=True)
class PlaceDatabaseConfig:
    """Parameters of the place database (the rules are in `loopclosure.place_database`).

    Attributes:
        prefilter: Euclidean-vector stages screening every keyframe ("pairs",
            "fft", "ring", "fft-near": `NEAR_FFT`, "pairs-near": `NEAR_PAIRS`).
        prefilter_weights: weight of each prefilter stage in the normalised sum
            (empty: all 1).
        verifiers: matchers run on the K candidates (any registered name, e.g.
            "flirt", "mrm", "shape-context", "integral"); may be empty.
        top_k: K, candidates verified per query.
        fusion: "logistic", "rank", "verifier", "prefilter", or "auto" (logistic
            unless ``scale_invariant``, then rank: see `resolved_fusion`).
        logistic: the logistic model (its names must be the stages, in any order;
            left at `DEFAULT_LOGISTIC` for stages of another model of
            `FITTED_LOGISTIC`, that model).
        rank_constant: c of reciprocal rank fusion.
        n_headings: heading hypotheses per candidate from the range functions (0:
            none, FFT not computed unless it is a stage).
        grid_headings: heading hypotheses per candidate from the polar occupancy
            grids, tried before those (0: none; never when ``scale_invariant``).
        grid_rings: rings of the polar grid.
        grid_sectors: bearing sectors of the polar grid.
        grid_range: radius of the polar grid [m].
        grid_extra: candidates added to the K by the grids' ranking of the prefilter's
            shortlist (`loopclosure.grid_rerank`; 0: none; only with grid headings).
        grid_shortlist: keyframes with the smallest prefilter distance that the grids
            rank.
        grid_weight: w of the shortlist score p - w c.
        fft_harmonics: FFT amplitudes kept by the FFT stage (`FFTConfig.n_harmonics`).
        fft_near_harmonics: FFT amplitudes of the near polygon (and as many of the
            whole polygon's) kept by the ``fft-near`` stage.
        fft_near_radius: R of the ``fft-near`` stage [m]: the polygon within R of the
            sensor, far vertices pulled in along their rays (`FFTConfig.near_radius`).
        fft_far_weight: weight of the whole polygon's amplitudes appended to the near
            polygon's by the ``fft-near`` stage (`FFTConfig.far_weight`).
        pairs_near_radius: R of the ``pairs-near`` stage [m]: surfaces within R of
            the sensor (`PairHistogramConfig.max_range`).
        ring_rings: circles of the ring stage (`RingConfig.n_rings`).
        scale_invariant: passed to every matcher (True for MPEG-7, never for places).
        fixed_scales: per stage (prefilter then verifiers), fixed scales instead of
            the database estimate (empty: estimated).
        scale_pairs: random stored pairs per verifier scale estimate.
        seed: seed of the pair sampling.
        query_viewpoints: a query carrying offset viewpoints of its own (descriptor
            ``viewpoints``, `loopclosure.place_views`) is compared from each of them
            too, the smallest distance kept (False: its own description only).
        viewpoint_scores: the fused score of a candidate sees the prefilter
            distances of its best pair of viewpoints (the ones p took); False: of the
            query's and the candidate's own descriptions, the distances the logistic
            model was fitted on (the viewpoints then only choose the candidates).
        stored_viewpoints: a stored keyframe's offset viewpoints are screened (False:
            the database keeps them in the keyframe's descriptors, so that the
            keyframe asking as a query carries them, but compares a query with the
            stored own descriptions only: with ``query_viewpoints`` the viewpoints
            then stand on the query's side alone, one screen of the database per
            query viewpoint instead of one per stored and query viewpoint pair).
        viewpoint_order: how the offset viewpoints (the query's, with
            ``query_viewpoints``, and the stored keyframes') rank the stored
            keyframes: ``"min"``, by the smallest p over every pair of descriptions;
            ``"interleave"``, by up to three lists interleaved by rank
            (`loopclosure.place_shortlist.rank_interleave`): p of the two own
            descriptions, the smallest of it and the query viewpoints' p, and the
            smallest of it and the stored viewpoints' p
            (`PlaceDatabase.prefilter_lists`), so the own descriptions' best places
            keep their ranks among the first and each side's viewpoints' best fill
            the places between them.
            ``"rerank"``: the own descriptions alone screen the database, and only
            the ``viewpoint_pool`` smallest p are ranked again by the viewpoints,
            each query description's p rescaled by its ``viewpoint_rank``-th
            smallest over that pool (`loopclosure.place_views.rank_normalised`), so
            a description close to many places (a generic view) takes no places
            from the own description's best.
        viewpoint_pool: rows a ``"rerank"`` query ranks again by its viewpoints
            (at least the shortlist's).
        viewpoint_rank: the rank of the smallest p a ``"rerank"`` query
            normalises each of its descriptions by (0: no normalisation).
        vote: ``"off"`` (default) or ``"fuse"``: a keypoint-pair vote
            (`loopclosure.place_vote`) picks candidates too: the first ``vote_split``
            of the prefilter's K are kept and the rest of the K are the vote's best
            places not among them (then the prefilter's order, when the vote has too
            few places with a vote).  Only a query with the vote's keypoints
            (`PlaceDatabase.describe` makes them when on) against the database's own
            descriptions (`PlaceDatabase.candidates`; not `query_stored`).
        vote_split: prefilter candidates kept before the vote's (K or more: the vote
            adds none).
        vote_step: boundary sampling step of the vote's keypoints [m].
        vote_range: farthest vote keypoint from the sensor [m].
        vote_features: strongest interest points a place keeps for the vote.
        vote_stop_share: stop-list of the vote: a key with more postings than this
            share of the places stored is skipped (0: none).
    """

    prefilter: tuple[str, ...] = ("pairs",)
    prefilter_weights: tuple[float, ...] = ()
    verifiers: tuple[str, ...] = ("flirt",)
    top_k: int = 10
    fusion: str = "logistic"
    logistic: LogisticFusion = field(default_factory=lambda: DEFAULT_LOGISTIC)
    rank_constant: float = DEFAULT_RANK_CONSTANT
    n_headings: int = 3
    grid_headings: int = 3
    grid_rings: int = 20
    grid_sectors: int = 120
    grid_range: float = 20.0
    grid_extra: int = 5
    grid_shortlist: int = 50
    grid_weight: float = 1.0
    fft_harmonics: int = 8
    ring_rings: int = 12
    fft_near_harmonics: int = 16
    fft_near_radius: float = 6.0
    fft_far_weight: float = 0.05
    pairs_near_radius: float = 6.0
    scale_invariant: bool = False
    fixed_scales: tuple[float, ...] = ()
    scale_pairs: int = 64
    seed: int = 0
    query_viewpoints: bool = False
    viewpoint_scores: bool = False
    stored_viewpoints: bool = True
    viewpoint_order: str = "min"
    viewpoint_pool: int = 128
    viewpoint_rank: int = 30
    vote: str = "off"
    vote_split: int = 5
    vote_step: float = 0.2
    vote_range: float = 15.0
    vote_features: int = 80
    vote_stop_share: float = 0.0

    def __post_init__(self) -> None:
        if self.viewpoint_order not in VIEWPOINT_ORDERS:
            raise UserError(
                f"place database: viewpoint_order must be one of "
                f"{', '.join(VIEWPOINT_ORDERS)}, got {self.viewpoint_order!r}"
            )
        if self.viewpoint_pool < 1 or self.viewpoint_rank < 0:
            raise UserError("place database: need viewpoint_pool >= 1 and viewpoint_rank >= 0")
        if self.vote not in VOTE_MODES:
            raise UserError(f"place database: vote must be one of {', '.join(VOTE_MODES)}, "
                            f"got {self.vote!r}")
        if self.vote_split < 0 or self.vote_features < 1:
            raise UserError("place database: need vote_split >= 0 and vote_features >= 1")
        if not all(np.isfinite(x) and x > 0 for x in (self.vote_step, self.vote_range)):
            raise UserError("place database: vote_step and vote_range must be positive [m]")
        if not (np.isfinite(self.vote_stop_share) and self.vote_stop_share >= 0):
            raise UserError("place database: vote_stop_share must be >= 0 (0: no stop-list)")
        if not self.prefilter:
            raise UserError("place database: at least one prefilter stage is needed")
        for s in self.prefilter:
            if s not in PREFILTER_STAGES:
                raise UserError(
                    f"place database: prefilter stage {s!r} is not a vector descriptor; "
                    f"use {' or '.join(PREFILTER_STAGES)}"
                )
        for s in self.verifiers:
            if s not in MATCHER_NAMES:
                raise UserError(
                    f"place database: unknown verifier {s!r}; known: {', '.join(MATCHER_NAMES)}"
                )
        stages = self.stages
        if len(set(stages)) != len(stages):
            raise UserError(f"place database: a stage is listed twice: {', '.join(stages)}")
        if self.prefilter_weights and len(self.prefilter_weights) != len(self.prefilter):
            raise UserError("place database: one prefilter weight per prefilter stage")
        if any(not (np.isfinite(w) and w >= 0) for w in self.prefilter_weights):
            raise UserError("place database: prefilter weights must be finite and >= 0")
        if self.top_k < 1:
            raise UserError(f"place database: top_k must be >= 1, got {self.top_k}")
        if self.fusion not in FUSION_MODES:
            raise UserError(
                f"place database: fusion {self.fusion!r} unknown; use {', '.join(FUSION_MODES)}"
            )
        if self.fusion == "verifier" and not self.verifiers:
            raise UserError("place database: fusion 'verifier' needs at least one verifier")
        if self.logistic == DEFAULT_LOGISTIC and sorted(self.logistic.names) != sorted(stages):
            # The default model of another stage set: the one fitted for these stages.
            fitted = [m for m in FITTED_LOGISTIC if sorted(m.names) == sorted(stages)]
            if fitted:
                object.__setattr__(self, "logistic", fitted[0])
        if self.resolved_fusion == "logistic" and sorted(self.logistic.names) != sorted(stages):
            raise UserError(
                "place database: the logistic model is fitted for stages "
                f"{', '.join(self.logistic.names) or '(none)'} but the stages are "
                f"{', '.join(stages)}; refit it (loopclosure.cascade.calibrate_logistic) "
                "or use fusion 'rank'"
            )
        if self.fixed_scales and (
            len(self.fixed_scales) != len(stages)
            or any(not (np.isfinite(s) and s > 0) for s in self.fixed_scales)
        ):
            raise UserError("place database: fixed_scales needs one positive scale per stage")
        if self.fft_harmonics < 1 or self.ring_rings < 1 or self.fft_near_harmonics < 1:
            raise UserError("place database: fft_harmonics, fft_near_harmonics and "
                            "ring_rings must be >= 1")
        if not (np.isfinite(self.fft_near_radius) and self.fft_near_radius > 0):
            raise UserError("place database: fft_near_radius must be a positive length [m]")
        if not (np.isfinite(self.pairs_near_radius) and self.pairs_near_radius > 0):
            raise UserError("place database: pairs_near_radius must be a positive length [m]")
        if not (np.isfinite(self.fft_far_weight) and self.fft_far_weight >= 0):
            raise UserError("place database: fft_far_weight must be finite and >= 0")
        if self.n_headings < 0 or self.scale_pairs < 1:
            raise UserError("place database: n_headings must be >= 0 and scale_pairs >= 1")
        if self.grid_headings < 0 or self.grid_rings < 1 or self.grid_sectors < 3:
            raise UserError(
                "place database: grid_headings >= 0, grid_rings >= 1 and grid_sectors >= 3"
            )
        if not (np.isfinite(self.grid_range) and self.grid_range > 0):
            raise UserError("place database: grid_range must be a positive length [m]")
        if self.grid_extra < 0 or self.grid_shortlist < 1:
            raise UserError("place database: grid_extra >= 0 and grid_shortlist >= 1")
        if not (np.isfinite(self.grid_weight) and self.grid_weight >= 0):
            raise UserError("place database: grid_weight must be finite and >= 0")

    @property
    def stages(self) -> tuple[str, ...]:
        """Prefilter stages then verifiers."""
        return tuple(self.prefilter) + tuple(self.verifiers)

    @property
    def resolved_fusion(self) -> str:
        """The fusion mode in use: "auto" is "logistic" for places (not scale
        invariant), "rank" for scale-invariant shape sets (MPEG-7), where the
        logistic calibrated on laser places does not transfer: which matcher is
        reliable differs between the domains (FLIRT is perfect on the simulated
        places and the weakest verifier on MPEG-7)."""
        if self.fusion != "auto":
            return self.fusion
        return "rank" if self.scale_invariant else "logistic"


def stage_matcher(stage: str, config: PlaceDatabaseConfig) -> Matcher:
    """The matcher of one stage of `config` (any registered matcher by its name, with
    the config's descriptor sizes; ``fft-near``: the FFT matcher of the polygon within
    ``fft_near_radius`` [m] of the sensor, the whole polygon's amplitudes appended
    with weight ``fft_far_weight``; ``pairs-near``: the pair histogram of the surfaces
    within ``pairs_near_radius`` [m])."""
    if stage == NEAR_PAIRS:
        return get_matcher("pairs", scale_invariant=config.scale_invariant,
                           max_range=config.pairs_near_radius)
    if stage == NEAR_FFT:
        return get_matcher("fft", scale_invariant=config.scale_invariant,
                           n_harmonics=config.fft_near_harmonics,
                           near_radius=config.fft_near_radius,
                           far_weight=config.fft_far_weight)
    sizes = {"fft": {"n_harmonics": config.fft_harmonics},
             "ring": {"n_rings": config.ring_rings}}
    return get_matcher(stage, scale_invariant=config.scale_invariant, **sizes.get(stage, {}))


__all__ = [
    "DEFAULT_LOGISTIC",
    "FITTED_LOGISTIC",
    "FUSION_MODES",
    "NEAR_FFT",
    "NEAR_FFT_LOGISTIC",
    "NEAR_PAIRS",
    "NEAR_PAIRS_LOGISTIC",
    "PAPER_LOGISTIC",
    "PREFILTER_STAGES",
    "VIEWPOINT_ORDERS",
    "VOTE_MODES",
    "WIDE_LOGISTIC",
    "PlaceDatabaseConfig",
    "stage_matcher",
]
