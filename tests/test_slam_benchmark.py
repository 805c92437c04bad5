"""`loopclosure bench slam`: the runner (evaluation.slam_benchmark and its modules) and its
command."""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import evaluation.loop_verdicts as lv
import evaluation.slam_benchmark as sb
import evaluation.slam_input as si
import evaluation.slam_methods as sm
import evaluation.slam_reference as sr
import evaluation.slam_report as report
from data import se2
from data.carmen import write_log
from data.errors import UserError
from data.relations import write_relations
from data.sim import MotionConfig, SimulatedRun, simulate_run, write_run
from data.types import Relation, Trajectory
from evaluation.trajectory_error import trajectory_errors
from slam.cli.common import to_json_text
from slam.cli.main import main
from slam.config import PipelineConfig
from tests.helpers import shared_file

SIM = {"fov_deg": 180.0, "beams": 181, "max_range": 12.0, "noise_sigma": 0.02}
METHOD_KEYS = {"method", "wall_s", "ms_per_scan", "relations", "ate", "loops"}
RELATION_KEYS = {"trans_abs_mean", "trans_abs_std", "rot_abs_mean_deg", "rot_abs_std_deg",
                 "relations_used", "relations_total"}


def ground_truth_relations(run: SimulatedRun, step: int = 5, long: int = 40,
                           seed: int = 0) -> list[Relation]:
    """Relations as the Freiburg files hold them, exact from the simulator's ground truth:
    a chain every `step` scans plus `long` random revisit pairs (the loop relations)."""
    xyt, stamps = run.ground_truth.xytheta(), run.ground_truth.stamps
    pairs = [(i, i + step) for i in range(0, len(stamps) - step, step)]
    revisits = run.revisits(1.0, 30.0)
    pick = np.random.default_rng(seed).choice(len(revisits), min(long, len(revisits)),
                                              replace=False)
    pairs += [(int(a), int(b)) for a, b in revisits[pick]]
    return [Relation(float(stamps[i]), float(stamps[j]), se2.to_se3(se2.between(xyt[i], xyt[j])))
            for i, j in pairs]


def sim_input(run: SimulatedRun, name: str = "sim") -> si.SlamInput:
    """The simulated scans as the benchmark's in-memory input."""
    logged = np.array([s.odom for s in run.scans])
    return si.SlamInput(name, list(run.scans), 0.0, logged)


@pytest.fixture(scope="module")
def sim() -> SimulatedRun:
    return simulate_run("box", seed=3, motion=MotionConfig(laps=1.3), **SIM)


@pytest.fixture(scope="module")
def captured(sim: SimulatedRun, tmp_path_factory) -> tuple[sb.SlamBenchmark, dict]:
    """All three methods on 665 simulated scans, with relations and the true trajectory,
    writing into a folder (no map); and each method's full run, kept as it ran here."""
    runs: dict[str, sm.MethodRun] = {}
    real = sb.run_method

    def keep(name, data, config, progress=si.no_progress):
        runs[name] = real(name, data, config, progress)
        return runs[name]

    sb.run_method = keep
    try:
        bench = sb.run_slam_benchmark(
            sim_input(sim), list(sm.METHODS), PipelineConfig(),
            relations=ground_truth_relations(sim), relations_file="sim.relations",
            reference=sim.ground_truth, reference_name="groundtruth.tum",
            out=tmp_path_factory.mktemp("bench_out"), write_map=False,
        )
    finally:
        sb.run_method = real
    return bench, runs


@pytest.fixture(scope="module")
def bench(captured) -> sb.SlamBenchmark:
    return captured[0]


# ------------------------------------------------------------------------ small parts


def test_parse_methods() -> None:
    assert sm.parse_methods("all") == ["pipeline", "wheel", "kiss-icp"]
    assert sm.parse_methods(" wheel, kiss ,wheel") == ["wheel", "kiss-icp"]
    with pytest.raises(UserError, match="unknown method"):
        sm.parse_methods("pipeline,cartographer")
    with pytest.raises(UserError, match="at least one"):
        sm.parse_methods(" , ")


def test_evaluation_stamps_fall_back_to_the_scan_index() -> None:
    stamps, rule = si.evaluation_stamps(np.array([3.0, 2.0, 5.0]))
    assert rule == "scan stamps" and stamps.tolist() == [3.0, 2.0, 5.0]
    stamps, rule = si.evaluation_stamps(np.zeros(4))
    assert rule == "scan index" and stamps.tolist() == [0.0, 1.0, 2.0, 3.0]


def test_trajectory_at_stamps_sorts_and_keeps_the_first_duplicate() -> None:
    poses = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0]])
    traj = sr.trajectory_at_stamps(np.array([2.0, 1.0, 2.0, 0.5]), poses)
    assert traj.stamps.tolist() == [0.5, 1.0, 2.0]
    assert traj.xytheta()[:, 0].tolist() == [3.0, 1.0, 0.0]


def test_relations_reference_hand_checked() -> None:
    """Truth: 0.5 m per scan along x; the odometry says 1 m (scale error 2).

    Relations 0-2, 2-4, 4-9 (true deltas).  Keyframes 0, 1, 3, 6, 9.  Keyframe 1 sits
    halfway (by odometry, equal gap weights) between relation nodes 0 and 2, so its
    reference is about 0.5 m; keyframe 6 lies in a 5 m odometry gap (> 2 m): no reference.
    """
    stamps = np.arange(10, dtype=float) + 100.0
    truth = np.column_stack([0.5 * np.arange(10), np.zeros(10), np.zeros(10)])
    odometry = np.column_stack([np.arange(10.0), np.zeros(10), np.zeros(10)])
    rels = [Relation(stamps[i], stamps[j], se2.to_se3(se2.between(truth[i], truth[j])))
            for i, j in ((0, 2), (2, 4), (4, 9))]
    ref = sr.relations_reference(stamps, rels, [0, 1, 3, 6, 9], odometry)
    assert ref.scan_index.tolist() == [0, 1, 3, 9]
    assert ref.nodes == 7 and ref.relations == 3 and ref.keyframes == 5
    # Weighted least squares along x: a relation (variance 1e-4 m^2) against the gap
    # edges beside it (MotionNoise: 0.1^2 m^2 per metre + 1e-6 floor, in series) leaves
    # the relation the share var_rel / (var_rel + var_gaps) of the disagreement.
    var_rel, var_m, floor = 0.01**2, 0.1**2, 1e-6
    e1 = 1e-4 * 1.0 / (var_rel + 2 * (var_m + floor))  # relations 0-2 and 2-4: 1 m vs 2 m
    e2 = 1e-4 * 2.5 / (var_rel + 5 * var_m + 2 * floor)  # relation 4-9: 2.5 m vs 5 m
    expect = [0.0, (1 + e1) / 2, 1.5 * (1 + e1), 2 * (1 + e1) + 2.5 + e2]
    np.testing.assert_allclose(ref.poses[:, 0], expect, atol=1e-6)
    assert max(abs(np.array(expect) - [0.0, 0.5, 1.5, 4.5])) < 0.02  # the relations win
    np.testing.assert_allclose(ref.poses[:, 1:], 0.0, atol=1e-6)
    assert ref.fit_trans_mean_m == pytest.approx((2 * e1 + e2) / 3, abs=1e-6)
    traj = ref.trajectory()
    assert traj.stamps.tolist() == [0.0, 1.0, 3.0, 9.0]  # scan-index time


def test_relations_reference_without_relations_in_range_is_empty() -> None:
    stamps = np.arange(5.0)
    rel = [Relation(50.0, 51.0, np.eye(4))]
    ref = sr.relations_reference(stamps, rel, [0, 2, 4], np.zeros((5, 3)))
    assert len(ref.scan_index) == 0 and ref.nodes == 0


@settings(max_examples=15, deadline=None)
@given(x=st.floats(-50, 50), y=st.floats(-50, 50), th=st.floats(-3.1, 3.1))
def test_relations_reference_follows_the_odometry_frame(x: float, y: float, th: float) -> None:
    """Moving the gap odometry's frame by T moves the reference by T (first node held)."""
    rng = np.random.default_rng(1)
    steps = np.column_stack([rng.uniform(0.2, 0.4, 30), rng.normal(0, 0.02, 30),
                             rng.normal(0, 0.1, 30)])
    truth = np.zeros((31, 3))
    for k, s in enumerate(steps):
        truth[k + 1] = se2.compose(truth[k], s)
    odometry = se2.compose(truth, np.array([0.01, 0.0, 0.005]))  # biased per-scan error
    odometry[0] = truth[0]
    stamps = np.arange(31, dtype=float)
    rels = [Relation(float(i), float(i + 4), se2.to_se3(se2.between(truth[i], truth[i + 4])))
            for i in range(0, 27, 4)]
    kfs = list(range(0, 31, 3))
    base = sr.relations_reference(stamps, rels, kfs, odometry)
    moved = sr.relations_reference(stamps, rels, kfs, se2.compose(np.array([x, y, th]),
                                                                  odometry))
    expect = se2.compose(np.array([x, y, th]), base.poses)
    np.testing.assert_allclose(moved.poses[:, :2], expect[:, :2], atol=1e-5)
    np.testing.assert_allclose(se2.wrap_angle(moved.poses[:, 2] - expect[:, 2]), 0, atol=1e-6)


def test_synthetic_odometry_and_logged_reference(sim: SimulatedRun) -> None:
    """A corrected log carries the reference in its odometry: --odometry-noise replaces it."""
    truth = sim.ground_truth.xytheta()[:50]
    scans = [dataclasses.replace(s, odom=p) for s, p in zip(sim.scans[:50], truth, strict=True)]
    clean = si.SlamInput("corrected", scans, 0.0, truth)
    with pytest.raises(UserError, match="--odometry-noise"):
        sr.logged_reference(clean)
    noisy = si.synthetic_odometry(scans, truth, seed=4)
    odom = np.array([s.odom for s in noisy])
    np.testing.assert_allclose(odom[0], truth[0])
    drift = np.hypot(*(odom[-1, :2] - truth[-1, :2]))
    assert 1e-3 < drift < 1.0
    again = np.array([s.odom for s in si.synthetic_odometry(scans, truth, seed=4)])
    np.testing.assert_array_equal(odom, again)
    ref = sr.logged_reference(si.SlamInput("corrected", noisy, 0.0, truth, odometry_noise=4))
    np.testing.assert_allclose(ref.xytheta(), truth, atol=1e-9)


# ------------------------------------------------------------------ on the simulator


def test_pipeline_beats_wheel_odometry_on_relations_and_ate(bench: sb.SlamBenchmark) -> None:
    rows = {r["method"]: r for r in bench.reports}
    assert list(rows) == ["pipeline", "wheel", "kiss-icp"]
    pipe, wheel = rows["pipeline"]["relations"], rows["wheel"]["relations"]
    assert pipe["relations_used"] == pipe["relations_total"] == len(bench.relations_used) > 100
    assert pipe["trans_abs_mean"] < 0.05
    assert pipe["trans_abs_mean"] < 0.2 * wheel["trans_abs_mean"]
    assert pipe["rot_abs_mean_deg"] < wheel["rot_abs_mean_deg"]
    assert rows["pipeline"]["ate"]["ate_rmse"] < 0.2 * rows["wheel"]["ate"]["ate_rmse"]
    for r in rows.values():
        assert r["wall_s"] > 0 and r["ms_per_scan"] == pytest.approx(
            1000 * r["wall_s"] / len(bench.input.scans))


def test_json_document_keys(bench: sb.SlamBenchmark) -> None:
    doc = json.loads(to_json_text(report.json_document(bench)))
    assert doc["scans"] == len(bench.input.scans) and doc["input"] == "sim"
    assert doc["relations"]["in_range"] == doc["relations"]["in_file"]
    for m in doc["methods"]:
        assert METHOD_KEYS <= set(m)
        assert RELATION_KEYS <= set(m["relations"])
        assert {"ate_rmse", "rpe_trans_rmse"} <= set(m["ate"])
    loops = {m["method"]: m["loops"] for m in doc["methods"]}
    assert loops["wheel"] is None and loops["kiss-icp"] is None
    pipe = loops["pipeline"]
    assert pipe["proposed"] == pipe["accepted"] + pipe["rejected_by_check"] + pipe[
        "rejected_by_gnc"]
    assert pipe["evaluated_against"] == "reference"
    assert set(pipe["against"]) == {"reference", "relations"}
    assert doc["relations_reference"]["keyframes"] == pipe["keyframes"]


def test_loop_precision_against_both_references(bench: sb.SlamBenchmark) -> None:
    loops = bench.reports[0]["loops"]
    truth, rel = loops["against"]["reference"], loops["against"]["relations"]
    assert loops["accepted"] >= 10
    assert truth["precision"] >= 0.99 and truth["recall"] > 0.3
    assert truth["verifiable"] == truth["proposals"] == loops["proposed"]
    # The reference built from relations agrees with the true one on nearly every loop.
    assert rel["precision"] >= 0.99
    assert rel["verifiable"] >= 0.9 * rel["proposals"]
    assert abs(rel["true_positives"] - truth["true_positives"]) <= 2


def test_relations_reference_matches_ground_truth(bench: sb.SlamBenchmark,
                                                  sim: SimulatedRun) -> None:
    ref = bench.relations_ref
    assert ref is not None and ref.gap_odometry == "front end (icp2d)"
    assert len(ref.scan_index) >= 0.9 * ref.keyframes
    assert ref.fit_trans_mean_m < 0.005
    truth = Trajectory.from_xytheta(np.arange(len(sim.scans), dtype=float),
                                    sim.ground_truth.xytheta())
    err = trajectory_errors(ref.trajectory(), truth)
    assert err.ate_rmse < 0.03  # the wheel odometry alone is off by metres (ATE above)


def test_a_wrong_loop_transform_is_a_false_positive(captured) -> None:
    """The precision can fail: one accepted loop moved by 0.5 m becomes a false positive."""
    bench, runs = captured
    result = runs["pipeline"].result
    event = result.accepted_loops[0]
    kept = event.candidate.relative.copy()
    try:
        event.candidate.relative = se2.compose(kept, np.array([0.5, 0.0, 0.0]))
        doc = lv.loop_evaluation(result, bench.relations_ref.trajectory())
    finally:
        event.candidate.relative = kept
    assert doc["false_positives"] == 1 and doc["precision"] < 1.0


def test_table_and_outputs(bench: sb.SlamBenchmark) -> None:
    headers, rows = report.table_rows(bench)
    assert headers == ["measure", "pipeline", "wheel", "kiss-icp"]
    labels = [r[0] for r in rows]
    for label in ("wall [s]", "relations trans [m]", "ATE rmse [m]", "loops accepted",
                  "loop precision (reference)", "loop recall (relations)"):
        assert label in labels
    assert all(len(r) == 4 for r in rows)
    tmp_path = bench.out
    paths = report.write_outputs(bench)
    for name in ("report.md", "results.json", "trajectories.png", "pipeline.tum", "wheel.tum",
                 "kiss-icp.tum", "pipeline/trajectory.tum", "pipeline/loops.csv",
                 "pipeline/summary.json", "pipeline/config.yaml"):
        assert (tmp_path / name).is_file(), name
    assert "| relations trans [m] |" in paths["report"].read_text()
    assert json.loads((tmp_path / "results.json").read_text())["scans"] == len(bench.input.scans)


def test_loop_verdicts_agree_with_the_counts(bench: sb.SlamBenchmark) -> None:
    """The per-loop CSV says which loops were true, consistently with the JSON counts."""
    tmp_path = bench.out
    loops = bench.reports[0]["loops"]
    for name in ("reference", "relations"):
        with (tmp_path / "pipeline" / f"loops_vs_{name}.csv").open() as f:
            rows = list(csv.DictReader(f))
        assert len(rows) == loops["proposed"]
        kept = [r for r in rows if r["accepted"] == "1" and r["rejected_by_gnc"] == "0"]
        doc = loops["against"][name]
        assert sum(r["verdict"] == "true" for r in kept) == doc["true_positives"]
        assert sum(r["verdict"] == "false" for r in kept) == doc["false_positives"]
        assert sum(r["verdict"] == "unverifiable" for r in rows) == doc["unverifiable"]
        for r in rows:
            if r["verdict"] == "true":
                assert float(r["error_m"]) <= 0.2 and float(r["error_deg"]) <= 2.0
                assert float(r["reference_distance_m"]) <= 2.0
            assert int(r["scan_a"]) < int(r["scan_b"])


def test_bad_relations_and_reference_fail_before_any_run(sim: SimulatedRun) -> None:
    data = sim_input(sim)
    far = [Relation(1e6, 1e6 + 1, np.eye(4))]
    with pytest.raises(UserError, match="none of its 1 relations"):
        sb.run_slam_benchmark(data, ["pipeline"], PipelineConfig(), relations=far)
    shifted = Trajectory(sim.ground_truth.stamps + 1000.0, sim.ground_truth.poses)
    with pytest.raises(UserError, match="only 0 of its"):
        sb.run_slam_benchmark(data, ["pipeline"], PipelineConfig(), reference=shifted,
                              reference_name="shifted.tum")


def test_a_failing_method_is_reported_and_the_others_still_run(sim: SimulatedRun, monkeypatch,
                                                               tmp_path: Path) -> None:
    real = sm.run_odometry

    def broken(name, scans, config, progress=si.no_progress):
        if name == "kiss-icp":
            raise RuntimeError("Indeterminate linear system\nmore detail")
        return real(name, scans, config, progress)

    monkeypatch.setattr(sm, "run_odometry", broken)
    run = simulate_run("box", seed=5, motion=MotionConfig(laps=0.3), **SIM)
    with pytest.warns(UserWarning, match="kiss-icp failed on sim: RuntimeError: Indeterminate"):
        bench = sb.run_slam_benchmark(sim_input(run), ["kiss-icp", "wheel"], PipelineConfig(),
                                      reference=run.ground_truth, out=tmp_path)
    kiss, wheel = bench.reports
    assert kiss["error"] == "RuntimeError: Indeterminate linear system" and kiss["ate"] is None
    assert wheel["error"] is None and wheel["ate"]["ate_rmse"] > 0
    _, rows = report.table_rows(bench)
    assert rows[0] == ["status", "failed (RuntimeError)", "ok"]
    assert next(r for r in rows if r[0] == "ATE rmse [m]")[1] == "-"
    report.write_outputs(bench)
    assert (tmp_path / "wheel.tum").is_file() and not (tmp_path / "kiss-icp.tum").exists()


# ----------------------------------------------------------------------- command line


@pytest.fixture(scope="module")
def sim_files(sim: SimulatedRun, tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("bench_slam")
    files = write_run(sim, folder)
    files["relations"] = folder / "sim.relations"
    write_relations(files["relations"], ground_truth_relations(sim))
    return files


def test_cli_json_and_out(sim_files: dict[str, Path], tmp_path: Path, capsys) -> None:
    out = tmp_path / "report"
    code = main(["bench", "slam", str(sim_files["log"]), "--relations",
                 str(sim_files["relations"]), "--reference", str(sim_files["groundtruth"]),
                 "--methods", "pipeline,wheel", "--limit", "300", "--no-map",
                 "--set", "loops.global_every=2", "--out", str(out), "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    doc = json.loads(captured.out)
    assert doc["scans"] == 300
    assert [m["method"] for m in doc["methods"]] == ["pipeline", "wheel"]
    assert doc["relations"]["in_range"] < doc["relations"]["in_file"]
    for m in doc["methods"]:
        assert METHOD_KEYS <= set(m) and m["relations"]["relations_used"] > 0
    assert (out / "report.md").is_file() and (out / "pipeline" / "trajectory.tum").is_file()
    cfg = (out / "pipeline" / "config.yaml").read_text()
    assert "global_every: 2" in cfg


def test_cli_table(sim_files: dict[str, Path], capsys) -> None:
    code = main(["bench", "slam", str(sim_files["log"]), "--relations",
                 str(sim_files["relations"]), "--methods", "wheel,kiss-icp", "--limit", "80"])
    out = capsys.readouterr().out
    assert code == 0
    assert "wheel" in out and "kiss-icp" in out and "relations trans [m]" in out
    assert "80 scans read" in out


def test_cli_corrected_log_with_synthetic_odometry(sim: SimulatedRun, tmp_path: Path,
                                                   capsys) -> None:
    """A log whose odometry fields are the true poses (like the GMapping-corrected logs)
    and whose stamps are all equal: --odometry-noise and --reference-from-log."""
    truth = sim.ground_truth.xytheta()[:120]
    scans = [dataclasses.replace(s, odom=p, stamp=0.0)
             for s, p in zip(sim.scans[:120], truth, strict=True)]
    log = tmp_path / "corrected.log"
    write_log(log, scans, odometry=[(0.0, p) for p in truth])
    code = main(["bench", "slam", str(log), "--methods", "wheel,kiss-icp",
                 "--odometry-noise", "0", "--reference-from-log", "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    doc = json.loads(captured.out)
    assert doc["trajectory_stamps"] == "scan index" and doc["odometry_noise"] == 0
    wheel, kiss = (m["ate"] for m in doc["methods"])
    assert wheel["matched"] == 120
    assert wheel["ate_rmse"] > 1e-3  # the synthetic odometry drifts from the reference
    assert kiss["ate_rmse"] < wheel["ate_rmse"]
    # without the synthetic odometry the wheel row would be the reference itself
    assert main(["bench", "slam", str(log), "--methods", "wheel",
                 "--reference-from-log"]) == 2
    assert "--odometry-noise" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["{tmp}/missing.clf"], "no such file"),
        (["{log}", "--methods", "wheel,gmapping"], "unknown method"),
        (["{log}", "--limit", "1"], "--limit"),
        (["{log}", "--relations", "{tmp}/far.relations"], "none of its 1 relations"),
        (["{log}", "--reference", "{tmp}/missing.tum"], "missing.tum"),
        (["{log}", "--set", "loops.nonsense=1"], "nonsense"),
        (["{log}", "--out", "{tmp}/far.relations"], "exists and is not a folder"),
    ],
)
def test_cli_bad_input_exits_2(sim_files: dict[str, Path], tmp_path: Path, capsys,
                               args: list[str], message: str) -> None:
    write_relations(tmp_path / "far.relations", [Relation(1e6, 1e6 + 1, np.eye(4))])
    argv = ["bench", "slam", *[a.format(tmp=tmp_path, log=sim_files["log"]) for a in args]]
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    lines = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and message in lines[0], err
    assert "Traceback" not in err


# ---------------------------------------------------------------------- the Intel log


@pytest.mark.slow
def test_intel_first_scans() -> None:
    log = shared_file("carmen/intel.clf.bz2")
    rel_path = shared_file("carmen/intel.relations")
    from data.relations import read_relations

    data = si.load_input(log, limit=2000)  # the first revisits come after scan 1,800
    assert len(data.scans) == 2000 and data.logged_poses is not None
    relations = read_relations(rel_path)
    bench = sb.run_slam_benchmark(data, ["pipeline", "wheel"], PipelineConfig(),
                                  relations=relations, relations_file=str(rel_path))
    pipe, wheel = (r["relations"] for r in bench.reports)
    assert 0 < pipe["relations_used"] == pipe["relations_total"] < len(relations)
    assert pipe["trans_abs_mean"] < wheel["trans_abs_mean"]
    assert pipe["trans_abs_mean"] < 0.1
    ref = bench.relations_ref
    assert ref is not None and ref.fit_trans_mean_m < 0.02
    loops = bench.reports[0]["loops"]
    assert loops["evaluated_against"] == "relations"
    rel = loops["against"]["relations"]
    assert loops["accepted"] >= 5 and rel["verifiable"] >= 5
    assert loops["precision"] >= 0.99 and rel["true_positives"] >= 5


def test_relative_sigmas_of_a_relation_chain_hand_checked() -> None:
    """Poses 2 m apart along x joined by two relations of sigma 0.01 (m, m, rad).

    Pair (1, 2): one relation, so its own sigmas.  Pair (0, 2): x and theta add in
    quadrature (sqrt(2) * 0.01); y also gets the lever arm of node 1's heading error
    over the 2 m of the second step: sqrt(2 * 0.01^2 + (2 * 0.01)^2)."""
    from slam.pose_graph import PoseGraph

    graph = PoseGraph(dim=2)
    poses = np.array([[0.0, 0, 0], [2.0, 0, 0], [4.0, 0, 0]])
    for k, p in enumerate(poses):
        graph.add_pose(k, p)
    graph.fixed = {0}
    info = np.diag(np.full(3, 1e4))
    graph.add_loop(0, 1, poses[1], info)
    graph.add_loop(1, 2, poses[1], info)
    built = sr.ReferenceGraph(graph, np.array([10, 20, 30]), np.array([10, 20, 30]), [])
    sig = sr.relative_sigmas(built, poses, [(20, 30), (10, 30), (10, 10)])
    np.testing.assert_allclose(sig[0], [0.01, 0.01, 0.01], rtol=1e-3)
    np.testing.assert_allclose(sig[1], [np.sqrt(2) * 0.01, np.sqrt(6e-4), np.sqrt(2) * 0.01],
                               rtol=1e-3)
    np.testing.assert_allclose(sig[2], 0.0)
    with pytest.raises(UserError):
        sr.relative_sigmas(built, poses, [(10, 25)])
