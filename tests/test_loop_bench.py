"""`loopclosure bench loops`: the measures (hand-checked), the runner and the command."""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

import numpy as np
import pytest

import evaluation.loop_bench as lb
import evaluation.loop_bench_truth as truth
import loopclosure.keyframe_store as keyframe_store
from data.errors import UserError
from data.sim import MotionConfig, SimulatedRun, simulate_run
from evaluation.loop_bench_queries import interleaved_order
from loopclosure.place_database import PlaceDatabase
from loopclosure.polygon import DegeneratePolygonError, polygon_from_scan
from slam.cli.main import main
from slam.config import PipelineConfig
from tests.helpers import shared_file

SIM = {"fov_deg": 180.0, "beams": 181, "max_range": 12.0, "noise_sigma": 0.02}
CHEAP = ["pairs", "prefilter", "flirt@10", "fused", "flirt-alone"]

# ------------------------------------------------------------------------ the measures


def test_views_interleave_by_rank_not_by_distance() -> None:
    """The wide view's distances run lower: merged by the smaller distance, its second
    row would push the own view's best row to third; interleaved by rank, each view's
    best row comes first (the smaller distance first), then the rank-1 rows."""
    own = np.array([0.1, 0.2, 0.3])
    wide = np.array([0.09, 0.01, 0.02])
    order, distance = interleaved_order([own, wide])
    assert order.tolist() == [1, 0, 2]
    np.testing.assert_allclose(distance, [0.1, 0.01, 0.02])
    # A row the second view does not hold, and one view alone: its own order.
    order, distance = interleaved_order([np.array([0.5, 0.4, 0.6]),
                                            np.array([np.inf, 0.3, np.inf])])
    assert order.tolist() == [1, 0, 2]
    np.testing.assert_allclose(distance, [0.5, 0.3, 0.6])
    order, _ = interleaved_order([np.array([0.3, 0.1, 0.2])])
    assert order.tolist() == [1, 2, 0]


def test_pr_curve_hand_checked() -> None:
    """Scores 0.9 0.8 0.7 0.6, correct T T F T, 4 revisits: recall 1/4 2/4 2/4 3/4 at
    precision 1 1 2/3 3/4."""
    c = truth.pr_curve([0.6, 0.9, 0.7, 0.8], [True, True, False, True], revisits=4)
    np.testing.assert_allclose(c.recall, [0, 0.25, 0.5, 0.5, 0.75])
    np.testing.assert_allclose(c.precision, [1, 1, 1, 2 / 3, 0.75])
    assert c.thresholds[0] == np.inf and c.thresholds[1:].tolist() == [0.9, 0.8, 0.7, 0.6]
    assert truth.recall_at_precision(c, 1.0) == 0.5
    assert truth.recall_at_precision(c, 0.99) == 0.5
    assert truth.recall_at_precision(c, 0.75) == 0.75
    assert truth.average_precision(c) == pytest.approx(0.25 + 0.25 + 0.25 * 0.75)


def test_pr_curve_ties_are_accepted_together() -> None:
    c = truth.pr_curve([0.9, 0.9, 0.5], [True, False, True], revisits=2)
    np.testing.assert_allclose(c.recall, [0, 0.5, 1.0])
    np.testing.assert_allclose(c.precision, [1, 0.5, 2 / 3])
    assert truth.recall_at_precision(c, 1.0) == 0.0  # the best score already holds a wrong one
    assert truth.average_precision(c) == pytest.approx(0.5 * 0.5 + 0.5 * 2 / 3)


def test_recall_at_99_percent_precision_differs_from_100() -> None:
    """50 correct, 1 wrong, 49 correct (100 revisits): precision 0.99 at the end."""
    correct = np.r_[np.ones(50, bool), False, np.ones(49, bool)]
    scores = -np.arange(100.0)
    c = truth.pr_curve(scores, correct, revisits=100)
    assert truth.recall_at_precision(c, 1.0) == pytest.approx(0.50)
    assert truth.recall_at_precision(c, 0.99) == pytest.approx(0.99)


def test_queries_without_a_proposal_are_never_accepted() -> None:
    c = truth.pr_curve([-np.inf, np.nan, 0.3], [False, False, True], revisits=3)
    np.testing.assert_allclose(c.recall, [0, 1 / 3])
    assert truth.recall_at_precision(c, 1.0) == pytest.approx(1 / 3)
    empty = truth.pr_curve([], [], revisits=0)
    assert truth.average_precision(empty) == 0.0 and truth.recall_at_precision(empty, 1.0) == 0
    with pytest.raises(UserError, match="revisits"):
        truth.pr_curve([0.5, 0.4], [True, True], revisits=1)
    with pytest.raises(UserError, match="scores"):
        truth.pr_curve([0.5], [True, False], revisits=2)


def test_recall_at_k_hand_checked() -> None:
    hits = [[False, True, False], [True, False, False], [False, False, False],
            [False, False, True]]
    has = [True, True, True, False]  # the last query has no revisit: left out
    assert truth.recall_at_k(hits, has, (1, 2, 3)) == {1: pytest.approx(1 / 3),
                                                       2: pytest.approx(2 / 3),
                                                       3: pytest.approx(2 / 3)}
    assert truth.recall_at_k(np.zeros((2, 3), bool), [False, False], (1,)) == {1: 0.0}
    with pytest.raises(UserError, match="K"):
        truth.recall_at_k(hits, has, (0,))


def test_revisit_truth_and_place_correct() -> None:
    has, d = truth.revisit_truth([0, 0], [[3, 0], [1.5, 1.5]])
    assert not has and d == pytest.approx([3.0, np.hypot(1.5, 1.5)])
    assert truth.revisit_truth([0, 0], [[3, 0], [1.9, 0.0]])[0]
    assert truth.revisit_truth([0, 0], [[2.0, 0.0]])[0]  # within 2 m counts
    assert not truth.revisit_truth([0, 0], np.zeros((0, 2)))[0]  # empty database
    assert truth.place_correct([[0, 0], [0, 0]], [[1, 1], [2, 1]]).tolist() == [True, False]


def test_pose_correct_hand_checked() -> None:
    """The match at the origin, the query 1 m ahead: the relative pose is (1, 0, 0)."""
    q, m = np.array([[1.0, 0, 0]] * 4), np.array([[0.0, 0, 0]] * 4)
    rel = np.array([[1.0, 0, 0], [1.25, 0, 0], [1.0, 0.1, np.radians(3)],
                    [1.1, -0.1, np.radians(1.5)]])
    assert truth.pose_correct(q, m, rel).tolist() == [True, False, False, True]
    err = truth.pose_errors(q, m, rel)
    np.testing.assert_allclose(err[:, 0], [0, 0.25, 0.1, np.hypot(0.1, 0.1)], atol=1e-12)
    np.testing.assert_allclose(err[:, 1], [0, 0, 3, 1.5], atol=1e-9)
    far = np.array([[5.0, 0, 0]])
    assert not truth.pose_correct(far, m[:1], [[5.0, 0, 0]])[0]  # right pose, not a revisit


# ------------------------------------------------------------------------ bad input


def test_within_reference_uncertainty_hand_checked() -> None:
    """Tolerances 2 m / 0.2 m / 2 deg widened by 3 sigma: a 2.9 deg error with a
    reference heading sigma of 0.5 deg is inside (2 + 1.5 = 3.5), with 0.2 deg not
    (2.6); a place 2.1 m apart needs a position sigma of at least 0.1 / 3 m; an unknown
    sigma (NaN) is never inside."""
    deg = np.radians
    errors = [[0.05, 2.9], [0.05, 2.9], [0.05, 0.3], [0.05, 0.3], [0.05, 2.9]]
    place = [1.0, 1.0, 2.1, 2.1, 1.0]
    sig = [[0.0, 0.0, deg(0.5)], [0.0, 0.0, deg(0.2)], [0.03, 0.04, 0.0],
           [0.02, 0.0, 0.0], [np.nan, np.nan, np.nan]]
    got = truth.within_reference_uncertainty(errors, place, sig)
    assert got.tolist() == [True, False, True, False, False]


def test_empty_and_one_keyframe_databases_give_no_candidate() -> None:
    run = simulate_run("box", seed=0)
    db = PlaceDatabase()
    assert db.query(polygon_from_scan(run.scans[0])) == []
    db.add(0, polygon_from_scan(run.scans[0]))
    assert db.query(db.descriptors(0), exclude_keys=[0]) == []
    assert db.query(db.descriptors(0), allowed=np.zeros(1, bool)) == []


def test_stages_are_parsed_against_the_config() -> None:
    cfg = PipelineConfig()
    assert lb.parse_stages(None, cfg) == CHEAP
    assert lb.parse_stages("flirt, fused,flirt", cfg) == ["flirt@10", "fused"]
    assert lb.parse_stages("pairs-alone", cfg) == ["pairs-alone"]
    with pytest.raises(UserError, match="unknown stage"):
        lb.parse_stages("sift", cfg)
    with pytest.raises(UserError, match="unknown stage"):
        lb.parse_stages("tangent-alone", cfg)


@pytest.fixture(scope="module")
def sim() -> SimulatedRun:
    return simulate_run("box", seed=3, motion=MotionConfig(laps=1.3), **SIM)


def _truth(run: SimulatedRun):
    gt = run.ground_truth.xytheta()
    return lambda result: gt[[k.scan_index for k in result.keyframes]]


def test_a_reference_covering_too_few_keyframes_is_refused(sim: SimulatedRun) -> None:
    gt = sim.ground_truth.xytheta()

    def sparse(result):
        ref = gt[[k.scan_index for k in result.keyframes]]
        ref[5:] = np.nan
        return ref

    with pytest.raises(UserError, match=r"covers 5 of \d+ keyframes \(\d+\.\d%\)"):
        lb.run_loop_bench("sim", sim.scans[:150], PipelineConfig(), sparse)


def test_short_runs_and_undescribed_keyframes_propose_nothing(
    sim: SimulatedRun, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every database is empty (all keyframes within the recent window), and one keyframe
    gets no polygon: no row proposes anything, every score is -inf, nothing is NaN."""
    real = keyframe_store.polygon_from_scan
    calls = []

    def polygon(scan, config=None):
        calls.append(1)
        if len(calls) == 7:  # the seventh keyframe described
            raise DegeneratePolygonError("no valid beams")
        return real(scan, config)

    monkeypatch.setattr(keyframe_store, "polygon_from_scan", polygon)
    bench = lb.run_loop_bench("sim", sim.scans[:80], PipelineConfig(), _truth(sim))
    assert "no descriptor" in bench.reasons
    assert len(bench.query_keys) == bench.keyframes
    for s in [*bench.stages.values(), bench.final]:
        assert (s.match == -1).all() and np.isneginf(s.score).all()
        assert not np.isnan(s.curve.precision).any()
    assert bench.revisits == 0 and set(bench.reasons) <= {"empty database", "no descriptor"}


# ------------------------------------------------------------------------ end to end


@pytest.fixture(scope="module")
def bench(sim: SimulatedRun) -> lb.LoopBench:
    return lb.run_loop_bench("sim", sim.scans, PipelineConfig(), _truth(sim), max_queries=40)


def test_simulated_world_end_to_end(bench: lb.LoopBench) -> None:
    assert len(bench.query_keys) == 40 and bench.revisits > 5
    assert list(bench.stages) == CHEAP
    for s in [*bench.stages.values(), bench.final]:
        assert len(s.match) == 40 and np.isfinite(s.ms_per_query)
        assert not np.isnan(s.score).any()
        assert (s.correct <= bench.has_revisit).all()  # a correct proposal is a revisit
    # The simulated box is easy: the verified cascade finds most revisits, no wrong one.
    summary = truth.curve_summary(bench.final.curve)
    assert summary["recall_at_p100"] >= 0.5
    assert bench.final.correct.sum() == (bench.accepted & bench.final.correct).sum()
    assert bench.recall_at_k["prefilter"][50] >= bench.recall_at_k["prefilter"][1] > 0.5
    # Every revisit has a nearest true place within 2 m, seen by both submaps.
    near = bench.nearest[bench.has_revisit]
    assert (near[:, 0] >= 0).all() and (near[:, 1] <= 2.0).all()
    assert np.nanmedian(near[:, 3]) > 0.5
    found = bench.prefilter_rank[bench.has_revisit]
    assert math.isclose(float(((found >= 0) & (found < 10)).mean()),
                        bench.recall_at_k["prefilter"][10])
    # A database keyframe within 2 m exists for every query that has a revisit.
    ref = bench.reference
    for i in np.flatnonzero(bench.has_revisit)[:5]:
        k = bench.query_keys[i]
        assert np.hypot(*(ref[: k - 30, :2] - ref[k, :2]).T).min() <= 2.0


def test_report_outputs(bench: lb.LoopBench, tmp_path: Path) -> None:
    import evaluation.loop_bench_report as report

    paths = report.write_outputs(bench, tmp_path / "out")
    for key in ("results", "queries", "pr_curves", "detections", "report"):
        assert paths[key].exists() and paths[key].stat().st_size > 0
    doc = json.loads(paths["results"].read_text())
    assert {"queries", "revisits", "stages", "final", "recall_at_k"} <= set(doc)
    for entry in [*doc["stages"].values(), doc["final"]]:
        assert {"recall_at_p100", "recall_at_p99", "average_precision", "ms_per_query"} <= set(
            entry)
    assert set(doc["recall_at_k"]["prefilter"]) == {"1", "10", "50"}
    lines = paths["queries"].read_text().splitlines()
    assert len(lines) == 41 and lines[0].startswith("keyframe,scan_index,revisit")
    assert lines[0].endswith("prefilter_rank,nearest_key,nearest_m,nearest_dtheta_deg,"
                             "nearest_overlap,check_fitness,check_consistency,"
                             "check_matched_length,check_margin,check_degeneracy,"
                             "check_axis_length,check_axis_hold,check_pinned_length,"
                             "accepted_places,reference_sigma_m,reference_sigma_deg,"
                             "unverifiable")
    rows = list(csv.DictReader(io.StringIO(paths["queries"].read_text())))
    for row in rows:  # an accepted final place has its check's figures
        if row["final_match"]:
            assert int(row["accepted_places"]) >= 1
            assert 0 <= float(row["check_fitness"]) <= 1
    misses = doc["prefilter_misses"]
    assert sum(b["queries"] for b in misses["nearest_m"]) == bench.revisits
    assert "R@100%P" in paths["report"].read_text()


def test_command_on_a_simulated_world(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    code = main(["bench", "loops", "--world", "box", "--limit", "500", "--max-queries", "12",
                 "--stages", "prefilter,fused", "--json"])
    assert code == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["queries"] == 12 and list(doc["stages"]) == ["prefilter", "fused"]
    assert doc["input"] == "simulated box world (seed 0)"


def test_command_refuses_bad_arguments(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    log = tmp_path / "x.clf"
    log.write_text("")
    assert main(["bench", "loops", str(log)]) == 2
    assert "needs a reference" in capsys.readouterr().err
    assert main(["bench", "loops", str(log), "--relations", "a", "--reference", "b"]) == 2
    assert "one of" in capsys.readouterr().err
    assert main(["bench", "loops", "--world", "maze"]) == 2
    assert "unknown world" in capsys.readouterr().err
    assert main(["bench", "loops", "--stages", "sift"]) == 2
    assert "unknown stage" in capsys.readouterr().err


def test_real_corrected_log(tmp_path: Path) -> None:
    """A GMapping-corrected log with its own poses as the reference (a quick subsample)."""
    path = shared_file("carmen-corrected/orebro-corrected.log.gz")
    assert main(["bench", "loops", str(path), "--reference-from-log", "--odometry-noise", "0",
                 "--max-queries", "20", "--stages", "prefilter,fused",
                 "--out", str(tmp_path / "o")]) == 0
    doc = json.loads((tmp_path / "o" / "results.json").read_text())
    assert doc["queries"] == 20 and doc["keyframes_with_reference"] == doc["keyframes"]


def test_command_with_a_tum_reference(sim: SimulatedRun, tmp_path: Path,
                                      capsys: pytest.CaptureFixture) -> None:
    """A simulated log on disk with its ground truth as a TUM file: the same figures as the
    in-memory run with exact truth (the reference is read at the keyframes' stamps)."""
    from data.sim import write_run

    files = write_run(sim, tmp_path / "sim")
    args = ["--max-queries", "10", "--stages", "prefilter,fused", "--json", "--limit", "400"]
    assert main(["bench", "loops", str(files["log"]), "--reference",
                 str(files["groundtruth"]), *args]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["keyframes_with_reference"] == doc["keyframes"] and doc["queries"] == 10


def test_command_with_relations_reports_the_reference_uncertainty(
        sim: SimulatedRun, tmp_path: Path) -> None:
    """A relations reference knows its own uncertainty: every accepted final detection
    gets its sigmas, and the figures with the unverifiable ones set aside are never
    below the benchmark's own."""
    from data.relations import write_relations
    from data.sim import write_run
    from tests.test_slam_benchmark import ground_truth_relations

    files = write_run(sim, tmp_path / "sim")
    write_relations(tmp_path / "sim.relations", ground_truth_relations(sim))
    assert main(["bench", "loops", str(files["log"]), "--relations",
                 str(tmp_path / "sim.relations"), "--max-queries", "12", "--limit", "400",
                 "--stages", "prefilter,fused", "--out", str(tmp_path / "o")]) == 0
    doc = json.loads((tmp_path / "o" / "results.json").read_text())
    final = doc["final"]
    assert 0 <= final["unverifiable"] <= final["accepted"]
    assert final["verifiable"]["recall_at_p100"] >= final["recall_at_p100"]
    rows = list(csv.DictReader((tmp_path / "o" / "queries.csv").open()))
    accepted = [r for r in rows if r["check_verdict"] == "accepted"]
    assert accepted and all(float(r["reference_sigma_deg"]) > 0 for r in accepted)
    assert all(r["reference_sigma_m"] == "" for r in rows if r["check_verdict"] != "accepted")


def test_prefilter_row_interleaves_the_viewpoint_lists(
    sim: SimulatedRun, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With the query's viewpoints interleaved (`viewpoint_order`), the prefilter row
    orders the own view by the database's lists (`PlaceDatabase.prefilter_lists`)."""
    from slam.config_io import apply_overrides

    config = apply_overrides(PipelineConfig(), [
        "loops.viewpoints.radii=1.5", "loops.viewpoints.count=2",
        "loops.database.query_viewpoints=true", "loops.database.stored_viewpoints=false",
        "loops.database.viewpoint_order=interleave"])
    asked = []
    real = PlaceDatabase.prefilter_lists

    def lists(self, query, rows=None):
        out = real(self, query, rows)
        asked.append(len(out))
        return out

    monkeypatch.setattr(PlaceDatabase, "prefilter_lists", lists)
    bench = lb.run_loop_bench("sim", sim.scans[:200], config, _truth(sim), max_queries=8)
    assert asked and max(asked) == 2
    r = bench.recall_at_k["prefilter"]
    assert 0.0 <= r[1] <= r[10] <= r[50] <= 1.0


def test_the_vote_row_keeps_the_prefilter_s_first_places(sim: SimulatedRun) -> None:
    """With ``loops.database.vote=fuse`` a ``prefilter+vote`` recall row is reported;
    its first ``vote_split`` places are the prefilter row's, so recall@1 is the same."""
    from slam.config_io import apply_overrides

    config = apply_overrides(PipelineConfig(), ["loops.database.vote=fuse"])
    bench = lb.run_loop_bench("sim", sim.scans[:200], config, _truth(sim), max_queries=8)
    r, pre = bench.recall_at_k["prefilter+vote"], bench.recall_at_k["prefilter"]
    assert r[1] == pre[1] and 0.0 <= r[1] <= r[10] <= r[50] <= 1.0
    off = lb.run_loop_bench("sim", sim.scans[:200], PipelineConfig(), _truth(sim),
                            max_queries=8)
    assert "prefilter+vote" not in off.recall_at_k
    assert off.recall_at_k["prefilter"] == pre
