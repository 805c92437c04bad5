"""The README's promises: CI runs its test command verbatim, and its example runs."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def _blocks(language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", README, flags=re.S)


def test_readme_opens_with_the_two_commands_and_ci_runs_the_second() -> None:
    first_two = _blocks("bash")[:2]
    assert "loopclosure run" in first_two[0]
    assert "pytest" in first_two[1] and ".[test]" in first_two[1]
    assert README.index(first_two[0]) < README.index("##")  # before any section
    ci = (ROOT / ".ci" / "run").read_text()
    assert first_two[1].strip() in ci.splitlines()


def test_the_embedding_example_finds_loops_that_agree_with_ground_truth() -> None:
    example = _blocks("python")[0]
    out = io.StringIO()
    scope: dict = {}
    with contextlib.redirect_stdout(out):
        exec(compile(example, "README.md", "exec"), scope)
    lines = out.getvalue().splitlines()
    assert len(lines) >= 10
    from data import se2

    gt = scope["run"].ground_truth.xytheta()
    step = 4  # keyframes = run.scans[::4]
    for line in lines:
        match, query = (int(x) for x in line.split()[:2])
        rel = [float(x) for x in re.findall(r"-?\d+\.\d*", line.split("[")[1])]
        truth = se2.between(gt[match * step], gt[query * step])
        assert abs(rel[0] - truth[0]) < 0.2 and abs(rel[1] - truth[1]) < 0.2, line
