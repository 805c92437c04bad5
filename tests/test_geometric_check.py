"""Geometric verification of loop candidates on hand-made geometry."""

from __future__ import annotations

import numpy as np
import pytest

from data import se2
from loopclosure.free_space import Consistency
from loopclosure.geometric_check import (
    GeometricCheckConfig,
    implausible_runner_up,
    required_margin,
    verify,
)
from loopclosure.registration import RegistrationTarget


def _walls(segments: list[tuple[tuple[float, float], tuple[float, float]]], step=0.02):
    pts = []
    for (x0, y0), (x1, y1) in segments:
        n = max(2, int(np.hypot(x1 - x0, y1 - y0) / step))
        t = np.linspace(0, 1, n)
        pts.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)]))
    return np.vstack(pts)


# An L-shaped room with a pillar: no symmetry, corners in every direction.
ROOM = _walls([((0, 0), (6, 0)), ((6, 0), (6, 3)), ((6, 3), (3, 3)), ((3, 3), (3, 5)),
               ((3, 5), (0, 5)), ((0, 5), (0, 0)), ((1.5, 1.5), (2.0, 1.5)),
               ((2.0, 1.5), (2.0, 2.0)), ((2.0, 2.0), (1.5, 2.0)), ((1.5, 2.0), (1.5, 1.5))])


def _seen_from(world_points: np.ndarray, pose: np.ndarray, rng=None, noise=0.0) -> np.ndarray:
    pts = se2.transform_points(se2.inverse(pose), world_points)
    if rng is not None:
        pts = pts + rng.normal(0, noise, pts.shape)
    return pts


def test_accepts_a_true_revisit_and_recovers_the_relative_pose() -> None:
    rng = np.random.default_rng(0)
    a, b = np.array([1.0, 1.0, 0.3]), np.array([1.6, 0.8, 1.1])
    target = RegistrationTarget(_seen_from(ROOM, a, rng, 0.005))
    truth = se2.between(a, b)
    prior = se2.compose(truth, np.array([0.15, -0.1, 0.05]))  # a drifted estimate
    result = verify(_seen_from(ROOM, b, rng, 0.005), target, prior=prior,
                    prior_covariance=np.diag([0.1, 0.1, 0.02]) ** 2 * 4)
    assert result.accepted, result.reason
    np.testing.assert_allclose(result.relative[:2], truth[:2], atol=0.01)
    assert abs(se2.wrap_angle(result.relative[2] - truth[2])) < np.radians(0.5)
    # The covariance never drops below the configured floor.
    floor = GeometricCheckConfig().covariance_floor
    assert result.covariance[0, 0] >= floor[0] ** 2 - 1e-15


def test_headings_let_it_find_a_large_rotation_without_prior() -> None:
    a, b = np.array([1.0, 1.0, 0.0]), np.array([1.2, 1.1, np.radians(170)])
    target = RegistrationTarget(_seen_from(ROOM, a))
    truth = se2.between(a, b)
    result = verify(_seen_from(ROOM, b), target, headings=[truth[2] + 0.05],
                    translation=truth[:2] + 0.1)
    assert result.accepted, result.reason
    np.testing.assert_allclose(result.relative[:2], truth[:2], atol=0.01)


def test_rejects_a_different_place() -> None:
    other = _walls([((0, 0), (4, 0)), ((4, 0), (4, 4)), ((4, 4), (0, 4)), ((0, 4), (0, 0)),
                    ((2.5, 1.0), (3.0, 2.5))])
    target = RegistrationTarget(_seen_from(ROOM, np.array([1.0, 1.0, 0.0])))
    result = verify(_seen_from(other, np.array([1.0, 1.0, 0.0])), target, prior=np.zeros(3))
    assert not result.accepted


def test_a_prior_where_the_submaps_do_not_overlap_runs_no_icp() -> None:
    a = np.array([1.0, 1.0, 0.0])
    target = RegistrationTarget(_seen_from(ROOM, a))
    query = _seen_from(ROOM, a) + np.array([30.0, 0.0])  # the same room, 30 m away
    cov = np.diag([0.1, 0.1, 0.02]) ** 2
    screened = verify(query, target, prior=np.zeros(3), prior_covariance=cov)
    assert not screened.accepted and screened.hypotheses == 0
    assert screened.reason.startswith("no overlap at the prior (0.000 <")
    # Off, ICP runs from every guess (and fails: nothing within its gate).
    off = verify(query, target, prior=np.zeros(3), prior_covariance=cov,
                 config=GeometricCheckConfig(min_prior_overlap=0.0, bound_reach=0.0))
    assert not off.accepted and off.hypotheses > 0
    # A true revisit 0.3 m off the prior scores far above the screen and is accepted.
    b = np.array([1.6, 0.8, 0.4])
    prior = se2.compose(se2.between(a, b), np.array([0.3, -0.2, 0.05]))
    kept = verify(_seen_from(ROOM, b), target, prior=prior, prior_covariance=cov * 4)
    assert kept.accepted, kept.reason
    # A prior drifted beyond the guesses' offsets (wheel odometry) is still tried and
    # recovered by ICP.
    drifted = se2.compose(se2.between(a, b), np.array([0.0, 0.9, 0.25]))
    wide = verify(_seen_from(ROOM, b), target, prior=drifted, prior_covariance=cov * 100)
    assert wide.hypotheses > 0 and wide.accepted, wide.reason


def test_the_screen_skips_only_fits_that_could_not_pass() -> None:
    """A query that shares a few of its points with the candidate scores under the
    screen's bar (half of `min_fitness_gated`) at the prior, and is rejected without
    ICP; ICP from every guess (screen off) would not reach `min_fitness_gated`
    either: the same verdict."""
    a = np.array([1.0, 1.0, 0.0])
    target = RegistrationTarget(_seen_from(ROOM, a))
    shared = _seen_from(ROOM, a)
    elsewhere = _seen_from(ROOM, a) + np.array([30.0, 0.0])
    query = np.vstack([shared[::30], elsewhere])
    cov = np.diag([0.1, 0.1, 0.02]) ** 2
    cfg = GeometricCheckConfig()
    assert cfg.min_prior_overlap == cfg.min_fitness_gated / 2
    screened = verify(query, target, prior=np.zeros(3), prior_covariance=cov)
    assert screened.hypotheses == 0 and screened.reason.startswith("no overlap at the prior")
    full = verify(query, target, prior=np.zeros(3), prior_covariance=cov,
                  config=GeometricCheckConfig(min_prior_overlap=0.0, bound_reach=0.0))
    assert full.hypotheses > 0 and not full.accepted
    assert full.fitness < cfg.min_fitness_gated


def test_the_overlap_bound_skips_a_fit_below_the_inlier_threshold() -> None:
    """A quarter of the query's points (after its 0.1 m voxels) lie on the candidate's
    walls at the prior, the rest 30 m away: the screen (0.25 > 0.15) lets it through,
    the overlap bound
    (0.25 < max(0.3, 0.35)) rejects it without ICP, and ICP (bound off) rejects it
    too.  A true revisit gets the same verdict and pose with the bound on and off."""
    a = np.array([1.0, 1.0, 0.0])
    target = RegistrationTarget(_seen_from(ROOM, a))
    shared = _seen_from(ROOM, a)
    query = np.vstack([shared[::15], shared + np.array([30.0, 0.0])])  # 0.3 and 0.1 m voxels
    cov = np.diag([0.1, 0.1, 0.02]) ** 2
    bounded = verify(query, target, prior=np.zeros(3), prior_covariance=cov)
    assert bounded.hypotheses == 0, bounded.reason
    assert bounded.reason.startswith("no fit within reach (overlap bound 0.2")
    full = verify(query, target, prior=np.zeros(3), prior_covariance=cov,
                  config=GeometricCheckConfig(bound_reach=0.0))
    assert full.hypotheses > 0 and not full.accepted
    b = np.array([1.6, 0.8, 0.4])
    prior = se2.compose(se2.between(a, b), np.array([0.3, -0.2, 0.05]))
    on = verify(_seen_from(ROOM, b), target, prior=prior, prior_covariance=cov * 4)
    off = verify(_seen_from(ROOM, b), target, prior=prior, prior_covariance=cov * 4,
                 config=GeometricCheckConfig(bound_reach=0.0))
    assert on.accepted and off.accepted
    np.testing.assert_array_equal(on.relative, off.relative)


def test_rejects_a_corridor_as_degenerate() -> None:
    corridor = _walls([((-10, 0), (10, 0)), ((-10, 2), (10, 2))])
    a, b = np.array([0.0, 1.0, 0.0]), np.array([0.5, 1.0, 0.0])
    target = RegistrationTarget(_seen_from(corridor, a))
    prior = se2.between(a, b) + np.array([0.3, 0, 0])
    result = verify(_seen_from(corridor, b), target, prior=prior)
    assert not result.accepted
    assert "degenerate" in result.reason


@pytest.mark.parametrize("offset", [np.array([2.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.8])])
def test_prior_gate_rejects_a_match_far_from_the_prediction(offset: np.ndarray) -> None:
    a, b = np.array([1.0, 1.0, 0.0]), np.array([1.5, 1.0, 0.2])
    target = RegistrationTarget(_seen_from(ROOM, a))
    truth = se2.between(a, b)
    # A prior that claims (with a tight covariance) a different relative pose.
    cfg = GeometricCheckConfig(offsets=0.0)
    result = verify(_seen_from(ROOM, b), target, prior=se2.compose(truth, offset),
                    prior_covariance=np.diag([0.05, 0.05, 0.01]) ** 2, headings=[truth[2]],
                    config=cfg)
    assert not result.accepted


def test_partial_overlap_needs_the_prior_gate_with_multi_start_icp() -> None:
    """With ``method="icp"``, a revisit sharing ~45% of its submap passes only as a
    pose-gated candidate (the correlative check judges it by free space instead)."""
    a, b = np.array([1.0, 1.0, 0.3]), np.array([1.6, 0.8, 1.1])
    # The query's submap also holds a wing the candidate's never saw.
    wing = _walls([((6, 0), (14, 0)), ((14, 0), (14, 3)), ((14, 3), (7, 3)), ((8, -2), (12, -2))])
    target = RegistrationTarget(_seen_from(ROOM, a))
    query = _seen_from(np.vstack([ROOM, wing]), b)
    truth = se2.between(a, b)
    gated = verify(query, target, prior=truth, prior_covariance=np.diag([0.1, 0.1, 0.02]) ** 2)
    cfg = GeometricCheckConfig()
    assert cfg.min_fitness_gated <= gated.fitness < cfg.min_fitness
    assert gated.accepted, gated.reason
    np.testing.assert_allclose(gated.relative[:2], truth[:2], atol=0.01)
    appearance = verify(query, target, headings=[truth[2]], translation=truth[:2],
                        config=GeometricCheckConfig(method="icp"))
    assert not appearance.accepted
    assert appearance.reason.startswith("fitness")


def test_partial_overlap_must_be_well_constrained() -> None:
    """The lower gated threshold does not admit a poorly constrained partial overlap."""
    a, b = np.array([1.0, 1.0, 0.3]), np.array([1.6, 0.8, 1.1])
    wing = _walls([((6, 0), (14, 0)), ((14, 0), (14, 3)), ((14, 3), (7, 3)), ((8, -2), (12, -2))])
    query = _seen_from(np.vstack([ROOM, wing]), b)
    truth = se2.between(a, b)
    cfg = GeometricCheckConfig(min_degeneracy_partial=0.6)  # above any real degeneracy
    result = verify(query, RegistrationTarget(_seen_from(ROOM, a)), prior=truth,
                    prior_covariance=np.diag([0.1, 0.1, 0.02]) ** 2, config=cfg)
    assert not result.accepted and result.reason.startswith("partial overlap")


def test_a_fit_farther_than_max_distance_is_not_a_revisit() -> None:
    rng = np.random.default_rng(0)
    a, b = np.array([1.0, 1.0, 0.3]), np.array([1.6, 0.8, 1.1])
    target = RegistrationTarget(_seen_from(ROOM, a, rng, 0.005))
    truth = se2.between(a, b)
    query = _seen_from(ROOM, b, rng, 0.005)
    prior_cov = np.diag([0.1, 0.1, 0.02]) ** 2 * 4
    near = verify(query, target, prior=truth, prior_covariance=prior_cov, max_distance=1.0)
    assert near.accepted, near.reason
    far = verify(query, target, prior=truth, prior_covariance=prior_cov, max_distance=0.5)
    assert not far.accepted
    assert far.reason == f"not a revisit ({np.hypot(*far.relative[:2]):.1f} m apart)"
    np.testing.assert_array_equal(far.relative, near.relative)


def test_origin_guesses_rescue_a_bad_centroid_translation() -> None:
    """A revisit 0.4 m away whose given translation (e.g. misaligned centroids) is 3 m
    off: only the guesses at translation 0 start inside ICP's reach."""
    a, b = np.array([1.0, 1.0, 0.2]), np.array([1.3, 1.25, 1.0])
    target = RegistrationTarget(_seen_from(ROOM, a))
    truth = se2.between(a, b)
    wrong = truth[:2] + np.array([3.0, -1.5])
    icp = GeometricCheckConfig(method="icp")
    found = verify(_seen_from(ROOM, b), target, headings=[truth[2] + 0.03], translation=wrong,
                   config=icp)
    assert found.accepted, found.reason
    np.testing.assert_allclose(found.relative[:2], truth[:2], atol=0.01)
    off = GeometricCheckConfig(method="icp", origin_guesses=False)
    lost = verify(_seen_from(ROOM, b), target, headings=[truth[2] + 0.03], translation=wrong,
                  config=off)
    assert not (lost.accepted and np.allclose(lost.relative[:2], truth[:2], atol=0.05))


@pytest.mark.parametrize(
    ("fitness", "expected"),
    [(0.8, 0.1), (0.2, 0.1), (0.1, 0.05), (0.06, 0.03), (0.0, 0.0)],
)
def test_required_margin_is_absolute_for_good_fits_and_relative_for_weak_ones(
    fitness: float, expected: float
) -> None:
    # min(0.1, 0.5 * fitness): a runner-up must fit at most half as well as a weak best.
    cfg = GeometricCheckConfig(min_fitness_margin=0.1, min_relative_margin=0.5)
    assert required_margin(fitness, cfg) == pytest.approx(expected)


@pytest.mark.parametrize(
    ("runner_up", "best", "expected"),
    [(0.86, 0.97, True),     # fails the bar, 0.11 more conflict than the best: ruled out
     (0.85, 0.925, False),   # fails the bar, but only 0.075 more: clutter may explain it
     (0.93, 0.99, False),    # passes the bar on its own: a plausible other answer
     (0.83, 0.92, True)],    # 0.09 apart, the best at the bar itself
)
def test_a_runner_up_is_implausible_when_free_space_rules_it_out(
    runner_up: float, best: float, expected: bool
) -> None:
    # Bar 0.92: the allowance for clutter is 1 - 0.92 = 0.08 of conflict share.
    cfg = GeometricCheckConfig(min_consistency=0.92)

    def c(v: float) -> Consistency:
        return Consistency(consistency=v, conflict_ratio=1 - v, hits=100, conflicts=0)

    assert implausible_runner_up(c(runner_up), c(best), cfg) is expected


def test_check_from_a_prior_on_a_lazy_grid_equals_the_check_on_the_target() -> None:
    """A lazy grid of the candidate's submap in cells of the normals' radius gives the
    check every figure the prepared target gives (the same normals where ICP meets
    points); a grid is refused for a check without a prior."""
    from data.errors import UserError
    from loopclosure.fast_icp import TARGET_GRID_CELL, GridTarget, estimate_normals_fast

    rng = np.random.default_rng(4)
    a, b = np.array([1.0, 1.0, 0.3]), np.array([1.6, 0.8, 1.1])
    cfg = GeometricCheckConfig()
    cand = _seen_from(ROOM, a, rng, 0.005)
    query = _seen_from(ROOM, b, rng, 0.005)
    target = RegistrationTarget(cand, cfg.icp, normals=estimate_normals_fast)
    for off, cov in (([0.15, -0.1, 0.05], np.diag([0.1, 0.1, 0.02]) ** 2 * 4),
                     ([0.6, 0.4, 0.2], np.diag([0.3, 0.3, 0.1]) ** 2)):
        prior = se2.compose(se2.between(a, b), np.array(off))
        grid = GridTarget(cand, cfg.icp, TARGET_GRID_CELL, lazy=True)
        ref = verify(query, target, prior=prior, prior_covariance=cov, config=cfg)
        got = verify(query, None, prior=prior, prior_covariance=cov, config=cfg, grid=grid)
        assert got.reason == ref.reason and got.accepted == ref.accepted
        np.testing.assert_array_equal(got.relative, ref.relative)
        np.testing.assert_array_equal(got.covariance, ref.covariance)
        assert (got.fitness, got.rms, got.margin, got.hypotheses) == (
            ref.fitness, ref.rms, ref.margin, ref.hypotheses)
    with pytest.raises(UserError):
        verify(query, target, headings=[0.0], config=cfg, grid=grid)
    with pytest.raises(UserError):
        verify(query, None, prior=prior, config=cfg)
