"""`pair_kernel._pair_bins`: a pair's distance-bin row and angle terms, by hand."""

from __future__ import annotations

import pytest

from loopclosure.matchers.pair_kernel import _pair_bins


def test_a_3_4_5_pair_falls_in_the_row_and_angles_worked_out_by_hand():
    # Offset (3, 4) m: d = 5 m, u = (0.6, 0.8).  4 bins per m (40 bins over 10 m):
    # distance bin floor(5 * 4) = 20, row 20 * 8 = 160 of the flat (40, 8) histogram.
    # Normals (1, 0) and (0, -1): |n . u| = 0.6 and 0.8.
    row, ca, cb = _pair_bins(3.0, 4.0, 25.0, 1.0, 0.0, 0.0, -1.0, 4.0, 40, 8)
    assert row == 160
    assert ca == pytest.approx(0.6, abs=1e-15) and cb == pytest.approx(0.8, abs=1e-15)


def test_a_pair_at_the_far_edge_stays_in_the_last_distance_bin():
    # d = 10 m exactly: floor(10 * 4) = 40 is past the last bin (39): row 39 * 8 = 312.
    row, ca, cb = _pair_bins(0.0, 10.0, 100.0, 0.0, 1.0, 1.0, 0.0, 4.0, 40, 8)
    assert row == 312 and ca == 1.0 and cb == 0.0
