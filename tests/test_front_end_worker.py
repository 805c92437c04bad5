"""`slam.front_end_worker`: results in order, errors raised here, early stop, and a
mapper whose front end runs in the worker maps exactly as one without."""

from __future__ import annotations

import numpy as np
import pytest

from data.sim import MotionConfig, simulate_run
from slam.config import PipelineConfig
from slam.front_end_worker import BATCH, map_in_worker, worker_available
from slam.pipeline import Mapper

pytestmark = pytest.mark.skipif(not worker_available(), reason="no fork on this platform")


def _square(x: int, ahead: int) -> int:
    assert ahead >= 0
    return x * x


def _box_run(laps: float):
    """A simulated box world seen by a 180-degree, 181-beam laser, `laps` laps."""
    return simulate_run("box", seed=3, fov_deg=180.0, beams=181, max_range=12.0,
                        motion=MotionConfig(laps=laps))


def test_results_come_back_in_input_order_across_batches() -> None:
    items = range(3 * BATCH + 5)
    stats: dict[str, float] = {}
    assert list(map_in_worker(_square, iter(items), stats)) == [(x, x * x) for x in items]
    assert stats["peak_rss_mb"] > 10  # a Python process with numpy loaded


def test_an_empty_input_yields_nothing() -> None:
    assert list(map_in_worker(_square, iter([]))) == []


def test_an_exception_in_the_worker_is_raised_here_after_the_earlier_results() -> None:
    def step(x: int, ahead: int) -> int:
        if x == BATCH + 3:
            raise ValueError("bad scan 19")
        return x

    seen = []
    with pytest.raises(ValueError, match="bad scan 19"):
        for x, _ in map_in_worker(step, iter(range(100))):
            seen.append(x)
    assert seen == list(range(BATCH))  # the first full batch arrived before the error


def test_closing_early_stops_the_worker() -> None:
    gen = map_in_worker(_square, iter(range(10**9)))
    assert [next(gen) for _ in range(3)] == [(0, 0), (1, 1), (2, 4)]
    gen.close()  # must return promptly: the worker is terminated, not drained


def test_mapper_with_the_front_end_in_a_worker_maps_identically() -> None:
    run = _box_run(laps=1.0)
    results = [Mapper(PipelineConfig(odometry="icp2d", front_end_worker=w)).run(run.scans)
               for w in (False, True)]
    assert len(results[1].scan_poses) == len(run.scans)
    np.testing.assert_array_equal(results[0].odometry_poses, results[1].odometry_poses)
    np.testing.assert_array_equal(results[0].scan_poses, results[1].scan_poses)
    assert len(results[0].accepted_loops) == len(results[1].accepted_loops) > 0
    assert results[0].worker_peak_rss_mb == 0.0 < results[1].worker_peak_rss_mb


def test_no_worker_from_a_thread_other_than_the_main_one() -> None:
    import threading

    seen = []
    thread = threading.Thread(target=lambda: seen.append(worker_available()))
    thread.start()
    thread.join()
    assert seen == [False]


def test_ahead_counts_the_results_sent_and_not_yet_taken() -> None:
    import time

    gen = map_in_worker(lambda x, ahead: ahead, iter(range(6 * BATCH)))
    first = [next(gen) for _ in range(BATCH)]
    time.sleep(1.0)  # the worker runs on while this side holds back
    rest = list(gen)
    assert [a for _, a in first[:BATCH]] == [0] * BATCH  # nothing sent yet
    assert max(a for _, a in rest) >= BATCH  # later batches saw unread results


def test_mapping_scan_by_scan_needs_no_worker() -> None:
    run = _box_run(laps=0.3)
    by_scan = Mapper(PipelineConfig(odometry="icp2d"))
    for scan in run.scans:
        by_scan.process(scan)
    result = by_scan.finish()
    whole = Mapper(PipelineConfig(odometry="icp2d")).run(run.scans)
    np.testing.assert_array_equal(result.scan_poses, whole.scan_poses)
    assert result.worker_peak_rss_mb == 0.0


def test_a_keyframes_submap_from_the_worker_is_the_one_the_mapper_builds() -> None:
    run = _box_run(laps=0.3)
    worker, mapper = (Mapper(PipelineConfig(odometry="icp2d")) for _ in range(2))
    sent = []
    for scan in run.scans:  # the worker's steps, here, then the mapper's
        step = worker._worker_step(scan, ahead=0)
        assert step[3] is None  # not ahead: the place query stays with the mapper
        if step[5] is not None:
            sent.append(step[5])
        mapper._after_odometry(scan, *step, from_worker=True)
    n = len(worker.keyframes.keyframes)
    assert n > 3 and len(sent) == n  # a 180-degree sensor: every keyframe's submap made
    for key, (version, points) in enumerate(sent):
        assert version == key  # the newest keyframe when it was described
        # what the mapper would build for `key` with only keys <= version
        first = max(0, key - mapper.config.submap_neighbours())
        np.testing.assert_array_equal(points, mapper._local_points(key, first, version))
    newest = n - 1
    assert mapper.submap(newest) is sent[newest][1]  # adopted, not rebuilt


def test_an_outdated_submap_from_the_worker_is_not_adopted() -> None:
    run = _box_run(laps=0.3)
    mapper = Mapper(PipelineConfig(odometry="icp2d"))
    for scan in run.scans:
        mapper.process(scan)
    assert len(mapper.keyframes.keyframes) > 12
    stale = np.zeros((1, 2))
    mapper._submaps.clear()
    mapper._adopt_submap(0, 0, stale)  # version 0, but keyframe 0's submap is at 10 now
    assert 0 not in mapper._submaps
    assert mapper.submap_version(0) == 10
    mapper._adopt_submap(0, 10, stale)
    assert mapper.submap(0) is stale
