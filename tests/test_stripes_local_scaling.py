"""Local scaling of the fused object matcher's parts (`loopclosure.stripes.fusion`)."""

from __future__ import annotations

import numpy as np
import pytest

from data.errors import UserError
from loopclosure.polygon import Polygon
from loopclosure.stripes import (
    FusedObjectDatabase,
    ProfileDatabase,
    combine,
    database_scales,
    describe_profiles,
    fuse,
    local_scaled,
    neighbour_scale,
    normalised,
)

# Three objects, one method: d(0,1) = 2, d(0,2) = 4, d(1,2) = 1.
D = np.array([[0.0, 2.0, 4.0], [2.0, 0.0, 1.0], [4.0, 1.0, 0.0]])


def test_neighbour_scale_skips_the_objects_own_zero_distance():
    row = np.array([0.0, 3.0, 1.0, 6.0, 2.0, 5.0, 4.0])
    assert neighbour_scale(row, 2) == pytest.approx(2.0)
    assert neighbour_scale(row, 5) == pytest.approx(5.0)
    # Fewer neighbours than asked: the farthest; nothing but zeros: 1.
    assert neighbour_scale(row, 10) == pytest.approx(6.0)
    assert neighbour_scale(np.zeros(4), 5) == pytest.approx(1.0)
    # Infinite distances are no neighbours; rows are independent.
    np.testing.assert_allclose(neighbour_scale([[0, np.inf, 3.0], [1.0, 2.0, 0]], 1), [3, 1])
    with pytest.raises(UserError, match="at least 1"):
        neighbour_scale(row, 0)
    with pytest.raises(UserError, match="non-negative"):
        neighbour_scale([-1.0, 1.0])


def test_local_scaling_by_hand():
    # Nearest neighbour (n = 1) of each object: 0 -> 1 (2), 1 -> 2 (1), 2 -> 1 (1).
    s = database_scales(D, 1)
    np.testing.assert_allclose(s, [2.0, 1.0, 1.0])
    r2 = np.sqrt(2.0)
    want = np.array([[0, 2 / r2, 4 / r2], [2 / r2, 0, 1], [4 / r2, 1, 0]])
    np.testing.assert_allclose(local_scaled(D, s, 1), want)
    np.testing.assert_allclose(fuse([D], scaling="local", neighbour=1), want)
    # n = 2 (every other object): s = [4, 2, 4]; d(0,1) / sqrt(4 * 2).
    np.testing.assert_allclose(database_scales(D, 2), [4.0, 2.0, 4.0])
    assert fuse([D], scaling="local", neighbour=2)[0, 1] == pytest.approx(2 / np.sqrt(8))
    # A query outside the database: s(q) from its own row, s(j) from the database.
    q = np.array([1.0, 3.0, 5.0])
    np.testing.assert_allclose(local_scaled(q, s, 1), q / np.sqrt(1.0 * s))
    np.testing.assert_allclose(fuse([q], scaling="local", databases=[D], neighbour=1),
                               q / np.sqrt(s))


def test_local_scaling_is_invariant_to_scaling_one_part():
    rng = np.random.default_rng(3)
    a = rng.uniform(0.1, 1.0, (12, 12))
    b = rng.uniform(0.1, 1.0, (12, 12))
    np.fill_diagonal(a, 0.0)
    np.fill_diagonal(b, 0.0)
    ref = fuse([a, b], scaling="local")
    np.testing.assert_allclose(fuse([a, 7.5 * b], scaling="local"), ref)
    np.testing.assert_allclose(fuse([1e-3 * a, b], scaling="local"), ref)
    # And the weights still weigh: all weight on a is a's scaled distances alone.
    np.testing.assert_allclose(fuse([a, b], [1.0, 0.0], scaling="local"),
                               fuse([a], scaling="local"))


def test_geometric_mean_counts_each_part_by_ratios():
    # Two parts, three candidates.  Part 1 spreads widely (scores 0.5, 4, 8), part 2
    # narrowly (2, 1, 0.9).  Arithmetic mean: 1.25, 2.5, 4.45.  Geometric: sqrt(0.5*2) = 1,
    # sqrt(4*1) = 2, sqrt(8*0.9) = sqrt(7.2).
    p1, p2 = np.array([0.5, 4.0, 8.0]), np.array([2.0, 1.0, 0.9])
    w = np.array([0.5, 0.5])
    np.testing.assert_allclose(combine([p1, p2], w, "arithmetic"), [1.25, 2.5, 4.45])
    np.testing.assert_allclose(combine([p1, p2], w, "geometric"), [1.0, 2.0, np.sqrt(7.2)])
    # Candidates c0 = (1, 5) and c1 = (8, 0.5): part 1 finds c0 8x nearer (a gap of 7),
    # part 2 finds c1 10x nearer (a gap of 4.5).  Arithmetic: 3 < 4.25, part 1's wider
    # gap decides; geometric: sqrt(5) > sqrt(4), the larger ratio decides.
    c0c1 = [np.array([1.0, 8.0]), np.array([5.0, 0.5])]
    np.testing.assert_allclose(combine(c0c1, w, "arithmetic"), [3.0, 4.25])
    np.testing.assert_allclose(combine(c0c1, w, "geometric"), [np.sqrt(5.0), 2.0])
    # Weights are exponents; a zero score is floored (0.01) unless every score is zero.
    np.testing.assert_allclose(combine([p1, p2], np.array([1.0, 0.0]), "geometric"), p1)
    np.testing.assert_allclose(combine([np.array([0.0, 0.0]), np.array([0.0, 4.0])], w,
                                       "geometric"), [0.0, np.sqrt(0.01 * 4.0)])
    # Scale-free as local scaling: one part times a constant leaves the fusion as it is.
    rng = np.random.default_rng(4)
    m1, m2 = rng.uniform(0.1, 1.0, (2, 10, 10))
    np.fill_diagonal(m1, 0.0)
    np.fill_diagonal(m2, 0.0)
    ref = fuse([m1, m2], scaling="local", mean="geometric")
    np.testing.assert_allclose(fuse([m1, 30.0 * m2], scaling="local", mean="geometric"), ref)
    assert np.all(np.diag(ref) == 0.0)
    with pytest.raises(UserError, match="unknown mean"):
        fuse([m1, m2], scaling="local", mean="harmonic")
    with pytest.raises(UserError, match="unknown mean"):
        FusedObjectDatabase(*_objects(), mean="harmonic")


def test_median_scaling_is_the_earlier_rule():
    a, b = np.array([1.0, 2.0, 3.0]), np.array([30.0, 20.0, 10.0])
    np.testing.assert_allclose(fuse([a, b], scaling="median"), (normalised(a) + normalised(b)) / 2)
    np.testing.assert_allclose(fuse([a, b]), fuse([a, b], scaling="median"))
    with pytest.raises(UserError, match="unknown scaling"):
        fuse([a, b], scaling="zscore")
    with pytest.raises(UserError, match="own \\(M, M\\)"):
        fuse([a, b], scaling="local")


def _objects():
    t = np.linspace(0.2, np.pi - 0.2, 40)
    shapes = []
    for r in (10.0, 14.0, 18.0, 22.0):
        shapes.append([np.column_stack([r * np.cos(t), r * np.sin(t)])] * 20)
    for w in (30, 40, 50):
        shapes.append([np.column_stack([np.arange(float(w)), np.zeros(w)])] * 20)
    u = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    polys = [Polygon(np.column_stack([(20 + 3 * i) * np.cos(u), (15 + i) * np.sin(u)]))
             for i in range(len(shapes))]
    return describe_profiles(shapes), polys


def test_fused_database_local_and_median():
    profiles, polys = _objects()
    db = FusedObjectDatabase(profiles, polys, verifiers=("fft",), neighbour=2)
    assert db.scaling == "local" and db.scales is not None and len(db.scales) == 2
    m = db.matchers[0]
    own = [ProfileDatabase(profiles).pairwise(), m.pairwise([m.describe(p) for p in polys])]
    for i in (0, 5):
        parts = db.method_distances(profiles[i], polys[i])
        want = fuse(parts, scaling="local", databases=own, neighbour=2, mean="geometric")
        np.testing.assert_allclose(db.distances(profiles[i], polys[i]), want)
        # A query that is in the database: its own zero distance is skipped, so its
        # scaled row is its row of the all-pairs local scaling.
        np.testing.assert_allclose(
            want, fuse(own, scaling="local", neighbour=2, mean="geometric")[i], atol=1e-9)
        assert db.query(profiles[i], polys[i], k=1)[0][0] == i
    median = FusedObjectDatabase(profiles, polys, verifiers=("fft",), scaling="median",
                                 mean="arithmetic")
    assert median.scales is None
    parts = median.method_distances(profiles[2], polys[2])
    np.testing.assert_allclose(median.distances(profiles[2], polys[2]), fuse(parts))
    with pytest.raises(UserError, match="unknown scaling"):
        FusedObjectDatabase(profiles, polys, scaling="rank")
    with pytest.raises(UserError, match="neighbour"):
        FusedObjectDatabase(profiles, polys, neighbour=0)


def test_diagnosis_blocks_and_figures_by_hand():
    from benchmarks.stripes_diagnosis import Column, hit_rate, pose_figures, profile_block

    profiles, _ = _objects()
    stack = np.stack([p.profile for p in profiles])
    everything = np.arange(len(profiles))
    np.testing.assert_allclose(profile_block(stack, everything, everything),
                               ProfileDatabase(profiles).pairwise())
    # A query block against part of the database: that database's medians.
    rows, cols = np.array([0, 5]), np.array([1, 2, 3, 6])
    sub = ProfileDatabase([profiles[i] for i in cols])
    np.testing.assert_allclose(profile_block(stack, rows, cols),
                               [sub.distances(profiles[i]) for i in rows])
    # Two queries (objects 0, 1; classes a, b) against scans of objects 0, 1, 2.
    col = Column(0, 1, np.array(["a", "b"]), np.array(["a", "b", "a"]), np.array([0, 1]),
                 np.array([0, 1, 2]), ["x", "y"], ["x", "y", "z"], np.zeros(2))
    d = np.array([[0.1, 0.5, 0.9], [0.2, 0.3, 0.1]])
    # Own objects are no answers: query 0 -> object 1 (b, miss), query 1 -> 2 (a, miss).
    assert hit_rate(d, col) == 0.0
    assert hit_rate(np.array([[0.1, 0.9, 0.5], [0.2, 0.3, 0.1]]), col) == 0.5
    own, ratio = pose_figures(d, col)
    # Own scan nearest for query 0 only; ratios: 0.1 / 0.5, 0.3 / median(0.2, 0.1).
    assert own == 0.5
    np.testing.assert_allclose(ratio, [0.2, 0.3 / 0.15])


def test_speed_benchmark_judges_decisions_by_hand():
    from benchmarks.stripes_speed import decision_changes, nearest_other, relative_change

    old = np.array([[0.0, 1.0, 2.0], [1.0, 0.0, 3.0], [2.0, 3.0, 0.0]])
    # The diagonal (the query itself) is no answer: 0 -> 1, 1 -> 0, 2 -> 0.
    np.testing.assert_array_equal(nearest_other(old), [0 + 1, 0, 0])
    # Relative changes: |1.001 - 1| / 1 = 1e-3 is the largest; zeros stay zeros.
    new = old.copy()
    new[0, 1], new[2, 1] = 1.001, 3.0 * (1 + 1e-9)
    assert relative_change(old, new) == pytest.approx(1e-3)
    assert decision_changes(old, new) == 0
    # Query 2 flips from object 0 (2.0) to object 1 (3.0 -> 1.9): one changed decision.
    moved = old.copy()
    moved[2, 1] = 1.9
    assert decision_changes(old, moved) == 1
    # Non-finite entries are never nearest; a matrix against itself changes nothing.
    inf = old.copy()
    inf[0, 1] = np.inf
    np.testing.assert_array_equal(nearest_other(inf), [2, 0, 0])
    assert decision_changes(inf, inf) == 0
