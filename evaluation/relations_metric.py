"""The relation-based SLAM error of Kümmerle et al. (2009), as Cartographer computes it.

Cartographer's ``compute_relations_metrics`` (ground_truth/compute_relations_metrics_main.cc),
for every relation ``(t1, t2, delta*)``:

    delta = P(t1)^-1 P(t2)                 estimated relative pose
    E     = delta * delta*^-1              (composed in this order)
    trans = ||translation(E)||   [m]
    rot   = angle(rotation(E))   [deg]     (angle of the rotation, 0..180)

and reports mean +/- sample standard deviation (n - 1) of ``trans``, ``trans^2``,
``rot`` and ``rot^2``.  ``delta*`` is built from ``x y z roll pitch yaw`` as
``R = Rz(yaw) Ry(pitch) Rx(roll)`` (see `data.relations`).

Poses are looked up at the relation's stamps exactly: the trajectory pose whose
stamp is nearest, accepted when within `tolerance` (1 ms); relations with a stamp
not found are skipped and counted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from data.types import Relation, Trajectory
from evaluation.trajectory_error import rotation_angle_deg

Array = NDArray[np.float64]


@dataclass(slots=True)
class RelationsMetric:
    """Summary of the relations error (keys of ``loopclosure eval relations --json``)."""

    trans_abs_mean: float
    trans_abs_std: float
    trans_sq_mean: float
    trans_sq_std: float
    rot_abs_mean_deg: float
    rot_abs_std_deg: float
    rot_sq_mean_deg2: float
    rot_sq_std_deg2: float
    relations_used: int
    relations_total: int
    trans_errors: Array
    rot_errors_deg: Array

    def to_json(self) -> dict[str, float | int]:
        """The summary figures (without the per-relation arrays)."""
        return {
            k: getattr(self, k)
            for k in (
                "trans_abs_mean",
                "trans_abs_std",
                "trans_sq_mean",
                "trans_sq_std",
                "rot_abs_mean_deg",
                "rot_abs_std_deg",
                "rot_sq_mean_deg2",
                "rot_sq_std_deg2",
                "relations_used",
                "relations_total",
            )
        }

    def cartographer_text(self) -> str:
        """The four lines Cartographer prints, with its formatting (5 decimals)."""
        return (
            f"Abs translational error {self.trans_abs_mean:.5f} +/- {self.trans_abs_std:.5f} m\n"
            f"Sqr translational error {self.trans_sq_mean:.5f} +/- {self.trans_sq_std:.5f} m^2\n"
            f"Abs rotational error {self.rot_abs_mean_deg:.5f} +/- {self.rot_abs_std_deg:.5f} deg\n"
            f"Sqr rotational error {self.rot_sq_mean_deg2:.5f} +/- {self.rot_sq_std_deg2:.5f} "
            "deg^2"
        )


def lookup(stamps: Array, query: Array, tolerance: float) -> NDArray[np.intp]:
    """Index of the nearest stamp for each query, -1 where none is within `tolerance` [s]."""
    stamps = np.asarray(stamps, dtype=float)
    query = np.asarray(query, dtype=float)
    order = np.argsort(stamps, kind="stable")
    s = stamps[order]
    hi = np.clip(np.searchsorted(s, query), 1, max(len(s) - 1, 1))
    lo = hi - 1
    if len(s) == 1:
        lo = hi = np.zeros(len(query), dtype=np.intp)
    nearest = np.where(np.abs(s[lo] - query) <= np.abs(s[hi] - query), lo, hi)
    found = np.abs(s[nearest] - query) <= tolerance
    return np.where(found, order[nearest], -1)


def _mean_std(values: Array) -> tuple[float, float]:
    if len(values) == 0:
        return float("nan"), float("nan")
    std = float(np.std(values, ddof=1)) if len(values) > 1 else 0.0
    return float(np.mean(values)), std


def relations_metric(
    trajectory: Trajectory, relations: list[Relation], tolerance: float = 1e-3
) -> RelationsMetric:
    """The relations error of `trajectory` (see module docstring)."""
    if not relations:
        raise UserError("no relations to evaluate")
    t1 = np.array([r.t1 for r in relations])
    t2 = np.array([r.t2 for r in relations])
    delta_ref = np.stack([r.delta for r in relations])
    i1 = lookup(trajectory.stamps, t1, tolerance)
    i2 = lookup(trajectory.stamps, t2, tolerance)
    ok = (i1 >= 0) & (i2 >= 0)
    p1, p2 = trajectory.poses[i1[ok]], trajectory.poses[i2[ok]]
    delta = np.linalg.inv(p1) @ p2
    err = delta @ np.linalg.inv(delta_ref[ok])
    trans = np.linalg.norm(err[:, :3, 3], axis=1)
    rot = rotation_angle_deg(err[:, :3, :3])
    ta, tas = _mean_std(trans)
    tq, tqs = _mean_std(trans**2)
    ra, ras = _mean_std(rot)
    rq, rqs = _mean_std(rot**2)
    return RelationsMetric(
        ta, tas, tq, tqs, ra, ras, rq, rqs, int(ok.sum()), len(relations), trans, rot
    )
