"""Relations files (Kümmerle et al. 2009): rotation convention, errors, round trips, real file."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from data.errors import DataError, UserError
from data.relations import (
    matrix_to_rpy,
    read_relations,
    relations_arrays,
    rpy_to_matrix,
    write_relations,
)
from data.types import Relation
from tests.helpers import shared_file

SNIPPET = """\
# t1 t2 x y z roll pitch yaw
976052905.167303 976052911.885496 -0.056990 -0.128430 0.000000 0.000000 0.000000 -1.682210

976052896.784509 976052905.167303 1 2 3 0.1 -0.2 0.3
"""


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "r.relations"
    path.write_text(text)
    return path


def test_rotation_convention_by_hand() -> None:
    q = math.pi / 2
    # Roll alone turns y into z; pitch alone turns x into -z; yaw alone turns x into y.
    np.testing.assert_allclose(rpy_to_matrix(q, 0, 0)[0] @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(rpy_to_matrix(0, q, 0)[0] @ [1, 0, 0], [0, 0, -1], atol=1e-15)
    np.testing.assert_allclose(rpy_to_matrix(0, 0, q)[0] @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    # Order: R = Rz(yaw) Ry(pitch) Rx(roll).  With roll = yaw = 90 degrees, y goes to z
    # (roll first, then yaw leaves z alone); the other order (Rx Rz) would give -x.
    np.testing.assert_allclose(rpy_to_matrix(q, 0, q)[0] @ [0, 1, 0], [0, 0, 1], atol=1e-15)


@settings(max_examples=60, deadline=None)
@given(
    roll=st.floats(-math.pi, math.pi),
    pitch=st.floats(-1.5, 1.5),
    yaw=st.floats(-math.pi, math.pi),
)
def test_rpy_matches_intrinsic_zyx_and_inverts(roll: float, pitch: float, yaw: float) -> None:
    m = rpy_to_matrix(roll, pitch, yaw)[0]
    expected = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
    np.testing.assert_allclose(m, expected, atol=1e-12)
    back = matrix_to_rpy(m)[0]
    np.testing.assert_allclose(rpy_to_matrix(*back)[0], m, atol=1e-12)
    assert -math.pi / 2 <= back[1] <= math.pi / 2


def test_gimbal_lock_gives_same_rotation() -> None:
    m = rpy_to_matrix(0.3, math.pi / 2, -0.4)[0]
    r, p, y = matrix_to_rpy(m)[0]
    assert r == 0.0
    np.testing.assert_allclose(rpy_to_matrix(r, p, y)[0], m, atol=1e-12)


def test_snippet_by_hand(tmp_path: Path) -> None:
    rels = read_relations(_write(tmp_path, SNIPPET))
    assert len(rels) == 2
    a = rels[0]
    assert (a.t1, a.t2) == (976052905.167303, 976052911.885496)
    c, s = math.cos(-1.68221), math.sin(-1.68221)
    np.testing.assert_allclose(
        a.delta,
        [[c, -s, 0, -0.05699], [s, c, 0, -0.12843], [0, 0, 1, 0], [0, 0, 0, 1]],
        atol=1e-15,
    )
    b = rels[1]
    np.testing.assert_array_equal(b.delta[:3, 3], [1, 2, 3])
    np.testing.assert_allclose(b.delta[:3, :3], rpy_to_matrix(0.1, -0.2, 0.3)[0], atol=0)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("", "empty file"),
        ("# nothing\n", "empty file"),
        ("1 2 0 0 0 0 0\n", "line 1: relation .* needs 8 values, found 7"),
        ("1 2 0 0 0 0 0 0\n1 2 0 0 0 0 0 nan\n", "line 2: non-finite"),
        ("1 2 0 0 0 0 0 0\n\n1 2 0 0 0 0 yaw 0\n", "line 3: 'yaw' is not a number"),
    ],
)
def test_bad_input(tmp_path: Path, text: str, match: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(DataError, match=match) as err:
        read_relations(path)
    assert str(path) in str(err.value)


def test_round_trip(tmp_path: Path) -> None:
    rels = read_relations(_write(tmp_path, SNIPPET))
    write_relations(tmp_path / "out.relations", rels)
    back = read_relations(tmp_path / "out.relations")
    a, b = relations_arrays(rels), relations_arrays(back)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    np.testing.assert_array_equal(a[2][:, :3, 3], b[2][:, :3, 3])
    np.testing.assert_allclose(a[2], b[2], rtol=0, atol=1e-15)
    first = (tmp_path / "out.relations").read_text().splitlines()[0].split()
    assert first[:4] == ["976052905.167303", "976052911.885496", "-0.05699", "-0.12843"]


def test_writer_refuses_bad_relations(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="no relations"):
        write_relations(tmp_path / "x", [])
    with pytest.raises(UserError, match="NaN"):
        write_relations(tmp_path / "x", [Relation(0.0, 1.0, np.full((4, 4), np.nan))])
    with pytest.raises(UserError, match="4x4"):
        write_relations(tmp_path / "x", [Relation(0.0, 1.0, np.zeros(3))])
    assert not (tmp_path / "x").exists()


def test_real_intel_relations(tmp_path: Path) -> None:
    path = shared_file("carmen/intel.relations")
    rels = read_relations(path)
    assert len(rels) == 2984
    t1, t2, delta = relations_arrays(rels)
    # First line: 976052905.167303 976052911.885496 -0.056990 -0.128430 0 0 0 -1.682210
    assert (t1[0], t2[0]) == (976052905.167303, 976052911.885496)
    np.testing.assert_allclose(matrix_to_rpy(delta[:1])[0], [0, 0, -1.68221], atol=1e-15)
    # Planar: only yaw and x, y are non-zero.
    np.testing.assert_array_equal(delta[:, 2, 3], 0.0)
    np.testing.assert_allclose(delta[:, 2, :3], np.broadcast_to([0, 0, 1], (2984, 3)), atol=0)
    assert np.all(np.isfinite(delta))
    write_relations(tmp_path / "intel.relations", rels)
    back = relations_arrays(read_relations(tmp_path / "intel.relations"))
    np.testing.assert_array_equal(back[0], t1)
    np.testing.assert_array_equal(back[1], t2)
    np.testing.assert_allclose(back[2], delta, rtol=0, atol=1e-15)
