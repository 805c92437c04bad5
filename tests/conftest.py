"""Shared fixtures: the real data sets beside the project, skipped when absent."""

from __future__ import annotations

import os
from pathlib import Path

# One BLAS thread: the suite's timings and small matrix products are far slower
# with a thread pool fighting for two cores.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pytest

_DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "data"
SHARED_DATA = Path(os.environ.get("LOOPCLOSURE_SHARED_DATA", _DEFAULT))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` (or $LOOPCLOSURE_SHARED_DATA); skips the test when it is missing."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA} (needs ../shared beside the checkout)")
    return SHARED_DATA


def shared_file(relative: str) -> Path:
    """A file under the shared data folder, or skip the calling test with a reason."""
    path = SHARED_DATA / relative
    if not path.exists():
        pytest.skip(f"real data file {path} not found (needs ../shared/data beside the checkout)")
    return path
