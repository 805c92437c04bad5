"""The canonical profile: virtual stripes along the footprint's long axis
(`loopclosure.stripes.canonical`)."""

from __future__ import annotations

import numpy as np
import pytest

from data.errors import DataError, UserError
from loopclosure.stripes import (
    CanonicalConfig,
    CanonicalDatabase,
    FusedObjectDatabase,
    describe_canonical,
    describe_profiles,
)
from loopclosure.stripes.canonical import footprint_frame

#: Cell spacings (row_m, column_m) of the simulated scanner's height maps (laser step
#: along the sweep, one image column across) and the same swept the other way.
SWEEP = (0.0008, 0.00042)
ACROSS = (0.00042, 0.0008)


def height_map(shape, yaw: float, cell: tuple[float, float], half: float = 0.09) -> np.ndarray:
    """Heights [m] of `shape(x, y)` (object frame, NaN outside) turned by `yaw` [rad] on a
    grid of `cell` spacing covering +-`half` metres."""
    dy, dx = cell
    y, x = np.meshgrid(np.arange(-half, half, dy), np.arange(-half, half, dx), indexing="ij")
    c, s = np.cos(yaw), np.sin(yaw)
    return shape(c * x + s * y, -s * x + c * y)


def box(x, y):
    return np.where((np.abs(x) < 0.06) & (np.abs(y) < 0.02), 0.03, np.nan)


def lying_cylinder(x, y):
    inside = (np.abs(x) < 0.06) & (np.abs(y) < 0.02)
    return np.where(inside, np.sqrt(np.maximum(0.02**2 - y**2, 0.0)), np.nan)


def banana(x, y):
    """A bent bar: centre line y = 8 x^2 (metres), 2 cm wide, rounded."""
    off = y - 8.0 * x**2
    inside = (np.abs(x) < 0.06) & (np.abs(off) < 0.01)
    return np.where(inside, np.sqrt(np.maximum(0.01**2 - off**2, 0.0)) + 0.005, np.nan)


def _gap(a, b) -> float:
    """Largest absolute difference of two profiles, the better of both directions."""
    return min(np.abs(a.profile - b.profile).max(), np.abs(a.profile - b.profile[::-1]).max())


def test_footprint_frame_of_a_turned_rectangle():
    """A 4 x 1 grid of points turned by 30 deg and shifted: u, v are its own coordinates
    (up to the axes' signs), by hand: u in -2..2 along the long side, v in -0.5..0.5."""
    a, b = np.meshgrid(np.linspace(-2.0, 2.0, 41), np.linspace(-0.5, 0.5, 11))
    a, b = a.ravel(), b.ravel()
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    u, v = footprint_frame(3.0 + c * a - s * b, -1.0 + s * a + c * b)
    assert np.allclose(np.abs(u), np.abs(a), atol=1e-12)
    assert np.allclose(np.abs(v), np.abs(b), atol=1e-12)
    assert np.allclose(u * v, a * b, atol=1e-12)  # a turn, not a mirror


@pytest.mark.parametrize("shape", [box, lying_cylinder, banana])
def test_independent_of_yaw_and_scan_direction(shape):
    ref = describe_canonical(height_map(shape, 0.0, SWEEP), SWEEP)
    for yaw, cell in ((0.4, SWEEP), (np.pi / 2, SWEEP), (1.1, ACROSS), (np.pi + 0.3, ACROSS),
                      (-2.0, SWEEP)):
        other = describe_canonical(height_map(shape, yaw, cell), cell)
        assert _gap(ref, other) < 0.12, (shape.__name__, yaw)
        assert other.length == pytest.approx(ref.length, rel=0.03)
        assert other.width == pytest.approx(ref.width, rel=0.05)


def test_box_and_cylinder_differ_and_are_found():
    b = describe_canonical(height_map(box, 0.0, SWEEP), SWEEP)
    c = describe_canonical(height_map(lying_cylinder, 0.0, SWEEP), SWEEP)
    bent = describe_canonical(height_map(banana, 0.0, SWEEP), SWEEP)
    # Same footprint (4 x 12 cm): equal widths; a box's top is flat (mean height = top
    # everywhere), a lying cylinder's falls off to its sides (mean pi/4 of its top).
    np.testing.assert_allclose(b.profile[:, 0], c.profile[:, 0], atol=0.05)
    np.testing.assert_allclose(b.profile[:, 1], 1.0, atol=0.02)
    np.testing.assert_allclose(c.profile[1:-1, 1], np.pi / 4, atol=0.05)
    # The bent bar's virtual stripes lie off its long axis; the box's do not.
    assert bent.profile[:, 2].max() > 0.3 and b.profile[:, 2].max() < 0.02
    db = CanonicalDatabase([b, c, bent])
    for shape, want in ((box, 0), (lying_cylinder, 1), (banana, 2)):
        q = describe_canonical(height_map(shape, 1.0, ACROSS), ACROSS)
        assert db.query(q, k=1)[0][0] == want
    pw = db.pairwise()
    np.testing.assert_allclose(np.diag(pw), 0.0, atol=1e-12)
    np.testing.assert_allclose(pw[1], db.distances(c))


def test_scale_free_and_errors():
    small = describe_canonical(height_map(box, 0.3, SWEEP), SWEEP)
    big = describe_canonical(height_map(lambda x, y: 2 * box(x / 2, y / 2), 0.3, SWEEP,
                                        half=0.18), SWEEP)
    assert _gap(small, big) < 0.08
    assert big.length == pytest.approx(2 * small.length, rel=0.03)
    assert small.profile.shape == (CanonicalConfig().samples, 3)
    with pytest.raises(DataError, match="no height"):
        describe_canonical(np.full((4, 4), np.nan), SWEEP)
    with pytest.raises(UserError, match="cell spacing"):
        describe_canonical(np.ones((4, 4)), (0.0, 1.0))
    with pytest.raises(UserError, match="samples"):
        CanonicalConfig(samples=1)
    with pytest.raises(UserError, match="one shape"):
        CanonicalDatabase([small, describe_canonical(np.ones((9, 9)), SWEEP,
                                                     CanonicalConfig(samples=8))])


def test_fused_database_takes_canonicals():
    from loopclosure.polygon import Polygon

    shapes = (box, lying_cylinder, banana)
    canon = [describe_canonical(height_map(s, 0.0, SWEEP), SWEEP) for s in shapes]
    t = np.linspace(0.2, np.pi - 0.2, 40)
    stripes = [[np.column_stack([20 * np.cos(t), 20 * np.sin(t)])] * 20,
               [np.column_stack([np.arange(40.0), np.zeros(40)])] * 20,
               [np.column_stack([30 * np.cos(t), 10 * np.sin(t)])] * 20]
    profiles = describe_profiles(stripes)
    polys = [Polygon(np.array([[0, 0], [120, 0], [120, 40], [0, 40]], float))] * 3
    db = FusedObjectDatabase(profiles, polys, verifiers=(), canonicals=canon)
    parts = db.method_distances(profiles[2], polys[2], canonical=canon[2])
    assert len(parts) == 2
    np.testing.assert_allclose(parts[1], CanonicalDatabase(canon).distances(canon[2]))
    assert db.query(profiles[2], polys[2], k=1, canonical=canon[2])[0][0] == 2
    with pytest.raises(UserError, match="canonical profile exactly"):
        db.distances(profiles[2], polys[2])
    with pytest.raises(UserError, match="weights need 2"):
        FusedObjectDatabase(profiles, polys, verifiers=(), canonicals=canon, weights=[1.0])
