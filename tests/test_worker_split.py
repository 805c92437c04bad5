"""`benchmarks/worker_split.simulate`: the two-core schedule of the mapper and its
front-end worker, on hand-checked per-scan costs."""

from __future__ import annotations

import pytest

from tests.helpers import load_benchmark

simulate = load_benchmark("worker_split").simulate


def test_a_slow_worker_sets_the_pace_and_the_mapper_waits() -> None:
    # batches of 2: the worker sends at 2, 4; the mapper takes 0.5 a scan
    wall, wait, in_worker = simulate([1.0] * 4, [0.5] * 4, {}, "ahead", batch=2)
    assert wall == pytest.approx(5.0)  # scans 2, 3 start at 4: 4 + 0.5 + 0.5
    assert wait == pytest.approx(3.0)  # 2 before the first batch, 1 before the second
    assert in_worker == 0


def test_queries_go_where_the_policy_puts_them() -> None:
    worker, mapper, query = [1.0] * 4, [0.5] * 4, {3: 2.0}
    # never in the worker: the mapper's last scan costs 2.5
    assert simulate(worker, mapper, query, "mapper", batch=2)[0] == pytest.approx(7.0)
    # always: the worker's last batch arrives at 6, the mapper needs 1 more
    assert simulate(worker, mapper, query, "worker", batch=2) == pytest.approx((7.0, 5.0, 1))
    # the rule: at scan 3 the worker has sent 2 scans, the mapper taken 2 by then:
    # not ahead, so the mapper asks
    assert simulate(worker, mapper, query, "ahead", threshold=1, batch=2)[2] == 0
