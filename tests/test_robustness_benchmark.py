"""The robustness sweep's verdicts: holds, objective-limited, breakdown ratios; tls_gap rows."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from data import se2
from evaluation.robustness import run_robustness
from slam.pose_graph import PoseGraph

ROOT = Path(__file__).resolve().parents[1]


def _benchmark():
    spec = importlib.util.spec_from_file_location("robustness_bench",
                                                  ROOT / "benchmarks" / "robustness.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _row(ratio: float, ate: float, obeyed: int = 0, gap: float = 0.0) -> dict:
    return {"outlier_ratio": ratio, "ate_vs_clean_m": ate, "false_factors_obeyed": obeyed,
            "tls_gap": gap, "seconds": 1.0}


def test_holds_objective_limited_and_the_two_breakdowns() -> None:
    b = _benchmark()
    assert b.holds(_row(0.0, 5e-4)) and not b.holds(_row(0.0, 2e-3))
    assert b.holds(_row(0.5, 0.04)) and not b.holds(_row(0.5, 0.04, obeyed=1))
    assert b.objective_limited(_row(0.5, 0.2, obeyed=1, gap=-2.5))
    assert not b.objective_limited(_row(0.5, 0.2, obeyed=1, gap=3.0))
    assert not b.objective_limited(_row(0.5, 0.01))  # a row that holds is not a failure
    rows = [_row(0.0, 0.0), _row(0.1, 0.0), _row(0.3, 0.2, 1, -1.0), _row(0.5, 0.0),
            _row(0.7, 9.0, 5, 40.0)]
    ratios = [0.0, 0.1, 0.3, 0.5, 0.7]
    assert b.breakdown(rows, ratios)[0] == 0.1
    assert b.breakdown(rows, ratios, b.solver_holds)[0] == 0.5
    assert b.breakdown([_row(0.0, 1.0)], [0.0])[0] is None


def _ring(n: int = 40) -> PoseGraph:
    """A 40-pose circle driven twice with exact measurements, a loop at every revisit."""
    info = np.diag([100.0, 100.0, 400.0])
    step = np.array([1.0, 0.0, 2 * np.pi / n])
    graph = PoseGraph(dim=2)
    pose = np.zeros(3)
    for k in range(2 * n):
        graph.add_pose(k, pose)
        if k:
            graph.add_odometry(k - 1, k, step, info)
        pose = se2.compose(pose, step)
    for k in range(n, 2 * n):
        graph.add_loop(k - n, k, np.zeros(3), info)
    return graph


def test_tls_gap_is_zero_at_the_reference_and_positive_for_least_squares() -> None:
    rows = run_robustness(_ring(), [0.0, 0.3], ["none"], seed=1)
    assert abs(rows[0].tls_gap) < 1e-6
    # Plain least squares over false loops is a worse TLS solution than the clean one.
    assert rows[1].tls_gap > 0 and rows[1].false_factors_obeyed > 0


def test_cluster_cells_equal_the_serial_sweep(tmp_path, capsys) -> None:
    import json

    from data.g2o import write_g2o
    from evaluation.cluster import map_tasks
    from evaluation.robustness import robustness_cells, robustness_task
    from slam.cli.main import main

    graph = _ring()
    path = tmp_path / "ring.g2o"
    write_g2o(path, graph.to_g2o())
    serial = run_robustness(graph, [0.0, 0.3], ["none", "cauchy"], seed=1,
                            policies=["random", "grouped"], group_size=3)
    cells = robustness_cells(str(path), graph, [0.0, 0.3], ["none", "cauchy"], seed=1,
                             policies=["random", "grouped"], group_size=3)
    tasks = [o.value for o in map_tasks(robustness_task, cells, progress=False)]

    def figures(rows: list) -> list[dict]:
        return [{k: v for k, v in r.to_json().items() if k != "seconds"} for r in rows]

    assert figures(tasks) == figures(serial)
    # The CLI on a LocalCluster of two workers gives the same rows.
    argv = ["eval", "robustness", "--g2o", str(path), "--outliers", "0,30", "--kernels",
            "none,cauchy", "--seed", "1", "--json"]
    assert main(argv) == 0
    here = json.loads(capsys.readouterr().out)["results"]
    assert main([*argv, "--cluster", "local:2"]) == 0
    there = json.loads(capsys.readouterr().out)["results"]
    drop = lambda rows: [{k: v for k, v in r.items() if k != "seconds"} for r in rows]  # noqa: E731
    assert drop(there) == drop(here)


def test_a_single_cell_reads_scales_and_corrupts_the_graph(tmp_path) -> None:
    """`corrupted_graph`: 30% of the ring's 40 loops false among 40 / 0.7 loops, marked;
    the odometry information scaled; a given reference is used as given."""
    from data.g2o import write_g2o
    from evaluation.robustness import clean_optimum, corrupted_graph

    ring = _ring()
    path = tmp_path / "ring.g2o"
    write_g2o(path, ring.to_g2o())
    graph, reference, corrupted, false = corrupted_graph(str(path), 0.1, 0.3, "random", 1)
    assert len(false) == len(corrupted.loops) and false.sum() == len(corrupted.loops) - 40
    assert 0.25 <= false.mean() <= 0.35
    np.testing.assert_allclose(graph.odometry[0].information, 0.1 * ring.odometry[0].information)
    clean = clean_optimum(graph)
    assert max(np.abs(reference[k] - clean[k]).max() for k in clean) < 1e-9
    given = {k: v + 1.0 for k, v in reference.items()}
    assert corrupted_graph(str(path), 0.1, 0.3, "random", 1, reference=given)[1] is given
