"""`ReadProgress`: a progress total known without a pass over the input."""

from __future__ import annotations

import multiprocessing as mp
import pickle

import pytest

from data.carmen import CarmenLog
from data.compression import iter_lines
from data.progress import ReadProgress
from data.rosbag import RosBag
from tests.test_carmen import flaser, write
from tests.test_rosbag import HUMBLE, _scenario, _write_bag


def _log_text(n: int) -> str:
    return "".join(flaser([1.0 + (k % 7) * 0.1] * (5 + k % 11), stamp=100.0 + 0.1 * k)
                   for k in range(n))


def test_plain_file_progress_is_the_byte_offset_after_each_line(tmp_path):
    # Lines of 1..299 bytes, about 150 kB: many lines cross the 32 KiB read pieces.
    lines = [b"x" * (1 + k % 299) for k in range(1000)]
    path = tmp_path / "plain.txt"
    path.write_bytes(b"\n".join(lines) + b"\n")
    progress = ReadProgress(path.stat().st_size, "bytes")
    offset = 0
    for line, expected in zip(iter_lines(path, progress), lines, strict=True):
        assert line == expected
        offset += len(line) + 1
        assert progress.done == offset
    assert progress.done == progress.total


@pytest.mark.parametrize("name", ["log.clf", "log.clf.gz", "log.clf.bz2"])
def test_carmen_progress_counts_stored_bytes_without_info(tmp_path, name):
    path = write(tmp_path, _log_text(400), name)
    log = CarmenLog(path)
    progress = log.progress()
    assert (progress.total, progress.unit, progress.done) == (path.stat().st_size, "bytes", 0)
    seen = []
    for _ in log:
        seen.append(progress.done)
    assert log._info is None  # no counting pass was made
    assert len(seen) == 400
    assert seen == sorted(seen) and 0 <= seen[0] and seen[-1] <= progress.total
    assert progress.done == progress.total
    assert progress.fraction() == 1.0
    assert progress.scan_total() == (400, True)
    # The lines are those of a read without progress.
    assert [s.ranges.tolist() for s in CarmenLog(path)] == [s.ranges.tolist() for s in log]


def test_progress_of_a_pass_in_a_forked_process_is_seen_here(tmp_path):
    path = write(tmp_path, _log_text(50), "log.clf.gz")
    log = CarmenLog(path)
    child = mp.get_context("fork").Process(target=lambda: sum(1 for _ in log))
    child.start()
    child.join(timeout=30)
    assert child.exitcode == 0
    assert log.progress().done == path.stat().st_size
    assert log.progress().scan_total() == (50, True)


def test_scan_total_extrapolates_scans_per_byte_until_the_pass_ends():
    progress = ReadProgress(1000, "bytes")
    assert progress.scan_total() == (None, False)  # nothing read
    progress.done, progress.scans = 250, 30
    assert progress.scan_total() == (120, False)  # 30 scans * 1000 / 250 bytes
    progress.done, progress.scans = 999, 1
    assert progress.scan_total() == (1, False)
    progress.scans = 97
    progress.finish()
    assert progress.scan_total() == (97, True) and progress.done == 1000
    progress.start()
    assert (progress.done, progress.scans, progress.scan_total()) == (0, 0, (None, False))
    by_count = ReadProgress(40, "scans")
    assert by_count.scan_total() == (40, True)  # an index count: exact from the start


def test_progress_pickles_as_numbers():
    progress = ReadProgress(1000, "bytes")
    progress.done = 250
    copy = pickle.loads(pickle.dumps(progress))
    assert (copy.total, copy.unit, copy.done, copy.fraction()) == (1000, "bytes", 250, 0.25)
    copy.done = 900
    assert progress.done == 250  # the copy counts on its own
    assert ReadProgress(None, "scans").fraction() is None
    with pytest.raises(ValueError):
        ReadProgress(10, "lines")


@pytest.mark.parametrize("kind", ["sqlite3", "mcap"])
def test_bag_progress_total_is_the_index_count(tmp_path, kind):
    path = _write_bag(tmp_path / "b", kind, _scenario(HUMBLE))
    bag = RosBag(path)
    assert (bag.progress().total, bag.progress().unit, bag.progress().done) == (2, "scans", 0)
    assert len(list(bag)) == 2
    assert bag.progress().done == 2 == bag.info().scans
    assert bag.progress().scan_total() == (2, True)


def test_run_opens_its_input_without_reading_it(tmp_path, monkeypatch):
    from slam.cli.run_command import _open_input

    path = write(tmp_path, _log_text(20), "log.clf.bz2")

    def no_pass(self):
        raise AssertionError("info() read the log before the run")

    monkeypatch.setattr(CarmenLog, "info", no_pass)
    source, scans, reading, name = _open_input(path, None, None, False)
    assert scans is source and name == str(path)
    assert (reading.total, reading.unit) == (path.stat().st_size, "bytes")
