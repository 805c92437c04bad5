"""The prior-free geometric check: correlative search, free-space consistency, acceptance."""

from __future__ import annotations

import numpy as np
import pytest

from data import se2
from loopclosure.correlative import LikelihoodGrid, peaks, search, search_angles
from loopclosure.free_space import RangeImage, Submap, consistency
from loopclosure.geometric_check import GeometricCheckConfig, verify
from loopclosure.prior_free import _QueryProducts, match_prior_free
from loopclosure.registration import IcpConfig, RegistrationTarget, voxel_downsample
from tests.test_geometric_check import ROOM, _seen_from, _walls

# -- the likelihood grid and the lattice, by hand ---------------------------------------


def test_likelihood_is_the_truncated_quadratic_of_the_distance() -> None:
    grid = LikelihoodGrid(np.array([[0.05, 0.05]]), resolution=0.1, sigma=0.3, pad=1.0)
    cell = np.floor((np.array([0.05, 0.05]) - grid.origin) / 0.1).astype(int)
    value = grid.likelihood()
    q = 0.5 / 255  # stored to 1/255
    assert value[cell[1], cell[0]] == pytest.approx(1.0)
    # Two cells to the right: d = 0.2 m -> 1 - (0.2 / 0.3)^2 = 5/9.
    assert value[cell[1], cell[0] + 2] == pytest.approx(5 / 9, abs=q)
    # Three cells up and one right: d = sqrt(10) * 0.1 > 0.3 -> 0.
    assert value[cell[1] + 3, cell[0] + 1] == 0.0
    narrow, wide = LikelihoodGrid.widths(np.array([[0.05, 0.05]]), 0.1, (0.3, 0.6), pad=1.0)
    np.testing.assert_array_equal(narrow.values, grid.values)
    assert wide.likelihood()[cell[1], cell[0] + 2] == pytest.approx(1 - (0.2 / 0.6) ** 2, abs=q)


def test_search_scores_the_mean_likelihood_of_the_moved_points() -> None:
    grid = LikelihoodGrid(np.array([[1.05, 0.05]]), resolution=0.1, sigma=0.3)
    query = np.array([[1.05, 0.05], [-5.0, -5.0]])  # one on the target point, one far off
    result = search(query, grid, [0.0], radius=0.2, step_cells=1)
    assert result.scores.shape == (1, 5, 5)
    centre = result.scores[0, 2, 2]
    assert centre == pytest.approx(0.5)  # (1 + 0) / 2
    # Shifted by +0.1 m in x: d = 0.1 m -> (1 - 1/9) / 2.
    assert result.scores[0, 2, 3] == pytest.approx((1 - 1 / 9) / 2, abs=0.5 / 255)
    best, score = peaks(result, 1, 0.5, 0.1)
    np.testing.assert_allclose(best[0], [0.0, 0.0, 0.0], atol=1e-12)
    assert score[0] == pytest.approx(0.5)


def test_search_angles_share_one_lattice() -> None:
    step = np.radians(2.0)
    angles = search_angles([0.0, np.radians(2.8)], np.radians(4.0), step)  # 2.8 -> 2
    np.testing.assert_allclose(np.degrees(angles), [-4, -2, 0, 2, 4, 6], atol=1e-9)
    full = search_angles([0.0], np.pi, step)
    assert len(full) == 180


def test_peaks_are_distinct() -> None:
    scores = np.zeros((1, 5, 5))
    scores[0, 2, 2], scores[0, 2, 3], scores[0, 0, 0] = 1.0, 0.9, 0.5
    from loopclosure.correlative import SearchResult

    result = SearchResult(scores, np.zeros(1), np.arange(-2, 3) * 0.1, np.zeros(2))
    poses, values = peaks(result, 2, separation=0.15, angle_separation=0.1)
    np.testing.assert_allclose(poses[:, :2], [[0.0, 0.0], [-0.2, -0.2]], atol=1e-12)
    np.testing.assert_allclose(values, [1.0, 0.5])


# -- free space, by hand ------------------------------------------------------------------


def test_range_image_free_space() -> None:
    ring = 5.0 * np.column_stack([np.cos(np.linspace(-np.pi, np.pi, 720, endpoint=False)),
                                  np.sin(np.linspace(-np.pi, np.pi, 720, endpoint=False))])
    image = RangeImage(ring[ring[:, 0] > 0], bins=720, spread=1)  # only the right half seen
    pts = np.array([[2.0, 0.0], [4.8, 0.0], [6.0, 0.0], [-2.0, 0.0]])
    # 2 m < 5 - 0.3: free; 4.8 m: inside the margin; 6 m: behind the wall; left: unseen.
    np.testing.assert_array_equal(image.free(pts, margin=0.3), [True, False, False, False])


def test_consistency_counts_hits_and_conflicts_both_ways() -> None:
    wall = _walls([((3, -2), (3, 2))], step=0.1)  # a wall 3 m ahead
    cand = Submap.of(wall)
    # The query sees the same wall and, 1 m ahead, a box the candidate saw through.
    box = _walls([((1, -0.2), (1, 0.2))], step=0.1)
    query = Submap.of(np.vstack([wall, box]))
    c = consistency(query, cand, np.zeros(3), tolerance=0.05, margin=0.3)
    # Hits: the wall's points both ways; conflicts: the box's points in the candidate's
    # free space (the candidate's wall points are behind the box for the query: neutral).
    assert c.hits == 2 * len(wall)
    assert c.conflicts == len(box)
    assert c.consistency == pytest.approx(2 * len(wall) / (2 * len(wall) + len(box)))


# -- the check ----------------------------------------------------------------------------


def _pair(a, b, world=ROOM, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    target = RegistrationTarget(_seen_from(world, a, rng, noise))
    return _seen_from(world, b, rng, noise), target, se2.between(a, b)


@pytest.mark.parametrize("b", [np.array([1.6, 0.8, 1.1]), np.array([2.5, 2.2, -2.6]),
                               np.array([0.6, 2.9, 0.2])])
def test_correlative_check_recovers_a_known_rigid_transform(b: np.ndarray) -> None:
    a = np.array([1.0, 1.0, 0.3])
    query, target, truth = _pair(a, b, noise=0.005)
    result = verify(query, target, headings=[truth[2] + np.radians(6)], max_distance=2.0)
    assert result.accepted, result.reason
    np.testing.assert_allclose(result.relative[:2], truth[:2], atol=0.01)
    assert abs(se2.wrap_angle(result.relative[2] - truth[2])) < np.radians(0.5)
    assert result.consistency > 0.95


def test_turning_the_query_sensor_turns_the_result() -> None:
    """Rotating the query submap by -phi (its sensor turned by phi) adds phi to the
    heading and leaves the translation: the search has no preferred direction."""
    a, b = np.array([1.0, 1.0, 0.3]), np.array([1.6, 0.8, 1.1])
    query, target, truth = _pair(a, b)
    base = verify(query, target, headings=[truth[2]])
    for phi in (0.7, -2.0, 3.0):
        turned = se2.transform_points(np.array([0.0, 0.0, -phi]), query)
        res = verify(turned, target, headings=[truth[2] + phi])
        assert res.accepted, res.reason
        np.testing.assert_allclose(res.relative[:2], base.relative[:2], atol=0.01)
        assert abs(se2.wrap_angle(res.relative[2] - base.relative[2] - phi)) < np.radians(0.3)


def test_partial_overlap_with_unseen_rest_is_accepted_without_prior() -> None:
    """A wing the candidate never saw (behind its walls) is neutral, not a mismatch."""
    a, b = np.array([1.0, 1.0, 0.3]), np.array([1.6, 0.8, 1.1])
    wing = _walls([((6, 0), (14, 0)), ((14, 0), (14, 3)), ((14, 3), (7, 3)), ((8, -2), (12, -2))])
    target = RegistrationTarget(_seen_from(ROOM, a))
    query = _seen_from(np.vstack([ROOM, wing]), b)
    truth = se2.between(a, b)
    result = verify(query, target, headings=[truth[2]])
    assert result.fitness < GeometricCheckConfig().min_fitness
    assert result.accepted, result.reason
    np.testing.assert_allclose(result.relative[:2], truth[:2], atol=0.01)


def test_the_matched_length_is_fitness_times_points_times_voxel() -> None:
    """The floor of the check is a length of matched surface (fitness, a soft count
    over the query's voxelised points, times their number and spacing), not a share
    of the query: a far wing the candidate never saw lowers the share, not the length."""
    a, b = np.array([1.0, 1.0, 0.3]), np.array([1.6, 0.8, 1.1])
    target = RegistrationTarget(_seen_from(ROOM, a))
    truth = se2.between(a, b)
    cfg = GeometricCheckConfig()
    plain = verify(_seen_from(ROOM, b), target, headings=[truth[2]], config=cfg)
    wing = _walls([((6, 0), (30, 0)), ((30, 0), (30, 9)), ((30, 9), (7, 9)),
                   ((8, -2), (28, -2))])
    query = _seen_from(np.vstack([ROOM, wing]), b)
    winged = verify(query, target, headings=[truth[2]], config=cfg)
    assert winged.accepted, winged.reason
    points = len(voxel_downsample(query, cfg.source_voxel))
    assert winged.matched_length == pytest.approx(winged.fitness * points * cfg.source_voxel)
    assert winged.fitness < 0.8 * plain.fitness  # the share drops with the wing ...
    assert winged.matched_length == pytest.approx(plain.matched_length, rel=0.1)  # not the length
    strict = GeometricCheckConfig(min_matched_length=winged.matched_length + 0.5)
    refused = verify(query, target, headings=[truth[2]], config=strict)
    assert not refused.accepted and refused.reason.startswith("matched")


def test_points_in_observed_free_space_reject_a_partial_match() -> None:
    """The same room with walls across it (another place that shares its outline in
    part): the query's extra walls lie where the candidate saw free space."""
    a, b = np.array([1.0, 1.0, 0.3]), np.array([1.2, 1.0, 0.5])
    inner = _walls([((0.5, 3.5), (2.5, 3.5)), ((4.5, 0.5), (4.5, 2.5)), ((2.5, 0.5), (2.5, 1.2)),
                    ((0.3, 0.4), (1.2, 0.4))])
    target = RegistrationTarget(_seen_from(ROOM, a))
    query = _seen_from(np.vstack([ROOM[ROOM[:, 1] < 2.5], inner]), b)
    truth = se2.between(a, b)
    result = verify(query, target, headings=[truth[2]])
    assert not result.accepted
    assert result.consistency < GeometricCheckConfig().min_consistency


@pytest.mark.parametrize("both", [True, False])
def test_a_symmetric_room_is_ambiguous(both: bool) -> None:
    """A rectangle fits at theta and theta + pi: the check must not choose, also when
    the hypotheses name only one of the two (the search adds the opposite heading)."""
    rect = _walls([((-3, -1.5), (3, -1.5)), ((3, -1.5), (3, 1.5)), ((3, 1.5), (-3, 1.5)),
                   ((-3, 1.5), (-3, -1.5))])
    a, b = np.array([0.2, 0.1, 0.0]), np.array([-0.1, 0.2, 0.4])
    query, target, truth = _pair(a, b, world=rect)
    heads = [truth[2], truth[2] + np.pi] if both else [truth[2] + np.pi]
    result = verify(query, target, headings=heads)
    assert not result.accepted
    assert "ambiguous" in result.reason or "degenerate" in result.reason


@pytest.mark.parametrize("which", ["query", "candidate", "both"])
def test_an_empty_submap_is_rejected_not_an_error(which: str) -> None:
    full = _seen_from(ROOM, np.array([1.0, 1.0, 0.0]))
    empty = np.zeros((0, 2))
    query = empty if which in ("query", "both") else full
    target = RegistrationTarget(empty if which in ("candidate", "both") else full)
    result = verify(query, target, headings=[0.0], max_distance=2.0)
    assert not result.accepted
    assert result.reason == "registration failed"
    assert np.all(np.isfinite(result.relative)) and np.all(np.isfinite(result.covariance))


def test_no_headings_searches_the_whole_circle() -> None:
    a, b = np.array([1.0, 1.0, 0.3]), np.array([1.4, 1.2, 2.9])
    query, target, truth = _pair(a, b)
    result = verify(query, target)
    assert result.accepted, result.reason
    np.testing.assert_allclose(result.relative[:2], truth[:2], atol=0.01)


def test_the_likelihood_grid_is_cached_on_the_target() -> None:
    a, b = np.array([1.0, 1.0, 0.3]), np.array([1.6, 0.8, 1.1])
    query, target, truth = _pair(a, b)
    first = match_prior_free(query, target, headings=[truth[2]], max_distance=2.0,
                             source_voxel=0.1, icp=IcpConfig())
    grids = {k: v for k, v in target.derived.items() if k[0] == "likelihood"}
    again = match_prior_free(query, target, headings=[truth[2]], max_distance=2.0,
                             source_voxel=0.1, icp=IcpConfig())
    assert all(target.derived[k] is v for k, v in grids.items()) and grids
    np.testing.assert_array_equal(first.results[0].pose, again.results[0].pose)


def test_query_products_are_kept_for_an_equal_query_only() -> None:
    cache = _QueryProducts()
    query = np.array([[0.0, 0.0], [1.0, 2.0]])
    made = cache.get(query, ("voxel", 0.1), lambda: query * 2)
    np.testing.assert_array_equal(made, [[0.0, 0.0], [2.0, 4.0]])
    # An equal copy (another array object) gets the same product, not a new one.
    assert cache.get(query.copy(), ("voxel", 0.1), lambda: query * 3) is made
    # Another parameter is another product of the same query.
    assert cache.get(query, ("voxel", 0.2), lambda: query * 3)[1, 1] == 6.0
    # A different query starts afresh, and the old one's products are dropped.
    moved = query + np.array([0.0, 1e-12])
    assert cache.get(moved, ("voxel", 0.1), lambda: moved * 5)[1, 1] == pytest.approx(10.0)
    assert cache.get(query, ("voxel", 0.1), lambda: query * 7)[1, 1] == 14.0
    # The same array changed in place is another query.
    query[1, 1] = 3.0
    assert cache.get(query, ("voxel", 0.1), lambda: query * 7)[1, 1] == 21.0


def test_one_query_against_several_candidates_matches_fresh_calls() -> None:
    """The products kept for the last query change no figure of the next check: a
    query checked against two candidates in a row, then each alone after another
    query, gives the same runs bit for bit."""
    a, b, c = np.array([1.0, 1.0, 0.3]), np.array([1.6, 0.8, 1.1]), np.array([2.0, 1.5, -0.4])
    query, target_a, truth = _pair(a, b)
    other, target_c, _ = _pair(c, a, seed=1)
    kw = {"max_distance": 2.0, "source_voxel": 0.1, "icp": IcpConfig()}
    in_a_row = [match_prior_free(query, t, headings=[truth[2]], **kw)
                for t in (target_a, target_c)]
    alone = []
    for t in (target_a, target_c):
        match_prior_free(other, target_a, headings=[0.0], **kw)  # another query between
        alone.append(match_prior_free(query.copy(), t, headings=[truth[2]], **kw))
    for x, y in zip(in_a_row, alone, strict=True):
        assert len(x.results) == len(y.results) > 0
        for r, s in zip(x.results, y.results, strict=True):
            np.testing.assert_array_equal(r.pose, s.pose)
            assert (r.fitness, r.rms) == (s.fitness, s.rms)
        assert [f.hits for f in x.consistency] == [f.hits for f in y.consistency]
        np.testing.assert_array_equal(x.peak_scores, y.peak_scores)


def test_an_unknown_method_is_a_user_error() -> None:
    from data.errors import UserError

    with pytest.raises(UserError, match="correlative or icp"):
        GeometricCheckConfig(method="ransac")


def test_a_prior_keeps_the_multi_start_check() -> None:
    """With a prior the check is the pose-gated ICP, whatever the method."""
    a, b = np.array([1.0, 1.0, 0.3]), np.array([1.6, 0.8, 1.1])
    query, target, truth = _pair(a, b, noise=0.005)
    cov = np.diag([0.1, 0.1, 0.02]) ** 2
    new = verify(query, target, prior=truth, prior_covariance=cov)
    old = verify(query, target, prior=truth, prior_covariance=cov,
                 config=GeometricCheckConfig(method="icp"))
    np.testing.assert_array_equal(new.relative, old.relative)
    assert new.fitness == old.fitness and np.isnan(new.consistency)
