"""benchmarks/robust_time_options_ab.py: a run's name sets exactly the settings it names,
and every run is followed by the defaults again."""

from __future__ import annotations

import pytest

import slam.fast_path_screen as fast_path_screen
import slam.isam_prefix as isam_prefix
import slam.least_squares as least_squares
from tests.helpers import load_benchmark


def test_settings_of_run_names() -> None:
    bench = load_benchmark("robust_time_options_ab")
    window, relinearize, stiff = bench.DEFAULTS
    assert bench.settings("default") == (window, relinearize, stiff)
    assert bench.settings("dogleg-off") == (0, relinearize, stiff)
    assert bench.settings("relin-1e-2") == (window, 0.01, stiff)
    assert bench.settings("relin-3e-3+stiff-on+dogleg-off") == (0, 0.003, True)
    with pytest.raises(SystemExit):
        bench.settings("relin-1e-2+faster")


def test_apply_sets_the_modules_and_defaults_restore_them() -> None:
    bench = load_benchmark("robust_time_options_ab")
    try:
        bench.apply((0, 0.01, True))
        assert fast_path_screen.STALL_WINDOW == 0 and isam_prefix.RELINEARIZE == 0.01
        assert least_squares.STIFF_CHOLESKY
    finally:
        bench.apply(bench.DEFAULTS)
    assert (fast_path_screen.STALL_WINDOW, isam_prefix.RELINEARIZE,
            least_squares.STIFF_CHOLESKY) == bench.DEFAULTS
