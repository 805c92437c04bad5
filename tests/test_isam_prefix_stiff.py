"""The iSAM2 prefix with the stiff factors' poses ordered first (`slam.isam_prefix`,
`STIFF_FIRST`): the ordering groups, the constrained updates and the QR fallback."""

from __future__ import annotations

import gtsam
import numpy as np

from slam.isam_prefix import IsamPrefix, ordering_groups
from tests.test_consistency_prefix import square_chain_prefix

# An information matrix as stiff as the worst odometry factor of the Intel log (an
# in-place turn): eigenvalues about 11, 636 and 2.7e12 (x, y mixed; heading free).
STIFF = np.array([[2.69353835e12, -1.57146640e11, 0.0],
                  [-1.57146640e11, 9.16826248e9, 0.0],
                  [0.0, 0.0, 636.44]])


def test_ordering_groups_put_the_first_keys_first_and_the_new_ones_last() -> None:
    groups = ordering_groups([0, 1, 2, 3, 4], frozenset({2}), [4, 2])
    assert groups.size() == 5
    assert [groups.at(k) for k in range(5)] == [1, 1, 0, 1, 2]


def test_constrained_updates_solve_as_gtsam_orders() -> None:
    """Poses ordered first on a well-conditioned graph: the same solution (to the solver's
    tolerance), a loop added and taken out again included."""
    solutions = []
    for first in (frozenset(), frozenset({3, 4})):
        isam = IsamPrefix()
        graph, factors = square_chain_prefix(isam)
        isam._first = first
        isam.solve()
        loop = graph.between_factor(graph.loops[0])
        isam.add(loop, "loop")
        with_loop = isam.solve()
        isam.remove(["loop"])
        solutions.append((with_loop, isam.solve(), factors, loop))
    (a_loop, a_chain, factors, loop), (b_loop, b_chain, _, _) = solutions
    both = gtsam.NonlinearFactorGraph(factors)
    both.add(loop)
    assert abs(both.error(a_loop) - both.error(b_loop)) < 1e-9
    assert factors.error(b_chain) < 1e-9 and factors.error(a_chain) < 1e-9
    for k in a_loop.keys():
        assert np.allclose(a_loop.atPose2(k).matrix(), b_loop.atPose2(k).matrix(), atol=1e-6)


def _stiff_chain(stiff_first: bool) -> tuple[IsamPrefix, gtsam.Values]:
    """A 30-pose chain whose 12th odometry factor is `STIFF`, closed by one loop from
    pose 0 to 25 that disagrees with the chain by a few centimetres."""
    isam = IsamPrefix(stiff_first=stiff_first)
    isam.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(), gtsam.noiseModel.Isotropic.Sigma(3, 1e-3)))
    poses = [gtsam.Pose2()]
    isam.insert(0, poses[0])
    for k in range(1, 30):
        step, info = gtsam.Pose2(1.0, 0.0, 0.1), np.diag([100.0, 100.0, 1000.0])
        if k == 12:
            step, info = gtsam.Pose2(0.0, 0.0, 0.98), STIFF
        isam.add(gtsam.BetweenFactorPose2(k - 1, k, step,
                                          gtsam.noiseModel.Gaussian.Information(info)))
        poses.append(poses[-1].compose(step))
        isam.insert(k, poses[-1])
    isam.solve()
    rel = poses[0].between(poses[25]).compose(gtsam.Pose2(0.05, -0.02, 0.01))
    isam.add(gtsam.BetweenFactorPose2(0, 25, rel, gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    return isam, isam.solve()


def test_a_stiff_graph_that_breaks_cholesky_even_ordered_first_falls_back_to_qr() -> None:
    """Cholesky breaks down on this chain whatever the order: with the option the prefix
    tries the stiff poses first, then ends on QR with the same solution as without it."""
    plain, expected = _stiff_chain(stiff_first=False)
    tried, solved = _stiff_chain(stiff_first=True)
    assert plain.factorization == tried.factorization == "QR"
    assert not tried._first
    for k in expected.keys():
        assert np.allclose(expected.atPose2(k).matrix(), solved.atPose2(k).matrix(), atol=1e-9)
