"""The surface context: pair distances and elevations over the whole object
(`loopclosure.stripes.surface`), and the default fused matcher that holds it."""

from __future__ import annotations

import numpy as np
import pytest

from data.errors import DataError, UserError
from loopclosure.stripes import (
    StripeSurface,
    SurfaceConfig,
    SurfaceDatabase,
    describe_surface,
    surface_histogram,
    surface_points,
)
from tests.test_stripes_relief import dome


def test_surface_histogram_of_three_hand_checked_points():
    # Pairs: (1,0,0)-(0,0,0): r = 1, flat (elevation 0); (0,0,1)-(0,0,0): r = 1,
    # vertical (pi/2); (0,0,1)-(1,0,0): r = sqrt 2, elevation pi/4.  Median r = 1, so
    # log(r / median) = 0, 0, log sqrt 2 = 0.347.  Distance bins: 8 over [-2, 1), width
    # 3/8: 0 -> bin 5 (5.33), 0.347 -> bin 6 (6.26); elevation bins: 8 over [0, pi/2]:
    # 0 -> 0, pi/2 -> 7 (the last bin holds its upper end), pi/4 -> 4.
    h = surface_histogram([[0, 0, 0], [1, 0, 0], [0, 0, 1]])
    expected = np.zeros((8, 8))
    expected[5, 0] = expected[5, 7] = expected[6, 4] = 1 / 3
    np.testing.assert_allclose(h, expected)
    # One point: no pair; all mass at the median distance, flat.
    one = surface_histogram([[0.0, 0.0, 0.0]], SurfaceConfig(distance_bins=3, elevation_bins=2))
    np.testing.assert_allclose(one, [[0, 0], [0, 0], [1, 0]])


def test_surface_points_take_the_seen_cells_in_metres():
    z = np.array([[1.0, np.nan], [2.0, 3.0]])
    p = surface_points(z, (0.5, 0.25))  # rows 0.5 m apart, columns 0.25 m
    np.testing.assert_allclose(p, [[0.0, 0.0, 1.0], [0.0, 0.5, 2.0], [0.25, 0.5, 3.0]])
    # More cells than points: a fixed draw of that many, the same every time.
    big = dome(41)
    a, b = surface_points(big, (0.0025, 0.0025), 50), surface_points(big, (0.0025, 0.0025), 50)
    assert a.shape == (50, 3)
    np.testing.assert_array_equal(a, b)
    with pytest.raises(DataError, match="no height"):
        surface_points(np.full((2, 2), np.nan), (1.0, 1.0))
    with pytest.raises(UserError, match="positive"):
        surface_points(z, (0.0, 1.0))


def test_surface_context_is_free_of_turn_mirror_and_scale():
    # A flat-topped oval box with a dome on it: not symmetric under a quarter turn.
    n = 24
    y, x = np.mgrid[0:n, 0:n + 8]
    z = np.where(((x - 16) / 15.0) ** 2 + ((y - 12) / 11.0) ** 2 < 1, 0.02, np.nan)
    z = z + 0.01 * np.exp(-((x - 10) ** 2 + (y - 8) ** 2) / 20.0)
    cfg = SurfaceConfig(points=10_000)  # every cell, no draw
    a = describe_surface(z, (0.001, 0.001), cfg).histogram
    turned = describe_surface(z.T, (0.001, 0.001), cfg).histogram  # quarter turn + mirror
    scaled = describe_surface(3 * z, (0.003, 0.003), cfg).histogram
    np.testing.assert_allclose(turned, a, atol=1e-12)
    np.testing.assert_allclose(scaled, a, atol=1e-12)
    assert a.sum() == pytest.approx(1.0)


def test_flat_box_and_dome_differ_in_elevation():
    cfg = SurfaceConfig(points=400)
    flat = describe_surface(np.full((20, 30), 0.05), (0.002, 0.002), cfg).histogram
    np.testing.assert_allclose(flat[:, 0].sum(), 1.0)  # every pair in the table plane
    ball = describe_surface(dome(41), (0.0025, 0.0025), cfg).histogram
    assert ball[:, 1:].sum() > 0.3  # a dome's pairs climb
    db = SurfaceDatabase([StripeSurface(flat), StripeSurface(ball)])
    np.testing.assert_allclose(db.distances(StripeSurface(flat)),
                               [0.0, np.abs(flat - ball).sum()])
    np.testing.assert_allclose(db.pairwise(), db.pairwise().T)
    with pytest.raises(UserError, match="bins"):
        db.distances(StripeSurface(np.zeros((2, 2))))
    with pytest.raises(UserError, match="one shape"):
        SurfaceDatabase([StripeSurface(flat), StripeSurface(np.zeros((2, 2)))])
    with pytest.raises(UserError, match="log range"):
        SurfaceConfig(log_range=(1.0, 0.0))


def test_fused_database_with_reliefs_and_surfaces_is_the_four_part_fusion():
    from loopclosure.polygon import Polygon
    from loopclosure.stripes import (
        FusedObjectDatabase,
        ProfileDatabase,
        ReliefDatabase,
        describe_profiles,
        describe_relief,
        fuse,
    )

    heights = [np.full((20, 20), 0.04), dome(41), dome(41, lid=0.02)]
    cells = [(0.002, 0.002), (0.0025, 0.0025), (0.0025, 0.0025)]
    stripes = [[np.column_stack([np.arange(20.0), np.zeros(20)])] * 20,
               [np.column_stack([np.arange(30.0), np.abs(np.arange(30.0) - 15)])] * 30,
               [np.column_stack([np.arange(30.0), np.minimum(np.abs(np.arange(30.0) - 15),
                                                             8)])] * 30]
    profiles = describe_profiles(stripes)
    reliefs = [describe_relief(h, c) for h, c in zip(heights, cells, strict=True)]
    surfaces = [describe_surface(h, c) for h, c in zip(heights, cells, strict=True)]
    t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    circle = Polygon(np.column_stack([50 * np.cos(t), 50 * np.sin(t)]))
    polys = [Polygon(np.array([[0, 0], [40, 0], [40, 40], [0, 40]], float)), circle, circle]
    db = FusedObjectDatabase(profiles, polys, verifiers=("fft",), reliefs=reliefs,
                             surfaces=surfaces)
    parts = db.method_distances(profiles[1], polys[1], reliefs[1], surfaces[1])
    assert len(parts) == 4
    np.testing.assert_allclose(parts[0], ProfileDatabase(profiles).distances(profiles[1]))
    np.testing.assert_allclose(parts[2], SurfaceDatabase(surfaces).distances(surfaces[1]))
    # Default: each part locally scaled by the database's own distances, geometric mean.
    own = [ProfileDatabase(profiles).pairwise(), ReliefDatabase(reliefs).pairwise(),
           SurfaceDatabase(surfaces).pairwise(), db.matchers[0].pairwise(
               [db.matchers[0].describe(p) for p in polys])]
    np.testing.assert_allclose(db.distances(profiles[1], polys[1], reliefs[1], surfaces[1]),
                               fuse(parts, scaling="local", databases=own, mean="geometric"))
    median = FusedObjectDatabase(profiles, polys, verifiers=("fft",), reliefs=reliefs,
                                 surfaces=surfaces, scaling="median", mean="arithmetic")
    np.testing.assert_allclose(
        median.distances(profiles[1], polys[1], reliefs[1], surfaces[1]), fuse(parts))
    assert db.query(profiles[1], polys[1], k=1, relief=reliefs[1],
                    surface=surfaces[1])[0][0] == 1
    with pytest.raises(UserError, match="surface context exactly"):
        db.distances(profiles[1], polys[1], reliefs[1])
    with pytest.raises(UserError, match="surfaces must hold one per object"):
        FusedObjectDatabase(profiles, polys, verifiers=("fft",), surfaces=surfaces[:2])
    with pytest.raises(UserError, match="weights need 4"):
        FusedObjectDatabase(profiles, polys, verifiers=("fft",), reliefs=reliefs,
                            surfaces=surfaces, weights=[1, 1])


def test_fused_row_is_profile_relief_surface_and_shape_context():
    from dataclasses import replace

    from data.stripe_scanner import ScannerConfig
    from evaluation.stripes_benchmark import (
        StripesBenchmarkConfig,
        baseline_distances,
        run_stripes_benchmark,
        surface_distances,
    )
    from evaluation.stripes_objects import daily_objects, silhouette_polygon
    from loopclosure.stripes import fuse

    objs = daily_objects(1, 2, ("apple", "pen"))
    scanner = replace(ScannerConfig(), step=0.004)
    cfg = StripesBenchmarkConfig(seed=1, baselines=(), fused_sc=(), fused_relief=(),
                                 scanner=scanner)
    res = run_stripes_benchmark(objs, cfg)
    m = res.methods()
    assert list(m)[:7] == ["stripes", "profile", "relief", "surface", "canonical",
                           "fused-stripes", "fused"]
    surface, _ = surface_distances(res.scanned.scans, scanner)
    np.testing.assert_allclose(res.surface.distances, surface)
    three = [res.profile.distances, res.relief.distances, surface]
    # fused-stripes: the three and the canonical profile, each locally scaled, their
    # geometric mean.
    np.testing.assert_allclose(
        res.fused_stripes.distances,
        fuse([*three, res.canonical.distances], scaling="local", mean="geometric"))
    # The fused row: the three and shape context on 50 points, same rule.
    polys = [silhouette_polygon(x, scanner) for x in res.scanned.scans]
    sc = baseline_distances("shape-context-50", polys)[0]
    np.testing.assert_allclose(res.fused.distances,
                               fuse([*three, sc], scaling="local", mean="geometric"))
    assert res.to_json()["fused"]["options"]["mean"] == "geometric"
    # The median rule with the arithmetic mean is the earlier one.
    old = run_stripes_benchmark(objs, replace(cfg, scaling="median", mean="arithmetic"))
    np.testing.assert_allclose(old.fused.distances, fuse([*three, sc]))
    js = res.to_json()
    assert js["fused"]["options"]["verifiers"] == ["shape-context-50"]
    assert js["fused"]["top10_counts"][0] == 4 and js["fused_stripes"]["top10_counts"][0] == 4
    none = run_stripes_benchmark(objs, replace(cfg, fused=()))
    assert none.fused is None and "fused" not in none.methods()
    assert "fused-stripes" in none.methods()
