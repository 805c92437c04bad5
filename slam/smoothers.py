"""The back end a mapper feeds as keyframes and loops arrive: batch or incremental.

`Smoother` is the interface: ``add_pose``, ``add_odometry``, ``add_loop``, ``update``,
``estimate``, ``marginal_covariance``.  `BatchSmoother` re-solves the whole graph with
LM (`slam.optimize.optimize`) on each update; `IncrementalSmoother` feeds gtsam.ISAM2
only what is new.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import gtsam
import numpy as np
from numpy.typing import NDArray

from data.errors import warn
from slam.optimize import optimize
from slam.pose_graph import PoseGraph, RobustKernel, poses_from_values, to_gtsam_pose

__all__ = ["BatchSmoother", "IncrementalSmoother", "Smoother"]

Array = NDArray[np.float64]


class Smoother(ABC):
    """What a mapper needs from a back end, batch or incremental alike."""

    def __init__(self, dim: int = 2, kernel: str | RobustKernel = "cauchy") -> None:
        self.graph = PoseGraph(dim=dim)
        self.kernel = RobustKernel(kernel) if isinstance(kernel, str) else kernel

    @property
    def dim(self) -> int:
        return self.graph.dim

    def add_pose(self, key: int, guess: Array) -> None:
        """A new pose with its initial guess (e.g. the odometry-composed pose)."""
        self.graph.add_pose(key, guess)
        self._on_pose(key, guess)

    def add_odometry(self, i: int, j: int, measurement: Array, information: Array) -> None:
        """An odometry constraint (Gaussian)."""
        self.graph.add_odometry(i, j, measurement, information)
        self._on_factor(self.graph.between_factor(self.graph.odometry[-1]), is_loop=False)

    def add_loop(self, i: int, j: int, measurement: Array, information: Array) -> int:
        """A loop-closure constraint with the smoother's robust kernel; returns its index."""
        index = self.graph.add_loop(i, j, measurement, information)
        self._on_factor(
            self.graph.between_factor(self.graph.loops[index], self.kernel), is_loop=True
        )
        return index

    @abstractmethod
    def _on_pose(self, key: int, guess: Array) -> None: ...

    @abstractmethod
    def _on_factor(self, factor: gtsam.NonlinearFactor, is_loop: bool) -> None: ...

    @abstractmethod
    def update(self) -> None:
        """Bring the estimate up to date with everything added so far."""

    @abstractmethod
    def estimate(self) -> dict[int, Array]:
        """Current id -> pose estimate (of every pose added so far)."""

    def estimate_rows(self) -> tuple[NDArray[np.int64], Array]:
        """The current estimate as arrays: ids ascending ``(N,)`` and their poses
        (``(N, 3)`` in 2-D, ``(N, 4, 4)`` in 3-D), for a caller that wants them all."""
        est = self.estimate()
        keys = np.array(sorted(est), dtype=np.int64)
        shape = (0, 3) if self.dim == 2 else (0, 4, 4)
        poses = np.array([est[k] for k in keys]) if len(keys) else np.empty(shape)
        return keys, poses

    @abstractmethod
    def marginal_covariance(self, key: int) -> Array:
        """Marginal covariance of pose `key` (gtsam tangent order) at the current estimate."""


class BatchSmoother(Smoother):
    """Re-solves the whole graph with Levenberg-Marquardt at every `update`."""

    def __init__(self, dim: int = 2, kernel: str | RobustKernel = "cauchy") -> None:
        super().__init__(dim, kernel)
        self._poses: dict[int, Array] = {}
        self._marginals: gtsam.Marginals | None = None

    def _on_pose(self, key: int, guess: Array) -> None:
        self._poses[key] = np.asarray(guess, dtype=float)
        self._marginals = None

    def _on_factor(self, factor: gtsam.NonlinearFactor, is_loop: bool) -> None:
        self._marginals = None

    def update(self) -> None:
        result = optimize(self.graph, self.kernel, "lm", initial=self._poses)
        self._poses = result.poses

    def estimate(self) -> dict[int, Array]:
        return dict(self._poses)

    def marginal_covariance(self, key: int) -> Array:
        if self._marginals is None:
            factors, _ = self.graph.factor_graph(self.kernel)
            self._marginals = gtsam.Marginals(factors, self.graph.gtsam_values(self._poses))
        return np.asarray(self._marginals.marginalCovariance(key))


class IncrementalSmoother(Smoother):
    """gtsam.ISAM2: each `update` folds in only the poses and factors added since the last.

    Args:
        relinearize_threshold: iSAM2 relinearisation threshold (tangent units).
        extra_iterations: further ``update()`` calls without new factors after a loop
            closure, so iSAM2's single Gauss-Newton step converges on large corrections.
            They stop at the first that relinearises no variable: such a call leaves
            the linearisation point and the Bayes tree as they were, so the next one
            would check the same delta against the same threshold and do nothing too.

    Factorisation: Cholesky, the fast one.  When it gives up on an ill-conditioned
    system (gtsam's "indeterminate linear system": e.g. an odometry step whose
    covariance says the front end is lost, 10 m and pi rad, next to millimetre-level
    steps), iSAM2 is rebuilt once from the whole graph with QR factorisation, about
    1.4x slower but stable, for the rest of the run (one warning).
    """

    def __init__(
        self,
        dim: int = 2,
        kernel: str | RobustKernel = "cauchy",
        relinearize_threshold: float = 0.01,
        extra_iterations: int = 2,
    ) -> None:
        super().__init__(dim, kernel)
        self._relinearize_threshold = relinearize_threshold
        self._factorization = "CHOLESKY"
        self._isam = self._new_isam()
        self._new_factors = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()
        self._anchored = False
        self._loop_pending = False
        self._extra_iterations = extra_iterations
        self._estimate: gtsam.Values | None = None
        # Keys of `_estimate`, ascending (what ``_estimate.keys()`` lists), and the keys
        # added since the last `update` (in `_new_values`).
        self._keys = np.zeros(0, dtype=np.int64)
        self._new_keys: list[int] = []

    def _on_pose(self, key: int, guess: Array) -> None:
        self._new_values.insert(key, to_gtsam_pose(guess, self.dim))
        self._new_keys.append(key)
        if not self._anchored:
            self._new_factors.add(self.graph.prior_factor(key, guess))
            self._anchored = True

    def _on_factor(self, factor: gtsam.NonlinearFactor, is_loop: bool) -> None:
        self._new_factors.add(factor)
        self._loop_pending |= is_loop

    def _new_isam(self) -> gtsam.ISAM2:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(self._relinearize_threshold)
        params.relinearizeSkip = 1
        params.setFactorization(self._factorization)
        return gtsam.ISAM2(params)

    def _restart_with_qr(self) -> None:
        """Rebuild iSAM2 with QR from every factor and the latest estimate (class doc)."""
        warn("iSAM2: Cholesky found the pose graph ill-conditioned; continuing with QR "
             "factorisation (slower)")
        self._factorization = "QR"
        self._isam = self._new_isam()
        factors, _ = self.graph.factor_graph(self.kernel)
        current = self.estimate()
        values = gtsam.Values()
        for key, guess in self.graph.initial.items():
            values.insert(key, to_gtsam_pose(current.get(key, guess), self.dim))
        self._isam.update(factors, values)

    def update(self) -> None:
        if self._new_factors.size() == 0 and self._new_values.size() == 0:
            return
        try:
            self._isam.update(self._new_factors, self._new_values)
        except RuntimeError:
            if self._factorization == "QR":
                raise
            self._restart_with_qr()
        if self._loop_pending:
            for _ in range(self._extra_iterations):
                if not self._isam.update().getVariablesRelinearized():
                    break  # nothing moved: a further call would do nothing (class doc)
        self._new_factors = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()
        self._loop_pending = False
        self._estimate = self._isam.calculateEstimate()
        self._keys = _merged_keys(self._keys, self._new_keys)
        self._new_keys = []

    def estimate(self) -> dict[int, Array]:
        if self._estimate is None:
            return {}
        return poses_from_values(self._estimate, self.dim)

    def estimate_rows(self) -> tuple[NDArray[np.int64], Array]:
        if self._estimate is None or self.dim != 2:
            return super().estimate_rows()
        # `_keys` is ``_estimate.keys()`` (ascending) without converting gtsam's list
        return self._keys.copy(), gtsam.utilities.extractPose2(self._estimate)  # key order

    def marginal_covariance(self, key: int) -> Array:
        return np.asarray(self._isam.marginalCovariance(key))


def _merged_keys(keys: NDArray[np.int64], new: list[int]) -> NDArray[np.int64]:
    """The ascending keys of an estimate after `new` keys (none of them in `keys`, in
    any order) joined the ascending `keys`; appended as they are when they come in
    increasing order after the last, as a mapper adds its poses."""
    if not new:
        return keys
    added = np.asarray(new, dtype=np.int64)
    if (len(keys) == 0 or added[0] > keys[-1]) and np.all(added[1:] > added[:-1]):
        return np.concatenate([keys, added])
    return np.sort(np.concatenate([keys, added]))
