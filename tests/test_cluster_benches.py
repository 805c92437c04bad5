"""The `bench` commands with ``--cluster``: on a 2-worker Dask LocalCluster, the same
rows as the serial run; a bad address fails before any work."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from data.sim import MotionConfig, simulate_run, write_run
from slam.cli.main import main

distributed = pytest.importorskip("distributed", reason="needs the `distributed` package")

TIMINGS = {"wall_s", "ms_per_scan", "ms_per_query", "read_s", "seconds", "outputs"}


def _untimed(value):
    """`value` without its timings (they are all that may differ between two runs)."""
    if isinstance(value, dict):
        return {k: _untimed(v) for k, v in value.items() if k not in TIMINGS}
    if isinstance(value, list):
        return [_untimed(v) for v in value]
    return value


def _json(capsys, argv: list[str]) -> dict:
    code = main(argv)
    captured = capsys.readouterr()
    assert code == 0, captured.err
    return json.loads(captured.out)


def _fails_at_once(capsys, argv: list[str], out: Path) -> None:
    """`argv` with a bad ``--cluster`` exits 2 with one clear line and writes nothing."""
    code = main([*argv, "--out", str(out), "--cluster", "nonsense"])
    err = capsys.readouterr().err
    assert code == 2 and "--cluster nonsense" in err and "Traceback" not in err
    assert not out.exists()


# ------------------------------------------------------------------------------ slam


@pytest.fixture(scope="module")
def sim_log(tmp_path_factory) -> dict[str, Path]:
    run = simulate_run("box", seed=4, motion=MotionConfig(laps=0.3), fov_deg=180.0, beams=181,
                       max_range=12.0)
    return write_run(run, tmp_path_factory.mktemp("slam_log"))


def test_bench_slam_on_a_cluster_equals_the_serial_run(sim_log, cluster, tmp_path,
                                                       capsys) -> None:
    argv = ["bench", "slam", str(sim_log["log"]), "--reference", str(sim_log["groundtruth"]),
            "--limit", "80", "--no-map", "--json"]
    here = _json(capsys, [*argv, "--out", str(tmp_path / "here")])
    there = _json(capsys, [*argv, "--out", str(tmp_path / "there"), "--cluster", cluster])
    assert [m["method"] for m in there["methods"]] == ["pipeline", "wheel", "kiss-icp"]
    assert all(m["error"] is None for m in there["methods"])
    assert _untimed(there) == _untimed(here)
    for name in ("pipeline.tum", "wheel.tum", "kiss-icp.tum", "pipeline/trajectory.tum",
                 "pipeline/loops.csv", "pipeline/loops_vs_reference.csv"):
        assert (tmp_path / "there" / name).read_bytes() == \
            (tmp_path / "here" / name).read_bytes(), name
    assert (tmp_path / "there" / "report.md").is_file()


def test_bench_slam_bad_cluster_fails_before_reading(sim_log, tmp_path, capsys) -> None:
    _fails_at_once(capsys, ["bench", "slam", str(sim_log["log"])], tmp_path / "out")


# ----------------------------------------------------------------------------- loops


def test_bench_loops_on_a_cluster_equals_the_serial_run(cluster, capsys) -> None:
    """Two stage blocks (the cascade, FLIRT alone), each mapping the world on its worker."""
    argv = ["bench", "loops", "--world", "box", "--limit", "250", "--max-queries", "25",
            "--stages", "pairs,prefilter,flirt@10,fused,flirt-alone", "--json"]
    here = _json(capsys, argv)
    there = _json(capsys, [*argv, "--cluster", cluster])
    assert list(there["stages"]) == ["pairs", "prefilter", "flirt@10", "fused", "flirt-alone"]
    assert there["queries"] > 10
    assert _untimed(there) == _untimed(here)


def test_bench_loops_bad_cluster_fails_before_mapping(tmp_path, capsys) -> None:
    _fails_at_once(capsys, ["bench", "loops", "--world", "box"], tmp_path / "out")


# ---------------------------------------------------------------------------- places


def test_places_blocks_on_a_cluster_equal_the_serial_matrix_bit_for_bit(cluster) -> None:
    from evaluation.place_datasets import load_dataset
    from evaluation.places_matrix import PlaceSource, matrix_by_blocks

    polygons = load_dataset("box", seed=1).polygons
    for name in ("fft", "ring"):
        here, *_ = matrix_by_blocks(name, {}, polygons)
        there, *_ = matrix_by_blocks(name, {}, polygons, source=PlaceSource("box", 1),
                                     cluster=cluster)
        assert here.shape == (len(polygons), len(polygons))
        assert here.tobytes() == there.tobytes(), name


def test_bench_places_on_a_cluster_equals_the_serial_run(cluster, capsys) -> None:
    argv = ["bench", "places", "--dataset", "box", "--methods", "fft,ring", "--seed", "1",
            "--json"]
    here = _json(capsys, argv)
    there = _json(capsys, [*argv, "--cluster", cluster])
    assert set(there["methods"]) == {"fft", "ring"} and not there["failed"]
    untimed = {k for k in here["methods"]["fft"] if k.startswith("ms_")}
    drop = lambda doc: {n: {k: v for k, v in m.items() if k not in untimed}  # noqa: E731
                        for n, m in doc["methods"].items()}
    assert drop(there) == drop(here)
    assert _untimed({**there, "methods": None}) == _untimed({**here, "methods": None})


def test_bench_places_bad_cluster_fails_before_loading(tmp_path, capsys) -> None:
    _fails_at_once(capsys, ["bench", "places", "--dataset", "box"], tmp_path / "out")


# --------------------------------------------------------------------------- stripes


def test_bench_stripes_on_a_cluster_equals_the_serial_run(cluster, capsys) -> None:
    """One task per matcher: stripes, profile, fft, and ring (a verifier of the fused row)."""
    argv = ["bench", "stripes", "--dataset", "daily-sim", "--classes", "apple,pen",
            "--per-class", "2", "--step", "0.004", "--baselines", "fft", "--seed", "1",
            "--json"]
    here = _json(capsys, argv)
    there = _json(capsys, [*argv, "--cluster", cluster])
    assert set(there["baselines"]) == {"fft"} and there["fused"] is not None
    drop = {"scan_seconds", "silhouette_seconds", "speedup_vs_paper", "paper_seconds"}
    assert _untimed({k: v for k, v in there.items() if k not in drop}) == \
        _untimed({k: v for k, v in here.items() if k not in drop})


def test_bench_stripes_bad_cluster_fails_before_scanning(tmp_path, capsys) -> None:
    _fails_at_once(capsys, ["bench", "stripes", "--dataset", "daily-sim"], tmp_path / "out")


# ------------------------------------------------------------------------- landmarks


def test_landmark_seeds_on_a_cluster_equal_the_serial_runs(cluster, tmp_path) -> None:
    from evaluation.landmarks_benchmark import LandmarksCell, run_landmarks_cells
    from tests.test_landmarks import _tiny_config

    cells = [LandmarksCell(seed, _tiny_config()) for seed in (3, 4)]
    here = run_landmarks_cells(cells)
    there = run_landmarks_cells(cells, cluster=cluster)
    assert [d["seed"] for d in there] == [3, 4]
    assert _untimed(there) == _untimed(here)


def test_bench_landmarks_bad_cluster_fails_before_simulating(tmp_path, capsys) -> None:
    _fails_at_once(capsys, ["bench", "landmarks", "--seeds", "0,1"], tmp_path / "out")


# ---------------------------------------------------------------------------- README


def _commands_with_cluster(app, prefix: str = "loopclosure") -> list[str]:
    import inspect

    found = []
    for command in app.registered_commands:
        name = command.name or command.callback.__name__.replace("_", "-")
        if "cluster" in inspect.signature(command.callback).parameters:
            found.append(f"{prefix} {name}")
    for group in app.registered_groups:
        found += _commands_with_cluster(group.typer_instance, f"{prefix} {group.name}")
    return found


def test_the_readme_lists_every_command_that_takes_cluster() -> None:
    from slam.cli.main import build_app

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    section = readme.split("## Map many logs, here or on a cluster")[1].split("\n## ")[0]
    # (the command groups are module-level: every app built adds its commands again)
    commands = list(dict.fromkeys(_commands_with_cluster(build_app())))
    assert len(commands) == 7, commands
    for command in commands:
        assert f"`{command} " in section and "--cluster" in section, command
