"""The dependency order of DESIGN.md, enforced: data <- loopclosure <- slam <- evaluation.

The contracts live in pyproject.toml (``[tool.importlinter]``): a layers contract
(no module imports a layer above its own) and an acyclic-siblings contract (no
import cycle between the modules of any package, function-level imports included).
"""

from __future__ import annotations

import contextlib
import io
import os
from pathlib import Path

from importlinter.cli import lint_imports

ROOT = Path(__file__).resolve().parents[1]


def test_import_contracts_hold() -> None:
    out = io.StringIO()
    cwd = Path.cwd()
    try:
        os.chdir(ROOT)
        with contextlib.redirect_stdout(out):
            status = lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True)
    finally:
        os.chdir(cwd)
    report = out.getvalue()
    assert status == 0, report[report.find("Broken contracts"):] or report
    assert "2 kept, 0 broken" in report
