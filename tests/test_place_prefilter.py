"""The place database's prefilter index, the vote's candidate merge and the verify
step, against hand-checked cases (loopclosure.place_prefilter, place_shortlist,
place_fusion)."""

from __future__ import annotations

import numpy as np

from loopclosure.matchers.base import Matcher
from loopclosure.place_config import PlaceDatabaseConfig
from loopclosure.place_fusion import stage_distances
from loopclosure.place_prefilter import PrefilterIndex
from loopclosure.place_shortlist import vote_picks, with_votes


def test_vote_picks_by_hand() -> None:
    order = np.array([3, 1, 0, 2, 4])
    votes = np.array([0.0, 5.0, 2.0, 9.0, 2.0])
    head, voted = vote_picks(order, votes, 2, 4)
    assert head.tolist() == [3, 1]
    assert voted.tolist() == [2, 4]  # 3 and 1 are the head; 2 and 4 tie: by position
    head, voted = vote_picks(order[:3], votes, 1, 3)  # order may hold fewer positions
    assert head.tolist() == [3] and voted.tolist() == [1, 2]


def test_with_votes_keeps_the_head_and_the_extras_by_hand() -> None:
    # 8 stored rows; the prefilter's K = 4 are rows 5, 2, 6, 0, the grids' extra row 7.
    pick = np.array([5, 2, 6, 0, 7])
    votes = np.zeros(8)
    votes[[7, 6, 3, 1]] = [9.0, 4.0, 3.0, 1.0]  # 7 is an extra: never voted in
    take, voted = with_votes(pick, votes, 2, 4)
    assert voted.tolist() == [6, 3]  # the best two not among the head 5, 2
    # head 5, 2; voted 6, 3; no prefilter row left below K; the extra 7 last
    rows = np.concatenate([pick[take[:2]], voted, pick[take[2:]]])
    assert rows.tolist() == [5, 2, 6, 3, 7]
    take, voted = with_votes(pick, np.zeros(8), 2, 4)  # no vote: the prefilter's order
    assert voted.tolist() == [] and pick[take].tolist() == pick.tolist()


def test_prefilter_index_p_is_the_weighted_normalised_sum_by_hand() -> None:
    cfg = PlaceDatabaseConfig(prefilter=("fft", "ring"), prefilter_weights=(1.0, 2.0),
                              verifiers=(), fusion="prefilter")
    index = PrefilterIndex(cfg)
    stored = [(np.array([0.0, 0.0]), np.array([1.0])),
              (np.array([3.0, 4.0]), np.array([3.0])),
              (np.array([1.0, 0.0]), np.array([0.0]))]
    for fft, ring in stored:
        index.append({"fft": fft, "ring": ring})
    scales = np.array([5.0, 2.0])
    q = {"fft": np.array([0.0, 0.0]), "ring": np.array([1.0])}
    # p = 1 * |fft| / 5 + 2 * |ring| / 2: rows 0, 1, 2 -> 0, 1 + 2, 0.2 + 1
    p, raw = index.exact(q, np.arange(3), scales)
    np.testing.assert_allclose(p, [0.0, 3.0, 1.2])
    np.testing.assert_allclose(raw["fft"], [0.0, 5.0, 1.0])
    np.testing.assert_allclose(index.screen(q, 3, scales), [0.0, 3.0, 1.2], atol=1e-5)
    short = index.shortlist(q, None, 2, 3, scales, False, None)
    assert short.rows.tolist() == [0, 2]
    # a mask holding row 1 only: the exact path over the allowed rows
    short = index.shortlist(q, np.array([False, True, False]), 2, 3, scales, True, None)
    assert short.rows.tolist() == [1]
    assert np.isinf(short.prefilter_all[[0, 2]]).all()


class _Absolute(Matcher):
    """A verifier whose distance is |a - b| of scalar descriptors (NaN: not finite)."""

    name = "absolute"

    def describe(self, polygon):  # pragma: no cover - never described here
        raise NotImplementedError

    def distance(self, a, b) -> float:
        return abs(a - b)

    def stack(self, many):
        return np.asarray(many, float)

    def distances(self, query, many):
        return np.abs(np.asarray(many, float) - query)


def test_stage_distances_by_hand() -> None:
    cfg = PlaceDatabaseConfig(prefilter=("pairs",), verifiers=("flirt",), fusion="rank")
    stored = [{"flirt": 1.0}, {"flirt": 4.0}, {"flirt": np.nan}]
    out = stage_distances(cfg, {"flirt": _Absolute()}, stored, {"flirt": 2.0},
                          np.array([1, 0, 2]), {"pairs": np.array([0.5, 0.25, 0.125])})
    np.testing.assert_array_equal(out[0], [0.5, 0.25, 0.125])
    np.testing.assert_array_equal(out[1], [2.0, 1.0, np.finfo(float).max])


def _box_polygons(n: int) -> list:
    from data.sim import place_dataset
    from loopclosure.polygon import polygon_from_scan

    return [polygon_from_scan(scan) for _, scan in place_dataset("box", places=2,
                                                                    scans_per_place=n)]


def test_near_fft_stage_is_its_own_fft_and_leaves_the_heading_fft_alone() -> None:
    from loopclosure.matchers.fft import FFTMatcher
    from loopclosure.place_database import PlaceDatabase
    from loopclosure.place_headings import HEADING

    polygon = _box_polygons(1)[0]
    db = PlaceDatabase(prefilter=("pairs", "fft-near"), fusion="rank", fft_near_radius=4.0,
                       fft_far_weight=0.5, fft_near_harmonics=8)
    desc = db.describe(polygon)
    near = FFTMatcher(n_harmonics=8, near_radius=4.0, far_weight=0.5).describe(polygon)
    np.testing.assert_array_equal(desc["fft-near"].amplitudes, near.amplitudes)
    assert len(near.amplitudes) == 16  # 8 near-field amplitudes, then 8 of the whole
    whole = FFTMatcher().describe(polygon)  # the heading range function: whole polygon
    np.testing.assert_array_equal(desc[HEADING].range_function, whole.range_function)
    assert not np.array_equal(near.range_function, whole.range_function)


def test_the_fitted_logistic_of_the_stage_set_is_picked_when_left_at_default() -> None:
    from loopclosure.fusion import LogisticFusion
    from loopclosure.place_config import DEFAULT_LOGISTIC, NEAR_FFT_LOGISTIC

    assert PlaceDatabaseConfig().logistic is DEFAULT_LOGISTIC
    near = PlaceDatabaseConfig(prefilter=("pairs", "fft-near"))
    assert near.logistic is NEAR_FFT_LOGISTIC
    mine = LogisticFusion(names=("flirt", "fft-near", "pairs"), coefficients=(-1.0, -1.0, -1.0))
    assert PlaceDatabaseConfig(prefilter=("pairs", "fft-near"), logistic=mine).logistic is mine


def test_near_pairs_stage_is_the_pair_histogram_of_the_near_surfaces() -> None:
    from itertools import pairwise

    import pytest

    from data.errors import UserError
    from loopclosure.matchers.pair_histogram import PairHistogramMatcher
    from loopclosure.place_config import NEAR_PAIRS_LOGISTIC
    from loopclosure.place_database import PlaceDatabase
    from loopclosure.polygon import Polygon

    def walls(corners: list[list[float]]) -> Polygon:
        """A polygon with a vertex every 0.1 m along its walls (as a scan's)."""
        c = np.array(corners + corners[:1], float)
        pts = [a + (b - a) * t for a, b in pairwise(c)
               for t in np.arange(0.0, 1.0, 0.1 / np.linalg.norm(b - a))]
        return Polygon(np.array(pts))

    # A 4 m square room around the sensor: every vertex within 2.9 m of it, so the
    # near field (R = 6 m) is the whole view and both histograms are equal.
    room = walls([[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]])
    db = PlaceDatabase(prefilter=("pairs", "pairs-near"), prefilter_weights=(1.0, 0.25))
    assert db.config.logistic is NEAR_PAIRS_LOGISTIC
    assert dict(zip(NEAR_PAIRS_LOGISTIC.names, NEAR_PAIRS_LOGISTIC.coefficients,
                    strict=True))["pairs-near"] == 0.0  # the default's score, unchanged
    desc = db.describe(room)
    assert np.asarray(desc["pairs"]).sum() > 0
    np.testing.assert_array_equal(desc["pairs-near"], desc["pairs"])
    # A 20 m corridor, 2 m wide: its far ends (beyond 6 m) are open space to the near
    # stage only, which is then the histogram of the corridor's middle 12 m.
    hall = walls([[-10.0, -1.0], [10.0, -1.0], [10.0, 1.0], [-10.0, 1.0]])
    desc = db.describe(hall)
    near = PairHistogramMatcher(max_range=6.0).describe(hall)
    np.testing.assert_array_equal(desc["pairs-near"], near)
    assert np.asarray(near).sum() > 0
    assert not np.allclose(desc["pairs-near"], desc["pairs"])
    with pytest.raises(UserError, match="pairs_near_radius"):
        PlaceDatabaseConfig(prefilter=("pairs", "pairs-near"), pairs_near_radius=0.0)


def test_a_further_prefilter_stage_leaves_the_other_stages_scales() -> None:
    from loopclosure.place_database import PlaceDatabase

    polygons = _box_polygons(9)[:16]
    one = PlaceDatabase(prefilter=("pairs",))
    two = PlaceDatabase(prefilter=("pairs", "pairs-near"), prefilter_weights=(1.0, 0.15))
    for i, p in enumerate(polygons):
        one.add(i, p)
        two.add(i, p)
    a, b = one.scales, two.scales
    assert a["pairs"] == b["pairs"] and a["flirt"] == b["flirt"]
    # The further stage's scale by hand: 256 pairs of the first 16 rows from the
    # generator seeded (seed 0, m 16, stage 1), a != b, the median of their distances.
    rng = np.random.default_rng([0, 16, 1])
    i = rng.integers(0, 16, size=256)
    j = rng.integers(0, 15, size=256)
    j = j + (j >= i)
    vecs = np.array([np.asarray(two.descriptors(k)["pairs-near"], float) for k in range(16)])
    by_hand = np.median(np.linalg.norm(vecs[i] - vecs[j], axis=1))
    assert abs(b["pairs-near"] - by_hand) < 1e-6 * by_hand
