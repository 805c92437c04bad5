"""The plugin's main object: feed keyframes, get verified loop closures.

`LoopClosureDetector` owns the place database and the geometric check.  A host
(our `slam.pipeline`, or anybody's mapper) calls, for every keyframe in order:

1. ``add_keyframe(key, stamp, scan, place_points)``: the keyframe is described once
   (a 360-degree polygon: its own scan when the sensor covers the full circle,
   else a virtual scan of `place_points`, the local map around it, see
   `loopclosure.virtual_scan`) and stored in the place database;
2. ``detect(key, poses, covariance)`` with the host's current pose estimates of all
   keyframes so far: two searches, both verified by the geometric check
   (`loopclosure.geometric_check.verify`) on local submaps that the host supplies
   through the `submap` callback:

   - **local** (pose-gated): older keyframes whose estimated position lies within
     ``local_radius + local_sigmas * sigma`` of the query (sigma: the largest
     standard deviation of the query's position from `covariance`), nearest first,
     at most `local_max`, each from the predicted relative pose;
   - **global** (appearance; every `global_every` keyframes unless a loop was
     accepted within the last `global_every` keyframes (the pose is then anchored to
     the map and the local search covers it), and at every keyframe while the pose
     uncertainty exceeds `global_sigma` when that is set): the place database's cascade (prefilter
     over every older keyframe, verifier on the top K, fused score) — candidates
     with a fused score of at least `min_score`, the best `global_verify` of them —
     each from the FFT heading hypotheses and a centroid-aligned translation, with no
     pose prior: this is what closes loops after large drift or a kidnap.

   Keyframes newer than `exclude_recent` keyframes or `exclude_recent_s` seconds are
   never candidates (they are odometry's business); the time rule is dropped for the
   rest of the run once two keyframes share a stamp (logs whose stamps are all 0, as
   some corrected Radish logs, would otherwise never close a loop).  A loop closure is a revisit: a
   verified relative pose longer than `max_distance` is rejected.  At most
   `max_loops` are accepted per query, local and global alike.

Every candidate tried is returned (accepted or not, with the reason), so the host
can report them all (``loops.csv``).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data import se2
from data.types import Scan
from loopclosure.geometric_check import GeometricCheckConfig, LoopVerification, verify
from loopclosure.place_database import PlaceDatabase, PlaceDatabaseConfig
from loopclosure.polygon import DegeneratePolygonError, PolygonConfig, polygon_from_scan
from loopclosure.registration import RegistrationTarget
from loopclosure.virtual_scan import virtual_scan

Array = NDArray[np.float64]
SubmapFn = Callable[[int], Array]


@dataclass(slots=True)
class LoopClosureConfig:
    """Every parameter of the loop-closure plugin (see the module docstring).

    Attributes:
        exclude_recent: keyframes this close in sequence are never candidates.
        exclude_recent_s: ... nor keyframes this close in time [s].
        max_distance: a loop closure is a revisit: a verified relative pose longer than
            this is rejected (the two keyframes see overlapping but distinct places) [m].
        local_radius: base search radius of the pose-gated search [m].
        local_sigmas: radius grows by this many position standard deviations.
        local_max: candidates verified per query by the local search.
        global_every: run the appearance search every this many keyframes without an
            accepted loop (0: never).
        global_sigma: ... and at every keyframe while the position sigma exceeds this
            [m] (0: never by uncertainty; with the pipeline's since-last-loop
            uncertainty this would fire all through every exploration phase).
        min_score: fused place-recognition score a global candidate needs, in [0, 1].
        global_verify: global candidates verified geometrically per query.
        max_loops: accepted loops per query at most.
        virtual_beams: beams of the 360-degree virtual scan describing a keyframe.
        virtual_range: range of that virtual scan [m].
        full_circle_deg: a sensor covering at least this is described by its own scan.
        target_cache: registration targets (KD-tree + normals) kept in memory.
        database: the place database (prefilter, verifiers, fusion).
        check: the geometric check.
        polygon: the scan -> polygon rule.
    """

    exclude_recent: int = 30
    exclude_recent_s: float = 20.0
    max_distance: float = 2.0
    local_radius: float = 1.5
    local_sigmas: float = 3.0
    local_max: int = 2
    global_every: int = 10
    global_sigma: float = 0.0
    min_score: float = 0.5
    global_verify: int = 2
    max_loops: int = 2
    virtual_beams: int = 360
    virtual_range: float = 20.0
    full_circle_deg: float = 359.0
    target_cache: int = 256
    database: PlaceDatabaseConfig = field(default_factory=PlaceDatabaseConfig)
    check: GeometricCheckConfig = field(default_factory=GeometricCheckConfig)
    polygon: PolygonConfig = field(default_factory=PolygonConfig)


@dataclass(slots=True)
class LoopCandidate:
    """One candidate of one query, verified or rejected.

    Attributes:
        query: the new keyframe's key.
        match: the older keyframe's key.
        source: ``"local"`` (pose-gated) or ``"global"`` (place recognition).
        scores: per stage: ``prefilter`` (normalised distance), ``prefilter_rank``, each
            verifier's distance, ``fused`` score (global); ``distance`` [m] between
            the estimates (local).
        accepted: the geometric check accepted it.
        reason: why not (or ``"accepted"``).
        relative: ``(3,)`` pose of the query keyframe in the match's frame.
        covariance: ``3x3`` covariance of `relative` (floored).
        verification: the full geometric-check result.
    """

    query: int
    match: int
    source: str
    scores: dict[str, float]
    accepted: bool
    reason: str
    relative: Array
    covariance: Array
    verification: LoopVerification | None = None


class LoopClosureDetector:
    """Place database + geometric check behind one call per keyframe (module docstring)."""

    def __init__(self, config: LoopClosureConfig | None = None, submap: SubmapFn | None = None):
        self.config = config or LoopClosureConfig()
        self.database = PlaceDatabase(self.config.database)
        self._submap = submap
        self._stamps: list[float] = []
        self._clock = True  # stamps tell time (see `eligible`)
        self._centroids: list[Array] = []
        self._described: list[bool] = []
        self._targets: OrderedDict[int, RegistrationTarget] = OrderedDict()
        self._since_global = 0
        self._since_loop = 0
        self._query: tuple[int, dict] | None = None  # descriptors of the newest keyframe

    # -- keyframes -------------------------------------------------------------------

    def add_keyframe(
        self, key: int, stamp: float, scan: Scan, place_points: ArrayLike | None = None
    ) -> bool:
        """Describe and store keyframe `key` (keys are 0, 1, 2, ... in order).

        Returns False when no polygon could be made (all beams invalid, a degenerate
        local map): the keyframe is then never a candidate, but keys stay aligned.
        """
        if key != len(self._stamps):
            raise ValueError(f"keyframes must be added in order: expected {len(self._stamps)}")
        cfg = self.config
        if self._stamps and float(stamp) == self._stamps[-1]:
            self._clock = False  # repeated stamps (e.g. all 0): time says nothing
        self._stamps.append(float(stamp))
        try:
            if np.degrees(scan.fov) >= cfg.full_circle_deg or place_points is None:
                polygon = polygon_from_scan(scan, cfg.polygon)
            else:
                pts = np.asarray(place_points, dtype=float).reshape(-1, 2)
                virtual = virtual_scan(pts, cfg.virtual_beams, cfg.virtual_range, stamp=stamp)
                polygon = polygon_from_scan(virtual, cfg.polygon)
        except DegeneratePolygonError:
            self._centroids.append(np.zeros(2))
            self._described.append(False)
            return False
        self._centroids.append(polygon.centroid())
        self._described.append(True)
        self._query = (key, self.database.describe(polygon))
        self.database.add_descriptors(key, self._query[1], stamp=stamp)
        return True

    def _target(self, key: int) -> RegistrationTarget:
        target = self._targets.get(key)
        if target is None:
            target = RegistrationTarget(self._submap_points(key), self.config.check.icp)
            self._targets[key] = target
            while len(self._targets) > self.config.target_cache:
                self._targets.popitem(last=False)
        else:
            self._targets.move_to_end(key)
        return target

    def forget_target(self, key: int) -> None:
        """Drop the cached registration target of `key` (its submap changed)."""
        self._targets.pop(key, None)

    def _submap_points(self, key: int) -> Array:
        if self._submap is None:
            raise RuntimeError("LoopClosureDetector needs a submap callback to verify loops")
        return np.asarray(self._submap(key), dtype=float).reshape(-1, 2)

    # -- detection -------------------------------------------------------------------

    def eligible(self, key: int) -> NDArray[np.bool_]:
        """Boolean mask over keys ``0..key-1`` of keyframes old enough to be candidates."""
        cfg = self.config
        stamps = np.asarray(self._stamps[:key])
        ids = np.arange(key)
        ok = ids < key - cfg.exclude_recent
        if self._clock:
            ok &= np.abs(stamps - self._stamps[key]) >= cfg.exclude_recent_s
        return ok & np.asarray(self._described[:key], dtype=bool)

    def detect(
        self, key: int, poses: ArrayLike, covariance: ArrayLike | None = None
    ) -> list[LoopCandidate]:
        """Candidates of keyframe `key`, each verified (see the module docstring).

        Args:
            key: the query (already added).
            poses: ``(key + 1, 3)`` current estimates of keyframes ``0..key`` (map frame).
            covariance: ``3x3`` marginal covariance of the query's pose, or None.
        """
        cfg = self.config
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        eligible = self.eligible(key)
        if not eligible.any() or not self._described[key]:
            return []
        cov = None if covariance is None else np.asarray(covariance, dtype=float)
        sigma = 0.0 if cov is None else float(np.sqrt(max(np.linalg.eigvalsh(cov[:2, :2]))))
        out: list[LoopCandidate] = []
        accepted = 0
        query_points = self._submap_points(key)
        tried: set[int] = set()
        self._since_global += 1
        self._since_loop += 1
        for cand in self._local(key, poses, eligible, sigma):
            lc = self._check_local(key, cand, poses, cov, sigma, query_points)
            out.append(lc)
            tried.add(cand)
            accepted += lc.accepted
            if accepted >= cfg.max_loops:
                break
        if accepted:
            self._since_loop = 0
            return out
        due = min(self._since_global, self._since_loop) >= cfg.global_every
        uncertain = 0.0 < cfg.global_sigma < sigma
        if cfg.global_every > 0 and (due or uncertain):
            self._since_global = 0
            for lc in self._global(key, eligible, tried, query_points):
                out.append(lc)
                accepted += lc.accepted
                if accepted >= cfg.max_loops:
                    break
            if accepted:
                self._since_loop = 0
        return out

    def _local(
        self, key: int, poses: Array, eligible: NDArray[np.bool_], sigma: float
    ) -> list[int]:
        cfg = self.config
        if cfg.local_max <= 0:
            return []
        ids = np.flatnonzero(eligible)
        d = np.hypot(*(poses[ids, :2] - poses[key, :2]).T)
        radius = cfg.local_radius + cfg.local_sigmas * sigma
        near = ids[d <= radius]
        order = np.argsort(d[d <= radius], kind="stable")
        chosen: list[int] = []
        for k in near[order]:
            # Spread the candidates: skip keyframes adjacent to one already chosen.
            if all(abs(int(k) - c) > 5 for c in chosen):
                chosen.append(int(k))
            if len(chosen) == cfg.local_max:
                break
        return chosen

    def _check_local(
        self, key: int, cand: int, poses: Array, cov: Array | None, sigma: float,
        query_points: Array,
    ) -> LoopCandidate:
        prior = se2.between(poses[cand], poses[key])
        prior_cov = None if cov is None else 2.0 * cov
        # A prior good to better than the offset step needs no offset guesses.
        offsets = 0.0 if sigma < 0.5 * self.config.check.offsets else None
        result = verify(
            query_points, self._target(cand), prior=prior, prior_covariance=prior_cov,
            offsets=offsets, config=self.config.check,
        )
        scores = {"distance": float(np.hypot(prior[0], prior[1]))}
        return _candidate(key, cand, "local", scores, result, self.config.max_distance)

    def _global(
        self, key: int, eligible: NDArray[np.bool_], tried: set[int], query_points: Array
    ) -> list[LoopCandidate]:
        cfg = self.config
        mask = eligible.copy()
        mask[list(tried)] = False
        if not mask.any() or self._query is None or self._query[0] != key:
            return []
        matches = self.database.query(self._query[1], allowed=np.flatnonzero(mask))
        out: list[LoopCandidate] = []
        good = [m for m in matches if m.score >= cfg.min_score][: cfg.global_verify]
        for m in good:
            cand = int(m.key)
            # angle = heading(stored) - heading(query): the query's heading in the
            # stored frame is -angle; align the two places' centroids.
            headings = [-a for a, _ in m.headings] or [0.0]
            c, s = np.cos(headings[0]), np.sin(headings[0])
            rot = np.array([[c, -s], [s, c]])
            translation = self._centroids[cand] - rot @ self._centroids[key]
            result = verify(
                query_points, self._target(cand), headings=headings,
                translation=translation, config=cfg.check,
            )
            scores = {
                "prefilter": m.prefilter_distance,
                "prefilter_rank": float(m.prefilter_rank),
                "fused": m.score,
                **{f"{k}": v for k, v in m.verifier_distances.items()},
            }
            out.append(_candidate(key, cand, "global", scores, result, cfg.max_distance))
        return out


def _candidate(
    key: int,
    cand: int,
    source: str,
    scores: dict[str, float],
    result: LoopVerification,
    max_distance: float,
) -> LoopCandidate:
    accepted, reason = result.accepted, result.reason
    distance = float(np.hypot(result.relative[0], result.relative[1]))
    if accepted and distance > max_distance:
        accepted, reason = False, f"not a revisit ({distance:.1f} m apart)"
    return LoopCandidate(
        query=key, match=cand, source=source, scores=scores, accepted=accepted,
        reason=reason, relative=result.relative, covariance=result.covariance,
        verification=result,
    )
