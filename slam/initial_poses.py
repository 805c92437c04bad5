"""Initial poses of a batch solve: the graph's own guesses, the odometry chain, or LAGO."""

from __future__ import annotations

import gtsam
import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from slam.pose_graph import PoseGraph, poses_from_values, relative_compose, to_gtsam_pose

__all__ = ["INITIALISATIONS", "initial_guess"]

Array = NDArray[np.float64]
INITIALISATIONS = ("given", "odometry", "lago")


def initial_guess(graph: PoseGraph, init: str = "given") -> dict[int, Array]:
    """Initial poses for a batch solve.

    ``given``: the graph's own initial guesses (g2o vertices, mapper estimates).
    ``odometry``: the anchor pose composed along odometry constraints (breadth-first;
    poses no odometry reaches keep their given guess).
    ``lago``: gtsam's LAGO (Carlone et al. 2014) linear approximation over every
    constraint, 2D only, with the diagonal of each information matrix (LAGO accepts
    diagonal noise only).  Far better than odometry on long loops, but it trusts
    every loop, so it is a poor start when false loops are present.
    """
    if init not in INITIALISATIONS:
        raise UserError(f"unknown initialisation {init!r}; use {', '.join(INITIALISATIONS)}")
    if init == "given":
        return dict(graph.initial)
    if init == "odometry":
        poses = dict(graph.initial)
        children: dict[int, list] = {}
        for c in graph.odometry:
            children.setdefault(c.i, []).append(c)
        frontier = list(graph.anchor_keys())
        seen = set(frontier)
        while frontier:
            key = frontier.pop()
            for c in children.get(key, []):
                if c.j not in seen:
                    poses[c.j] = relative_compose(poses[key], c.measurement, graph.dim)
                    seen.add(c.j)
                    frontier.append(c.j)
        return poses
    if graph.dim != 2:
        raise UserError("LAGO initialisation is for 2D graphs only")
    factors = gtsam.NonlinearFactorGraph()
    for key in graph.anchor_keys():
        factors.add(graph.prior_factor(key))
    for c in graph.odometry + graph.loops:
        noise = gtsam.noiseModel.Diagonal.Precisions(np.maximum(np.diag(c.information), 1e-12))
        factors.add(gtsam.BetweenFactorPose2(c.i, c.j, to_gtsam_pose(c.measurement, 2), noise))
    return poses_from_values(gtsam.lago.initialize(factors), 2)
