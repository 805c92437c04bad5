"""Pose graph over gtsam: poses, odometry factors and robust loop-closure factors.

2D graphs use `gtsam.Pose2` / `BetweenFactorPose2` (tangent order x, y, theta, the
same as g2o's ``EDGE_SE2``); 3D graphs use `gtsam.Pose3` / `BetweenFactorPose3`.
A g2o ``EDGE_SE3:QUAT`` information matrix is ordered (x, y, z, rx, ry, rz); gtsam's
Pose3 tangent is (rx, ry, rz, x, y, z), so the blocks are swapped on the way in and
out (the usual convention, as gtsam's own g2o reader does; no rescaling).

Odometry factors (measurement from the front end or ``j == i + 1`` edges of a g2o
file) are plain Gaussian.  Loop-closure factors are kept apart so the robust
kernel, GNC outlier classification and the robustness benchmark can act on them
alone.  Kernels (`RobustKernel`) act on the whitened residual (Mahalanobis units):

=============  ==============  ======================================================
name           default scale   gtsam model
=============  ==============  ======================================================
none           -               Gaussian only
huber          1.345           ``mEstimator.Huber`` (95% efficiency for Gaussian noise)
cauchy         1.0             ``mEstimator.Cauchy``
dcs            1.0             ``mEstimator.DCS`` (Agarwal et al. 2013: Phi = 1)
gemanmcclure   1.0             ``mEstimator.GemanMcClure``
=============  ==============  ======================================================

GNC (graduated non-convexity with the truncated-least-squares loss, Yang et al.
2020) is a batch mode of `slam.optimize`, not a kernel: it sees loop factors with
their plain Gaussian noise and decides which are outliers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.special import chdtri

from data import se2
from data.errors import UserError
from data.types import GraphEdge, PoseGraphData

Array = NDArray[np.float64]

KERNEL_SCALES: dict[str, float] = {
    "none": 0.0,
    "huber": 1.345,
    "cauchy": 1.0,
    "dcs": 1.0,
    "gemanmcclure": 1.0,
}
KERNELS: tuple[str, ...] = tuple(KERNEL_SCALES)


@dataclass(frozen=True, slots=True)
class RobustKernel:
    """An M-estimator for loop factors: `name` in `KERNELS`, `scale` in whitened units.

    A scale of None takes the documented default of the kernel (`KERNEL_SCALES`).
    """

    name: str = "cauchy"
    scale: float | None = None

    def __post_init__(self) -> None:
        if self.name not in KERNEL_SCALES:
            raise UserError(f"unknown kernel {self.name!r}; choose one of {', '.join(KERNELS)}")

    @property
    def effective_scale(self) -> float:
        """The scale actually used (the default when `scale` is None)."""
        return KERNEL_SCALES[self.name] if self.scale is None else float(self.scale)

    def noise(self, information: Array) -> gtsam.noiseModel.Base:
        """Noise model of a factor with this kernel around a Gaussian of `information`."""
        gaussian = gtsam.noiseModel.Gaussian.Information(np.asarray(information, dtype=float))
        if self.name == "none":
            return gaussian
        k = self.effective_scale
        estimator = {
            "huber": gtsam.noiseModel.mEstimator.Huber,
            "cauchy": gtsam.noiseModel.mEstimator.Cauchy,
            "dcs": gtsam.noiseModel.mEstimator.DCS,
            "gemanmcclure": gtsam.noiseModel.mEstimator.GemanMcClure,
        }[self.name].Create(k)
        return gtsam.noiseModel.Robust.Create(estimator, gaussian)


_GAUSSIAN = RobustKernel("none")


def _g2o_to_gtsam_information(information: Array) -> Array:
    """6x6 information from g2o order (t, r) to gtsam Pose3 order (r, t)."""
    perm = [3, 4, 5, 0, 1, 2]
    return np.asarray(information)[np.ix_(perm, perm)]


def _gtsam_to_g2o_information(information: Array) -> Array:
    return _g2o_to_gtsam_information(information)  # the swap is its own inverse


@dataclass(slots=True)
class Constraint:
    """A relative-pose factor of the graph (pose of `j` in the frame of `i`).

    `measurement` is ``(3,)`` (x, y, theta) in 2D or ``4x4`` in 3D; `information`
    is in g2o order (x, y, theta) / (x, y, z, rx, ry, rz).
    """

    i: int
    j: int
    measurement: Array
    information: Array


@dataclass
class PoseGraph:
    """Poses with initial guesses, odometry constraints and loop-closure constraints.

    Attributes:
        dim: 2 or 3.
        initial: id -> initial pose ((3,) planar or 4x4).
        odometry: constraints from the front end (Gaussian).
        loops: loop-closure constraints (robust / GNC-classified).
        fixed: ids held at their initial pose by a strong prior (the first id if empty).
    """

    dim: int = 2
    initial: dict[int, Array] = field(default_factory=dict)
    odometry: list[Constraint] = field(default_factory=list)
    loops: list[Constraint] = field(default_factory=list)
    fixed: set[int] = field(default_factory=set)
    # `factor_graph`'s gtsam factors of the graph's own constraints, by (id, kernel):
    # (constraint, its measurement, its information, factor).  An entry holds its
    # constraint, so the id is not reused while the entry lives, and it is used only
    # while the constraint still holds the same measurement and information arrays.
    _factors: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    # -- building ---------------------------------------------------------------------------
    def add_pose(self, key: int, guess: Array) -> None:
        """Add pose `key` with an initial guess ((3,) planar or 4x4)."""
        self.initial[int(key)] = np.asarray(guess, dtype=float)

    def add_odometry(self, i: int, j: int, measurement: Array, information: Array) -> None:
        """Add an odometry constraint: pose of `j` in the frame of `i`."""
        self.odometry.append(_constraint(i, j, measurement, information))

    def add_loop(self, i: int, j: int, measurement: Array, information: Array) -> int:
        """Add a loop-closure constraint; returns its index in `loops`."""
        self.loops.append(_constraint(i, j, measurement, information))
        return len(self.loops) - 1

    @classmethod
    def from_g2o(cls, data: PoseGraphData) -> PoseGraph:
        """Graph of a g2o file: ``j == i + 1`` edges are odometry, all others loops."""
        graph = cls(dim=data.dim, fixed=set(data.fixed))
        for key, pose in data.vertices.items():
            graph.add_pose(key, pose)
        for edge in data.edges:
            for key in (edge.i, edge.j):
                if key not in graph.initial:
                    raise UserError(f"edge {edge.i} -> {edge.j} refers to unknown vertex {key}")
            target = graph.odometry if edge.j == edge.i + 1 else graph.loops
            target.append(_constraint(edge.i, edge.j, edge.measurement, edge.information))
        return graph

    def to_g2o(self, poses: dict[int, Array] | None = None) -> PoseGraphData:
        """g2o data with `poses` (default: the initial guesses) and every constraint."""
        poses = self.initial if poses is None else poses
        edges = [
            GraphEdge(c.i, c.j, c.measurement, c.information)
            for c in sorted(self.odometry + self.loops, key=lambda c: (c.i, c.j))
        ]
        return PoseGraphData(self.dim, dict(sorted(poses.items())), edges, set(self.fixed))

    @property
    def keys(self) -> list[int]:
        """Pose ids in increasing order."""
        return sorted(self.initial)

    # -- gtsam ------------------------------------------------------------------------------
    def anchor_keys(self) -> list[int]:
        """Ids held fixed by a prior: `fixed`, or the smallest id."""
        return sorted(self.fixed) if self.fixed else self.keys[:1]

    def gtsam_values(self, poses: dict[int, Array] | None = None) -> gtsam.Values:
        """gtsam Values of `poses` (default: the initial guesses)."""
        values = gtsam.Values()
        for key, pose in (self.initial if poses is None else poses).items():
            values.insert(key, to_gtsam_pose(pose, self.dim))
        return values

    def prior_factor(self, key: int, pose: Array | None = None) -> gtsam.NonlinearFactor:
        """A strong prior holding `key` at `pose` (default its initial guess)."""
        pose = self.initial[key] if pose is None else pose
        sigmas = np.full(pose_dof(self.dim), 1e-6)
        noise = gtsam.noiseModel.Diagonal.Sigmas(sigmas)
        if self.dim == 2:
            return gtsam.PriorFactorPose2(key, to_gtsam_pose(pose, 2), noise)
        return gtsam.PriorFactorPose3(key, to_gtsam_pose(pose, 3), noise)

    def between_factor(
        self, c: Constraint, kernel: RobustKernel | None = None
    ) -> gtsam.NonlinearFactor:
        """The gtsam factor of constraint `c` (Gaussian, or robust with `kernel`)."""
        if self.dim == 2 and (kernel is None or kernel.name == "none"):
            # the planar Gaussian factor, built directly (the final pass makes tens of
            # thousands): the same gtsam calls on the same numbers as below
            m = c.measurement
            return gtsam.BetweenFactorPose2(
                c.i, c.j, gtsam.Pose2(float(m[0]), float(m[1]), float(m[2])),
                gtsam.noiseModel.Gaussian.Information(np.asarray(c.information, dtype=float)))
        info = c.information if self.dim == 2 else _g2o_to_gtsam_information(c.information)
        noise = (kernel or _GAUSSIAN).noise(info)
        if self.dim == 2:
            return gtsam.BetweenFactorPose2(c.i, c.j, to_gtsam_pose(c.measurement, 2), noise)
        return gtsam.BetweenFactorPose3(c.i, c.j, to_gtsam_pose(c.measurement, 3), noise)

    def factor_graph(
        self, kernel: RobustKernel | None = None
    ) -> tuple[gtsam.NonlinearFactorGraph, list[int]]:
        """The whole graph (priors, odometry, loops with `kernel`); second value: the factor
        index of every loop constraint, in `loops` order."""
        graph = gtsam.NonlinearFactorGraph()
        for key in self.anchor_keys():
            graph.add(self.prior_factor(key))
        for c in self.odometry:
            graph.add(self._own_factor(c, None))
        loop_index = []
        for c in self.loops:
            loop_index.append(graph.size())
            graph.add(self._own_factor(c, kernel))
        return graph, loop_index

    def _own_factor(self, c: Constraint, kernel: RobustKernel | None) -> gtsam.NonlinearFactor:
        """`between_factor` of a constraint of this graph, made once and kept: the
        final pass builds the whole graph several times, and a gtsam factor is
        immutable (the same factor object serves every graph that holds it).  A
        constraint whose measurement or information was replaced gets a new factor;
        the cache is pruned of constraints no longer in the graph when it doubles."""
        kernel = kernel or _GAUSSIAN
        key = (id(c), kernel)
        entry = self._factors.get(key)
        if (entry is not None and entry[0] is c and entry[1] is c.measurement
                and entry[2] is c.information):
            return entry[3]
        factor = self.between_factor(c, kernel)
        self._factors[key] = (c, c.measurement, c.information, factor)
        if len(self._factors) > 4 * (len(self.odometry) + len(self.loops)) + 64:
            own = {id(o): o for o in (*self.odometry, *self.loops)}
            self._factors = {k: v for k, v in self._factors.items() if own.get(k[0]) is v[0]}
        return factor


def pose_dof(dim: int) -> int:
    """Degrees of freedom of a pose: 3 in 2D (x, y, theta), 6 in 3D."""
    return 3 if dim == 2 else 6


def chi2_quantile(probability: float, dof: int) -> float:
    """The `probability` quantile of the chi-square distribution with `dof` degrees of
    freedom (``scipy.special.chdtri`` of the upper tail: the same number as
    ``scipy.stats.chi2.ppf`` without importing the large ``scipy.stats``)."""
    return float(chdtri(dof, 1.0 - probability))


def _constraint(i: int, j: int, measurement: Array, information: Array) -> Constraint:
    m = np.asarray(measurement, dtype=float)
    info = np.asarray(information, dtype=float)
    if not (np.all(np.isfinite(m)) and np.all(np.isfinite(info))):
        raise UserError(f"constraint {i} -> {j} has non-finite values")
    return Constraint(int(i), int(j), m, 0.5 * (info + info.T))


def to_gtsam_pose(pose: Array, dim: int) -> gtsam.Pose2 | gtsam.Pose3:
    """gtsam pose of a (3,) planar pose (dim 2) or a 4x4 matrix (dim 3)."""
    p = np.asarray(pose, dtype=float)
    if dim == 2:
        return gtsam.Pose2(float(p[0]), float(p[1]), float(p[2]))
    return gtsam.Pose3(p)


def poses_from_values(values: gtsam.Values, dim: int) -> dict[int, Array]:
    """id -> pose ((3,) or 4x4) of every pose in `values`."""
    keys = list(values.keys())
    if dim == 2:
        arr = gtsam.utilities.extractPose2(values)  # rows ordered by key
        return {k: arr[n].copy() for n, k in enumerate(sorted(keys))}
    return {k: values.atPose3(k).matrix() for k in keys}


def relative_compose(a: Array, delta: Array, dim: int) -> Array:
    """Pose `delta` given in the frame of `a`, in `a`'s parent frame ((3,) or 4x4)."""
    if dim == 2:
        return se2.compose(a, delta)
    return a @ delta


def relative_pose(a: Array, b: Array, dim: int) -> Array:
    """Pose of `b` in the frame of `a` ((3,) planar or 4x4)."""
    if dim == 2:
        return se2.between(a, b)
    return np.linalg.inv(a) @ b


def whitened_residual(c: Constraint, poses: dict[int, Array], dim: int) -> float:
    """Mahalanobis distance sqrt(e^T I e) of constraint `c` under `poses`."""
    if dim == 2:
        a, b, m = poses[c.i], poses[c.j], c.measurement
        if np.shape(a) == np.shape(b) == np.shape(m) == (3,):  # a mapper's poses
            e = np.array(_between_floats(m, _between_floats(a, b)))
        else:
            e = se2.between(m, se2.between(a, b))
        return float(np.sqrt(max(e @ c.information @ e, 0.0)))
    err = gtsam.Pose3(c.measurement).between(gtsam.Pose3(np.linalg.inv(poses[c.i]) @ poses[c.j]))
    log = gtsam.Pose3.Logmap(err)  # (rx, ry, rz, x, y, z)
    e = np.concatenate([log[3:], log[:3]])
    return float(np.sqrt(max(e @ c.information @ e, 0.0)))


def _between_floats(a: Array | list[float], b: Array | list[float]) -> list[float]:
    """`data.se2.between` of two ``(3,)`` poses (metres, radians) as a list of floats:
    the very operations of its single-pose path, in the same order, without making
    the arrays in between."""
    ax, ay, at = a.tolist() if isinstance(a, np.ndarray) else a
    bx, by, bt = b.tolist() if isinstance(b, np.ndarray) else b
    c, s = math.cos(at), math.sin(at)
    ix, iy, it = -c * ax - s * ay, s * ax - c * ay, _wrap(-at)
    c, s = math.cos(it), math.sin(it)
    return [ix + c * bx - s * by, iy + s * bx + c * by, _wrap(it + bt)]


def _wrap(theta: float) -> float:
    """An angle (radians) wrapped to ``[-pi, pi)``, as `data.se2` wraps a float."""
    return (theta + math.pi) % (2.0 * math.pi) - math.pi
