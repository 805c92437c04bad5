"""The demo report of `loopclosure run` and the run-reporter hook it reaches the CLI by."""

from __future__ import annotations

from pathlib import Path

import typer

from evaluation.demo_report import demo_lines, demo_reporter
from slam.cli import run_command
from slam.cli.main import build_app
from slam.cli.run_command import RunReport, add_run_reporter

FIGURES = {
    "ate_before_loop_closure_m": 0.011848, "ate_after_loop_closure_m": 0.005618,
    "loop_precision": 1.0, "loop_recall": 0.98913, "loops_true_positive": 204,
    "loops_false_positive": 0,
}


def test_demo_lines_are_the_two_report_lines() -> None:
    assert demo_lines(FIGURES) == [
        "ATE against ground truth: 0.0118 m before loop closure, 0.0056 m after",
        "loop closures: precision 1.000, recall 0.989 (204 true, 0 false)",
    ]


def test_the_demo_reporter_skips_sources_that_are_not_simulated(tmp_path: Path) -> None:
    assert demo_reporter(object(), tmp_path / "intel.clf", tmp_path) is None


def test_the_entry_point_registers_the_demo_reporter() -> None:
    build_app()
    assert run_command._REPORTERS.get("demo") is demo_reporter


def test_reporters_are_called_in_order_and_reset_by_a_new_app(tmp_path: Path) -> None:
    calls: list[tuple[object, object, Path]] = []

    def first(result: object, source: object, out: Path) -> RunReport:
        calls.append((result, source, out))
        return RunReport("first", {"n": 1}, ("line one",))

    def silent(result: object, source: object, out: Path) -> None:
        calls.append((result, source, out))

    run_command.register(typer.Typer())  # a new app starts without reporters
    try:
        add_run_reporter("first", first)
        add_run_reporter("silent", silent)
        add_run_reporter("first", first)  # the same name again replaces, never doubles
        reports = run_command._call_reporters("result", "source", tmp_path)
        assert [r.key for r in reports] == ["first"] and reports[0].lines == ("line one",)
        assert calls == [("result", "source", tmp_path)] * 2
        run_command.register(typer.Typer())
        assert run_command._call_reporters("result", "source", tmp_path) == []
    finally:
        build_app()  # leave the process as the CLI builds it


def test_run_with_an_out_that_is_a_file_is_one_error_line(tmp_path: Path, capsys) -> None:
    from slam.cli.main import main

    taken = tmp_path / "taken"
    taken.write_text("keep me\n")
    assert main(["run", "--out", str(taken)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {taken}: output folder exists and is not a folder"]
    assert taken.read_text() == "keep me\n"


def test_the_demo_drifts_by_metres_and_loop_closure_repairs_it(tmp_path: Path) -> None:
    """The README's first command: the demo's odometry drifts visibly (its ATE is
    metres), loop closure brings it to a small fraction of that, the place database
    proposes most of the accepted loops, and both maps are drawn."""
    import json

    from slam.cli.main import main

    out = tmp_path / "demo"
    assert main(["run", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    demo = summary["demo"]
    assert demo["ate_before_loop_closure_m"] > 1.0
    assert demo["ate_after_loop_closure_m"] < 0.1 * demo["ate_before_loop_closure_m"]
    assert demo["loop_precision"] == 1.0 and demo["loops_false_positive"] == 0
    by_search = summary["loops_by_stage"]
    assert by_search["appearance"] > by_search["pose"] > 0
    assert (out / "map.png").is_file() and (out / "map_before.png").is_file()
