"""The relief: mean depth below the object's top, ring by ring (`loopclosure.stripes.relief`)."""

from __future__ import annotations

import numpy as np
import pytest

from data.errors import DataError, UserError
from loopclosure.stripes import ReliefConfig, ReliefDatabase, describe_relief
from loopclosure.stripes.relief import RELIEF_RINGS, local_top


def dome(n: int = 41, radius: float = 0.05, lid: float = 0.0) -> np.ndarray:
    """Heights [m] of a hemisphere of `radius` on an n x n grid of 2 radius / n cells,
    NaN outside; with `lid` > 0 a flat cap at that height below the pole."""
    c = (np.arange(n) + 0.5) / n * 2 * radius - radius
    x, y = np.meshgrid(c, c)
    r2 = x**2 + y**2
    z = np.where(r2 < radius**2, np.sqrt(np.maximum(radius**2 - r2, 0.0)), np.nan)
    return np.minimum(z, radius - lid) if lid > 0 else z


def test_relief_hand_checked_square():
    # Four cells of 1 m x 1 m, heights 1, 1, 1, 0.5: area 4 -> r_eq = 2 / sqrt(pi); the
    # top (98th percentile) is 1, so three depths are 0 and one is 0.5 / r_eq.  Every
    # cell is sqrt(1/2) from the centroid = the RMS radius: rho = 1, and with 2 rings
    # over rho in [0, 2) all four fall in ring 1: mean depth (0.5 / r_eq) / 4.
    r = describe_relief([[1.0, 1.0], [1.0, 0.5]], (1.0, 1.0),
                        ReliefConfig(rings=2, fine_window=3.0))
    # Fine relief (square of side 3 m: every cell sees the whole 2 x 2 grid, local top
    # 1 m; cap 10 mm): depths 0, 0, 0, 0.5 m -> 0, 0, 0, 1 (capped), all in ring 1.
    np.testing.assert_allclose(r.relief, [0.0, np.sqrt(np.pi) / 16, 0.0, 0.25])
    coarse = describe_relief([[1.0, 1.0], [1.0, 0.5]], (1.0, 1.0),
                             ReliefConfig(rings=2, fine_window=0.0))
    np.testing.assert_allclose(coarse.relief, [0.0, np.sqrt(np.pi) / 16])


def test_local_top_hand_checked():
    # 1 x 5 grid of 1 mm cells, window 3 mm: each cell's top is the max of itself and
    # its two neighbours; NaN never a top; a square with no seen cell is -inf.
    z = np.array([[1.0, np.nan, 3.0, 2.0, np.nan, np.nan, np.nan]]) * 1e-3
    top = local_top(z, (1e-3, 1e-3), 3e-3)
    np.testing.assert_allclose(top[0, :5] * 1e3, [1.0, 3.0, 3.0, 3.0, 2.0])
    assert top[0, 6] == -np.inf
    # Rows 2 mm apart, columns 1 mm: a 5 mm square spans 5 columns but 3 rows.
    z = np.zeros((5, 7))
    z[0, 3] = z[2, 0] = 1.0
    top = local_top(z, (2e-3, 1e-3), 5e-3)
    assert top[1, 3] == 1.0 and top[2, 3] == 0.0  # row 0 is 2 rows from row 2
    assert top[2, 2] == 1.0 and top[2, 3] == 0.0  # column 0 is 2 columns from 2, not 3


def test_fine_relief_sees_studs_at_any_footprint_size():
    # A flat plate with 2 mm studs every 4 mm, and the same plate 4 times larger (same
    # studs): the size-free relief of the large one falls towards a flat box's, the
    # fine relief (millimetres) stays; a flat box top has none.
    def plate(n: int) -> np.ndarray:
        z = np.full((n, n), 0.01)
        for i in (0, 1):
            for j in (0, 1):
                z[i::8, j::8] = 0.012  # 0.5 mm cells: a 1 mm stud every 4 mm
        return z

    cell = (0.0005, 0.0005)
    small, large = (describe_relief(plate(n), cell).relief for n in (40, 160))
    box = describe_relief(np.full((160, 160), 0.01), cell).relief
    k = RELIEF_RINGS
    assert np.all(box == 0.0)
    assert large[:k].mean() < 0.3 * small[:k].mean()  # size-free: the large plate flattens
    np.testing.assert_allclose(large[k:k + 4], small[k:k + 4], atol=0.02)  # studs: mm stay
    assert large[k:].mean() > 0.1  # 2 mm below a stud out of a 10 mm cap, most cells


def test_relief_of_a_flat_top_is_zero_and_of_a_dome_grows_outwards():
    flat = np.full((10, 30), 0.04)
    flat[0, 0] = np.nan
    assert np.all(describe_relief(flat, (0.001, 0.002)).relief == 0.0)
    full = describe_relief(dome(), (0.1 / 41, 0.1 / 41)).relief
    for r in (full[:RELIEF_RINGS], full[RELIEF_RINGS:]):  # size-free, then fine relief
        seen = r[r > 0]
        assert len(seen) >= 5 and np.all(np.diff(seen) > 0)  # deeper towards the rim
        assert r[-1] == 0.0  # a disc does not reach 2 RMS radii


def test_relief_is_yaw_mirror_and_scale_free():
    z = dome(lid=0.01)
    z[:, :8] = np.nan  # not round: turning it matters
    cell = (0.1 / 41, 0.1 / 41)
    ref = describe_relief(z, cell).relief
    np.testing.assert_allclose(describe_relief(np.rot90(z), cell).relief, ref, atol=1e-12)
    np.testing.assert_allclose(describe_relief(z[:, ::-1], cell).relief, ref, atol=1e-12)
    # Scale-free: the size-free half; the fine half measures millimetres on purpose.
    k = RELIEF_RINGS
    big = describe_relief(3.0 * z, (3 * cell[0], 3 * cell[1])).relief
    np.testing.assert_allclose(big[:k], ref[:k], atol=1e-12)
    assert not np.allclose(big[k:], ref[k:])


def test_relief_database_distances():
    a = describe_relief(dome(), (0.1 / 41, 0.1 / 41))
    b = describe_relief(dome(lid=0.02), (0.1 / 41, 0.1 / 41))
    c = describe_relief(np.full((5, 5), 0.03), (0.01, 0.01))
    db = ReliefDatabase([a, b, c])
    d = db.pairwise()
    np.testing.assert_allclose(d, d.T)
    np.testing.assert_allclose(np.diag(d), 0.0)
    np.testing.assert_allclose(db.distances(a), d[0])
    assert d[0, 2] == pytest.approx(np.abs(a.relief).mean())
    assert d[1, 2] < d[0, 2]  # a lidded dome is flatter than the full one


def test_relief_errors():
    with pytest.raises(DataError, match="no relief"):
        describe_relief(np.full((3, 3), np.nan), (0.01, 0.01), name="ghost")
    with pytest.raises(UserError, match="cell spacing"):
        describe_relief(np.ones((3, 3)), (0.0, 0.01))
    with pytest.raises(UserError, match="rings"):
        ReliefConfig(rings=0)
    with pytest.raises(UserError, match="fine window"):
        ReliefConfig(fine_window=-0.001)
    with pytest.raises(UserError, match="fine cap"):
        ReliefConfig(fine_cap=0.0)
    with pytest.raises(UserError, match="one shape"):
        ReliefDatabase([describe_relief(np.ones((2, 2)), (1.0, 1.0)),
                        describe_relief(np.ones((2, 2)), (1.0, 1.0), ReliefConfig(rings=3))])


def test_fused_relief_row_is_the_fusion_of_profile_relief_and_shape_context():
    from dataclasses import replace

    from data.stripe_scanner import ScannerConfig
    from evaluation.stripes_benchmark import (
        StripesBenchmarkConfig,
        relief_distances,
        run_stripes_benchmark,
    )
    from evaluation.stripes_objects import daily_objects
    from loopclosure.stripes import fuse

    objs = daily_objects(1, 2, ("apple", "pen"))
    scanner = replace(ScannerConfig(), step=0.004)
    cfg = StripesBenchmarkConfig(seed=1, baselines=(), fused=(), scanner=scanner)
    res = run_stripes_benchmark(objs, cfg)
    m = res.methods()
    assert {"relief", "fused-sc", "fused-relief"} <= set(m)
    relief, _ = relief_distances(res.scanned.scans, scanner)
    np.testing.assert_allclose(res.relief.distances, relief)
    # Equal weights on median-normalised parts: fused-sc is (P + S) / 2, so fused-relief
    # (P + R + S) / 3 is (2 fused-sc + R) / 3 with R the normalised relief.
    np.testing.assert_allclose(res.fused_relief.distances,
                               (2 * res.fused_sc.distances + fuse([relief])) / 3)
    assert res.to_json()["fused_relief"]["top10_counts"][0] == 4
    none = run_stripes_benchmark(objs, StripesBenchmarkConfig(
        seed=1, baselines=(), fused=(), fused_sc=(), fused_relief=(), scanner=scanner))
    assert none.fused_relief is None and "fused-relief" not in none.methods()
    assert "relief" in none.methods()


def test_fused_database_with_reliefs_is_the_three_part_fusion():
    from loopclosure.polygon import Polygon
    from loopclosure.stripes import FusedObjectDatabase, ProfileDatabase, describe_profiles, fuse

    t = np.linspace(0.2, np.pi - 0.2, 40)
    arc = [np.column_stack([20 * np.cos(t), 20 * np.sin(t)])] * 20
    line = [np.column_stack([np.arange(40.0), np.zeros(40)])] * 20
    profiles = describe_profiles([arc, line, arc[:10]])
    cell = (0.1 / 41, 0.1 / 41)
    reliefs = [describe_relief(dome(), cell), describe_relief(np.full((9, 9), 0.02), cell),
               describe_relief(dome(lid=0.02), cell)]
    u = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    polys = [Polygon(np.column_stack([20 * np.cos(u), 20 * np.sin(u)])),
             Polygon(np.array([[0, 0], [40, 0], [40, 40], [0, 40]], float)),
             Polygon(np.column_stack([30 * np.cos(u), 20 * np.sin(u)]))]
    db = FusedObjectDatabase(profiles, polys, verifiers=("fft",), reliefs=reliefs,
                             scaling="median", mean="arithmetic")
    parts = db.method_distances(profiles[2], polys[2], reliefs[2])
    assert len(parts) == 3
    np.testing.assert_allclose(parts[0], ProfileDatabase(profiles).distances(profiles[2]))
    np.testing.assert_allclose(parts[1], ReliefDatabase(reliefs).distances(reliefs[2]))
    np.testing.assert_allclose(db.distances(profiles[2], polys[2], reliefs[2]), fuse(parts))
    assert db.query(profiles[2], polys[2], k=1, relief=reliefs[2])[0][0] == 2
    with pytest.raises(UserError, match="relief exactly"):
        db.distances(profiles[2], polys[2])
    with pytest.raises(UserError, match="weights need 3"):
        FusedObjectDatabase(profiles, polys, verifiers=("fft",), reliefs=reliefs, weights=[1, 1])
    with pytest.raises(UserError, match="reliefs must hold one per object"):
        FusedObjectDatabase(profiles, polys, verifiers=("fft",), reliefs=reliefs[:2])
    plain = FusedObjectDatabase(profiles, polys, verifiers=("fft",))
    with pytest.raises(UserError, match="no reliefs"):
        plain.distances(profiles[2], polys[2], reliefs[2])
