"""`loopclosure.warm_up`: the synthetic room's ranges, and every kernel compiled."""

import numpy as np
import pytest

from loopclosure import (
    correlative,
    fast_points,
    grid_overlap,
    grid_target,
    icp_kernel,
    prior_screen,
)
from loopclosure.matchers import flirt_grid_kernel, flirt_kernel, pair_kernel
from loopclosure.warm_up import cache_is_cold, room_scan, warm_up, warm_up_isolated


def _range_at(scan, angle):
    return scan.ranges[np.argmin(np.abs(np.angle(np.exp(1j * (scan.angles - angle)))))]


def test_room_scan_hits_the_nearest_wall_or_the_pillar():
    scan = room_scan(-1.0, -0.5)  # walls x = +-5, y = +-3; pillar (1, 0.5), r 0.4
    assert _range_at(scan, 0.0) == pytest.approx(6.0)  # east wall, pillar 1 m off the ray
    assert _range_at(scan, np.pi / 2) == pytest.approx(3.5)  # north wall
    assert _range_at(scan, np.pi) == pytest.approx(4.0)  # west wall
    below = room_scan(1.0, -2.0)
    assert _range_at(below, np.pi / 2) == pytest.approx(2.1)  # pillar's south side
    assert np.all(np.isfinite(scan.ranges)) and len(scan.ranges) == 360


def test_warm_up_compiles_every_kernel_the_mapper_calls():
    warm_up()
    kernels = [fast_points._voxel_kernel, grid_target._normals_kernel,
               icp_kernel._register_kernel, grid_overlap._screen_kernel,
               grid_overlap._bound_kernel, prior_screen._screen_until_kernel,
               correlative._correlate, pair_kernel._pair_kernel, flirt_kernel.flirt_entries,
               flirt_kernel.euclidean_distances,
               flirt_grid_kernel.beta_grid_counts]
    assert all(k.signatures for k in kernels)


def _children_spawned(monkeypatch) -> list:
    """Stand in for the spawned child: record each child's target, run nothing."""
    children: list = []

    class _Child:
        def __init__(self, target):
            children.append(target)

        def start(self):
            pass

        def join(self):
            pass

    class _Context:
        Process = _Child

    monkeypatch.setattr("loopclosure.warm_up.multiprocessing.get_context",
                        lambda method: _Context)
    return children


def test_after_a_warm_up_the_cache_is_warm(monkeypatch):
    warm_up()  # writes numba's on-disk cache (the package's __pycache__ or the user's)
    assert not cache_is_cold()
    # A cold cache: the isolated warm-up compiles in a child first, then loads here.
    children = _children_spawned(monkeypatch)
    monkeypatch.setattr("loopclosure.warm_up.cache_is_cold", lambda: True)
    warm_up_isolated()
    assert children == [warm_up]


def test_the_mapper_warm_up_covers_the_back_end_kernels(monkeypatch):
    """`slam.kernel_warm_up` compiles the re-check's selected-inverse kernels as well,
    and hands its own pair to the isolated warm-up's child."""
    from slam import kernel_warm_up, selected_inverse_kernel

    kernel_warm_up.warm_up()
    assert all(k.signatures for k in (selected_inverse_kernel._reach_counts,
                                       selected_inverse_kernel._solves,
                                       selected_inverse_kernel.sparse_block_dots))
    assert not kernel_warm_up.cache_is_cold()
    children = _children_spawned(monkeypatch)
    monkeypatch.setattr(kernel_warm_up, "cache_is_cold", lambda: True)
    kernel_warm_up.warm_up_isolated()
    assert children == [kernel_warm_up.warm_up]
