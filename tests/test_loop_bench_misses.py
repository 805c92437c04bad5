"""The prefilter miss diagnosis of `bench loops`: hand-checked geometry and bins."""

from __future__ import annotations

import math

import numpy as np

from evaluation.loop_bench_misses import miss_breakdown, nearest_place, submap_overlap


def test_nearest_place_hand_checked() -> None:
    ref = np.array([[0.0, 0.0, 0.0], [3.0, 4.0, math.pi - 0.1], [1.0, 0.0, -math.pi + 0.2],
                    [0.0, 0.5, math.radians(170.0)]])
    # Query 3 at (0, 0.5) heading 170 deg; candidates 0 (0.5 m) and 1 (3.04 m).
    key, dist, dth = nearest_place(ref, 3, [0, 1])
    assert key == 0 and math.isclose(dist, 0.5) and math.isclose(dth, 170.0)
    # Heading difference across the +-pi seam: 170 deg vs -180 + 11.46 deg = 21.46 deg apart.
    key, dist, dth = nearest_place(ref, 3, [2])
    assert key == 2 and math.isclose(dist, math.hypot(1.0, 0.5))
    assert math.isclose(dth, abs(170.0 - (-180.0 + math.degrees(0.2)) - 360.0))
    assert nearest_place(ref, 3, [])[0] == -1


def test_submap_overlap_hand_checked() -> None:
    # A wall of 11 points along x = 2 in the place's frame; the query stands 1 m behind
    # the place, turned 90 degrees left, so the wall is at y = -2 .. in the query frame.
    wall = np.column_stack([np.full(11, 2.0), np.linspace(-1.0, 1.0, 11)])
    place_pose = np.array([5.0, 5.0, 0.0])
    query_pose = np.array([4.0, 5.0, math.pi / 2])
    # The wall seen from the query: x_q = y_p, y_q = -(x_p + 1).
    seen = np.column_stack([wall[:, 1], -(wall[:, 0] + 1.0)])
    assert math.isclose(submap_overlap(seen, wall, query_pose, place_pose), 1.0)
    # Half the query's points 1 m off the wall: overlap 11 / 22.
    off = seen + np.array([0.0, -1.0])
    both = np.vstack([seen, off])
    assert math.isclose(submap_overlap(both, wall, query_pose, place_pose), 0.5)
    # 0.15 m off counts (radius 0.2 m), 0.25 m does not.
    assert submap_overlap(seen + np.array([0.0, -0.15]), wall, query_pose, place_pose) == 1.0
    assert submap_overlap(seen + np.array([0.0, -0.25]), wall, query_pose, place_pose) == 0.0
    assert math.isnan(submap_overlap(np.zeros((0, 2)), wall, query_pose, place_pose))


def test_miss_breakdown_bins_and_recall() -> None:
    rank = np.array([0, 5, 12, -1, 3])
    dist = np.array([0.1, 0.6, 0.7, 1.9, 2.0])
    dth = np.array([0.0, 45.0, 100.0, 179.0, 10.0])
    overlap = np.array([0.9, 0.6, 0.4, 0.1, 1.0])
    out = miss_breakdown(rank, dist, dth, overlap, k=10)
    by_dist = {b: (n, r) for b, n, r in out["nearest_m"]}
    assert by_dist["0-0.5"] == (1, 1.0)
    assert by_dist["0.5-1"] == (2, 0.5)  # ranks 5 (found) and 12 (missed)
    assert by_dist["1.5-2"] == (2, 0.5)  # 2.0 falls in the last bin, rank -1 is a miss
    assert math.isnan(dict((b, r) for b, _, r in out["nearest_m"])["1-1.5"])
    by_overlap = {b: (n, r) for b, n, r in out["nearest_overlap"]}
    assert by_overlap["0.7-1"] == (2, 1.0) and by_overlap["0-0.3"] == (1, 0.0)
    assert sum(n for _, n, _ in out["nearest_dtheta_deg"]) == 5
