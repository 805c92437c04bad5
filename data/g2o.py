"""g2o pose-graph files: read, write and summarise (SE2 and SE3).

Lines understood (whitespace separated; blank lines and ``#`` comments ignored;
plain, ``.gz`` or ``.bz2``):

- ``VERTEX_SE2 id x y theta``: pose (x [m], y [m], theta [rad]) in the world frame.
- ``EDGE_SE2 i j x y theta I11 I12 I13 I22 I23 I33``: pose of `j` in the frame of
  `i` and the upper triangle of its ``3x3`` information matrix, row-major, in the
  order (x, y, theta).
- ``VERTEX_SE3:QUAT id x y z qx qy qz qw``: pose as translation [m] and unit
  quaternion, scalar last (Hamilton, as `scipy.spatial.transform.Rotation`),
  stored as a ``4x4`` body-in-world matrix.
- ``EDGE_SE3:QUAT i j x y z qx qy qz qw`` + 21 numbers: the relative pose of `j` in
  the frame of `i` and the upper triangle (row-major) of its ``6x6`` information
  matrix in g2o's ordering (x, y, z, rx, ry, rz), where g2o's rotational error is
  the vector part of the error quaternion (about half the rotation vector for
  small errors).  A consumer with another tangent ordering (gtsam's Pose3 is
  rotation first) must permute the blocks.
- ``FIX id [id ...]``: vertices held fixed.

`read_g2o` returns full symmetric information matrices in `GraphEdge.information`,
quaternions normalised (a zero quaternion is an error; norms off by more than 1e-3
draw one warning).  Numbers are kept exactly as parsed (angles are not wrapped).

Rules for bad input, each a `DataError` naming the file and line: a known tag
with the wrong number of fields, a value that is not a number, NaN or inf, a
non-integer id, a duplicate vertex id, an edge from a vertex to itself, an edge or
``FIX`` naming a vertex that has no ``VERTEX`` line (when the file has vertices at
all), an information matrix that is not positive semi-definite (an eigenvalue
below ``-1e-9`` times its largest), SE2 and SE3 lines in one file, and a file
with no vertex or edge line (empty, or only unknown tags).  Unknown tags are
skipped with one warning listing each tag and its count.

Edges without vertices.  A file with edges but no ``VERTEX`` lines gets initial
poses by dead reckoning: the smallest id is placed at the identity; from each
placed vertex (first-in, first-out) the odometry chain (edges ``j == i + 1``, the
first such edge in file order) is followed forward as far as it goes, then every
edge touching that vertex (file order) places its other end, composing the
measurement forward, or its inverse when the edge points into the placed vertex.
A part of the graph not connected to the smallest id starts again from identity at
its own smallest id (one warning gives the number of such parts).

Writing (`write_g2o`) is atomic (temporary file then rename) and prints every
number with Python's shortest round-trip repr, so write -> read gives back the
same floats (SE3 rotations up to the ~1e-16 of the matrix <-> quaternion
conversion; quaternions are written with ``qw >= 0``).  Vertices keep their dict
order, then ``FIX`` lines, then edges in list order.
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data import se2
from data.atomic_write import write_text_atomic
from data.compression import open_text
from data.errors import DataError, UserError, warn
from data.text_table import PathArg, Row, data_rows, format_rows, parse_rows, read_lines
from data.trajectory_io import (
    checked_quaternions,
    pose_matrices,
    quaternion_to_rotation,
    rotation_to_quaternion,
)
from data.types import GraphEdge, PoseGraphData

Array = NDArray[np.float64]

PSD_TOL = 1e-9
"""An information matrix with an eigenvalue below ``-PSD_TOL * max |eigenvalue|`` is refused."""


@dataclass(frozen=True, slots=True)
class _Kind:
    """Layout of one pose-graph flavour."""

    dim: int
    vertex_tag: str
    edge_tag: str
    pose_size: int  # numbers of a pose on a line (3 for SE2, 7 for SE3:QUAT)
    info_size: int  # side of the information matrix

    @property
    def n_upper(self) -> int:
        return self.info_size * (self.info_size + 1) // 2


SE2 = _Kind(2, "VERTEX_SE2", "EDGE_SE2", 3, 3)
SE3 = _Kind(3, "VERTEX_SE3:QUAT", "EDGE_SE3:QUAT", 7, 6)
FIX_TAG = "FIX"
_KNOWN = {SE2.vertex_tag, SE2.edge_tag, SE3.vertex_tag, SE3.edge_tag, FIX_TAG}


# --------------------------------------------------------------------------- reading


def _int_tokens(path: PathArg, linenos: NDArray, tokens: list[str], what: str) -> NDArray:
    """``(N,)`` int64 ids of `tokens` (one per line), or `DataError` naming the bad line."""
    try:
        return np.array(tokens, dtype=str).astype(np.int64)
    except (ValueError, OverflowError):
        for n, tok in zip(linenos.tolist(), tokens, strict=True):
            try:
                int(tok)
            except ValueError:
                raise DataError(path, f"line {n}: {what} {tok!r} is not an integer") from None
        raise  # pragma: no cover


def _symmetric(upper: Array, size: int) -> Array:
    """``(M, size, size)`` symmetric matrices from their row-major upper triangles."""
    iu, ju = np.triu_indices(size)
    m = np.zeros((len(upper), size, size))
    m[:, iu, ju] = upper
    m[:, ju, iu] = upper
    return m


def _check_psd(path: PathArg, linenos: NDArray, info: Array) -> None:
    if len(info) == 0:
        return
    eig = np.linalg.eigvalsh(info)
    scale = np.maximum(np.abs(eig).max(axis=1), np.finfo(float).tiny)
    bad = np.flatnonzero(eig[:, 0] < -PSD_TOL * scale)
    if bad.size:
        k = int(bad[0])
        raise DataError(
            path,
            f"line {linenos[k]}: information matrix is not positive semi-definite "
            f"(eigenvalue {eig[k, 0]:.6g}; {bad.size} such edges)",
        )


def _first_duplicate(ids: NDArray, linenos: NDArray) -> int | None:
    """Position of the first line whose id already appeared earlier, or None."""
    _, first = np.unique(ids, return_index=True)
    if len(first) == len(ids):
        return None
    seen_first = np.zeros(len(ids), dtype=bool)
    seen_first[first] = True
    return int(np.flatnonzero(~seen_first)[0])


def _poses(kind: _Kind, path: PathArg, linenos: NDArray, values: Array, what: str) -> Array:
    """``(N, 3)`` SE2 poses or ``(N, 4, 4)`` SE3 matrices from the pose columns."""
    if kind is SE2:
        return values.copy()
    q = checked_quaternions(path, linenos, values[:, 3:7], what)
    return pose_matrices(values[:, 0:3], quaternion_to_rotation(q))


def _compose(kind: _Kind, a: Array, b: Array) -> Array:
    return se2.compose(a, b) if kind is SE2 else a @ b


def _inverse(kind: _Kind, a: Array) -> Array:
    if kind is SE2:
        return se2.inverse(a)
    inv = np.eye(4)
    inv[:3, :3] = a[:3, :3].T
    inv[:3, 3] = -a[:3, :3].T @ a[:3, 3]
    return inv


def _dead_reckoning(kind: _Kind, ei: NDArray, ej: NDArray, meas: Array) -> dict[int, Array]:
    """Initial poses of an edges-only graph (rule in the module docstring)."""
    identity = np.zeros(3) if kind is SE2 else np.eye(4)
    odometry: dict[int, int] = {}
    adjacency: dict[int, list[tuple[int, bool]]] = {}
    for e, (i, j) in enumerate(zip(ei.tolist(), ej.tolist(), strict=True)):
        if j == i + 1:
            odometry.setdefault(i, e)
        adjacency.setdefault(i, []).append((e, True))
        adjacency.setdefault(j, []).append((e, False))
    poses: dict[int, Array] = {}
    parts = 0
    for root in sorted(adjacency):
        if root in poses:
            continue
        parts += 1
        poses[root] = identity.copy()
        queue = deque([root])
        while queue:
            v = queue.popleft()
            k = v
            while k in odometry and k + 1 not in poses:
                poses[k + 1] = _compose(kind, poses[k], meas[odometry[k]])
                queue.append(k + 1)
                k += 1
            for e, forward in adjacency[v]:
                u = int(ej[e] if forward else ei[e])
                if u not in poses:
                    step = meas[e] if forward else _inverse(kind, meas[e])
                    poses[u] = _compose(kind, poses[v], step)
                    queue.append(u)
    if parts > 1:
        warn(
            f"edges-only graph has {parts} disconnected parts: each part after the first "
            "starts from the identity at its smallest id"
        )
    return {v: poses[v] for v in sorted(poses)}


def _split_by_tag(rows: list[Row]) -> tuple[dict[str, list[Row]], Counter[str]]:
    known: dict[str, list[Row]] = {tag: [] for tag in _KNOWN}
    unknown: Counter[str] = Counter()
    for row in rows:
        tag = row[1][0]
        if tag in known:
            known[tag].append(row)
        else:
            unknown[tag] += 1
    return known, unknown


def _describe_tags(counts: Counter[str], limit: int = 10) -> str:
    items = [f"{tag} x{n}" for tag, n in counts.most_common(limit)]
    more = len(counts) - limit
    return ", ".join(items) + (f" and {more} more tags" if more > 0 else "")


def _kind_of(path: PathArg, by_tag: dict[str, list[Row]], unknown: Counter[str]) -> _Kind:
    first = {
        kind: min((r[0] for tag in (kind.vertex_tag, kind.edge_tag) for r in by_tag[tag]),
                  default=None)
        for kind in (SE2, SE3)
    }
    if first[SE2] is not None and first[SE3] is not None:
        raise DataError(
            path,
            f"mixes SE2 (line {first[SE2]}) and SE3 (line {first[SE3]}) vertices or edges; "
            "a pose graph must be one or the other",
        )
    if first[SE2] is None and first[SE3] is None:
        found = f" (found only: {_describe_tags(unknown)})" if unknown else ""
        raise DataError(
            path,
            "no pose-graph lines: expected VERTEX_SE2/EDGE_SE2 or "
            f"VERTEX_SE3:QUAT/EDGE_SE3:QUAT{found}",
        )
    return SE2 if first[SE2] is not None else SE3


def read_g2o(path: PathArg) -> PoseGraphData:
    """Pose graph of a g2o file (format, checks and edges-only rule in the module docstring).

    Returns:
        `PoseGraphData` with ``dim`` 2 (vertices ``(3,)`` x, y, theta) or 3
        (vertices ``4x4``), edges in file order with full symmetric information
        matrices, and the ``FIX`` ids.

    Raises:
        DataError: missing, unreadable, empty or malformed file (names the line).
    """
    rows = data_rows(read_lines(path))
    if not rows:
        raise DataError(path, "empty file: no g2o vertex or edge lines")
    by_tag, unknown = _split_by_tag(rows)
    kind = _kind_of(path, by_tag, unknown)
    if unknown:
        warn(f"{path}: skipped {sum(unknown.values())} lines with unknown tags: "
             f"{_describe_tags(unknown)}")

    # Vertices: id + pose numbers.
    vrows = [(n, t[1:]) for n, t in by_tag[kind.vertex_tag]]
    vlines, vvals = parse_rows(path, vrows, 1 + kind.pose_size, kind.vertex_tag)
    vids = _int_tokens(path, vlines, [t[0] for _, t in vrows], "vertex id")
    dup = _first_duplicate(vids, vlines)
    if dup is not None:
        raise DataError(path, f"line {vlines[dup]}: duplicate vertex id {vids[dup]}")
    vposes = _poses(kind, path, vlines, vvals[:, 1:], kind.vertex_tag)

    # Edges: i, j + measurement + upper triangle of the information.
    erows = [(n, t[1:]) for n, t in by_tag[kind.edge_tag]]
    elines, evals = parse_rows(path, erows, 2 + kind.pose_size + kind.n_upper, kind.edge_tag)
    ei = _int_tokens(path, elines, [t[0] for _, t in erows], "vertex id")
    ej = _int_tokens(path, elines, [t[1] for _, t in erows], "vertex id")
    loops = np.flatnonzero(ei == ej)
    if loops.size:
        raise DataError(path, f"line {elines[loops[0]]}: edge from vertex {ei[loops[0]]} to itself")
    meas = _poses(kind, path, elines, evals[:, 2 : 2 + kind.pose_size], kind.edge_tag)
    info = _symmetric(evals[:, 2 + kind.pose_size :], kind.info_size)
    _check_psd(path, elines, info)

    if len(vids):
        known = np.isin(ei, vids) & np.isin(ej, vids)
        missing = np.flatnonzero(~known)
        if missing.size:
            k = int(missing[0])
            vid = ei[k] if ei[k] not in vids else ej[k]
            raise DataError(
                path,
                f"line {elines[k]}: edge names vertex {vid}, which has no {kind.vertex_tag} line "
                f"({missing.size} such edges)",
            )
        vertices = dict(zip(vids.tolist(), list(vposes), strict=True))
    else:
        vertices = _dead_reckoning(kind, ei, ej, meas)

    fixed: set[int] = set()
    for n, tokens in by_tag[FIX_TAG]:
        if len(tokens) < 2:
            raise DataError(path, f"line {n}: FIX needs at least one vertex id")
        ids = _int_tokens(path, np.full(len(tokens) - 1, n), tokens[1:], "FIX id")
        for vid in ids.tolist():
            if vid not in vertices:
                raise DataError(path, f"line {n}: FIX names vertex {vid}, not in the graph")
            fixed.add(vid)

    edges = [
        GraphEdge(int(i), int(j), m, w)
        for i, j, m, w in zip(ei.tolist(), ej.tolist(), meas, info, strict=True)
    ]
    return PoseGraphData(dim=kind.dim, vertices=vertices, edges=edges, fixed=fixed)


def is_g2o(path: PathArg, max_lines: int = 50) -> bool:
    """Cheap sniff: the first data line of the file carries a known g2o tag."""
    try:
        with open_text(path) as f:
            for _, line in zip(range(max_lines), f, strict=False):
                tokens = line.split()
                if tokens and not tokens[0].startswith("#"):
                    return tokens[0] in _KNOWN or tokens[0].startswith(("VERTEX_", "EDGE_"))
    except (OSError, EOFError, ValueError, DataError):
        return False
    return False


# --------------------------------------------------------------------------- writing


def _pose_columns(kind: _Kind, poses: Array) -> Array:
    if kind is SE2:
        return poses.reshape(-1, 3)
    poses = poses.reshape(-1, 4, 4)
    return np.column_stack([poses[:, :3, 3], rotation_to_quaternion(poses[:, :3, :3])])


def _stack(arrays: list[Any], shape: tuple[int, ...], what: str, names: list[str]) -> Array:
    """``(N, *shape)`` stack of finite arrays, or `UserError` naming the first bad one."""
    if not arrays:
        return np.zeros((0, *shape))
    try:
        out = np.stack([np.asarray(a, dtype=float) for a in arrays])
    except ValueError:
        out = None
    if out is None or out.shape[1:] != shape:
        bad = next((k for k, a in enumerate(arrays) if np.shape(a) != shape), 0)
        got = np.shape(arrays[bad])
        raise UserError(f"graph: {names[bad]}: {what} must be numeric, shape {shape}, not {got}")
    finite = np.isfinite(out.reshape(len(out), -1)).all(axis=1)
    if not finite.all():
        bad = int(np.flatnonzero(~finite)[0])
        raise UserError(f"graph: {names[bad]}: {what} has NaN or inf; refusing to write it "
                        "(need finite numbers)")
    return out


def write_g2o(path: PathArg, graph: PoseGraphData) -> None:
    """Write `graph` as a g2o file, atomically, with round-trip precision.

    Raises:
        UserError: a graph with the wrong dim, shapes, or non-finite numbers, an
            empty graph, or fixed ids without a vertex (a file the reader would
            refuse is never written).
        DataError: the file cannot be written.
    """
    if graph.dim not in (2, 3):
        raise UserError(f"graph.dim must be 2 or 3, not {graph.dim}")
    kind = SE2 if graph.dim == 2 else SE3
    if not graph.vertices and not graph.edges:
        raise UserError("graph: empty graph, no vertices and no edges to write")
    missing = graph.fixed - set(graph.vertices)
    if missing:
        raise UserError(f"graph.fixed: ids without a vertex: {sorted(missing)[:10]} "
                        "(every fixed id must be a key of graph.vertices)")
    shape = (3,) if kind is SE2 else (4, 4)
    ids = list(graph.vertices)
    poses = _stack(list(graph.vertices.values()), shape, "pose", [f"vertex {v}" for v in ids])
    names = [f"edge {e.i}->{e.j}" for e in graph.edges]
    meas = _stack([e.measurement for e in graph.edges], shape, "measurement", names)
    size = (kind.info_size, kind.info_size)
    info = _stack([e.information for e in graph.edges], size, "information", names)

    lines = [f"{kind.vertex_tag} {v} {b}"
             for v, b in zip(ids, format_rows(_pose_columns(kind, poses)), strict=True)]
    lines += [f"{FIX_TAG} {v}" for v in sorted(graph.fixed)]
    iu, ju = np.triu_indices(kind.info_size)
    upper = 0.5 * (info[:, iu, ju] + info[:, ju, iu])
    body = format_rows(np.column_stack([_pose_columns(kind, meas), upper]))
    lines += [f"{kind.edge_tag} {e.i} {e.j} {b}" for e, b in zip(graph.edges, body, strict=True)]
    write_text_atomic(path, "\n".join(lines) + "\n")


# --------------------------------------------------------------------------- summary


def graph_info(graph: PoseGraphData) -> dict[str, Any]:
    """Counts of a pose graph.

    Returns:
        ``{"dim", "vertices", "edges", "odometry_edges" (j == i + 1),
        "loop_edges" (all other edges), "fixed"}``.
    """
    ei = np.fromiter((e.i for e in graph.edges), dtype=np.int64, count=len(graph.edges))
    ej = np.fromiter((e.j for e in graph.edges), dtype=np.int64, count=len(graph.edges))
    odometry = int(np.count_nonzero(ej == ei + 1))
    return {
        "dim": graph.dim,
        "vertices": len(graph.vertices),
        "edges": len(graph.edges),
        "odometry_edges": odometry,
        "loop_edges": len(graph.edges) - odometry,
        "fixed": len(graph.fixed),
    }
