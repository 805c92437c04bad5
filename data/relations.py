"""Relations files of the Freiburg SLAM benchmark (Kümmerle et al. 2009): read and write.

Kümmerle, Steder, Dornhege, Ruhnke, Grisetti, Stachniss, Kleiner, "On measuring
the accuracy of SLAM algorithms", Autonomous Robots 27(4), 2009.  Each line is one
manually verified relative pose between the robot poses at two log stamps::

    t1 t2 x y z roll pitch yaw

Units: stamps in seconds (the log's ipc timestamps), x y z in metres, angles in
radians.  The relation is ``delta = x(t1)⁻¹ ⊕ x(t2)``: the pose of the body at
`t2` expressed in the body frame at `t1` (`Relation.delta`, ``4x4``), which is how
the benchmark's metric compares it with ``x̂(t1)⁻¹ ⊕ x̂(t2)`` of an estimate.

Rotation convention.  The angles follow Cartographer's reader of these files
(``cartographer/ground_truth/relations_text_file.cc``, used by
``compute_relations_metrics``), which builds the rotation with
``transform::RollPitchYaw(roll, pitch, yaw)`` = ``AngleAxis(yaw, z) *
AngleAxis(pitch, y) * AngleAxis(roll, x)``, i.e.::

    R = Rz(yaw) · Ry(pitch) · Rx(roll)

(intrinsic z-y'-x'' rotations, equivalently extrinsic x, then y, then z about
fixed axes; the usual aerospace / ROS ``RPY`` convention).  The planar files of
the benchmark (Intel among them) have roll = pitch = 0 and z = 0, so for them the
order does not matter and only yaw is non-zero.  `write_relations` extracts the
angles back with the same convention (pitch in ``[-pi/2, pi/2]``).

Rules for bad input (`DataError` naming the file and line): a data line without
exactly 8 values, a value that is not a number, NaN or inf.  Blank lines and
lines starting with ``#`` are ignored; an empty file is a `DataError`.  The order
of the lines is kept (relations are not sorted).  Writing is atomic; numbers are
written with the shortest round-trip repr (stamps as ``%.6f`` when exact), so
write -> read gives the same stamps and translations and rotations equal to
~1e-16 (angle <-> matrix conversion).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.atomic_write import write_text_atomic
from data.errors import DataError, UserError
from data.text_table import PathArg, data_rows, format_rows, format_stamps, parse_rows, read_lines
from data.types import Relation

Array = NDArray[np.float64]


def rpy_to_matrix(roll: ArrayLike, pitch: ArrayLike, yaw: ArrayLike) -> Array:
    """``(N, 3, 3)`` rotations ``Rz(yaw) · Ry(pitch) · Rx(roll)`` of angles [rad] (broadcast)."""
    angles = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (roll, pitch, yaw))
    r, p, y = np.broadcast_arrays(*angles)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    m = np.empty((*r.shape, 3, 3))
    m[..., 0, 0] = cy * cp
    m[..., 0, 1] = cy * sp * sr - sy * cr
    m[..., 0, 2] = cy * sp * cr + sy * sr
    m[..., 1, 0] = sy * cp
    m[..., 1, 1] = sy * sp * sr + cy * cr
    m[..., 1, 2] = sy * sp * cr - cy * sr
    m[..., 2, 0] = -sp
    m[..., 2, 1] = cp * sr
    m[..., 2, 2] = cp * cr
    return m


def matrix_to_rpy(rot: ArrayLike) -> Array:
    """``(N, 3)`` (roll, pitch, yaw) [rad] of rotations, inverse of `rpy_to_matrix`.

    Takes ``(N, 3, 3)`` rotations or ``(N, 4, 4)`` poses (their rotation block).
    Pitch is in ``[-pi/2, pi/2]``; at gimbal lock (``|pitch| = pi/2``) roll is set to 0.
    """
    m = np.asarray(rot, dtype=float)
    if m.shape[-2:] == (4, 4):
        m = m[..., :3, :3]
    m = m.reshape(-1, 3, 3)
    pitch = np.arctan2(-m[:, 2, 0], np.hypot(m[:, 0, 0], m[:, 1, 0]))
    lock = np.hypot(m[:, 0, 0], m[:, 1, 0]) < 1e-12
    yaw = np.where(lock, np.arctan2(-m[:, 0, 1], m[:, 1, 1]), np.arctan2(m[:, 1, 0], m[:, 0, 0]))
    roll = np.where(lock, 0.0, np.arctan2(m[:, 2, 1], m[:, 2, 2]))
    return np.column_stack([roll, pitch, yaw])


def read_relations(path: PathArg) -> list[Relation]:
    """Relations of a ``t1 t2 x y z roll pitch yaw`` file, in file order.

    Raises:
        DataError: missing, unreadable or empty file, or a malformed line (named).
    """
    rows = data_rows(read_lines(path))
    if not rows:
        raise DataError(path, "empty file: no relation lines (t1 t2 x y z roll pitch yaw)")
    _, v = parse_rows(path, rows, 8, "relation (t1 t2 x y z roll pitch yaw)")
    delta = np.zeros((len(v), 4, 4))
    delta[:, :3, :3] = rpy_to_matrix(v[:, 5], v[:, 6], v[:, 7])
    delta[:, :3, 3] = v[:, 2:5]
    delta[:, 3, 3] = 1.0
    return [
        Relation(t1, t2, d)
        for t1, t2, d in zip(v[:, 0].tolist(), v[:, 1].tolist(), delta, strict=True)
    ]


def relations_arrays(relations: Sequence[Relation]) -> tuple[Array, Array, Array]:
    """``(N,)`` t1, ``(N,)`` t2 [s] and ``(N, 4, 4)`` deltas of a list of relations."""
    n = len(relations)
    t1 = np.fromiter((r.t1 for r in relations), dtype=float, count=n)
    t2 = np.fromiter((r.t2 for r in relations), dtype=float, count=n)
    delta = np.stack([np.asarray(r.delta, float) for r in relations]) if n else np.zeros((0, 4, 4))
    return t1, t2, delta


def write_relations(path: PathArg, relations: Iterable[Relation]) -> None:
    """Write relations as ``t1 t2 x y z roll pitch yaw`` lines, atomically.

    Raises:
        UserError: no relations, a delta that is not ``4x4``, or non-finite numbers.
        DataError: the file cannot be written.
    """
    rels = list(relations)
    if not rels:
        raise UserError("relations: no relations to write (need at least one)")
    if any(np.shape(r.delta) != (4, 4) for r in rels):
        raise UserError("relations: every Relation.delta must be a 4x4 matrix")
    t1, t2, delta = relations_arrays(rels)
    if not (np.isfinite(t1).all() and np.isfinite(t2).all() and np.isfinite(delta).all()):
        raise UserError("relations: relations contain NaN or inf; refusing to write them "
                        "(need finite stamps and deltas)")
    body = format_rows(np.column_stack([delta[:, :3, 3], matrix_to_rpy(delta[:, :3, :3])]))
    rows = zip(format_stamps(t1), format_stamps(t2), body, strict=True)
    write_text_atomic(path, "".join(f"{a} {b} {c}\n" for a, b, c in rows))
