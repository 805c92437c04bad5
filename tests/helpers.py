"""Helpers that test modules import: where the real data sets are, and how to skip.

Fixtures live in ``conftest.py`` (pytest finds them by name); plain functions and
constants that a test imports live here, so no test imports ``conftest``.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

_DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "data"
SHARED_DATA = Path(os.environ.get("LOOPCLOSURE_SHARED_DATA", _DEFAULT))
"""``../shared/data`` beside the checkout, or ``$LOOPCLOSURE_SHARED_DATA``."""


def shared_file(relative: str) -> Path:
    """A file under the shared data folder, or skip the calling test with a reason."""
    path = SHARED_DATA / relative
    if not path.exists():
        pytest.skip(f"real data file {path} not found (needs ../shared/data beside the checkout)")
    return path


def load_benchmark(name: str):
    """The script ``benchmarks/<name>.py`` as a module (benchmarks are not a package)."""
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "benchmarks" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"{name}_bench", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
