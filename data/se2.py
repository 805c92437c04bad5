"""Planar rigid motions as ``(x, y, theta)`` arrays: metres and radians.

Every function takes single poses of shape ``(3,)`` or stacks of shape ``(N, 3)``
and broadcasts like numpy.  ``compose(a, b)`` is ``a ⊕ b`` (apply ``b`` in the
frame of ``a``); ``between(a, b)`` is ``a⁻¹ ⊕ b``, the pose of ``b`` seen from ``a``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


def wrap_angle(theta: ArrayLike) -> Array:
    """Angle(s) wrapped to ``[-pi, pi)`` (radians)."""
    theta = np.asarray(theta, dtype=float)
    return (theta + np.pi) % (2.0 * np.pi) - np.pi


def _wrap(theta: float) -> float:
    return (theta + math.pi) % (2.0 * math.pi) - math.pi


def compose(a: ArrayLike, b: ArrayLike) -> Array:
    """``a ⊕ b``: pose ``b``, given in the frame of ``a``, expressed in ``a``'s parent frame."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.shape == (3,) and b.shape == (3,):
        # One pose each (the pipeline's bookkeeping): scalar arithmetic, no array ops.
        ax, ay, at = a.tolist()
        bx, by, bt = b.tolist()
        c, s = math.cos(at), math.sin(at)
        return np.array([ax + c * bx - s * by, ay + s * bx + c * by, _wrap(at + bt)])
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    return np.stack([x, y, wrap_angle(a[..., 2] + b[..., 2])], axis=-1)


def inverse(a: ArrayLike) -> Array:
    """``a⁻¹`` such that ``compose(a, inverse(a))`` is the identity."""
    a = np.asarray(a, dtype=float)
    if a.shape == (3,):
        ax, ay, at = a.tolist()
        c, s = math.cos(at), math.sin(at)
        return np.array([-c * ax - s * ay, s * ax - c * ay, _wrap(-at)])
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = -c * a[..., 0] - s * a[..., 1]
    y = s * a[..., 0] - c * a[..., 1]
    return np.stack([x, y, wrap_angle(-a[..., 2])], axis=-1)


def between(a: ArrayLike, b: ArrayLike) -> Array:
    """``a⁻¹ ⊕ b``: the pose of ``b`` in the frame of ``a``."""
    return compose(inverse(a), b)


def transform_points(pose: ArrayLike, points: ArrayLike) -> Array:
    """Points ``(N, 2)`` given in the frame of ``pose`` expressed in its parent frame."""
    pose = np.asarray(pose, dtype=float)
    points = np.asarray(points, dtype=float)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, -s], [s, c]])
    return points @ rot.T + pose[:2]


def to_matrix(a: ArrayLike) -> Array:
    """Homogeneous ``3x3`` matrix (or ``(N, 3, 3)``) of pose(s) ``(x, y, theta)``."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    m = np.zeros((*a.shape[:-1], 3, 3))
    m[..., 0, 0], m[..., 0, 1], m[..., 0, 2] = c, -s, a[..., 0]
    m[..., 1, 0], m[..., 1, 1], m[..., 1, 2] = s, c, a[..., 1]
    m[..., 2, 2] = 1.0
    return m


def from_matrix(m: ArrayLike) -> Array:
    """Pose(s) ``(x, y, theta)`` of ``3x3`` homogeneous matrices (planar part of ``4x4`` ones)."""
    m = np.asarray(m, dtype=float)
    last = m.shape[-1] - 1
    theta = np.arctan2(m[..., 1, 0], m[..., 0, 0])
    return np.stack([m[..., 0, last], m[..., 1, last], theta], axis=-1)


def to_se3(a: ArrayLike) -> Array:
    """``4x4`` homogeneous matrix (or ``(N, 4, 4)``) of planar pose(s), z = 0."""
    a = np.asarray(a, dtype=float)
    m3 = to_matrix(a)
    m = np.zeros((*a.shape[:-1], 4, 4))
    m[..., :2, :2] = m3[..., :2, :2]
    m[..., :2, 3] = m3[..., :2, 2]
    m[..., 2, 2] = 1.0
    m[..., 3, 3] = 1.0
    return m


def interpolate(stamps: ArrayLike, poses: ArrayLike, query: ArrayLike) -> Array:
    """Poses at `query` stamps, linear in x, y and along the shortest arc in theta.

    `stamps` must be non-decreasing.  Queries outside ``[stamps[0], stamps[-1]]``
    take the nearest end pose (no extrapolation).
    """
    stamps = np.asarray(stamps, dtype=float)
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    query = np.atleast_1d(np.asarray(query, dtype=float))
    if len(stamps) == 1:
        return np.repeat(poses, len(query), axis=0)
    hi = np.clip(np.searchsorted(stamps, query, side="right"), 1, len(stamps) - 1)
    lo = hi - 1
    span = stamps[hi] - stamps[lo]
    w = np.where(span > 0, (query - stamps[lo]) / np.where(span > 0, span, 1.0), 0.0)
    w = np.clip(w, 0.0, 1.0)
    d_theta = wrap_angle(poses[hi, 2] - poses[lo, 2])
    xy = poses[lo, :2] + w[:, None] * (poses[hi, :2] - poses[lo, :2])
    theta = wrap_angle(poses[lo, 2] + w * d_theta)
    return np.column_stack([xy, theta])
