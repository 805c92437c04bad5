"""The geometric-check benchmark scripts run against the loop detector as it is: they
patch its internals to record checks, so a changed signature must fail here, not on
a user's log."""

from __future__ import annotations

import pickle
from pathlib import Path

from data.sim import MotionConfig, simulate_run, write_run
from tests.helpers import load_benchmark


def test_prior_free_check_collect_records_the_checks_with_no_prior(tmp_path: Path) -> None:
    run = simulate_run("box", seed=3, motion=MotionConfig(laps=1.1))
    log = write_run(run, tmp_path / "sim")["log"]
    out = tmp_path / "pairs.pkl"
    load_benchmark("prior_free_check").collect(log, None, out, max_queries=None)
    with open(out, "rb") as f:
        got = pickle.load(f)
    assert got["queries"] > 0 and got["revisits"] > 0
    assert got["pairs"], "more than a lap of the box revisits places: checks were made"
    pair = got["pairs"][0]
    assert pair["query_points"].shape[1] == 2 and pair["target_points"].shape[1] == 2
    assert pair["truth"].shape == (3,)


def test_view_retrieval_interleaving_keeps_the_top_1_of_the_smaller_distance(
        tmp_path: Path) -> None:
    """Interleaving two views by rank changes only the places after the first: its
    recall@1 equals the merge by the smaller distance, query by query."""
    from slam.config import PipelineConfig

    run = simulate_run("box", seed=3, motion=MotionConfig(laps=1.1))
    log = write_run(run, tmp_path / "sim")["log"]
    turn, hits, step = load_benchmark("view_retrieval").retrieval(str(log), None,
                                                                  PipelineConfig())
    assert len(turn) > 0 and all(len(h) == len(turn) for h in hits.values())
    assert [h[1] for h in hits["interleaved"]] == [h[1] for h in hits["min"]]
    assert 0 < step < 2.0
