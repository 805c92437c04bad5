"""The loop detector's keyframes: each one's place described and stored, its submap's
registration target, and what the place databases answer it.

`KeyframeStore` is the part of `loopclosure.loop_detector.LoopClosureDetector` that holds
the keyframes the host adds (that module's docstring: the host's callbacks, "The host's
side"; how a keyframe is described, 1.; sessions and frames, "Sessions").  It says which
older keyframes are eligible candidates of a query (`eligible`), which descriptions a
keyframe queries the databases with (`views`: its own, its wide view's, its trail's)
and what they answer (`query_places`), and it caches the registration targets (KD-tree +
normals) of the submaps the checks fit to (`_target`).  The searches and the checks
are the detector's (`loopclosure.candidate_checks`, `loopclosure.loop_detector`).

With ``check.free_space_origins = "scans"`` the free-space test of the check
(`loopclosure.free_space` (1')) needs each submap's scans about their own origins:
the store keeps every keyframe's free ranges about its sensor (`RangeImage` of the
scan given to `add_keyframe`, float32) and the host tells it, through the
``submap_origins`` callback (`set_submap_origins`), which keyframes' scans make up
a submap and where their sensors lie in its frame.  The free space then travels
with the submap: on the registration target (``derived[SCAN_FREE_SPACE]``) and on
the query's points (`loopclosure.free_space.SubmapPoints`).  Without the callback
the scans' model is unavailable: the submaps travel as plain points and the check
keeps the keyframe model (1), as for any pair lacking the scans' free space
(`loopclosure.geometric_check.GeometricCheckConfig.free_space_origins`).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError
from data.types import Scan
from loopclosure.free_space import SCAN_FREE_SPACE, RangeImage, ScanFreeSpace, SubmapPoints
from loopclosure.key_table import KeyTable
from loopclosure.loop_config import LoopClosureConfig
from loopclosure.place_choice import merge_views
from loopclosure.place_database import PlaceDatabase
from loopclosure.place_match import Descriptors, PlaceMatch
from loopclosure.place_views import VIEWPOINTS
from loopclosure.polygon import DegeneratePolygonError, polygon_from_scan
from loopclosure.registration import RegistrationTarget
from loopclosure.viewpoints import viewpoint_vectors
from loopclosure.virtual_scan import virtual_scan

Array = NDArray[np.float64]
SubmapFn = Callable[[int], ArrayLike]
"""``submap(key) -> (N, 2)`` points of keyframe `key`'s local map, its sensor frame [m]."""
SubmapVersionFn = Callable[[int], Hashable]
"""``submap_version(key) -> version`` of that local map (`loopclosure.loop_detector`)."""
TrailingMapFn = Callable[[int, int], ArrayLike]
"""``trailing_map(key, n) -> (N, 2)`` points of keyframes ``key - n .. key``, `key`'s
sensor frame [m] (`loopclosure.loop_detector`)."""
SubmapOriginsFn = Callable[[int], tuple[ArrayLike, ArrayLike]]
"""``submap_origins(key) -> (keys (K,), poses (K, 3))``: the keyframes whose scans make
up ``submap(key)`` and their sensor poses in `key`'s sensor frame [m, m, rad] (the
poses the host placed their points with)."""


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


class KeyframeStore:
    """Keyframes, their places and their submaps' targets (module docstring)."""

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
        # The wide view (`loopclosure.loop_detector`, 1.): its database, place centroids.
        self.wide_database: PlaceDatabase | None = (
            PlaceDatabase(self.config.wide_database, matchers=self.database.matchers)
            if trailing_map is not None and self.config.wide_keyframes > 0 else None)
        self._wide_centroids: dict[int, Array] = {}
        self._wide_keys: list[int] = []  # key -> the key whose wide view it queries with
        self._wide_described = np.zeros(0, np.int64)  # keys with a wide view, in order
        # key -> stamp, session, frame its pose estimates are given in
        # (`loopclosure.loop_detector`, "Sessions"), described: arrays that grow in place.
        self._table = KeyTable()
        self._clock = True  # stamps tell time (see `eligible`)
        self._centroids: list[Array] = []
        # key -> (submap version it was built from, target), least recently used first.
        self._targets: OrderedDict[int, tuple[Hashable, RegistrationTarget]] = OrderedDict()
        self._trails: dict[int, list[int]] = {}  # key -> the trail keys it queried with
        self._place_scans: list[Scan | None] = []
        self._submap_origins: SubmapOriginsFn | None = None
        # key -> free ranges of its own scan about its sensor (``(bins,)`` float32),
        # kept with ``check.free_space_origins = "scans"`` only.
        self._scan_ranges: list[NDArray[np.float32]] = []

    def set_submap_origins(self, submap_origins: SubmapOriginsFn | None) -> None:
        """The host's ``submap_origins`` callback (`SubmapOriginsFn`): needed by
        ``check.free_space_origins = "scans"`` (module docstring)."""
        self._submap_origins = submap_origins
        self._targets.clear()  # their free space changes

    @property
    def _keeps_scans(self) -> bool:
        """Each keyframe's free ranges are kept (the option on)."""
        return self.config.check.free_space_origins == "scans"

    @property
    def _per_scan(self) -> bool:
        """The submaps carry their scans' free space: the option on and the host's
        ``submap_origins`` callback given (else the keyframe model (1) alone)."""
        return self._keeps_scans and self._submap_origins is not None

    def submap_free_space(self, key: int, last: int | None = None) -> ScanFreeSpace:
        """The free space of ``submap(key)``'s scans, each about its own sensor
        (`loopclosure.free_space` (1'), `key`'s sensor frame), from the scans of keys
        up to `last` only when given (a submap as it was when `last` was the newest).

        The checks ask for it only when the callback is given (`_per_scan`).

        Raises:
            UserError: no ``submap_origins`` callback, or not kept (the option off).
        """
        self._check_key(key)
        if self._submap_origins is None or not self._keeps_scans:
            raise UserError(
                'check.free_space_origins = "scans" needs the host\'s submap_origins '
                "callback: detector.set_submap_origins(lambda key: (keys, poses))")
        keys, poses = self._submap_origins(key)
        keys = np.asarray(keys, dtype=np.int64).reshape(-1)
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        if last is not None:
            keys, poses = keys[keys <= last], poses[keys <= last]
        bins = self.config.check.search.free_bins
        ranges = (np.stack([self._scan_ranges[k] for k in keys]) if len(keys)
                  else np.zeros((0, bins), np.float32))
        check = self.config.check
        return ScanFreeSpace(poses, ranges, check.free_space_surface_cap,
                             check.free_space_return_window)

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
        `session` labels the log the keyframe comes from (`loopclosure.loop_detector`,
        "Sessions"); its frame starts as the session's own.  A keyframe described from
        a virtual scan of its submap is also described from the offset viewpoints of
        `LoopClosureConfig.viewpoints` (`loopclosure.viewpoints`; their prefilter
        vectors are stored with its descriptors, `loopclosure.place_views`).

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
        if self._keeps_scans:  # the callback may come later
            self._scan_ranges.append(RangeImage(
                scan.points(), self.config.check.search.free_bins).ranges.astype(np.float32))
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
        pts = None
        if place_scan is None:
            if np.degrees(scan.fov) >= cfg.full_circle_deg or self._submap is None:
                place_scan = scan
            else:
                pts = self._plain_points(key)
                place_scan = virtual_scan(pts, cfg.virtual_beams, cfg.virtual_range, stamp=stamp)
        place = KeyframePlace(place_scan)
        try:
            polygon = polygon_from_scan(place_scan, cfg.polygon)
        except DegeneratePolygonError:
            return place
        place.centroid = polygon.centroid()
        place.descriptors = self.database.describe(polygon)
        if pts is not None and cfg.viewpoints.enabled:
            views = viewpoint_vectors(pts, place_scan, cfg.viewpoints, self.database,
                                      cfg.polygon, cfg.virtual_beams, cfg.virtual_range)
            if views is not None:
                place.descriptors[VIEWPOINTS] = views
        if self.wide_database is not None and np.degrees(scan.fov) < cfg.full_circle_deg:
            self._describe_wide(key, stamp, session, place)
        return place

    def _describe_wide(self, key: int, stamp: float, session: int, place: KeyframePlace) -> None:
        """The key whose wide view `key` queries with (`loopclosure.loop_detector`, 1.):
        the latest one of its session while it is less than `wide_every` keyframes old,
        else `key` itself, described now (-1 when that makes no polygon)."""
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
        (the frame of an older session it was joined to: `loopclosure.loop_detector`,
        "Sessions")."""
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

        target = RegistrationTarget(self._plain_points(key), self.config.check.icp,
                                    normals=normals)
        if self._per_scan:
            target.derived[SCAN_FREE_SPACE] = self.submap_free_space(key)
        self._targets[key] = (version, target)
        self._targets.move_to_end(key)
        while len(self._targets) > self.config.target_cache:
            self._targets.popitem(last=False)
        return target

    def _submap_points(self, key: int) -> Array:
        """``submap(key)``; with ``free_space_origins = "scans"``, carrying its scans'
        free space (`SubmapPoints`)."""
        pts = self._plain_points(key)
        return SubmapPoints(pts, self.submap_free_space(key)) if self._per_scan else pts

    def _plain_points(self, key: int) -> Array:
        if self._submap is None:
            raise UserError(
                "LoopClosureDetector needs a submap callback to verify loops: pass "
                "submap=lambda key: <(N, 2) points of keyframe key in its sensor frame>"
            )
        return np.asarray(self._submap(key), dtype=float).reshape(-1, 2)

    # -- candidates and the databases' answers ---------------------------------------

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
