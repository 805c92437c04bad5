"""`slam.memory`: the process's peak, over its life and since a reset."""

import numpy as np

from slam.memory import peak_rss_mb, peak_rss_since_reset_mb, reset_peak_rss


def test_the_peak_since_a_reset_sees_a_new_allocation_and_never_exceeds_the_lifetime_peak():
    reset = reset_peak_rss()
    block = np.ones(64 * 2**20 // 8)  # 64 MB, touched
    since = peak_rss_since_reset_mb(reset)
    assert 64 < since <= peak_rss_mb() + 1.0  # VmHWM and ru_maxrss round apart
    del block


def test_without_a_reset_it_is_the_lifetime_peak():
    assert peak_rss_since_reset_mb(False) == peak_rss_mb()
