"""The icp2d front end's multi-hypothesis search on the compiled grid picks what the
numpy ICP on the map's `RegistrationTarget` picks."""

from __future__ import annotations

import numpy as np

from data import se2
from loopclosure.multi_start import initial_guesses, register_multi
from loopclosure.warm_up import room_scan
from slam.odometry.icp2d import Icp2dOdometry


def test_the_compiled_search_ranks_and_registers_as_the_numpy_one() -> None:
    front = Icp2dOdometry()
    front.process(room_scan(-1.0, -0.5))  # the first scan makes the map
    assert front._grid is not None
    true = np.array([0.3, 0.2, 0.0])  # the second scan's pose in the map
    scan = room_scan(-1.0 + true[0], -0.5 + true[1])
    points = front.scan_points(scan)
    guesses = initial_guesses((0.0, 0.0, 0.0), [0.3, -0.3, np.pi],
                              [[0.5, 0.0], [0.0, 0.5], [-0.5, 0.0], [0.0, -0.5]])
    compiled = front._multi(points, guesses, keep=6)
    numpy_ = register_multi(points, front._grid.target, guesses, config=front.config.icp,
                            keep=6)
    np.testing.assert_array_equal(compiled.guesses, numpy_.guesses)
    assert len(compiled.results) == 6
    for a, b in zip(compiled.results, numpy_.results, strict=True):
        assert a.ok == b.ok
        np.testing.assert_allclose(a.pose, b.pose, atol=1e-9)
        assert abs(a.fitness - b.fitness) < 1e-9
    d = se2.between(true, compiled.best.pose)
    assert np.hypot(d[0], d[1]) < 0.01 and abs(d[2]) < 0.01
