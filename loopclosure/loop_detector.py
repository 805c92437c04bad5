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
     of them, one per place (more than `place_separation` apart in the map; with
     `prefilter_first`, the own view's first prefilter ranks among them); the
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

The detector is three layers, a module each: the keyframes, their descriptions and
what the place databases answer them (`loopclosure.keyframe_store`); the geometric
checks of candidates (`loopclosure.candidate_checks`); and, here, the two searches and
the choice of what to check.  Its parameters are `loopclosure.loop_config`, its
verdicts `loopclosure.loop_candidate`, the merging of views and the distinct places
`loopclosure.place_choice`.

Example (a host whose submaps are the keyframes' own scans, which never change)::

    detector = LoopClosureDetector(submap=lambda key: keyframes[key].points())
    for key, scan in enumerate(keyframes):
        detector.add_keyframe(key, scan.stamp, scan)
        for loop in detector.detect(key, poses[: key + 1]):
            ...  # loop.relative, loop.covariance: a BetweenFactorPose2(match, query)
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError
from loopclosure.candidate_checks import CandidateChecks
from loopclosure.keyframe_store import KeyframePlace, SubmapFn, SubmapVersionFn, TrailingMapFn
from loopclosure.loop_candidate import LoopCandidate
from loopclosure.loop_config import SEARCHES, LoopClosureConfig
from loopclosure.place_choice import distinct_places, first_per_key, merge_views
from loopclosure.place_match import PlaceMatch

Array = NDArray[np.float64]

_NONE = np.zeros(0, dtype=np.int64)

__all__ = [
    "SEARCHES", "KeyframePlace", "LoopCandidate", "LoopClosureConfig", "LoopClosureDetector",
    "SubmapFn", "SubmapVersionFn", "TrailingMapFn", "distinct_places", "merge_views",
]


class LoopClosureDetector(CandidateChecks):
    """Place database + geometric check behind one call per keyframe (module docstring)."""

    def __init__(
        self,
        config: LoopClosureConfig | None = None,
        submap: SubmapFn | None = None,
        submap_version: SubmapVersionFn | None = None,
        trailing_map: TrailingMapFn | None = None,
    ):
        super().__init__(config, submap, submap_version, trailing_map)
        self._since_global = 0
        self._since_free = 0  # keyframes since a prior-free check or an accepted loop
        self._proposed: dict[int, NDArray[np.int64]] = {}  # key -> appearance proposals
        self._answers: dict[int, list[PlaceMatch]] = {}  # key -> its own views' matches
        # key -> keyframes its checks from a prior accepted (`_joined`)
        self._joins: dict[int, NDArray[np.int64]] = {}

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
        joined = False
        for k, m in inside:
            if sum(c.accepted for c in out) >= cfg.max_loops:
                break
            if m is None and any(c.match == k or (c.accepted and abs(c.match - k) <= 5)
                                 for c in out):
                continue
            if self._joined(key, k):
                joined = True
                continue
            out.append(self._check_prior(key, k, m, poses, cov, sigma, query_points))
        self._joins[key] = np.array([c.match for c in out if c.accepted], dtype=np.int64)
        anchored = joined or any(c.accepted for c in out)
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
                                       cfg.max_loops - sum(c.accepted for c in out),
                                       rescue=not any(c.accepted for c in out))

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

    def _joined(self, key: int, cand: int) -> bool:
        """A loop accepted from a prior at one of the `joined_keyframes` (W) keyframes
        before `key` joins a keyframe within W keys of `cand` (`LoopClosureConfig`)."""
        w = self.config.joined_keyframes
        return w > 0 and any(
            np.any(np.abs(self._joins.get(key - j, _NONE) - cand) <= w)
            for j in range(1, w + 1))

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
        when the K's places were not enough.

        With `prefilter_first` = F > 0, the own view's matches of prefilter rank below F
        (view 0: the query's own description) are among the `global_verify` places:
        one that is no place already taken takes the last slot of the fused order
        (checked after the fused places; the budget stays `global_verify`)."""
        cfg = self.config
        xy = np.asarray(poses, dtype=float).reshape(-1, 3)[:, :2]
        top_k = [db.config.top_k for db in (self.database, self.wide_database)
                 if db is not None]  # per view

        def in_k(m: PlaceMatch) -> bool:
            return m.prefilter_rank < top_k[min(m.view, len(top_k) - 1)]

        fused = [m for m in matches if in_k(m)]
        first = sorted((m for m in fused if m.view == 0 and m.prefilter_rank < cfg.prefilter_first),
                       key=lambda m: m.prefilter_rank)
        taken = self._with_first(fused, first, cfg.global_verify, xy)
        extras = [m for m in matches if not in_k(m)]
        if not extras:
            return taken
        return distinct_places([*taken, *extras], len(taken) + len(extras), xy,
                               self._frames, cfg.place_separation)

    def _with_first(self, fused: list[PlaceMatch], first: list[PlaceMatch], limit: int,
                    xy: Array) -> list[PlaceMatch]:
        """The first `limit` distinct places of `fused` (best first), the places of
        `first` (reserved matches, in order) among them: each one that is no place
        taken is appended, in place of the last fused places (`places`)."""
        cfg = self.config
        for n in range(limit, -1, -1):
            head = distinct_places(fused, n, xy, self._frames, cfg.place_separation)
            if not first:
                return head
            # `head` is distinct already: this appends the reserved places it lacks.
            both = distinct_places([*head, *first], len(head) + len(first), xy,
                                   self._frames, cfg.place_separation)
            if len(both) <= limit:
                return both
        return both[:limit]

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
        joined = [(m, -1) for m in matches] + [
            (m, base + i) for i, t in enumerate(trail) for m in answers[t]
            if m.view == 0 and (keep is None or int(m.key) in keep)]
        joined.sort(key=lambda f: -f[0].score)  # stable: the query's own first on ties
        return [m if view < 0 else m.with_view(view) for m, view in first_per_key(joined)]

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
