"""Every parameter of the loop detector (`loopclosure.loop_detector`): `LoopClosureConfig`."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from data.errors import UserError
from loopclosure.geometric_check import GeometricCheckConfig
from loopclosure.place_config import WIDE_LOGISTIC, PlaceDatabaseConfig
from loopclosure.polygon import PolygonConfig
from loopclosure.viewpoints import ViewpointConfig

SEARCHES = ("both", "appearance", "pose")
"""Values of `LoopClosureConfig.search`."""
VIEW_CALIBRATIONS = ("shared", "per-view")
"""Values of `LoopClosureConfig.view_calibration`."""


@dataclass(slots=True)
class LoopClosureConfig:
    """Every parameter of the loop-closure plugin (see `loopclosure.loop_detector`'s
    module docstring).

    Attributes:
        exclude_recent: keyframes this close in sequence are never candidates.
        exclude_recent_s: ... nor keyframes this close in time [s].
        max_distance: a loop closure is a revisit: a verified relative pose longer than
            this is rejected (the two keyframes see overlapping but distinct places) [m];
            passed to the geometric check (`verify`'s ``max_distance``).
        search: which searches propose candidates: ``both``, ``appearance`` (the place
            database alone; the pose gate still decides how a candidate is checked)
            or ``pose`` (the pose-gated search alone).
        local_radius: base radius of the pose gate [m].
        local_sigmas: the gate grows by this many position standard deviations.
        prior_max_sigma: while the query's position standard deviation exceeds this
            [m], its pose estimate is no prior: the pose search proposes nothing and
            every appearance candidate is checked as one outside the gate (a gate of
            ``local_radius + local_sigmas * sigma`` would then cover much of the map,
            and each check from such a loose prior is a wide multi-start search).
        local_max: candidates proposed per query by the pose search.
        global_every: ask the place database every this many keyframes (1: at every
            keyframe; 0: never, as ``search = pose``).
        min_score: fused place-recognition score an appearance candidate needs, in
            [0, 1].
        min_score_across: ... when it lies in another frame (a session not joined yet:
            its loops join the sessions only when several agree, so the score need not
            guard each one).
        global_verify: appearance candidates checked per query (distinct places,
            best fused score first).  A revisit's place may rank below a few
            look-alikes; every check costs 5-10 ms, so a budget, not a filter.
        place_separation: two candidates closer than this in the map are one place,
            checked once [m] (half of `max_distance`: the check of one searches the
            query within `max_distance` of it, so a neighbour farther away may be
            the revisit the first is not).
        prefilter_first: the query's own-view matches (view 0) of prefilter rank below
            this are always among the `global_verify` places checked, whatever their
            fused score: a place the fused ranking leaves out takes the budget's last
            slot (`LoopClosureDetector.places`).  The prefilter's first place is often
            the revisit when the verifiers disagree with it (a fused score near 0);
            with ``viewpoint_order = interleave`` the first ranks are the first
            places of the interleaved lists (one per list).  0: none.
        agree_distance: two candidates checked with no prior that are both accepted
            for one query must put the query within this of each other in the map
            [m]; else the query is ambiguous (a look-alike of one of the places) and
            both are rejected.
        free_every: check any appearance candidate outside the pose gate (no prior)
            every this many keyframes without an accepted loop (1: at every keyframe;
            0: only those the previous keyframe supports).
        sequence_keyframes: an appearance candidate outside the gate is supported when
            each of this many previous keyframes' appearance searches proposed ...
            (0: no candidate is supported)
        sequence_keys: ... a keyframe at most this many keys per step back from it,
        sequence_places: ... among its this many best distinct places (each query
            proposes up to `global_verify`; the more of them count, the more often a
            look-alike is supported by chance and checked in vain).
        max_loops: accepted loops per query at most.
        joined_keyframes: W > 0: a candidate inside the pose gate is not checked when
            a loop accepted from a prior at one of the query's W previous keyframes
            joins a keyframe within W keys of it: the two passes are already tied
            together there, the query by that loop and its odometry, the candidate
            by its neighbour, and its check would add a loop through largely the
            same submap points (consecutive keyframes' submaps share most of them).
            Along a revisit about one keyframe in W + 1 is then checked.  The query
            counts as anchored (no check without a prior in its frame).  0 (the
            default): every candidate is checked.
        circle_fallback: when no place checked with no prior was accepted for a
            query, at most this many of them, rejected for their fit, are checked
            again over the whole circle of headings instead of their heading
            hypotheses (`LoopClosureDetector._circle_fallback`; 0: never, the
            default).  Each re-check costs about as much as a check and nearly every
            query without a revisit pays for them, while the revisits they recover
            (a true place whose hypotheses all missed its heading, often ranked
            below several look-alikes) are a fraction of a percent of the real
            logs' revisits: off unless asked for.
        trail_radius: an appearance query also counts the place database's answers to
            the keyframes of its trail (its session's last `trail_keyframes`
            keyframes) whose map position lies within this of its own [m]: the place
            seen from nearby viewpoints on the way in (0: none; `with_trail`).
        trail_keyframes: ... at most this many keyframes back.
        virtual_beams: beams of the 360-degree virtual scan describing a keyframe.
        virtual_range: range of that virtual scan [m].
        full_circle_deg: a sensor covering at least this is described by its own scan.
        wide_keyframes: keyframes of path behind a keyframe in its wide view (a second
            description of a narrower sensor's keyframe, from the host's
            ``trailing_map``; 0: none).
        wide_every: a keyframe gets a wide view when the latest one of its session is
            this many keyframes old (1: every keyframe); the others query with it.
        view_calibration: how the wide view's fused scores are made: ``shared`` (the
            database's logistic, as the own view's) or ``per-view`` (the logistic
            fitted on wide views, `loopclosure.place_config.WIDE_LOGISTIC`, so that a
            query's two views are merged by comparable probabilities; needs the
            default stages and logistic fusion).
        viewpoints: offset viewpoints a keyframe described from a virtual scan of its
            submap is also described from, for the prefilter (`loopclosure.viewpoints`;
            no radii: none).
        target_cache: registration targets (KD-tree + normals) kept in memory.
        database: the place database (prefilter, verifiers, fusion).
        check: the geometric check.
        polygon: the scan -> polygon rule.
    """

    exclude_recent: int = 30
    exclude_recent_s: float = 20.0
    max_distance: float = 2.0
    search: str = "both"
    local_radius: float = 1.5
    local_sigmas: float = 3.0
    prior_max_sigma: float = 1.5
    local_max: int = 2
    global_every: int = 1
    min_score: float = 0.5
    min_score_across: float = 0.0
    global_verify: int = 8
    place_separation: float = 1.0
    prefilter_first: int = 0
    agree_distance: float = 1.0
    free_every: int = 10
    sequence_keyframes: int = 2
    sequence_keys: int = 3
    sequence_places: int = 1
    max_loops: int = 2
    joined_keyframes: int = 0
    circle_fallback: int = 0
    trail_radius: float = 1.5
    trail_keyframes: int = 10
    virtual_beams: int = 360
    virtual_range: float = 20.0
    full_circle_deg: float = 359.0
    wide_keyframes: int = 30
    wide_every: int = 3
    view_calibration: str = "shared"
    target_cache: int = 256
    viewpoints: ViewpointConfig = field(default_factory=ViewpointConfig)
    database: PlaceDatabaseConfig = field(default_factory=PlaceDatabaseConfig)
    check: GeometricCheckConfig = field(default_factory=GeometricCheckConfig)
    polygon: PolygonConfig = field(default_factory=PolygonConfig)

    def __post_init__(self) -> None:
        if self.search not in SEARCHES:
            raise UserError(
                f"loops.search must be one of {', '.join(SEARCHES)}, got {self.search!r}"
            )
        if not self.place_separation >= 0:
            raise UserError(
                f"loops.place_separation must be >= 0 m, got {self.place_separation}")
        if not 0 <= self.prefilter_first <= self.global_verify:
            raise UserError(f"loops.prefilter_first must be in 0..global_verify "
                            f"({self.global_verify}), got {self.prefilter_first}")
        if self.sequence_places < 1:
            raise UserError(f"loops.sequence_places must be >= 1, got {self.sequence_places}")
        if not self.agree_distance > 0:
            raise UserError(f"loops.agree_distance must be > 0 m, got {self.agree_distance}")
        if self.wide_keyframes < 0:
            raise UserError(f"loops.wide_keyframes must be >= 0, got {self.wide_keyframes}")
        if self.wide_every < 1:
            raise UserError(f"loops.wide_every must be >= 1, got {self.wide_every}")
        if self.view_calibration not in VIEW_CALIBRATIONS:
            raise UserError(f"loops.view_calibration must be one of "
                            f"{', '.join(VIEW_CALIBRATIONS)}, got {self.view_calibration!r}")
        if self.view_calibration == "per-view" and (
                self.database.resolved_fusion != "logistic"
                or sorted(self.database.stages) != sorted(WIDE_LOGISTIC.names)):
            raise UserError(
                "loops.view_calibration per-view needs logistic fusion of the stages "
                f"{', '.join(WIDE_LOGISTIC.names)} (the wide view's model is fitted for "
                f"those); the database has {self.database.resolved_fusion} fusion of "
                f"{', '.join(self.database.stages)}")
        if self.joined_keyframes < 0:
            raise UserError(f"loops.joined_keyframes must be >= 0, got {self.joined_keyframes}")
        if self.circle_fallback < 0:
            raise UserError(f"loops.circle_fallback must be >= 0, got {self.circle_fallback}")
        if not self.trail_radius >= 0 or self.trail_keyframes < 0:
            raise UserError("loops.trail_radius must be >= 0 m and loops.trail_keyframes "
                            f">= 0, got {self.trail_radius} and {self.trail_keyframes}")
        if not self.prior_max_sigma > 0:
            raise UserError(
                f"loops.prior_max_sigma must be > 0 m, got {self.prior_max_sigma}")

    @property
    def wide_database(self) -> PlaceDatabaseConfig:
        """The configuration of the wide view's database: `database`, with the wide
        view's logistic model when `view_calibration` is ``per-view``."""
        if self.view_calibration == "per-view":
            return replace(self.database, logistic=WIDE_LOGISTIC)
        return self.database
