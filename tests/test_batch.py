"""`loopclosure batch` and the task engine, serially and on a 2-worker Dask LocalCluster."""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path

import numpy as np
import pytest

from data.sim import MotionConfig, simulate_run, write_run
from evaluation.cluster import Engine, parse_cluster
from slam.cli.main import main

distributed = pytest.importorskip("distributed", reason="needs the `distributed` package")

MARKERS: Path | None = None


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> dict[str, Path]:
    """Two tiny simulated CARMEN logs, a garbage file, a relations file for the first
    log and a reference trajectory for the second."""
    root = tmp_path_factory.mktemp("batch")
    (root / "logs").mkdir()
    (root / "relations").mkdir()
    (root / "references").mkdir()
    for name, seed in (("a", 1), ("b", 2)):
        run = simulate_run("box", seed=seed, motion=MotionConfig(laps=0.25))
        files = write_run(run, root / f"sim-{name}")
        files["log"].rename(root / "logs" / f"{name}.clf")
        if name == "a":
            _write_relations(root / "relations" / "a.relations", files["groundtruth"])
        else:
            files["groundtruth"].rename(root / "references" / "b.tum")
    (root / "logs" / "garbage.log").write_bytes(b"this is no log\n\x00\xff\x17 at all\n")
    return {"root": root, "a": root / "logs" / "a.clf", "b": root / "logs" / "b.clf",
            "garbage": root / "logs" / "garbage.log"}


def _write_relations(path: Path, groundtruth: Path) -> None:
    """Relations between scans 10 apart, from the simulator's true poses (planar)."""
    gt = np.loadtxt(groundtruth)
    theta = 2 * np.arctan2(gt[:, 6], gt[:, 7])
    lines = []
    for i in range(0, len(gt) - 10, 10):
        j = i + 10
        dx, dy = gt[j, 1] - gt[i, 1], gt[j, 2] - gt[i, 2]
        c, s = np.cos(theta[i]), np.sin(theta[i])
        dtheta = np.arctan2(np.sin(theta[j] - theta[i]), np.cos(theta[j] - theta[i]))
        lines.append(f"{gt[i, 0]:.6f} {gt[j, 0]:.6f} {c * dx + s * dy:.6f} "
                     f"{-s * dx + c * dy:.6f} 0 0 0 {dtheta:.6f}\n")
    path.write_text("".join(lines))


def _batch(logs: dict[str, Path], out: Path, *extra: str) -> tuple[int, list[dict]]:
    code = main(["batch", str(logs["a"]), str(logs["b"]), str(logs["garbage"]),
                 "--out", str(out), "--no-map", "--json",
                 "--relations-dir", str(logs["root"] / "relations"),
                 "--reference-dir", str(logs["root"] / "references"), *extra])
    return code, json.loads((out / "batch.json").read_text())["runs"]


def _comparable(row: dict) -> dict:
    """A row without what depends on the machine and the output folder."""
    return {k: v for k, v in row.items() if k not in ("wall_s", "peak_rss_mb", "out")}


@pytest.fixture(scope="module")
def serial_rows(logs, tmp_path_factory):
    out = tmp_path_factory.mktemp("serial") / "out"
    return out, *_batch(logs, out)


def test_batch_gives_two_results_and_one_clear_error_row(serial_rows) -> None:
    out, code, rows = serial_rows
    assert code == 1  # one input failed
    assert [r["name"] for r in rows] == ["a", "b", "garbage"]
    a, b, bad = rows
    for r in (a, b):
        assert r["status"] == "done" and r["error"] is None
        assert r["scans"] > 50 and r["keyframes"] > 5
        assert r["wall_s"] > 0 and r["peak_rss_mb"] > 0
        assert (Path(r["out"]) / "trajectory.tum").is_file()
        assert (Path(r["out"]) / "config.yaml").is_file()
        summary = json.loads((Path(r["out"]) / "summary.json").read_text())
        assert summary["scans"] == r["scans"]
    assert a["relations"]["relations_used"] > 5 and a["relations"]["trans_abs_mean"] < 0.2
    assert a["ate"] is None and b["relations"] is None
    assert b["ate"]["rmse_m"] < 0.5 and b["ate"]["matched"] == b["scans"]
    assert bad["status"] == "failed" and bad["scans"] is None
    assert bad["error"].startswith(str(bad["input"])) and "unknown format" in bad["error"]
    assert not (out / "garbage").exists()
    md = (out / "batch.md").read_text()
    assert md.count("\n| ") == 4  # the header and one row per input
    assert "unknown format" in md


def test_cluster_results_equal_the_serial_ones(serial_rows, logs, cluster, tmp_path) -> None:
    out, _, rows = serial_rows
    code, cluster_rows = _batch(logs, tmp_path / "out", "--cluster", cluster)
    assert code == 1
    assert [_comparable(r) for r in cluster_rows] == [_comparable(r) for r in rows]
    for name in ("a", "b"):
        for file in ("trajectory.tum", "loops.csv", "graph.g2o"):
            assert (tmp_path / "out" / name / file).read_bytes() == \
                (out / name / file).read_bytes(), (name, file)


def kill_own_worker_once(item: tuple[str, int]) -> int:
    """``2 * n``; on its first attempt at item 1 it kills its own worker process."""
    markers, n = item
    marker = Path(markers) / f"{n}.attempted"
    if n == 1 and not marker.exists():
        marker.write_text(str(os.getpid()))
        os.kill(os.getpid(), signal.SIGKILL)
    return 2 * n


def test_a_killed_worker_still_gives_the_complete_table(cluster, tmp_path) -> None:
    items = [(str(tmp_path), n) for n in range(4)]
    with Engine(cluster, echo=lambda line: None) as engine:
        outcomes = list(engine.map(kill_own_worker_once, items, progress=False))
    assert (tmp_path / "1.attempted").is_file()  # the worker did die once
    assert [(o.index, o.status, o.value) for o in outcomes] == [
        (n, "done", 2 * n) for n in range(4)
    ]


def interrupt_at_two(n: int) -> int:
    if n == 2:
        raise KeyboardInterrupt
    return n


def test_ctrl_c_keeps_what_finished_and_marks_the_rest_interrupted() -> None:
    with Engine(None) as engine:
        outcomes = list(engine.map(interrupt_at_two, range(4), progress=False))
    assert [o.status for o in outcomes] == ["done", "done", "interrupted", "interrupted"]


def test_cluster_addresses() -> None:
    assert parse_cluster(None).kind == "serial"
    assert parse_cluster("local").workers >= 1
    assert parse_cluster("local:3").workers == 3
    assert parse_cluster("tcp://10.0.0.1:8786").address == "tcp://10.0.0.1:8786"
    assert parse_cluster("head-node:8786").kind == "scheduler"
    from data.errors import UserError

    for bad in ("local:0", "local:x", "nonsense"):
        with pytest.raises(UserError, match="--cluster"):
            parse_cluster(bad)
