"""`slam.submap_cache.SubmapCache`: local maps of hand-placed keyframes, versions that
grow with the session, adopted submaps and the stale incomplete ones dropped."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from slam.config import PipelineConfig, SubmapConfig
from slam.submap_cache import SubmapCache, segment_span


def _cache(poses: list[list[float]], neighbours: int = 1, max_range: float = 50.0):
    """A cache over keyframes at `poses` (odometry frame), each seeing one point 1 m
    ahead; the session is every keyframe (keys 0 .. len - 1), grown by appending."""
    keyframes = [SimpleNamespace(odom_pose=np.array(p, float), points=np.array([[1.0, 0.0]]))
                 for p in poses]
    config = PipelineConfig(submap=SubmapConfig(neighbours=neighbours, voxel=0.0,
                                                max_range=max_range))
    cache = SubmapCache(config, keyframes.__getitem__, lambda key: (0, len(keyframes) - 1))
    return cache, keyframes


def test_local_points_are_placed_by_the_odometry_in_the_keys_frame() -> None:
    # Keyframe 1 stands 1 m left of keyframe 0, facing left: its point (1 m ahead)
    # is at (0, 2) in 0's frame; keyframe 0's own point at (1, 0).
    cache, _ = _cache([[0.0, 0.0, 0.0], [0.0, 1.0, np.pi / 2]])
    np.testing.assert_allclose(cache.local_points(0, 0, 1), [[1.0, 0.0], [0.0, 2.0]],
                               atol=1e-12)
    # Seen from keyframe 1 (at (0, 1) facing +y): 0's point (1, 0) is 1 m behind-right.
    np.testing.assert_allclose(cache.local_points(1, 0, 1), [[-1.0, -1.0], [1.0, 0.0]],
                               atol=1e-12)
    keys, origins = cache.origins(0)
    np.testing.assert_array_equal(keys, [0, 1])
    np.testing.assert_allclose(origins, [[0.0, 0.0, 0.0], [0.0, 1.0, np.pi / 2]], atol=1e-12)


def test_points_beyond_the_range_are_dropped() -> None:
    cache, _ = _cache([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]], max_range=3.0)
    np.testing.assert_allclose(cache.submap(0), [[1.0, 0.0]])  # (6, 0) is 6 m away
    np.testing.assert_allclose(cache.trailing_map(1, 1), [[1.0, 0.0]])  # (-4, 0): 4 m


def test_the_version_grows_with_the_session_and_a_new_version_is_rebuilt() -> None:
    cache, keyframes = _cache([[0.0, 0.0, 0.0]])
    assert cache.version(0) == 0
    first = cache.submap(0)
    assert cache.submap(0) is first  # cached
    keyframes.append(SimpleNamespace(odom_pose=np.array([2.0, 0.0, 0.0]),
                                     points=np.array([[1.0, 0.0]])))
    assert cache.version(0) == 1
    np.testing.assert_allclose(cache.submap(0), [[1.0, 0.0], [3.0, 0.0]])
    keyframes.append(SimpleNamespace(odom_pose=np.array([4.0, 0.0, 0.0]),
                                     points=np.array([[1.0, 0.0]])))
    assert cache.version(0) == 1  # key + n: complete, never changes


def test_an_adopted_submap_is_kept_only_at_the_current_version() -> None:
    cache, _ = _cache([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    sent = np.array([[7.0, 7.0]])
    cache.adopt(0, 0, sent)  # the current version is 1
    assert 0 not in cache.submaps
    cache.adopt(0, 1, sent)
    assert cache.submap(0) is sent
    cache.clear()
    assert cache.submaps == {}


def test_incomplete_submaps_far_behind_are_dropped() -> None:
    cache, keyframes = _cache([[0.0, 0.0, 0.0]])
    cache.submap(0)  # version 0 < 0 + n: incomplete
    exclude = cache.config.loops.exclude_recent
    far = 4 * 1 + exclude + 1  # stale below key - 4 n - exclude_recent
    for k in range(1, far + 2):
        keyframes.append(SimpleNamespace(odom_pose=np.array([float(k), 0.0, 0.0]),
                                         points=np.array([[1.0, 0.0]])))
    cache.submap(far - 1)  # 0 is not below (far - 1) - 4 - exclude: kept
    assert 0 in cache.submaps
    cache.submap(far)
    assert 0 not in cache.submaps and far in cache.submaps



def test_segment_span_ends_before_the_next_start() -> None:
    starts = [0, 3, 7]
    assert segment_span(starts, 0, 9) == (0, 2)
    assert segment_span(starts, 2, 9) == (0, 2)
    assert segment_span(starts, 3, 9) == (3, 6)
    assert segment_span(starts, 7, 9) == (7, 9)
    assert segment_span(starts, 9, 9) == (7, 9)
    assert segment_span([5], 6, 6) == (5, 6)
    with pytest.raises(ValueError):
        segment_span([5], 4, 6)


def test_a_submap_stops_at_a_segment_start() -> None:
    # Keyframes 1 m apart along x; a segment starts at key 2 (a kidnapped step between
    # 1 and 2): with n = 2, 1's submap merges 0 .. 1 only, 2's merges 2 .. 3 only.
    poses = [[float(k), 0.0, 0.0] for k in range(4)]
    keyframes = [SimpleNamespace(odom_pose=np.array(p), points=np.array([[0.5, 0.0]]))
                 for p in poses]
    config = PipelineConfig(submap=SubmapConfig(neighbours=2, voxel=0.0, max_range=50.0))
    cache = SubmapCache(config, keyframes.__getitem__,
                        lambda key: segment_span([0, 2], key, len(keyframes) - 1))
    assert cache.version(0) == 1 and cache.version(1) == 1 and cache.version(2) == 3
    np.testing.assert_allclose(cache.submap(1), [[-0.5, 0.0], [0.5, 0.0]])
    np.testing.assert_allclose(cache.submap(2), [[0.5, 0.0], [1.5, 0.0]])
    keys, origins = cache.origins(2)
    np.testing.assert_array_equal(keys, [2, 3])
    np.testing.assert_allclose(origins[:, 0], [0.0, 1.0])
    np.testing.assert_allclose(cache.trailing_map(3, 3), [[-0.5, 0.0], [0.5, 0.0]])
    # With the session as the trailing maps' span, 3's trailing map reaches back to 0.
    whole = SubmapCache(config, keyframes.__getitem__,
                        lambda key: segment_span([0, 2], key, len(keyframes) - 1),
                        lambda key: (0, len(keyframes) - 1))
    np.testing.assert_allclose(whole.trailing_map(3, 3),
                               [[-2.5, 0.0], [-1.5, 0.0], [-0.5, 0.0], [0.5, 0.0]])
    assert whole.version(1) == 1 and whole.origins(2)[0].tolist() == [2, 3]
