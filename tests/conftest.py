"""Shared fixtures: the real data sets beside the project, skipped when absent."""

from __future__ import annotations

import os
from pathlib import Path

# One BLAS thread: the suite's timings and small matrix products are far slower
# with a thread pool fighting for two cores.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pytest
from hypothesis import settings

from tests.helpers import SHARED_DATA

# Property tests draw the same examples on every run, so CI on a fresh checkout
# (no hypothesis example database) is reproducible; HYPOTHESIS_PROFILE=explore
# draws new examples to hunt for failures.
settings.register_profile("ci", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` (or $LOOPCLOSURE_SHARED_DATA); skips the test when it is missing."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA} (needs ../shared beside the checkout)")
    return SHARED_DATA


@pytest.fixture(scope="module")
def cluster():
    """The scheduler address of a LocalCluster of 2 worker processes on the loopback, one
    per test module (a module may kill its workers)."""
    distributed = pytest.importorskip("distributed", reason="needs the `distributed` package")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
        scheduler_port=0, dashboard_address=None, silence_logs=50,
    ) as local:
        yield local.scheduler_address
