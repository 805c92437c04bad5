"""g2o reader/writer: hand-written snippets, edges-only initialisation, errors, round trips."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from data import se2
from data.errors import DataError, DataWarning, UserError
from data.g2o import graph_info, is_g2o, read_g2o, write_g2o
from data.types import GraphEdge, PoseGraphData
from tests.helpers import shared_file

SE2_SNIPPET = """\
# a small SE2 graph
VERTEX_SE2 0 0 0 0
VERTEX_SE2 1 1.5 0 0.5
VERTEX_SE2 2 1.5 2.0 -3.0

FIX 0
EDGE_SE2 0 1 1.5 0 0.5 10 1 2 20 3 30
EDGE_SE2 1 2 0.1 2 0.2 11 0 0 12 0 13
EDGE_SE2 2 0 -1 -1 3.0 5 0 0 5 0 1
"""

# Information upper triangle, row-major, of a diagonally dominant 6x6 matrix:
# diagonal 10..15, off-diagonals 0.1..1.5 in row-major order.
SE3_INFO = "10 0.1 0.2 0.3 0.4 0.5 11 0.6 0.7 0.8 0.9 12 1.0 1.1 1.2 13 1.3 1.4 14 1.5 15"
H = math.sqrt(0.5)
SE3_SNIPPET = f"""\
VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1
VERTEX_SE3:QUAT 1 1 2 3 0 0 {H!r} {H!r}
EDGE_SE3:QUAT 0 1 1 2 3 0 0 {H!r} {H!r} {SE3_INFO}
"""


def _write(tmp_path: Path, text: str, name: str = "g.g2o") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _no_warnings_read(path: Path) -> PoseGraphData:
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataWarning)
        return read_g2o(path)


# --------------------------------------------------------------------------- SE2 / SE3 snippets


def test_se2_snippet_values(tmp_path: Path) -> None:
    g = _no_warnings_read(_write(tmp_path, SE2_SNIPPET))
    assert g.dim == 2
    assert list(g.vertices) == [0, 1, 2]
    np.testing.assert_array_equal(g.vertices[2], [1.5, 2.0, -3.0])
    assert g.fixed == {0}
    assert [(e.i, e.j) for e in g.edges] == [(0, 1), (1, 2), (2, 0)]
    np.testing.assert_array_equal(g.edges[0].measurement, [1.5, 0.0, 0.5])
    # I11 I12 I13 I22 I23 I33 = 10 1 2 20 3 30
    np.testing.assert_array_equal(
        g.edges[0].information, [[10, 1, 2], [1, 20, 3], [2, 3, 30]]
    )
    for e in g.edges:
        np.testing.assert_array_equal(e.information, e.information.T)


def test_se3_snippet_values(tmp_path: Path) -> None:
    g = _no_warnings_read(_write(tmp_path, SE3_SNIPPET))
    assert g.dim == 3
    np.testing.assert_array_equal(g.vertices[0], np.eye(4))
    # 90 degrees about z: x -> y, y -> -x; translation (1, 2, 3).
    expected = np.array([[0, -1, 0, 1], [1, 0, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]], float)
    np.testing.assert_allclose(g.vertices[1], expected, atol=1e-15)
    np.testing.assert_allclose(g.edges[0].measurement, expected, atol=1e-15)
    info = g.edges[0].information
    np.testing.assert_array_equal(np.diag(info), [10, 11, 12, 13, 14, 15])
    assert info[0, 1] == info[1, 0] == 0.1
    assert info[0, 5] == info[5, 0] == 0.5
    assert info[1, 2] == info[2, 1] == 0.6
    assert info[2, 3] == info[3, 2] == 1.0
    assert info[3, 5] == info[5, 3] == 1.4
    assert info[4, 5] == info[5, 4] == 1.5


def test_se3_quaternion_normalised_with_one_warning(tmp_path: Path) -> None:
    text = "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 2\nVERTEX_SE3:QUAT 1 0 0 0 0 0 3 3\n"
    with pytest.warns(DataWarning, match="2 VERTEX_SE3:QUAT quaternions are not unit") as rec:
        g = read_g2o(_write(tmp_path, text))
    assert len(rec) == 1
    np.testing.assert_array_equal(g.vertices[0], np.eye(4))
    np.testing.assert_allclose(g.vertices[1][:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]],
                               atol=1e-15)


def test_fix_with_several_ids(tmp_path: Path) -> None:
    text = SE2_SNIPPET.replace("FIX 0", "FIX 0 2")
    assert _no_warnings_read(_write(tmp_path, text)).fixed == {0, 2}


def test_graph_info_counts(tmp_path: Path) -> None:
    info = graph_info(read_g2o(_write(tmp_path, SE2_SNIPPET)))
    assert info == {"dim": 2, "vertices": 3, "edges": 3, "odometry_edges": 2, "loop_edges": 1,
                    "fixed": 1}


def test_unknown_tags_one_warning_with_counts(tmp_path: Path) -> None:
    text = SE2_SNIPPET + "VERTEX_XY 7 1 2\nVERTEX_XY 8 1 2\nEDGE_SE2_XY 0 7 1 1 1 0 1\n"
    with pytest.warns(DataWarning) as rec:
        g = read_g2o(_write(tmp_path, text))
    assert len(rec) == 1
    msg = str(rec[0].message)
    assert "3 lines" in msg and "VERTEX_XY x2" in msg and "EDGE_SE2_XY x1" in msg
    assert len(g.vertices) == 3 and len(g.edges) == 3


def test_is_g2o_sniff(tmp_path: Path) -> None:
    assert is_g2o(_write(tmp_path, SE2_SNIPPET))
    assert not is_g2o(_write(tmp_path, "FLASER 180 1 2 3\n", "log.clf"))
    assert not is_g2o(tmp_path / "missing.g2o")


# --------------------------------------------------------------------------- edges only


EDGES_ONLY = """\
EDGE_SE2 0 2 5 5 0 1 0 0 1 0 1
EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1
EDGE_SE2 1 2 1 0 1.5707963267948966 1 0 0 1 0 1
EDGE_SE2 2 3 1 0 0 1 0 0 1 0 1
EDGE_SE2 0 4 0 -2 0 1 0 0 1 0 1
EDGE_SE2 5 3 1 0 0 1 0 0 1 0 1
"""


def test_edges_only_initialisation_by_hand(tmp_path: Path) -> None:
    g = _no_warnings_read(_write(tmp_path, EDGES_ONLY))
    assert sorted(g.vertices) == [0, 1, 2, 3, 4, 5]
    expected = {
        0: (0, 0, 0),
        1: (1, 0, 0),  # chain 0 -> 1
        2: (2, 0, math.pi / 2),  # chain 1 -> 2, not the earlier loop edge 0 -> 2
        3: (2, 1, math.pi / 2),  # chain 2 -> 3: one metre along the rotated x axis
        4: (0, -2, 0),  # loop edge from vertex 0
        5: (2, 0, math.pi / 2),  # edge 5 -> 3 used backwards: p3 ⊕ inverse((1, 0, 0))
    }
    for v, pose in expected.items():
        np.testing.assert_allclose(g.vertices[v], pose, atol=1e-12, err_msg=f"vertex {v}")


def test_edges_only_se3_chain(tmp_path: Path) -> None:
    text = (
        f"EDGE_SE3:QUAT 0 1 1 0 0 0 0 {H!r} {H!r} {SE3_INFO}\n"
        f"EDGE_SE3:QUAT 1 2 1 0 0 0 0 0 1 {SE3_INFO}\n"
    )
    g = _no_warnings_read(_write(tmp_path, text))
    np.testing.assert_array_equal(g.vertices[0], np.eye(4))
    # Vertex 1 at (1, 0, 0) facing +y; vertex 2 one metre further along +y.
    np.testing.assert_allclose(g.vertices[1][:3, 3], [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(g.vertices[2][:3, 3], [1, 1, 0], atol=1e-15)
    np.testing.assert_allclose(g.vertices[2], g.edges[0].measurement @ g.edges[1].measurement)


def test_edges_only_disconnected_parts_warn(tmp_path: Path) -> None:
    text = "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 5 6 2 0 0 1 0 0 1 0 1\n"
    with pytest.warns(DataWarning, match="2 disconnected parts") as rec:
        g = read_g2o(_write(tmp_path, text))
    assert len(rec) == 1
    np.testing.assert_array_equal(g.vertices[5], [0, 0, 0])
    np.testing.assert_array_equal(g.vertices[6], [2, 0, 0])


# --------------------------------------------------------------------------- bad input

V = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n"
E = "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n"


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("", "empty file"),
        ("# only a comment\n\n", "empty file"),
        ("VERTEX_XY 0 1 2\n", "no pose-graph lines.*VERTEX_XY x1"),
        (V + "EDGE_SE2 0 1 1 0 0 1 0 0 1 0\n", "line 3: EDGE_SE2 needs 11 values, found 10"),
        ("VERTEX_SE2 0 0 0\n", "line 1: VERTEX_SE2 needs 4 values"),
        (V + "EDGE_SE2 0 1 1 0 zero 1 0 0 1 0 1\n", "line 3: 'zero' is not a number"),
        (V + "EDGE_SE2 0 1 1 0 nan 1 0 0 1 0 1\n", "line 3: non-finite"),
        ("VERTEX_SE2 0 inf 0 0\n", "line 1: non-finite"),
        ("VERTEX_SE2 0.5 0 0 0\n", "line 1: vertex id '0.5' is not an integer"),
        (V + "VERTEX_SE2 1 2 2 2\n", "line 3: duplicate vertex id 1"),
        (V + "EDGE_SE2 1 1 1 0 0 1 0 0 1 0 1\n", "line 3: edge from vertex 1 to itself"),
        (V + "EDGE_SE2 0 7 1 0 0 1 0 0 1 0 1\n", "line 3: edge names vertex 7"),
        (V + E + "FIX 9\n", "line 4: FIX names vertex 9"),
        (V + E + "FIX\n", "line 4: FIX needs at least one vertex id"),
        (V + "EDGE_SE2 0 1 1 0 0 1 5 0 1 0 1\n", "line 3: information matrix is not positive"),
        (V + "VERTEX_SE3:QUAT 5 0 0 0 0 0 0 1\n", r"mixes SE2 \(line 1\) and SE3 \(line 3\)"),
        ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 0\n", "line 1: zero quaternion"),
    ],
)
def test_bad_input_is_data_error(tmp_path: Path, text: str, match: str) -> None:
    path = _write(tmp_path, text)
    with pytest.raises(DataError, match=match) as err:
        read_g2o(path)
    assert str(path) in str(err.value)


def test_missing_file_and_directory(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="no such file"):
        read_g2o(tmp_path / "nope.g2o")
    with pytest.raises(DataError, match="directory"):
        read_g2o(tmp_path)


def test_binary_garbage_is_data_error(tmp_path: Path) -> None:
    path = tmp_path / "garbage.g2o"
    path.write_bytes(bytes(range(256)) * 20)
    with pytest.raises(DataError):
        read_g2o(path)


# --------------------------------------------------------------------------- round trips


def _assert_same(a: PoseGraphData, b: PoseGraphData, atol: float = 0.0) -> None:
    assert a.dim == b.dim and a.fixed == b.fixed
    assert list(a.vertices) == list(b.vertices)
    for k in a.vertices:
        np.testing.assert_allclose(a.vertices[k], b.vertices[k], rtol=0, atol=atol)
    assert [(e.i, e.j) for e in a.edges] == [(e.i, e.j) for e in b.edges]
    for ea, eb in zip(a.edges, b.edges, strict=True):
        np.testing.assert_allclose(ea.measurement, eb.measurement, rtol=0, atol=atol)
        np.testing.assert_array_equal(ea.information, eb.information)


def test_round_trip_se2_identical(tmp_path: Path) -> None:
    g = read_g2o(_write(tmp_path, SE2_SNIPPET))
    write_g2o(tmp_path / "out.g2o", g)
    _assert_same(g, read_g2o(tmp_path / "out.g2o"))
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []


def test_round_trip_se3(tmp_path: Path) -> None:
    g = read_g2o(_write(tmp_path, SE3_SNIPPET.replace("FIX", "") + "FIX 1\n"))
    write_g2o(tmp_path / "out.g2o.gz", g)  # compressed by suffix, read back transparently
    _assert_same(g, read_g2o(tmp_path / "out.g2o.gz"), atol=1e-15)


finite = st.floats(-1e6, 1e6, allow_nan=False)


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    poses=st.lists(st.tuples(finite, finite, st.floats(-10, 10)), min_size=2, max_size=8),
    info_scale=st.floats(1e-6, 1e6),
)
def test_round_trip_random_se2_exact(tmp_path: Path, poses: list, info_scale: float) -> None:
    p = np.array(poses, dtype=float)
    info = info_scale * np.array([[2.0, 0.3, 0.1], [0.3, 1.0, 0.2], [0.1, 0.2, 3.0]])
    edges = [GraphEdge(k, k + 1, se2.between(p[k], p[k + 1]), info) for k in range(len(p) - 1)]
    g = PoseGraphData(2, dict(enumerate(p)), edges, {0})
    write_g2o(tmp_path / "r.g2o", g)
    _assert_same(g, read_g2o(tmp_path / "r.g2o"))


def test_writer_refuses_bad_graph_and_keeps_old_file(tmp_path: Path) -> None:
    out = _write(tmp_path, SE2_SNIPPET, "keep.g2o")
    g = read_g2o(out)
    g.vertices[1] = np.array([np.nan, 0.0, 0.0])
    with pytest.raises(UserError, match="vertex 1"):
        write_g2o(out, g)
    assert out.read_text() == SE2_SNIPPET
    with pytest.raises(UserError, match="empty graph"):
        write_g2o(tmp_path / "e.g2o", PoseGraphData(2))
    with pytest.raises(DataError, match="does not exist"):
        write_g2o(tmp_path / "no" / "dir.g2o", PoseGraphData(2, {0: np.zeros(3)}))


# --------------------------------------------------------------------------- real files


REAL = [
    ("input_INTEL_g2o.g2o", 2, 1228, 1483),
    ("input_M3500_g2o.g2o", 2, 3500, 5453),
    ("input_M3500a_g2o.g2o", 2, 3500, 5453),
    ("input_MITb_g2o.g2o", 2, 808, 827),
    ("parking-garage.g2o", 3, 1661, 6275),
]


@pytest.mark.parametrize(("name", "dim", "n_vertices", "n_edges"), REAL)
def test_real_graph_counts(name: str, dim: int, n_vertices: int, n_edges: int) -> None:
    g = _no_warnings_read(shared_file(f"g2o/{name}"))
    info = graph_info(g)
    assert (info["dim"], info["vertices"], info["edges"]) == (dim, n_vertices, n_edges)
    assert info["odometry_edges"] == n_vertices - 1
    assert info["odometry_edges"] + info["loop_edges"] == n_edges
    assert sorted(g.vertices) == list(range(n_vertices))
    infos = np.stack([e.information for e in g.edges])
    np.testing.assert_array_equal(infos, np.swapaxes(infos, 1, 2))
    if dim == 3:
        rot = np.stack([v[:3, :3] for v in g.vertices.values()])
        eye = np.broadcast_to(np.eye(3), rot.shape)
        np.testing.assert_allclose(rot @ np.swapaxes(rot, 1, 2), eye, atol=1e-12)


def test_real_intel_first_edge_and_round_trip(tmp_path: Path) -> None:
    g = read_g2o(shared_file("g2o/input_INTEL_g2o.g2o"))
    e = g.edges[0]
    # EDGE_SE2 0 1 0.000000 0.000000 -0.000642 11.111271 -0.249667 0.000000 399.999840 0 2496.793089
    assert (e.i, e.j) == (0, 1)
    np.testing.assert_array_equal(e.measurement, [0.0, 0.0, -0.000642])
    np.testing.assert_array_equal(
        e.information,
        [[11.111271, -0.249667, 0.0], [-0.249667, 399.99984, 0.0], [0.0, 0.0, 2496.793089]],
    )
    write_g2o(tmp_path / "intel.g2o", g)
    _assert_same(g, read_g2o(tmp_path / "intel.g2o"))


@pytest.mark.parametrize(("name", "tol"), [("input_INTEL_g2o.g2o", 1e-3),
                                           ("parking-garage.g2o", 1e-2)])
def test_real_edges_only_dead_reckoning_matches_file(tmp_path: Path, name: str, tol: float) -> None:
    """The files' own initial vertices are their odometry chains: stripping the
    VERTEX lines and dead-reckoning the edges gives them back (to print precision)."""
    src = shared_file(f"g2o/{name}")
    lines = src.read_text().splitlines()
    path = _write(tmp_path, "\n".join(ln for ln in lines if not ln.startswith("VERTEX")) + "\n")
    full, stripped = read_g2o(src), _no_warnings_read(path)
    assert sorted(stripped.vertices) == sorted(full.vertices)
    for k, pose in full.vertices.items():
        other = stripped.vertices[k]
        if full.dim == 2:
            diff = np.r_[pose[:2] - other[:2], se2.wrap_angle(pose[2] - other[2])]
        else:
            diff = (pose - other).ravel()
        assert np.abs(diff).max() < tol, f"vertex {k}"
