"""data.se2: the single-pose fast path agrees with the stacked arithmetic."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from data import se2

poses = st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-10, 10)).map(np.array)


def test_compose_by_hand() -> None:
    # Turn left 90 degrees at (1, 0), then move 2 m forward: (1, 2), heading pi/2.
    np.testing.assert_allclose(se2.compose([1.0, 0.0, np.pi / 2], [2.0, 0.0, 0.0]),
                               [1.0, 2.0, np.pi / 2], atol=1e-15)
    np.testing.assert_allclose(se2.inverse([1.0, 2.0, np.pi / 2]), [-2.0, 1.0, -np.pi / 2],
                               atol=1e-15)


@settings(max_examples=100, deadline=None)
@given(poses, poses)
def test_single_poses_equal_the_stacked_rows(a: np.ndarray, b: np.ndarray) -> None:
    stacked = se2.compose(np.stack([a, a]), np.stack([b, b]))
    np.testing.assert_allclose(se2.compose(a, b), stacked[0], atol=1e-12)
    np.testing.assert_allclose(se2.inverse(a), se2.inverse(np.stack([a]))[0], atol=1e-12)
    np.testing.assert_allclose(se2.between(a, b), se2.between(a[None], b[None])[0], atol=1e-12)
    assert -np.pi <= se2.compose(a, b)[2] < np.pi
    np.testing.assert_allclose(se2.compose(a, se2.inverse(a)), 0.0, atol=1e-12)
