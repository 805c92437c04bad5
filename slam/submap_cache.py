"""The mapper's local maps of its keyframes: submaps (cached, versioned) and trailing maps.

A keyframe's submap is the union of the points of keyframes ``k - n .. k + n`` of its
own session (those that exist), placed by their odometry poses relative to ``k``
(odometry is locally accurate), points beyond ``submap.max_range`` dropped,
voxel-downsampled, in k's sensor frame [m] (``n``:
`PipelineConfig.submap_neighbours`).  Its version is the newest keyframe it includes:
it grows until ``k + n`` exists, then never changes, so the loop detector knows when
a cached registration target is out of date.  A trailing map is the same union over
``k - n .. k`` (the map the robot built on its way to ``k``): a new keyframe's place
is described from its trailing submap, and the place database's wide view of it from
a longer trailing stretch, ``k - loops.wide_keyframes .. k``.

`SubmapCache` answers these for `slam.pipeline.Mapper`, which hands the loop
detector its `submap`, `version`, `origins` and `trailing_map`.  It sees the
keyframes through functions of the mapper: ``keyframe(key)`` (a keyframe of any
session), ``span(key)`` (the first and last key so far of that keyframe's submap
segment: its session, or with ``submap.stop_at_kidnap`` the stretch of it between
kidnapped odometry increments, `segment_span`) and ``trailing_span(key)`` (those of
its session, for trailing maps; default ``span``).
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from data import se2
from slam.config import PipelineConfig
from slam.keyframes import Keyframe

Array = NDArray[np.float64]


class SubmapCache:
    """Submaps and trailing maps of the keyframes `keyframe` returns (module docstring).

    Attributes:
        submaps: key -> (version, points ``(M, 2)`` in the key's sensor frame [m]).
    """

    def __init__(
        self, config: PipelineConfig, keyframe: Callable[[int], Keyframe],
        span: Callable[[int], tuple[int, int]],
        trailing_span: Callable[[int], tuple[int, int]] | None = None,
    ) -> None:
        self.config = config
        self._keyframe = keyframe
        self._span = span
        self._trailing_span = span if trailing_span is None else trailing_span
        self.submaps: dict[int, tuple[int, Array]] = {}
        self._incomplete: set[int] = set()  # keys of `submaps` below version key + n

    def version(self, key: int) -> int:
        """Version of `submap(key)`: the newest keyframe it includes (it grows until
        ``key + n`` exists, then never changes)."""
        return min(key + self.config.submap_neighbours(), self._span(key)[1])

    def submap(self, key: int) -> Array:
        """Local map of keyframe `key` in its sensor frame (module docstring), cached;
        only keyframes of its own session take part."""
        n = self.config.submap_neighbours()
        lo = self._span(key)[0]
        hi = self.version(key)
        cached = self.submaps.get(key)
        if cached is not None and cached[0] == hi:
            return cached[1]
        pts = self.local_points(key, max(lo, key - n), hi)
        self._cache(key, hi, pts)
        return pts

    def adopt(self, key: int, version: int, points: Array) -> None:
        """`submap(key)` as another process built it (version, points in `key`'s
        sensor frame [m]; the front end's worker, whose keyframes are the mapper's),
        cached here when it is the version this process would build now."""
        if version == self.version(key) and key not in self.submaps:
            self._cache(key, version, points)

    def _cache(self, key: int, version: int, points: Array) -> None:
        """`points` as `submap(key)` of `version`, and the incomplete submaps far
        behind `key` dropped."""
        n = self.config.submap_neighbours()
        self.submaps[key] = (version, points)
        if version < key + n:
            self._incomplete.add(key)
        else:
            self._incomplete.discard(key)
        # Incomplete submaps (of keys near a session's end when cached) far behind
        # the asked one are dropped: they would be rebuilt anyway.  Only the
        # incomplete ones are scanned, not every cached submap.
        stale = key - 4 * n - self.config.loops.exclude_recent
        for old in [k for k in self._incomplete if k < stale]:
            del self.submaps[old]
            self._incomplete.discard(old)

    def clear(self) -> None:
        """Every cached submap dropped (they are rebuilt on demand)."""
        self.submaps.clear()
        self._incomplete.clear()

    def origins(self, key: int) -> tuple[Array, Array]:
        """The keys `submap(key)` merges and their front-end sensor poses in `key`'s
        sensor frame (``(k,)``, ``(k, 3)`` [m, rad]): where each of its scans was seen
        from (the loop detector's ``check.free_space_origins = "scans"``)."""
        first = max(self._span(key)[0], key - self.config.submap_neighbours())
        keys = np.arange(first, self.version(key) + 1)
        inverse = se2.inverse(self._keyframe(key).odom_pose)
        poses = [se2.compose(inverse, self._keyframe(j).odom_pose) for j in keys]
        return keys, np.asarray(poses, dtype=float).reshape(-1, 3)

    def trailing_map(self, key: int, n: int) -> Array:
        """Keyframes ``key - n .. key`` of `key`'s session (``trailing_span``), in `key`'s
        sensor frame [m], cropped and voxelised as a submap: the map the robot built on
        its way to `key` (the loop detector's wide view)."""
        return self.local_points(key, max(self._trailing_span(key)[0], key - n), key)

    def local_points(self, key: int, first: int, last: int) -> Array:
        """Keyframes ``first .. last`` in `key`'s sensor frame (front-end poses), points
        beyond ``submap.max_range`` dropped, voxelised by ``submap.voxel`` [m] (the
        compiled `loopclosure.registration.voxel_downsample`)."""
        inverse = se2.inverse(self._keyframe(key).odom_pose)  # between(centre, .) each
        parts = [_transform(se2.compose(inverse, kf.odom_pose), kf.points)
                 for kf in map(self._keyframe, range(first, last + 1))]
        pts = np.vstack(parts) if parts else np.zeros((0, 2))
        pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= self.config.submap.max_range]
        from loopclosure.fast_icp import voxel_downsample_fast  # numba loads on first use

        return voxel_downsample_fast(pts, self.config.submap.voxel)


def segment_span(starts: Sequence[int], key: int, last: int) -> tuple[int, int]:
    """First and last key of the segment holding `key`: segments begin at the ascending
    keys `starts` (``starts[0] <= key``) and each ends before the next one begins, the
    newest at `last` (the newest key so far)."""
    i = bisect_right(starts, key) - 1
    if i < 0:
        raise ValueError(f"key {key} precedes the first segment start {starts[0]}")
    return starts[i], (starts[i + 1] - 1 if i + 1 < len(starts) else last)


def _transform(pose: Array, points: Array) -> Array:
    """`data.se2.transform_points` of a ``(3,)`` float pose and ``(N, 2)`` float points
    (the same operations, without its conversions: a submap transforms a few dozen
    keyframes)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return points @ np.array([[c, -s], [s, c]]).T + pose[:2]
