"""Compile (or load) every numba kernel a default run of the mapper calls.

`loopclosure.warm_up` covers the front end, the place descriptors and the geometric
checks; this module adds the front end's local-map crop
(`loopclosure.fast_points.points_within`) and the back end's selected-inverse kernels of
the final pass's re-check (`slam.selected_inverse_kernel`).  `warm_up` makes both
layers' first calls (here on a 4-pose chain's information matrix, factorised as the
re-check factorises it by
`slam.least_squares.factor_information`, with the same argument types).
`warm_up_isolated` compiles in a spawned child when either layer's cache is cold, so
that LLVM's memory leaves with the child and the mapper's peak memory is the
mapping's, on the first run after an install too.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from loopclosure import warm_up as loopclosure_warm_up
from loopclosure.kernel_cache import kernels_cold


def _chain_jacobian(poses: int = 4, dof: int = 3) -> sp.csr_matrix:
    """The whitened Jacobian of a chain of `poses` poses: a unit prior on the first and
    unit-information edges ``x_{i+1} - x_i`` (linearised at the identity)."""
    n = poses * dof
    edges = sp.eye(n - dof, n, k=dof) - sp.eye(n - dof, n)
    return sp.vstack([sp.eye(dof, n), edges]).tocsr()


def warm_up() -> None:
    """`loopclosure.warm_up.warm_up`, the front end's local-map crop, then one
    selected-inverse request of 3x3 blocks."""
    from loopclosure import fast_points
    from slam.least_squares import factor_information
    from slam.selected_inverse import SelectedInverse

    loopclosure_warm_up.warm_up()
    # `slam.odometry.icp2d` crops its map with these (one row kept, one compacted away)
    fast_points.points_within(np.array([[0.0, 0.0], [3.0, 4.0]]), np.zeros(2), 1.0)
    lu = factor_information(_chain_jacobian())
    SelectedInverse(lu, symmetric=True).blocks(np.array([0, 3]), np.array([9, 6]), 3)
    SelectedInverse(lu, symmetric=False).blocks(np.array([0]), np.array([9]), 3)


def cache_is_cold() -> bool:
    """True when either layer's numba cache lacks a kernel `warm_up` compiles."""
    from loopclosure import fast_points, grid_target
    from slam import selected_inverse_kernel as kernels

    if loopclosure_warm_up.cache_is_cold():
        return True
    compiled = (kernels._reach_counts, kernels._solves, kernels.sparse_block_dots,
                fast_points._within_kernel, fast_points._compact,
                grid_target._cells_kernel, grid_target._all_finite)
    return kernels_cold(compiled)


def warm_up_isolated() -> None:
    """`warm_up`, compiling in a spawned child first when the cache is cold."""
    loopclosure_warm_up.warm_up_isolated(warm_up, cache_is_cold)


__all__ = ["cache_is_cold", "warm_up", "warm_up_isolated"]
