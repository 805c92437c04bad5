"""TUM and KITTI trajectory files: read and write, plus the quaternion conversions.

Formats (units: seconds and metres; poses are body-in-world ``4x4`` matrices in a
`Trajectory`):

- **TUM** (TUM RGB-D benchmark, read by ``evo``): one pose per line,
  ``stamp x y z qx qy qz qw``; the quaternion is scalar-last (Hamilton convention,
  as `scipy.spatial.transform.Rotation` and ROS use it) and rotates body vectors
  into the world frame.  Lines starting with ``#`` and blank lines are ignored.
- **KITTI** (odometry benchmark ``poses/XX.txt``): one pose per line, the 12
  numbers of the top ``3x4`` block of the pose matrix, row-major
  (``r00 r01 r02 tx r10 r11 r12 ty r20 r21 r22 tz``).  The file has no stamps:
  they are ``0, 1, ..., N-1`` unless given (an array, or the path of a KITTI
  ``times.txt`` with one stamp per line).

Rules shared by both readers:

- Every data line must have exactly the format's number of columns, every value
  must parse as a finite number; otherwise `DataError` names the file and the line.
- A trajectory must have strictly increasing stamps: a stamp that does not
  increase is a `DataError` naming its line.
- TUM quaternions are normalised; a zero quaternion is a `DataError`, and
  quaternions whose norm is off by more than 1e-3 get one warning with their count.
- KITTI rotation blocks must be rotations to within 1e-2 (``max |RᵀR - I|`` and
  ``det R > 0``); they are kept exactly as written.

Writers write atomically (`data.atomic_write.write_text_atomic`), gzip or bzip2
compressed when the path ends in ``.gz`` / ``.bz2`` (the readers open either
transparently).  Precision: stamps as ``%.6f`` when that reads back
exactly (microsecond stamps such as CARMEN ipc times), else with Python's
shortest round-trip repr; pose numbers with the shortest round-trip repr (up to 17
significant digits, never fewer than needed), so write -> read gives the same
floats (TUM orientations up to the ~1e-16 of the quaternion <-> matrix conversion).

The text-table rules are `data.text_table`'s; the quaternion conversions here are
shared with `data.g2o`.
"""

from __future__ import annotations

from os import PathLike

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from data.atomic_write import write_text_atomic
from data.errors import DataError, UserError, warn
from data.text_table import PathArg, data_rows, format_rows, format_stamps, parse_rows, read_lines
from data.types import Trajectory

Array = NDArray[np.float64]

QUAT_NORM_TOL = 1e-3
"""Quaternions whose norm differs from 1 by more than this draw a warning (then normalised)."""

ROTATION_TOL = 1e-2
"""KITTI rotation blocks must satisfy ``max |RᵀR - I| <= ROTATION_TOL`` and ``det R > 0``."""


# --------------------------------------------------------------------------- rotations


def quaternion_to_rotation(q: ArrayLike) -> Array:
    """``(N, 3, 3)`` rotation matrices of ``(N, 4)`` quaternions ``(qx, qy, qz, qw)``.

    The quaternions are normalised first (callers check for zero norm).
    """
    q = np.asarray(q, dtype=float).reshape(-1, 4)
    if len(q) == 0:
        return np.zeros((0, 3, 3))
    return Rotation.from_quat(q).as_matrix().reshape(-1, 3, 3)


def rotation_to_quaternion(rot: ArrayLike) -> Array:
    """``(N, 4)`` unit quaternions ``(qx, qy, qz, qw)``, ``qw >= 0``, of ``(N, 3, 3)`` rotations."""
    rot = np.asarray(rot, dtype=float).reshape(-1, 3, 3)
    if len(rot) == 0:
        return np.zeros((0, 4))
    q = Rotation.from_matrix(rot).as_quat().reshape(-1, 4)
    return np.where(q[:, 3:4] < 0, -q, q)


def checked_quaternions(path: PathArg, linenos: NDArray, q: Array, what: str) -> Array:
    """Normalised copies of ``(N, 4)`` quaternions read from `path`.

    Raises `DataError` for a (near) zero quaternion, naming its line; warns once
    (with the count and the first line) when norms differ from 1 by more than
    `QUAT_NORM_TOL`.
    """
    norm = np.linalg.norm(q, axis=1)
    zero = np.flatnonzero(norm < 1e-12)
    if zero.size:
        raise DataError(path, f"line {linenos[zero[0]]}: zero quaternion in {what}")
    off = np.flatnonzero(np.abs(norm - 1.0) > QUAT_NORM_TOL)
    if off.size:
        warn(
            f"{path}: {off.size} {what} quaternions are not unit length "
            f"(first at line {linenos[off[0]]}, norm {norm[off[0]]:.6g}); normalised"
        )
    return q / norm[:, None]


def pose_matrices(translation: Array, rotation: Array) -> Array:
    """``(N, 4, 4)`` homogeneous matrices of ``(N, 3)`` translations and ``(N, 3, 3)`` rotations."""
    n = len(translation)
    m = np.zeros((n, 4, 4))
    m[:, :3, :3] = rotation
    m[:, :3, 3] = translation
    m[:, 3, 3] = 1.0
    return m


# --------------------------------------------------------------------------- trajectories


def _check_increasing(path: PathArg, linenos: NDArray, stamps: Array) -> None:
    bad = np.flatnonzero(np.diff(stamps) <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise DataError(
            path,
            f"line {linenos[k]}: stamp {float(stamps[k])!r} does not increase after "
            f"{float(stamps[k - 1])!r} "
            f"(a trajectory must have strictly increasing stamps; {bad.size} such lines)",
        )


def _check_writable(traj: Trajectory) -> None:
    if len(traj) == 0:
        raise UserError("traj: empty trajectory, nothing to write (need at least one pose)")
    if not (np.all(np.isfinite(traj.stamps)) and np.all(np.isfinite(traj.poses))):
        raise UserError("traj: trajectory has non-finite stamps or poses; refusing to write "
                        "NaN/inf (need finite numbers)")
    if np.any(np.diff(traj.stamps) <= 0):
        raise UserError("traj: trajectory stamps must be strictly increasing")


def read_tum(path: PathArg) -> Trajectory:
    """Trajectory from a TUM file ``stamp x y z qx qy qz qw`` (see module docstring).

    Raises:
        DataError: missing/unreadable/empty file, wrong column count, non-number,
            NaN/inf, zero quaternion, or stamps that do not strictly increase.
    """
    rows = data_rows(read_lines(path))
    if not rows:
        raise DataError(path, "empty file: no TUM pose lines (stamp x y z qx qy qz qw)")
    linenos, v = parse_rows(path, rows, 8, "TUM pose (stamp x y z qx qy qz qw)")
    _check_increasing(path, linenos, v[:, 0])
    q = checked_quaternions(path, linenos, v[:, 4:8], "TUM")
    return Trajectory(v[:, 0].copy(), pose_matrices(v[:, 1:4], quaternion_to_rotation(q)))


def write_tum(path: PathArg, traj: Trajectory) -> None:
    """Write `traj` as TUM ``stamp x y z qx qy qz qw``, atomically (see module docstring).

    Raises:
        UserError: an empty trajectory, non-finite values or stamps that do not
            strictly increase (a file the reader would refuse is never written).
        DataError: the file cannot be written.
    """
    _check_writable(traj)
    q = rotation_to_quaternion(traj.poses[:, :3, :3])
    body = format_rows(np.column_stack([traj.poses[:, :3, 3], q]))
    lines = ["# stamp x y z qx qy qz qw"]
    lines += [f"{s} {b}" for s, b in zip(format_stamps(traj.stamps), body, strict=True)]
    write_text_atomic(path, "\n".join(lines) + "\n")


def _stamps_from(stamps: ArrayLike | PathArg, n: int, path: PathArg) -> Array:
    if isinstance(stamps, (str, PathLike)):
        rows = data_rows(read_lines(stamps))
        linenos, v = parse_rows(stamps, rows, 1, "stamp")
        _check_increasing(stamps, linenos, v[:, 0])
        out, source = v[:, 0], stamps
    else:
        out = np.asarray(stamps, dtype=float).reshape(-1)
        source = "stamps argument"
        if not np.all(np.isfinite(out)):
            raise DataError(path, "the given stamps contain NaN or inf")
        bad = np.flatnonzero(np.diff(out) <= 0)
        if bad.size:
            raise DataError(
                path,
                f"given stamp {bad[0] + 1} does not increase "
                "(a trajectory must have strictly increasing stamps)",
            )
    if len(out) != n:
        raise DataError(path, f"{n} poses but {len(out)} stamps in {source}")
    return out.copy()


def read_kitti(path: PathArg, stamps: ArrayLike | PathArg | None = None) -> Trajectory:
    """Trajectory from a KITTI pose file (12 numbers per line, top ``3x4`` of the pose).

    Args:
        path: the pose file.
        stamps: ``None`` for stamps ``0..N-1`` [s], an array of N strictly
            increasing stamps [s], or the path of a KITTI ``times.txt``.

    Raises:
        DataError: unreadable/empty file, wrong column count, non-number, NaN/inf,
            a block that is not a rotation, or stamps of the wrong count or order.
    """
    rows = data_rows(read_lines(path))
    if not rows:
        raise DataError(path, "empty file: no KITTI pose lines (12 numbers each)")
    linenos, v = parse_rows(path, rows, 12, "KITTI pose (3x4 matrix, row-major)")
    block = v.reshape(-1, 3, 4)
    rot = block[:, :, :3]
    ortho = np.abs(np.swapaxes(rot, 1, 2) @ rot - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero((ortho > ROTATION_TOL) | (np.linalg.det(rot) <= 0))
    if bad.size:
        raise DataError(
            path,
            f"line {linenos[bad[0]]}: the 3x3 block is not a rotation matrix "
            f"({bad.size} such lines)",
        )
    t = np.arange(len(v), dtype=float) if stamps is None else _stamps_from(stamps, len(v), path)
    return Trajectory(t, pose_matrices(block[:, :, 3], rot))


def write_kitti(path: PathArg, traj: Trajectory) -> None:
    """Write the poses of `traj` as KITTI lines (top ``3x4``, row-major), atomically.

    Stamps are not part of the format and are not written.

    Raises:
        UserError: an empty trajectory, non-finite poses or stamps that do not
            strictly increase.
        DataError: the file cannot be written.
    """
    _check_writable(traj)
    lines = format_rows(traj.poses[:, :3, :4].reshape(-1, 12))
    write_text_atomic(path, "\n".join(lines) + "\n")
