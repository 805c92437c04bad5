"""iSAM2 survives graphs that Cholesky cannot factor (a lost odometry step)."""

from __future__ import annotations

import numpy as np
import pytest

from data import se2
from data.errors import DataWarning
from slam.optimize import optimize
from slam.smoothers import IncrementalSmoother


def _chain(smoother: IncrementalSmoother, lost_at: int, n: int = 12) -> list[np.ndarray]:
    rng = np.random.default_rng(0)
    tight = np.diag([1e6, 1e6, 1e7])
    lost = np.linalg.inv(np.diag([10.0, 10.0, np.pi]) ** 2)
    pose = np.zeros(3)
    truth = [pose]
    smoother.add_pose(0, pose)
    for k in range(1, n):
        step = np.array([0.5, 0.0, 0.2]) + rng.normal(0, 1e-3, 3)
        pose = se2.compose(pose, step)
        truth.append(pose)
        smoother.add_pose(k, pose)
        smoother.add_odometry(k - 1, k, step, lost if k == lost_at else tight)
        if k == n - 1:  # a loop back to the start pins the lost step down
            smoother.add_loop(0, k, se2.between(truth[0], pose), tight)
        smoother.update()
    return truth


def test_lost_odometry_step_falls_back_to_qr_and_matches_batch() -> None:
    smoother = IncrementalSmoother(kernel="none")
    with pytest.warns(DataWarning, match="QR"):
        _chain(smoother, lost_at=6)
    est = smoother.estimate()
    batch = optimize(smoother.graph, "none", "lm", initial=est).poses
    for k in est:
        np.testing.assert_allclose(est[k][:2], batch[k][:2], atol=1e-4)
    assert len(est) == 12
