"""The stripe profile (ordered, scale-free [l, d, e]) and the meshes' unit / up-axis handling."""

from __future__ import annotations

import gzip
import warnings

import numpy as np
import pytest

from data.errors import DataError, UserError
from data.stripe_scanner.meshes import (
    MAX_METRES_EXTENT,
    load_mesh,
    load_mesh_rows,
    to_metres,
    to_z_up,
)
from loopclosure.polygon import Polygon
from loopclosure.stripes import (
    FusedObjectDatabase,
    ProfileConfig,
    ProfileDatabase,
    StripeProfile,
    describe_profile,
    describe_profiles,
    resample_profile,
    stripe_shape,
)


def _arc(n: int, radius: float) -> np.ndarray:
    t = np.linspace(0.2, np.pi - 0.2, n)
    return np.column_stack([radius * np.cos(t), radius * np.sin(t)])


def _dome(n_stripes: int, radius: float) -> list[np.ndarray]:
    """Camera-like stripes of a half sphere: one point per unit of width, arcs whose
    width follows a circle along the sweep."""
    x = np.linspace(-0.95, 0.95, n_stripes)
    return [_arc(max(int(2 * radius * np.sqrt(1 - xi**2)), 4), radius * np.sqrt(1 - xi**2))
            for xi in x]


def _slab(n_stripes: int, width: int) -> list[np.ndarray]:
    """A flat box top: straight stripes of constant width."""
    return [np.column_stack([np.arange(float(width)), np.full(width, 5.0)])] * n_stripes


# ------------------------------------------------------------------------ per-stripe shape


def test_stripe_shape_by_hand():
    line = np.column_stack([np.arange(4.0), np.zeros(4)])  # flat, unit spacing
    # Pairs i > m: distances 1, 1, 1, 2, 2, 3 -> d = (3 log 2 + 2 log 3 + log 4) / 6.
    d, e = stripe_shape([line, line[:, ::-1], line * [1.0, 0.0] + line[:, ::-1] * [0.0, 1.0],
                         np.column_stack([np.arange(4.0), np.arange(4.0)])])
    assert d[0] == pytest.approx((3 * np.log(2) + 2 * np.log(3) + np.log(4)) / 6)
    assert e[0] == 0.0  # flat stripe: elevation 0 (Eq. 2's o would sit at the 0 / pi boundary)
    assert e[1] == pytest.approx(np.pi / 2)  # vertical stripe
    assert e[3] == pytest.approx(np.pi / 4)  # 45 degree line
    # Fewer than min_points points: d = e = 0.
    d2, e2 = stripe_shape([line[:3]])
    assert d2[0] == 0.0 and e2[0] == 0.0


def test_elevation_is_mirror_and_order_free():
    rng = np.random.default_rng(0)
    s = np.cumsum(rng.normal(size=(20, 2)), axis=0)
    d, e = stripe_shape([s, s[::-1], s * [-1.0, 1.0], s + 7.0])
    np.testing.assert_allclose(d, d[0], rtol=1e-6)
    np.testing.assert_allclose(e, e[0], rtol=1e-6)


def test_resample_profile_by_hand():
    f = np.array([[0.0, 10.0], [1.0, 20.0], [2.0, 0.0]])
    # Stripes at t = 0, .5, 1; bins of half-width 1/8 around 0, .25, .5, .75, 1, the
    # end bins clipped to [0, 1/8] and [7/8, 1].  Column 0 is the line 2t: the mean over
    # a bin is its value at the bin's middle, 2 * (1/16) at the first bin.
    got = resample_profile(f, 5)
    np.testing.assert_allclose(got[:, 0], [0.125, 0.5, 1.0, 1.5, 1.875])
    # Column 1 rises 10 -> 20 then falls to 0: the middle bin averages 10 + 20 * 7/16
    # over its first half and 20 - 40 / 16 over its second.
    np.testing.assert_allclose(got[:, 1], [11.25, 15.0, (18.75 + 17.5) / 2, 10.0, 2.5])
    # Many stripes of a constant: the constant; of a line: the bin means of the line.
    np.testing.assert_allclose(resample_profile(np.full((200, 1), 3.0), 7), 3.0)
    line = resample_profile(np.linspace(0, 1, 101)[:, None], 3)[:, 0]
    np.testing.assert_allclose(line, [0.125, 0.5, 0.875])
    np.testing.assert_allclose(resample_profile(f[:1], 3), np.repeat(f[:1], 3, axis=0))
    with pytest.raises(UserError, match="non-empty"):
        resample_profile(np.zeros((0, 3)), 4)


# ----------------------------------------------------------------------------- the profile


def test_profile_rows_are_l_d_e_over_fractions_of_the_length():
    stripes = [np.column_stack([np.arange(float(w)), np.zeros(w)]) for w in (10, 20, 30)]
    p = describe_profile(stripes, ProfileConfig(samples=3))
    assert p.profile.shape == (3, 3) and p.stripes == 3
    # l = H / mean H (Eq. 3) = 0.5, 1, 1.5 at t = 0, .5, 1, i.e. the line 0.5 + t; its
    # means over the bins [0, 1/4], [1/4, 3/4], [3/4, 1].
    np.testing.assert_allclose(p.profile[:, 0], [0.625, 1.0, 1.375])
    np.testing.assert_allclose(p.profile[:, 2], 0.0)  # flat stripes
    # d is Eq. 1 on each stripe in units of its own width / 100: straight stripes of
    # any width have about the same d (their width is l's business).
    np.testing.assert_allclose(p.profile[:, 1], p.profile[1, 1], rtol=0.03)
    # By hand: 4 points at unit spacing -> 25 units apart; pair distances 25 (x3),
    # 50 (x2), 75.
    one = describe_profile([np.column_stack([np.arange(4.0), np.zeros(4)])],
                           ProfileConfig(samples=2))
    want = (3 * np.log(26) + 2 * np.log(51) + np.log(76)) / 6
    np.testing.assert_allclose(one.profile, [[1.0, want, 0.0]] * 2, rtol=1e-6)
    with pytest.raises(DataError, match="empty stripe set"):
        describe_profile([np.zeros((0, 2))])
    with pytest.raises(UserError, match="samples"):
        ProfileConfig(samples=1)


def test_profile_is_scale_free_and_step_free():
    # Three times the size (three times the points per stripe, as a camera gives) and
    # three times the stripes (a finer laser step): nearly the same profile.
    small, big, dense = _dome(30, 40.0), _dome(30, 120.0), _dome(90, 40.0)
    a, b, c = (x.profile for x in describe_profiles([small, big, dense]))
    np.testing.assert_allclose(a[:, 0], b[:, 0], atol=0.06)
    np.testing.assert_allclose(a[:, 1:], b[:, 1:], atol=0.05)
    np.testing.assert_allclose(a, c, atol=0.08)


def test_profile_is_translation_free_and_turn_round_free():
    dome = _dome(40, 50.0)[:30]  # not symmetric along the sweep
    moved = [s + np.array([13.0, -4.0]) for s in dome]
    turned = [s[::-1] * [-1.0, 1.0] for s in dome[::-1]]  # swept backwards, mirrored
    slab = _slab(30, 60)
    profiles = describe_profiles([dome, moved, turned, slab])
    np.testing.assert_allclose(profiles[1].profile, profiles[0].profile, atol=1e-6)
    db = ProfileDatabase(profiles)
    d = db.distances(profiles[0])
    # Equal up to the float32 pair terms of Eq. 1.
    assert d[1] == pytest.approx(0.0, abs=1e-6) and d[2] == pytest.approx(0.0, abs=1e-6)
    assert d[3] > 0.5


def test_database_distances_by_hand():
    def prof(v):
        return StripeProfile(np.full((2, 3), float(v)), 2)

    db = ProfileDatabase([prof(0), prof(1), prof(3)])
    # Per feature |difference| 0, 1, 3; median over the database 1 -> 0, 1, 3.
    np.testing.assert_allclose(db.distances(prof(0)), [0.0, 1.0, 3.0])
    # From 3: differences 3, 2, 0, median 2 -> 1.5, 1, 0.
    np.testing.assert_allclose(db.distances(prof(3)), [1.5, 1.0, 0.0])
    pw = db.pairwise()
    for i, p in enumerate(db.profiles):
        np.testing.assert_allclose(pw[i], db.distances(p))
    order, dist = db.query(prof(1), k=2)
    assert order.tolist()[0] == 1 and dist[0] == 0.0
    with pytest.raises(UserError, match="shape"):
        db.distances(StripeProfile(np.zeros((3, 3)), 3))
    with pytest.raises(UserError, match="one shape"):
        ProfileDatabase([prof(0), StripeProfile(np.zeros((3, 3)), 3)])


def test_database_is_vectorised_and_matches_distances():
    rng = np.random.default_rng(1)
    objs = [[np.cumsum(rng.normal(size=(int(rng.integers(5, 40)), 2)), axis=0)
             for _ in range(int(rng.integers(3, 50)))] for _ in range(12)]
    profiles = describe_profiles(objs)
    for p, o in zip(profiles, objs, strict=True):
        np.testing.assert_allclose(p.profile, describe_profile(o).profile, atol=1e-9)
    db = ProfileDatabase(profiles)
    pw = db.pairwise()
    assert np.all(np.isfinite(pw)) and np.all(pw >= 0)
    np.testing.assert_allclose(np.diag(pw), 0.0, atol=1e-12)
    np.testing.assert_allclose(pw[5], db.distances(profiles[5]))


def test_fused_database_with_profiles():
    shapes = [_dome(30, 40.0), _slab(30, 50), _dome(60, 90.0)[10:]]
    square = Polygon(np.array([[0, 0], [40, 0], [40, 40], [0, 40]], float))
    t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    circle = Polygon(np.column_stack([20 * np.cos(t), 20 * np.sin(t)]))
    ellipse = Polygon(np.column_stack([40 * np.cos(t), 15 * np.sin(t)]))
    profiles = describe_profiles(shapes)
    db = FusedObjectDatabase(profiles, [circle, square, ellipse])
    order, dist = db.query(profiles[1], square, k=3)
    assert order[0] == 1 and dist[0] == pytest.approx(0.0, abs=1e-9)
    with pytest.raises(UserError, match="stripe_weights"):
        FusedObjectDatabase(profiles, [circle, square, ellipse], stripe_weights=(1, 1, 1))


# ------------------------------------------------------------------- mesh units and up axis


def test_units_from_the_bounding_box():
    v = np.array([[0.0, 0.0, 0.0], [120.0, 40.0, 30.0]])  # a 12 cm box in millimetres
    got, note = to_metres(v)
    np.testing.assert_allclose(got, v / 1000.0)
    assert "millimetres" in note
    same, none = to_metres(v / 1000.0)
    np.testing.assert_allclose(same, v / 1000.0)
    assert none is None
    edge = np.array([[0.0, 0, 0], [MAX_METRES_EXTENT, 0.1, 0.1]])  # 2 m: still metres
    assert to_metres(edge)[1] is None
    np.testing.assert_allclose(to_metres(v / 10.0, "cm")[0], v / 1000.0)
    with pytest.raises(UserError, match="units"):
        to_metres(v, "furlong")


def test_up_axis_rotation_is_proper():
    v = np.array([[1.0, 2.0, 3.0]])
    np.testing.assert_allclose(to_z_up(v, "y")[0], [[1.0, -3.0, 2.0]])
    np.testing.assert_allclose(to_z_up(v, "x")[0], [[-3.0, 2.0, 1.0]])
    same, note = to_z_up(v, "z")
    assert note is None and np.array_equal(same, v)
    for up in ("x", "y"):
        basis = to_z_up(np.eye(3), up)[0]  # rows: images of the unit axes
        assert np.linalg.det(basis) == pytest.approx(1.0)
        axis = "xyz".index(up)
        np.testing.assert_allclose(basis[axis], [0.0, 0.0, 1.0])
    with pytest.raises(UserError, match="up axis"):
        to_z_up(v, "w")


def test_a_millimetre_y_up_file_loads_in_metres_z_up(tmp_path):
    import trimesh

    # A 40 x 20 x 30 mm box (x, y up, z), written in millimetres with y up.
    tm = trimesh.creation.box(extents=(40.0, 30.0, 20.0))
    data = tm.export(file_type="ply")
    (tmp_path / "box.ply.gz").write_bytes(gzip.compress(data))
    with pytest.warns(Warning, match="millimetres"):
        mesh = load_mesh(tmp_path / "box.ply.gz", up="y")
    np.testing.assert_allclose(mesh.extent, [0.04, 0.02, 0.03], atol=1e-9)
    assert len(mesh.notes) == 2
    # A folder: one warning for every conversion.
    (tmp_path / "b2.ply.gz").write_bytes(gzip.compress(data))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = load_mesh_rows(tmp_path, [("box.ply.gz", "box"), ("b2.ply.gz", "box")], "labels",
                             up="y")
    texts = [str(w.message) for w in caught]
    assert len(texts) == 1 and "2 meshes read as millimetres" in texts[0]
    assert all(np.allclose(m.extent, [0.04, 0.02, 0.03]) for m in out.meshes)
