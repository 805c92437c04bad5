"""The plugin's main object: feed keyframes, get verified loop closures.

`LoopClosureDetector` owns the place database and the geometric check.

The host's side
---------------
A host (our `slam.pipeline`, or anybody's mapper) hands the detector its keyframes'
local maps through one callback and, if those maps change, their version:

- ``submap(key) -> points``: the local map of keyframe `key`, ``(N, 2)`` points [m]
  in its sensor frame (the keyframe's own scan points will do).  The detector asks
  for it whenever it needs it: to describe a keyframe whose sensor covers less than
  a full circle (at `add_keyframe`, so it then holds what the host has so far), for
  the query of every `detect`, and to verify a candidate.
- ``submap_version(key) -> version`` (optional): any value, compared with ``==``,
  that the host changes whenever ``submap(key)`` would return other points (e.g. the
  newest keyframe its submap includes, or a counter).  The detector caches the
  registration targets (KD-tree + normals) of recent candidates and rebuilds one
  only when its version changed.  Without it, submaps are taken to be fixed: each
  is built into a target once (until it drops out of the `target_cache`).
- ``trailing_map(key, n) -> points`` (optional): the points of keyframes
  ``key - n .. key`` (those that exist) in keyframe `key`'s sensor frame, ``(N, 2)``
  [m]: the map the robot built on its way to `key`.  With it, a keyframe whose
  sensor covers less than a full circle gets a second, *wide* description (see 1.).

and calls, for every keyframe:

1. ``add_keyframe(key, stamp, scan)`` (keys 0, 1, 2, ... in order): the keyframe is
   described once (a 360-degree polygon: its own scan when the sensor covers the
   full circle, else a virtual scan of ``submap(key)``, see
   `loopclosure.virtual_scan`) and stored in the place database.  With a
   ``trailing_map`` and `wide_keyframes` > 0, a narrower sensor's keyframe is also
   described from a virtual scan of ``trailing_map(key, wide_keyframes)``, in a
   second database of the same configuration (the *wide view*), every
   `wide_every` keyframes (the keyframes between, a few decimetres apart, query with
   the latest one's wide view: its heading hypotheses turned and its centroid moved
   into the query's frame by the two keyframes' relative pose estimate; a third of
   the description cost for nearly all of the gain).  Why two views: a
   submap of a few metres of path holds little of what lies behind a 180-degree
   laser, so a revisit from elsewhere in the place, or at another heading, shares
   little of it; a longer stretch of path fills the view in, but with parts of the
   path that another visit need not share (the way the robot came).  Which one
   carries a revisit depends on the two paths, so both are asked and the better
   match counts (`query_places`);
2. ``detect(key, poses, covariance)`` with the host's current pose estimates of all
   keyframes so far (any added key may be queried, in any order; the pipeline asks
   right after adding it).  Two searches propose candidates (``search``: ``both``,
   ``appearance`` or ``pose``), and the geometric check
   (`loopclosure.geometric_check.verify`) judges each on the submaps:

   - **appearance** (every `global_every` keyframes): the place database's cascade
     (prefilter over every older keyframe, verifier on the top K, fused score):
     candidates with a fused score of at least `min_score`, the best `global_verify`
     of them, one per place (more than `place_separation` apart in the map); the
     answers of the query's trail (its last keyframes within `trail_radius` of it,
     `with_trail`) count as well;
   - **pose** (pose-gated, not in ``appearance`` mode): older keyframes whose
     estimated position lies within the gate ``local_radius + local_sigmas * sigma``
     of the query (sigma: the largest standard deviation of the query's position
     from `covariance`), nearest first, at most `local_max`.  While sigma exceeds
     `prior_max_sigma` the gate is empty: the pose search proposes nothing and every
     candidate is outside the gate (a gate that wide covers much of the map, and a
     prior that loose makes each check a wide search: the check with no prior is
     cheaper and no weaker).

   A candidate inside the pose gate is checked from the predicted relative pose (the
   prior); one outside it (a revisit the odometry cannot explain: large drift, a
   kidnap, an unknown start) from the database's heading hypotheses
   (`loopclosure.headings`) at a centroid-aligned translation and at zero
   translation (`GeometricCheckConfig.origin_guesses`), with no pose prior.  When
   none of a query's candidates checked so is accepted, the first `circle_fallback`
   of them rejected for their fit are checked again over the whole circle of
   headings (the hypotheses can all miss a revisit's heading; same rules; off by
   default).
   That check is a search (several ICP starts) and on a log with good odometry it
   nearly always meets a look-alike place, so it runs only when no candidate inside
   the gate was accepted for this query (the two would contradict each other), and
   then for a candidate that each of the `sequence_keyframes` previous keyframes'
   appearance searches also proposed as one of its `sequence_places` best places
   (within `sequence_keys` keyframes per step back:
   a true revisit repeats along the path, a look-alike rarely does; the temporal
   consistency of appearance-based loop detectors such as FAB-MAP's), or for any
   candidate every `free_every` keyframes without an accepted loop.  Appearance
   candidates are tried first; a pose candidate already tried, or within 5 keyframes
   of an accepted one (the same place), is skipped, so a loop both searches propose
   is checked once and reported as ``appearance``.  Two candidates outside the gate
   that are both accepted must agree: the map's poses of the two places, each
   composed with its checked relative pose, must put the query within
   `agree_distance` of each other; else both are rejected as ambiguous (a self-similar
   building: the same corridor, seen from the query, fits two places of the map).

   Keyframes newer than `exclude_recent` keyframes or `exclude_recent_s` seconds are
   never candidates (they are odometry's business); the time rule is dropped for the
   rest of the run once two keyframes share a stamp (logs whose stamps are all 0, as
   some corrected Radish logs, would otherwise never close a loop).  A loop closure is
   a revisit: the geometric check rejects a verified relative pose longer than
   `max_distance`.  At most `max_loops` are accepted per query, from either search.

Sessions
--------
Keyframes may come from several logs (sessions) of one place: a host continuing a
saved map adds the saved keyframes first (``add_keyframe(..., session=0,
place_scan=...)``), then the new log's (``session=1``).  A keyframe of another session
is always eligible (recency is a rule within a log), and pose estimates are compared
only between keyframes of the same *frame*: a session starts in a frame of its own
(its odometry's), so the pose search never looks across sessions, and an appearance
candidate from another frame is checked with no prior, as a candidate outside the
gate, whatever the query's own search accepted; it needs only `min_score_across`
(the host joins two sessions on several loops that agree, not on one).  Once the
host has fixed the transform between the two frames from such loops, `join` puts the
session's keyframes into the older frame and the searches treat them as one log
(`detect_pose` then lets the host re-check the keyframes it added before).

A host that restarts keeps, for every keyframe, its stamp, its scan and
`place_scan(key)`, and re-adds them in key order with ``add_keyframe(key, stamp,
scan, session=0, place_scan=saved_place_scan)``: descriptors are a function of the
place scan, so the restored database answers as the old one did.
`slam.pipeline.Mapper` does exactly this with a saved map.

Every candidate tried is returned (accepted or not, with the reason and the figures
of each stage), so the host can report them all (``loops.csv``).

Example (a host whose submaps are the keyframes' own scans, which never change)::

    detector = LoopClosureDetector(submap=lambda key: keyframes[key].points())
    for key, scan in enumerate(keyframes):
        detector.add_keyframe(key, scan.stamp, scan)
        for loop in detector.detect(key, poses[: key + 1]):
            ...  # loop.relative, loop.covariance: a BetweenFactorPose2(match, query)
"""

from __future__ import annotations

import dataclasses
from collections import OrderedDict
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data import se2
from data.errors import UserError
from data.types import Scan
from loopclosure.geometric_check import (
    NOT_A_REVISIT,
    GeometricCheckConfig,
    LoopVerification,
    verify,
)
from loopclosure.key_table import KeyTable
from loopclosure.longer_check import is_degenerate, joined, recheck_longer, trailing_count
from loopclosure.place_config import PlaceDatabaseConfig
from loopclosure.place_database import Descriptors, PlaceDatabase, PlaceMatch
from loopclosure.polygon import DegeneratePolygonError, PolygonConfig, polygon_from_scan
from loopclosure.registration import RegistrationTarget
from loopclosure.virtual_scan import virtual_scan

Array = NDArray[np.float64]
SubmapFn = Callable[[int], ArrayLike]
"""``submap(key) -> (N, 2)`` points of keyframe `key`'s local map, its sensor frame [m]."""
SubmapVersionFn = Callable[[int], Hashable]
"""``submap_version(key) -> version`` of that local map (module docstring)."""
TrailingMapFn = Callable[[int, int], ArrayLike]
"""``trailing_map(key, n) -> (N, 2)`` points of keyframes ``key - n .. key``, `key`'s
sensor frame [m] (module docstring)."""
SEARCHES = ("both", "appearance", "pose")
"""Values of `LoopClosureConfig.search`."""


@dataclass(slots=True)
class LoopClosureConfig:
    """Every parameter of the loop-closure plugin (see the module docstring).

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
    agree_distance: float = 1.0
    free_every: int = 10
    sequence_keyframes: int = 2
    sequence_keys: int = 3
    sequence_places: int = 1
    max_loops: int = 2
    circle_fallback: int = 0
    trail_radius: float = 1.5
    trail_keyframes: int = 10
    virtual_beams: int = 360
    virtual_range: float = 20.0
    full_circle_deg: float = 359.0
    wide_keyframes: int = 30
    wide_every: int = 3
    target_cache: int = 256
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
        if self.sequence_places < 1:
            raise UserError(f"loops.sequence_places must be >= 1, got {self.sequence_places}")
        if not self.agree_distance > 0:
            raise UserError(f"loops.agree_distance must be > 0 m, got {self.agree_distance}")
        if self.wide_keyframes < 0:
            raise UserError(f"loops.wide_keyframes must be >= 0, got {self.wide_keyframes}")
        if self.wide_every < 1:
            raise UserError(f"loops.wide_every must be >= 1, got {self.wide_every}")
        if self.circle_fallback < 0:
            raise UserError(f"loops.circle_fallback must be >= 0, got {self.circle_fallback}")
        if not self.trail_radius >= 0 or self.trail_keyframes < 0:
            raise UserError("loops.trail_radius must be >= 0 m and loops.trail_keyframes "
                            f">= 0, got {self.trail_radius} and {self.trail_keyframes}")
        if not self.prior_max_sigma > 0:
            raise UserError(
                f"loops.prior_max_sigma must be > 0 m, got {self.prior_max_sigma}")



@dataclass(slots=True)
class LoopCandidate:
    """One candidate of one query, verified or rejected.

    Attributes:
        query: the new keyframe's key.
        match: the older keyframe's key.
        source: the search that proposed it: ``"pose"`` (pose-gated) or
            ``"appearance"`` (the place database; also when both proposed it).
        accepted: the geometric check accepted it.
        reason: why not (or ``"accepted"``).
        relative: ``(3,)`` pose of the query keyframe in the match's frame.
        covariance: ``3x3`` covariance of `relative` (floored).
        verification: the full geometric-check result.
        predicted_distance: distance [m] between the two keyframes' current estimates.
        prior: the check started from the predicted relative pose (the candidate lay
            inside the pose gate); else from the database's heading hypotheses.
        prefilter_distance: appearance: combined normalised prefilter distance
            (unitless; NaN for pose candidates).
        prefilter_rank: appearance: 0-based rank by prefilter distance (-1 for pose).
        fused_score: appearance: fused place-recognition score in [0, 1] (NaN for
            pose candidates).
        verifier_distances: appearance: each verifier's distance, by matcher name, in
            that matcher's unit (empty for pose candidates).
    """

    query: int
    match: int
    source: str
    accepted: bool
    reason: str
    relative: Array
    covariance: Array
    verification: LoopVerification | None = None
    predicted_distance: float = float("nan")
    prior: bool = False
    prefilter_distance: float = float("nan")
    prefilter_rank: int = -1
    fused_score: float = float("nan")
    verifier_distances: dict[str, float] = field(default_factory=dict)

    @classmethod
    def checked(
        cls,
        query: int,
        match: int,
        source: str,
        result: LoopVerification,
        *,
        predicted_distance: float = float("nan"),
        prior: bool = False,
        prefilter_distance: float = float("nan"),
        prefilter_rank: int = -1,
        fused_score: float = float("nan"),
        verifier_distances: dict[str, float] | None = None,
    ) -> LoopCandidate:
        """The candidate as the geometric check judged it, with its search's figures."""
        return cls(
            query=query, match=match, source=source, accepted=result.accepted,
            reason=result.reason, relative=result.relative, covariance=result.covariance,
            verification=result, predicted_distance=predicted_distance, prior=prior,
            prefilter_distance=prefilter_distance, prefilter_rank=prefilter_rank,
            fused_score=fused_score, verifier_distances=dict(verifier_distances or {}),
        )


@dataclass(slots=True)
class KeyframePlace:
    """A keyframe's place as `LoopClosureDetector.describe_keyframe` made it.

    Attributes:
        place_scan: the 360-degree scan the place was described from (its own scan
            or the virtual scan of its submap).
        centroid: ``(2,)`` centroid of its polygon [m, sensor frame]; None (and no
            descriptors) when no polygon could be made.
        descriptors: the place database's descriptors of the polygon.
        wide_key: the keyframe whose wide view it queries with (-1: none).
        wide_centroid, wide_descriptors: its own wide view, when `wide_key` is itself.
    """

    place_scan: Scan
    centroid: Array | None = None
    descriptors: Descriptors | None = None
    wide_key: int = -1
    wide_centroid: Array | None = None
    wide_descriptors: Descriptors | None = None


class LoopClosureDetector:
    """Place database + geometric check behind one call per keyframe (module docstring)."""

    def __init__(
        self,
        config: LoopClosureConfig | None = None,
        submap: SubmapFn | None = None,
        submap_version: SubmapVersionFn | None = None,
        trailing_map: TrailingMapFn | None = None,
    ):
        self.config = config or LoopClosureConfig()
        self.database = PlaceDatabase(self.config.database)
        self._submap = submap
        self._submap_version = submap_version
        self._trailing_map = trailing_map
        # The wide view (module docstring, 1.): its database and place centroids.
        self.wide_database: PlaceDatabase | None = (
            PlaceDatabase(self.config.database, matchers=self.database.matchers)
            if trailing_map is not None and self.config.wide_keyframes > 0 else None)
        self._wide_centroids: dict[int, Array] = {}
        self._wide_keys: list[int] = []  # key -> the key whose wide view it queries with
        self._wide_described = np.zeros(0, np.int64)  # keys with a wide view, in order
        # key -> stamp, session, frame its pose estimates are given in (module
        # docstring, "Sessions"), described: arrays that grow in place.
        self._table = KeyTable()
        self._clock = True  # stamps tell time (see `eligible`)
        self._centroids: list[Array] = []
        # key -> (submap version it was built from, target), least recently used first.
        self._targets: OrderedDict[int, tuple[Hashable, RegistrationTarget]] = OrderedDict()
        self._since_global = 0
        self._since_free = 0  # keyframes since a prior-free check or an accepted loop
        self._proposed: dict[int, NDArray[np.int64]] = {}  # key -> appearance proposals
        self._answers: dict[int, list[PlaceMatch]] = {}  # key -> its own views' matches
        self._trails: dict[int, list[int]] = {}  # key -> the trail keys it queried with
        self._place_scans: list[Scan | None] = []

    # -- keyframes -------------------------------------------------------------------

    def add_keyframe(
        self, key: int, stamp: float, scan: Scan, *, session: int = 0,
        place_scan: Scan | None = None, place: KeyframePlace | None = None,
    ) -> bool:
        """Describe and store keyframe `key` (keys are 0, 1, 2, ... in order).

        A sensor covering less than `full_circle_deg` is described by a virtual scan
        of ``submap(key)`` (its own scan when there is no `submap` callback).
        `place_scan` describes it from that scan instead (the `place_scan` of a
        keyframe restored from a saved map).  `place` stores a description already
        made by `describe_keyframe` (in another process, on the same keyframes).
        `session` labels the log the keyframe comes from (module docstring,
        "Sessions"); its frame starts as the session's own.

        Returns False when no polygon could be made (all beams invalid, a degenerate
        local map): the keyframe is then never a candidate, but keys stay aligned.

        Raises:
            UserError: `key` is not the next key.
        """
        if key != len(self._stamps):
            raise UserError(
                f"add_keyframe: keyframes must be added in order 0, 1, 2, ...: expected key "
                f"{len(self._stamps)}, got {key}"
            )
        if place is None:
            place = self.describe_keyframe(key, stamp, scan, session=session,
                                           place_scan=place_scan)
        if (len(self._table) and self._sessions[-1] == session
                and float(stamp) == self._stamps[-1]):
            self._clock = False  # repeated stamps (e.g. all 0): time says nothing
        self._table.append(float(stamp), int(session), place.descriptors is not None)
        self._place_scans.append(place.place_scan)
        self._wide_keys.append(place.wide_key)
        if place.wide_descriptors is not None:
            assert self.wide_database is not None and place.wide_centroid is not None
            self._wide_centroids[key] = place.wide_centroid
            self._wide_described = np.append(self._wide_described, key)
            self.wide_database.add_descriptors(key, place.wide_descriptors, stamp=stamp)
        if place.descriptors is None:
            self._centroids.append(np.zeros(2))
            return False
        self._centroids.append(place.centroid)
        self.database.add_descriptors(key, place.descriptors, stamp=stamp)
        return True

    def describe_keyframe(
        self, key: int, stamp: float, scan: Scan, *, session: int = 0,
        place_scan: Scan | None = None,
    ) -> KeyframePlace:
        """The description `add_keyframe(key, ...)` stores, made without storing it:
        it reads only keys before `key` and the `submap` / `trailing_map` callbacks."""
        cfg = self.config
        if place_scan is None:
            if np.degrees(scan.fov) >= cfg.full_circle_deg or self._submap is None:
                place_scan = scan
            else:
                pts = self._submap_points(key)
                place_scan = virtual_scan(pts, cfg.virtual_beams, cfg.virtual_range, stamp=stamp)
        place = KeyframePlace(place_scan)
        try:
            polygon = polygon_from_scan(place_scan, cfg.polygon)
        except DegeneratePolygonError:
            return place
        place.centroid = polygon.centroid()
        place.descriptors = self.database.describe(polygon)
        if self.wide_database is not None and np.degrees(scan.fov) < cfg.full_circle_deg:
            self._describe_wide(key, stamp, session, place)
        return place

    def _describe_wide(self, key: int, stamp: float, session: int, place: KeyframePlace) -> None:
        """The key whose wide view `key` queries with (module docstring, 1.): the latest
        one of its session while it is less than `wide_every` keyframes old, else `key`
        itself, described now (-1 when that makes no polygon)."""
        assert self._trailing_map is not None and self.wide_database is not None
        cfg = self.config
        latest = self._wide_keys[key - 1] if key > 0 else -1
        if latest >= 0 and key - latest < cfg.wide_every and self._sessions[latest] == session:
            place.wide_key = latest
            return
        pts = np.asarray(self._trailing_map(key, cfg.wide_keyframes), float).reshape(-1, 2)
        wide = virtual_scan(pts, cfg.virtual_beams, cfg.virtual_range, stamp=stamp)
        try:
            polygon = polygon_from_scan(wide, cfg.polygon)
        except DegeneratePolygonError:
            return
        place.wide_key = key
        place.wide_centroid = polygon.centroid()
        place.wide_descriptors = self.wide_database.describe(polygon)

    def wide_key(self, key: int) -> int | None:
        """The keyframe whose wide view `key` queries with (itself or a few keyframes
        older), None without one."""
        self._check_key(key)
        return self._wide_keys[key] if self._wide_keys[key] >= 0 else None

    def place_scan(self, key: int) -> Scan | None:
        """The 360-degree scan keyframe `key`'s place was described from (its own scan
        or the virtual scan of its submap; what a saved map stores)."""
        self._check_key(key)
        return self._place_scans[key]

    def join(self, session: int, frame: int) -> None:
        """From now on the pose estimates of `session`'s keyframes are given in `frame`
        (the frame of an older session it was joined to: module docstring)."""
        self._frames[self._sessions == session] = int(frame)

    def frame(self, key: int) -> int:
        """The frame keyframe `key`'s pose estimates are given in."""
        self._check_key(key)
        return int(self._frames[key])

    def release_caches(self) -> None:
        """Drop the cached registration targets of the submaps (rebuilt on demand):
        for a host about to need the memory, e.g. for its final optimisation."""
        self._targets.clear()

    def _target(self, key: int) -> RegistrationTarget:
        """The registration target of `key`'s submap, rebuilt when its version changed."""
        version = None if self._submap_version is None else self._submap_version(key)
        cached = self._targets.get(key)
        if cached is not None and cached[0] == version:
            self._targets.move_to_end(key)
            return cached[1]
        normals = None
        if self.config.check.compiled_icp:
            from loopclosure.fast_icp import estimate_normals_fast as normals  # numba

        target = RegistrationTarget(self._submap_points(key), self.config.check.icp,
                                    normals=normals)
        self._targets[key] = (version, target)
        self._targets.move_to_end(key)
        while len(self._targets) > self.config.target_cache:
            self._targets.popitem(last=False)
        return target

    def _submap_points(self, key: int) -> Array:
        if self._submap is None:
            raise UserError(
                "LoopClosureDetector needs a submap callback to verify loops: pass "
                "submap=lambda key: <(N, 2) points of keyframe key in its sensor frame>"
            )
        return np.asarray(self._submap(key), dtype=float).reshape(-1, 2)

    # -- detection -------------------------------------------------------------------

    def eligible(self, key: int) -> NDArray[np.bool_]:
        """Boolean mask over keys ``0..key-1`` of keyframes old enough to be candidates
        (every keyframe of another session is)."""
        self._check_key(key)
        cfg = self.config
        ok = np.arange(key) < key - cfg.exclude_recent
        if self._clock:
            ok &= np.abs(self._stamps[:key] - self._stamps[key]) >= cfg.exclude_recent_s
        ok |= self._sessions[:key] != self._sessions[key]
        return ok & self._described[:key]

    @property
    def _stamps(self) -> Array:
        return self._table.stamps

    @property
    def _sessions(self) -> NDArray[np.int64]:
        return self._table.sessions

    @property
    def _frames(self) -> NDArray[np.int64]:
        return self._table.frames

    @property
    def _described(self) -> NDArray[np.bool_]:
        return self._table.described

    def _check_key(self, key: int) -> None:
        if not 0 <= key < len(self._stamps):
            raise UserError(
                f"keyframe {key} was never added (added: 0..{len(self._stamps) - 1})"
            )

    def detect(
        self, key: int, poses: ArrayLike, covariance: ArrayLike | None = None,
        matches: list[PlaceMatch] | None = None,
    ) -> list[LoopCandidate]:
        """Candidates of keyframe `key`, each verified (see the module docstring).

        Args:
            key: the query (any added keyframe).
            poses: ``(n, 3)`` current estimates of keyframes ``0..n-1`` (map frame),
                ``n > key``.
            covariance: ``3x3`` marginal covariance of the query's pose, or None.
            matches: `appearance_matches(key)` when already made (in another process,
                on the same keyframes); None: asked here when needed.

        Raises:
            UserError: `key` was never added, or `poses` does not reach it.
        """
        cfg = self.config
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        eligible = self.eligible(key)
        if len(poses) <= key:
            raise UserError(f"detect: poses has {len(poses)} rows, keyframe {key} needs {key + 1}")
        if not eligible.any() or not self._described[key]:
            return []
        cov, sigma, gate = self._gate(covariance)
        query_points = self._submap_points(key)
        appearance = self._appearance(key, eligible, poses, matches)
        # Pose estimates comparable with the query's:
        same = self._frames[: len(eligible)] == self._frames[key]
        pose = [] if cfg.search == "appearance" else self._local(
            key, poses, eligible & same, gate)
        out: list[LoopCandidate] = []
        self._since_free += 1

        def gated(k: int) -> bool:
            return bool(same[k]) and self._distance(poses, k, key) <= gate

        # Inside the gate, appearance first; a pose candidate already tried, or within
        # 5 keyframes of an accepted one (that place is closed), is skipped.
        inside = [(int(m.key), m) for m in appearance if gated(int(m.key))] + [
            (k, None) for k in pose]
        for k, m in inside:
            if sum(c.accepted for c in out) >= cfg.max_loops:
                break
            if m is None and any(c.match == k or (c.accepted and abs(c.match - k) <= 5)
                                 for c in out):
                continue
            out.append(self._check_prior(key, k, m, poses, cov, sigma, query_points))
        anchored = any(c.accepted for c in out)
        if anchored:
            self._since_free = 0
        # Outside the gate: in the query's frame only when the pose is not anchored (a
        # place outside the gate would contradict the accepted one); in another frame
        # (a session not joined yet) always, the two frames being unrelated.
        free = [m for m in appearance if not gated(int(m.key))
                and not (anchored and same[int(m.key)])]
        if not (0 < cfg.free_every <= self._since_free):
            free = [m for m in free if self._supported(key, int(m.key))]
        if not free:
            return out
        self._since_free = 0
        return out + self._verify_free(key, free, query_points, poses,
                                       cfg.max_loops - sum(c.accepted for c in out))

    def detect_pose(
        self, key: int, poses: ArrayLike, covariance: ArrayLike | None = None,
        below: int | None = None,
    ) -> list[LoopCandidate]:
        """The pose-gated search alone for keyframe `key`: candidates in its frame
        within the gate (of keys below `below` when given), each checked from the
        predicted relative pose.  No appearance query, no counters: for a host that
        has just put keyframes into a frame where they meet older ones (a session
        joined to a saved map: its keyframes from before the join)."""
        cfg = self.config
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        eligible = self.eligible(key)
        if below is not None:
            eligible[below:] = False
        if not eligible.any() or not self._described[key]:
            return []
        cov, sigma, gate = self._gate(covariance)
        same = self._frames[: len(eligible)] == self._frames[key]
        out: list[LoopCandidate] = []
        query_points = self._submap_points(key)
        for k in self._local(key, poses, eligible & same, gate):
            if sum(c.accepted for c in out) >= cfg.max_loops:
                break
            out.append(self._check_prior(key, k, None, poses, cov, sigma, query_points))
        return out

    def _gate(self, covariance: ArrayLike | None) -> tuple[Array | None, float, float]:
        """``(covariance, sigma, gate)``: the query's covariance as an array (or None),
        the largest standard deviation of its position [m] and the pose gate's radius
        ``local_radius + local_sigmas * sigma`` [m], or ``-inf`` (no keyframe is
        inside) when ``sigma > prior_max_sigma``: the pose estimate is then no prior."""
        cfg = self.config
        cov = None if covariance is None else np.asarray(covariance, dtype=float)
        sigma = 0.0 if cov is None else float(np.sqrt(max(np.linalg.eigvalsh(cov[:2, :2]))))
        if sigma > cfg.prior_max_sigma:
            return cov, sigma, -np.inf
        return cov, sigma, cfg.local_radius + cfg.local_sigmas * sigma

    def _supported(self, key: int, match: int) -> bool:
        """The appearance searches of the `sequence_keyframes` keyframes before `key`
        each proposed a keyframe near `match` (module docstring)."""
        cfg = self.config
        if cfg.sequence_keyframes <= 0:
            return False
        empty = np.zeros(0, dtype=np.int64)
        return all(
            np.any(np.abs(self._proposed.get(key - j, empty) - match) <= cfg.sequence_keys * j)
            for j in range(1, cfg.sequence_keyframes + 1)
        )

    @staticmethod
    def _distance(poses: Array, a: int, b: int) -> float:
        return float(np.hypot(*(poses[a, :2] - poses[b, :2])))

    def views(self, key: int) -> list[tuple[PlaceDatabase, int]]:
        """``(database, key it is asked with)`` of every description `key` queries with:
        the database and `key`, then the wide view's with `wide_key(key)` when there
        is one, then the database and each keyframe of its trail (`with_trail`; a
        view's index is `PlaceMatch.view`)."""
        return self._own_views(key) + [(self.database, t) for t in self._trails.get(key, [])]

    def _own_views(self, key: int) -> list[tuple[PlaceDatabase, int]]:
        """`views` of `key`'s own descriptions: the database's, the wide view's."""
        out = [(self.database, key)] if key in self.database else []
        wide = self.wide_key(key)
        if self.wide_database is not None and wide is not None:
            out.append((self.wide_database, wide))
        return out

    def query_places(
        self, key: int, allowed: ArrayLike | None = None, *, headings: bool = False
    ) -> list[PlaceMatch]:
        """The place database's matches of keyframe `key` over the `allowed` keys
        (None: all), every view asked with its description of `key` (`views`): the union
        by decreasing fused score, one match per stored keyframe (its best view's).
        Heading hypotheses only with `headings` (`_verify_free` adds them for the
        candidates it checks)."""
        if allowed is not None:
            allowed = np.asarray(allowed, dtype=np.int64).ravel()
        per_view = []
        for db, asked in self._own_views(key):
            if db is not self.wide_database:
                per_view.append(db.query(db.descriptors(asked), allowed=allowed,
                                         headings=headings))
                continue
            keys = allowed
            if allowed is not None:  # the wide database holds some keys only
                keys = allowed[np.isin(allowed, self._wide_described)]
            # Keyframes sharing a wide view ask it again: `query_stored` reuses the
            # last answer and queries only the keys allowed since.
            per_view.append(db.query(db.descriptors(asked), allowed=keys, headings=True)
                            if headings else db.query_stored(asked, allowed=keys))
        return merge_views(per_view)

    def places(self, matches: Sequence[PlaceMatch], poses: ArrayLike) -> list[PlaceMatch]:
        """The places the global search checks among `matches` (best fused score
        first): the first `global_verify` distinct places among the prefilter's K best
        of their view (``prefilter_rank < top_k``), then the grids' extras
        (`PlaceDatabaseConfig.grid_extra`) that are places distinct from those; a
        match within `place_separation` of one taken in the map (`poses` ``(n, 3)``,
        keyframes ``0..n-1``) being the same place.

        The extras come after the K's places, whatever their fused score: the fused
        score (pairs and FLIRT) does not see the layout that made the grids choose an
        extra, so a wrong extra can outscore the K's true place of a corridor
        look-alike and take its slot; so ordered, the extras only add checks, made
        when the K's places were not enough."""
        cfg = self.config
        xy = np.asarray(poses, dtype=float).reshape(-1, 3)[:, :2]
        top_k = [db.config.top_k for db in (self.database, self.wide_database)
                 if db is not None]  # per view

        def in_k(m: PlaceMatch) -> bool:
            return m.prefilter_rank < top_k[min(m.view, len(top_k) - 1)]

        taken = distinct_places([m for m in matches if in_k(m)], cfg.global_verify, xy,
                                self._frames, cfg.place_separation)
        extras = [m for m in matches if not in_k(m)]
        if not extras:
            return taken
        return distinct_places([*taken, *extras], len(taken) + len(extras), xy,
                               self._frames, cfg.place_separation)

    def appearance_matches(self, key: int) -> list[PlaceMatch]:
        """The place database's matches of `key` over its eligible keyframes, as
        `detect` asks for them (empty where it would not ask).  They depend on the
        keyframes' descriptions and stamps only, not on any pose estimate."""
        cfg = self.config
        eligible = self.eligible(key)
        if (cfg.search == "pose" or cfg.global_every <= 0 or not eligible.any()
                or not self._described[key]):
            return []
        # Heading hypotheses only for the candidates checked with no prior
        # (`_verify_free`): one checked from the pose prior needs none.
        return self.query_places(key, np.flatnonzero(eligible))

    def _appearance(
        self, key: int, eligible: NDArray[np.bool_], poses: Array,
        matches: list[PlaceMatch] | None = None,
    ) -> list[PlaceMatch]:
        """The place database's proposals for `key` (empty when it is not asked)."""
        cfg = self.config
        if cfg.search == "pose" or cfg.global_every <= 0:
            return []
        self._since_global += 1
        if self._since_global < cfg.global_every:
            return []
        self._since_global = 0
        if matches is None:
            matches = self.query_places(key, np.flatnonzero(eligible))
        frame = self._frames[key]

        def scored(found: list[PlaceMatch]) -> list[PlaceMatch]:
            return [m for m in found
                    if m.score >= (cfg.min_score_across if self._frames[int(m.key)] != frame
                                   else cfg.min_score)]

        # The sequence support counts what each keyframe's own views proposed: its
        # trail shares its neighbours' answers, which must not support themselves.
        own = self.places(scored(matches), poses)
        self._proposed[key] = np.array([int(m.key) for m in own[: cfg.sequence_places]],
                                       dtype=np.int64)
        self._answers[key] = matches
        for old in [k for k in self._answers if k < key - cfg.trail_keyframes]:
            del self._answers[old]
        trailed = self.with_trail(key, matches, poses, self._answers, np.flatnonzero(eligible))
        return own if trailed is matches else self.places(scored(trailed), poses)

    def with_trail(
        self, key: int, matches: list[PlaceMatch], poses: ArrayLike,
        answers: dict[int, list[PlaceMatch]], allowed: ArrayLike | None = None,
    ) -> list[PlaceMatch]:
        """`matches` of keyframe `key` (its own views', `query_places`) joined by the
        answers of its trail: the keyframes ``key - trail_keyframes .. key - 1`` of its
        session and frame whose position in `poses` (``(n, 3)``, the map's) lies
        within `trail_radius` of its own and that have an answer in `answers` (key ->
        that keyframe's own matches, as this call's `matches`).

        A revisit a metre or two from the keyframe it revisits describes the place
        from another viewpoint, and what a virtual scan sees changes with it; the
        keyframes the robot passed on its way to `key` saw the place from nearby
        viewpoints, and one of them often lies nearer the stored keyframe.  Their
        answers (each one's own view: the database and that key) join as views of
        `key` (`views`: indices after its own), each stored keyframe once, as its
        best-scoring match (ties: the query's own first), restricted to `allowed`
        (keys; None: all).  Their checks are `key`'s own (its submap), from the
        heading hypotheses of the trail keyframe's description turned into `key`'s
        frame, as for the wide view.  Returns `matches` itself when no trail
        keyframe counts."""
        cfg = self.config
        self._check_key(key)
        xy = np.asarray(poses, dtype=float).reshape(-1, 3)[:, :2]
        trail = [t for t in range(key - 1, max(key - cfg.trail_keyframes, 0) - 1, -1)
                 if cfg.trail_radius > 0 and t in answers
                 and self._sessions[t] == self._sessions[key]
                 and self._frames[t] == self._frames[key]
                 and float(np.hypot(*(xy[t] - xy[key]))) <= cfg.trail_radius]
        self._trails[key] = trail
        if not trail:
            return matches
        keep = None if allowed is None else set(np.asarray(allowed).ravel().tolist())
        base = len(self._own_views(key))
        joined = list(matches) + [
            dataclasses.replace(m, view=base + i)
            for i, t in enumerate(trail) for m in answers[t]
            if m.view == 0 and (keep is None or int(m.key) in keep)]
        joined.sort(key=lambda m: -m.score)  # stable: the query's own first on ties
        seen: set[Hashable] = set()
        return [m for m in joined if not (m.key in seen or seen.add(m.key))]

    def _local(
        self, key: int, poses: Array, eligible: NDArray[np.bool_], gate: float
    ) -> list[int]:
        """Pose candidates: eligible keyframes within `gate` [m], nearest first, spread."""
        cfg = self.config
        if cfg.local_max <= 0:
            return []
        ids = np.flatnonzero(eligible)
        d = np.hypot(*(poses[ids, :2] - poses[key, :2]).T)
        near = ids[d <= gate]
        order = np.argsort(d[d <= gate], kind="stable")
        chosen: list[int] = []
        for k in near[order]:
            # Spread the candidates: skip keyframes adjacent to one already chosen.
            if all(abs(int(k) - c) > 5 for c in chosen):
                chosen.append(int(k))
            if len(chosen) == cfg.local_max:
                break
        return chosen

    def _check_prior(
        self, key: int, cand: int, match: PlaceMatch | None, poses: Array,
        cov: Array | None, sigma: float, query_points: Array,
    ) -> LoopCandidate:
        """The check of a candidate inside the pose gate, from the predicted pose."""
        cfg = self.config
        prior = se2.between(poses[cand], poses[key])
        prior_cov = None if cov is None else 2.0 * cov
        # A prior good to better than the offset step needs no offset guesses.
        offsets = 0.0 if sigma < 0.5 * cfg.check.offsets else None
        result = verify(
            query_points, self._target(cand), prior=prior, prior_covariance=prior_cov,
            offsets=offsets, max_distance=cfg.max_distance, config=cfg.check,
        )
        distance = float(np.hypot(prior[0], prior[1]))
        if match is None:
            return LoopCandidate.checked(
                key, cand, "pose", result, predicted_distance=distance, prior=True
            )
        return LoopCandidate.checked(
            key, cand, "appearance", result, predicted_distance=distance, prior=True,
            **_place_figures(match),
        )

    def verify_places(
        self, key: int, matches: Sequence[PlaceMatch], poses: ArrayLike,
        query_points: ArrayLike | None = None, allowed: ArrayLike | None = None,
    ) -> list[LoopCandidate]:
        """The geometric checks of several appearance candidates with no pose prior.

        `matches` (a database query's `PlaceMatch` list for keyframe `key`) are checked
        in order, as the global search of `detect` checks them, until `max_loops` are
        accepted, and the accepted ones must agree (`agree_distance`, module
        docstring).  `poses` ``(n, 3)`` are the map's estimates of keyframes
        ``0..n-1`` (the candidates' poses; the query's own is not used).
        `query_points` is the query's submap (``(N, 2)`` [m], its sensor frame;
        default ``submap(key)``).  Each check starts from the match's heading
        hypotheses and a centroid-aligned translation, as for a candidate outside the
        pose gate (and, when none is accepted, the whole-circle re-checks of
        `circle_fallback`).  `allowed` (keys; None: every eligible keyframe) bounds the
        keyframes a check may move to when it finds the query nearer another one
        (`_nearer_place`): a benchmark's keyframes with a reference pose.  For
        benchmarks that judge the appearance search alone (no search, no counters).
        """
        self._check_key(key)
        for m in matches:
            self._check_key(int(m.key))
        pts = self._submap_points(key) if query_points is None else np.asarray(
            query_points, dtype=float).reshape(-1, 2)
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        return self._verify_free(key, list(matches), pts, poses, self.config.max_loops,
                                 allowed)

    def _verify_free(
        self, key: int, matches: list[PlaceMatch], query_points: Array, poses: Array | None,
        budget: int, allowed: ArrayLike | None = None,
    ) -> list[LoopCandidate]:
        """Checks with no prior of `matches`, in order, until `budget` are accepted
        (`allowed`: as `verify_places`); none accepted, the whole-circle re-checks
        (`_circle_fallback`); then accepted candidates in one frame that put the
        query more than `agree_distance` apart (``poses[match] * relative``) are all
        rejected."""
        out: list[LoopCandidate] = []
        checked: list[PlaceMatch] = []
        for m in matches:
            if sum(c.accepted for c in out) >= budget:
                break
            if not m.headings:  # a query made without them (`_appearance`)
                db, asked = self.views(key)[m.view]
                m = db.with_headings(db.descriptors(asked), [m])[0]
            c = self._check_global(key, m, query_points, poses, allowed)
            out.append(c if c.match == int(m.key) else self._same_place(c, out, poses))
            checked.append(m)
        if not any(c.accepted for c in out):
            out = self._circle_fallback(key, checked, out, query_points, poses, budget)
        accepted = [i for i, c in enumerate(out) if c.accepted]
        if poses is None or len(accepted) < 2:
            return out
        implied = {i: se2.compose(poses[out[i].match], out[i].relative)[:2] for i in accepted}
        for i in accepted:
            far = [float(np.hypot(*(implied[i] - implied[j]))) for j in accepted
                   if j != i and self._frames[out[j].match] == self._frames[out[i].match]]
            spread = max(far, default=0.0)
            if spread > self.config.agree_distance:
                out[i] = dataclasses.replace(
                    out[i], accepted=False,
                    reason=f"ambiguous places (another accepted place puts the query "
                           f"{spread:.1f} m away)")
        return out

    def _same_place(self, c: LoopCandidate, before: list[LoopCandidate],
                    poses: Array | None) -> LoopCandidate:
        """`c`, a check that moved to a nearer keyframe (`_nearer_place`), rejected
        when it landed within `place_separation` of a place accepted before it for
        this query: that place is closed (one loop per place; the places chosen for
        checking are distinct, `places`, but a move can join two)."""
        if not c.accepted or poses is None:
            return c
        for b in before:
            if (b.accepted and self._frames[b.match] == self._frames[c.match]
                    and self._distance(poses, b.match, c.match) <= self.config.place_separation):
                return dataclasses.replace(
                    c, accepted=False, reason=f"same place as the accepted keyframe {b.match}")
        return c

    def _circle_fallback(
        self, key: int, matches: list[PlaceMatch], out: list[LoopCandidate],
        query_points: Array, poses: Array | None, budget: int,
    ) -> list[LoopCandidate]:
        """The whole-circle re-checks of a query none of whose `matches` (checked, in
        order, with verdicts `out`) was accepted from its heading hypotheses.

        A place's hypotheses (`loopclosure.headings`) can all miss the heading of a
        revisit (a place seen the other way, a range function dragged by open space):
        the check then searches the wrong headings and fits a wrong pose, or none, at
        the true place.  The first `circle_fallback` places rejected for their fit
        (every verdict but "not a revisit": a check that fitted well but too far
        away has found the query elsewhere, `_nearer_place`) are checked again by
        the same rules with no hypotheses: the correlative search then covers the
        whole circle of headings at its coarse heading step
        (`loopclosure.prior_free`), the ambiguity test included (a runner-up
        anywhere on the circle counts).  An accepted re-check replaces the place's
        verdict; a rejected one leaves it.  Stops once `budget` are accepted.
        Only for the correlative check (``check.method``); the multi-start ICP check
        without hypotheses would start from one heading only."""
        cfg = self.config
        if cfg.circle_fallback <= 0 or cfg.check.method != "correlative":
            return out
        out = list(out)
        tried = accepted = 0
        for i, (m, c) in enumerate(zip(matches, out, strict=True)):
            if tried >= cfg.circle_fallback or accepted >= budget:
                break
            if c.reason.startswith(NOT_A_REVISIT):
                continue
            tried += 1
            cand = int(c.match)
            result = verify(query_points, self._target(cand), headings=None,
                            max_distance=cfg.max_distance, config=cfg.check)
            if result.accepted:
                accepted += 1
                out[i] = LoopCandidate.checked(
                    key, cand, "appearance", result,
                    predicted_distance=c.predicted_distance, **_place_figures(m))
        return out

    def _check_global(
        self, key: int, m: PlaceMatch, query_points: Array, poses: Array | None = None,
        allowed: ArrayLike | None = None,
    ) -> LoopCandidate:
        """The check of an appearance candidate from its heading hypotheses alone."""
        cfg = self.config
        cand = int(m.key)
        # Headings of the query in the candidate's frame (`loopclosure.headings`); align
        # the two places' centroids under the best one.
        headings = [h for h, _ in m.headings] or [0.0]
        # The view's description may be another keyframe's (the wide view of an older
        # one, a trail keyframe): its hypotheses and centroid into the query's frame.
        db, asked = self.views(key)[m.view] if m.view else (self.database, key)
        centroids = self._wide_centroids if db is self.wide_database else self._centroids
        own = centroids[asked]
        if asked != key and poses is not None:
            rel = se2.between(poses[key], poses[asked])  # `asked` in the query's frame
            headings = [h - float(rel[2]) for h in headings]
            own = se2.transform_points(rel, own[None, :])[0]
        c, s = np.cos(headings[0]), np.sin(headings[0])
        rot = np.array([[c, -s], [s, c]])
        translation = centroids[cand] - rot @ own
        result = verify(
            query_points, self._target(cand), headings=headings, translation=translation,
            max_distance=cfg.max_distance, config=cfg.check,
        )
        if self._trailing_map is not None and is_degenerate(result):
            nq, nc = (trailing_count(poses, k, cfg.check) for k in (key, cand))
            if min(nq, nc) > 0:
                result = recheck_longer(  # `loopclosure.longer_check`
                    result, joined(query_points, self._trailing_map(key, nq)),
                    joined(self._submap_points(cand), self._trailing_map(cand, nc)),
                    max_distance=cfg.max_distance, config=cfg.check)
        if result.reason.startswith(NOT_A_REVISIT) and poses is not None:
            cand, result = self._nearer_place(key, cand, result, query_points, poses,
                                              allowed)
        distance = (float("nan") if poses is None or self._frames[cand] != self._frames[key]
                    else self._distance(poses, cand, key))
        return LoopCandidate.checked(
            key, cand, "appearance", result, predicted_distance=distance, **_place_figures(m)
        )

    def _nearer_place(
        self, key: int, cand: int, result: LoopVerification, query_points: Array,
        poses: Array, allowed: ArrayLike | None = None,
    ) -> tuple[int, LoopVerification]:
        """A check that fits the query `result.relative` beyond `max_distance` of
        `cand` has found where the query is: the map's pose of `cand` composed with
        that relative pose.  The eligible keyframe of `cand`'s frame nearest to that
        position, when it lies within `max_distance` of it (a revisit by the map), is
        checked the same way as `cand`, with no prior, its heading hypothesis the
        heading that position implies in its frame (the same search and thresholds:
        a check from that pose as a prior would judge by the stricter fitness of
        a pose-gated ICP); its result, if accepted, replaces `cand`'s.  `allowed`
        (keys, None: all) bounds the keyframes it may move to."""
        cfg = self.config
        at = se2.compose(poses[cand], result.relative)
        eligible = self.eligible(key)
        ids = np.flatnonzero(eligible & self._described[: len(eligible)]
                             & (self._frames[: len(eligible)] == self._frames[cand]))
        if allowed is not None:
            ids = ids[np.isin(ids, np.asarray(allowed, dtype=np.int64))]
        if len(ids) == 0:
            return cand, result
        d = np.hypot(*(poses[ids, :2] - at[:2]).T)
        near = int(ids[np.argmin(d)])
        if near == cand or d.min() > cfg.max_distance:
            return cand, result
        implied = se2.between(poses[near], at)
        second = verify(query_points, self._target(near), headings=[float(implied[2])],
                        translation=implied[:2], max_distance=cfg.max_distance,
                        config=cfg.check)
        return (near, second) if second.accepted else (cand, result)


def merge_views(per_view: Sequence[Sequence[PlaceMatch]]) -> list[PlaceMatch]:
    """One query's matches in several views (databases), as one list: each stored
    keyframe once, as its match with the highest fused score, marked with that view's
    index (`PlaceMatch.view`); by decreasing fused score (ties: the database's own
    order, the first view first)."""
    found = [m if m.view == view else dataclasses.replace(m, view=view)
             for view, matches in enumerate(per_view) for m in matches]
    found.sort(key=lambda m: -m.score)
    seen: set[Hashable] = set()
    return [m for m in found if not (m.key in seen or seen.add(m.key))]


def distinct_places(
    matches: Sequence[PlaceMatch], limit: int, positions: ArrayLike | None = None,
    frames: Sequence[int] | None = None, separation: float = 1.0,
) -> list[PlaceMatch]:
    """The first `limit` of `matches` (best first) that are distinct places.

    With `positions` (``(n, 2)`` map positions of keyframes ``0..n-1`` [m]) a match
    within `separation` [m] of one already taken, in the same frame (`frames`, the
    frame of every key; None: one frame), is the same place and is skipped.  Without
    positions a match within 5 keys of one taken is.  Positions are the better rule:
    on a log with one keyframe per metre, 5 keys span 5 m, and the keyframe next to
    a candidate that is 2.5 m from the query (not a revisit) may be 0.5 m from it.
    """
    if positions is None:
        def same(a: int, b: int) -> bool:
            return abs(a - b) <= 5
    else:
        xy = np.asarray(positions, dtype=float).reshape(-1, 2)

        def same(a: int, b: int) -> bool:
            return ((frames is None or frames[a] == frames[b])
                    and bool(np.hypot(*(xy[a] - xy[b])) <= separation))
    chosen: list[PlaceMatch] = []
    for m in matches:
        if len(chosen) == limit:
            break
        if not any(same(int(m.key), int(c.key)) for c in chosen):
            chosen.append(m)
    return chosen


def _place_figures(m: PlaceMatch) -> dict:
    """The appearance search's figures of one match, as `LoopCandidate` fields."""
    return {
        "prefilter_distance": m.prefilter_distance, "prefilter_rank": m.prefilter_rank,
        "fused_score": m.score, "verifier_distances": m.verifier_distances,
    }
