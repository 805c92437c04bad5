"""False loop closures injected the ways place recognition fails.

The policies of Sünderhauf & Protzel ("Switchable Constraints for Robust Pose Graph
SLAM", IROS 2012, and the Vertigo dataset script), each adding false loops to a
fraction ``p`` of all loop edges, ``n_false = round(n_true * p / (1 - p))``:

* ``random``: each false loop joins two poses drawn uniformly, more than
  `min_separation` ids apart;
* ``local``: the second pose lies within `local_window` ids of the first (but more
  than `min_separation` away): a place confused with one just visited;
* ``grouped``: false loops come in groups of `group_size` between two random places
  ``i, j``: the edges ``(i + k, j + k)``, k = 0 .. group_size - 1, all implied by one
  wrong transform ``T`` of ``j`` in ``i``'s frame, composed with the odometry
  chain, so they agree with each other exactly (perceptual aliasing: a sequence
  of scans matched to the wrong corridor);
* ``local-grouped``: groups as above with ``j`` within `local_window` of ``i``.

Every false loop carries the information matrix of a randomly drawn true loop, and
``random`` and ``local`` its measurement too (as plausible as a real loop, between
the wrong poses); a group's ``T`` is a randomly drawn true loop's measurement.
Measurements are (x, y, theta) [m, rad] in 2D or 4x4 in 3D, pose of ``j`` in ``i``'s
frame; the odometry chain is `slam.optimize.initial_guess` ``"odometry"``.
No pair already joined by a constraint is used twice, and given the outlier-free
optimum no false loop is one that optimum already obeys (a copied measurement can
be right by chance, above all between poses close in the sequence).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from slam.optimize import default_outlier_residual, initial_guess
from slam.pose_graph import (
    Constraint,
    PoseGraph,
    relative_compose,
    relative_pose,
    whitened_residual,
)

Array = NDArray[np.float64]
POLICIES = ("random", "local", "grouped", "local-grouped")
LOCAL_WINDOW = 20  # ids: how close in the sequence a `local` false loop's poses are


def parse_policies(text: str) -> list[str]:
    """Policy names from a comma-separated list, checked (raises UserError for `--policy`)."""
    names = [p.strip() for p in text.split(",") if p.strip()]
    bad = [p for p in names if p not in POLICIES]
    if bad or not names:
        raise UserError(f"--policy: unknown policy {', '.join(bad) or text!r}; "
                        f"choose from {', '.join(POLICIES)}")
    return names


def _partner(i: int, n: int, local: bool, rng: np.random.Generator, window: int) -> int:
    """Index of the second pose of a false loop starting at index `i` (of `n`)."""
    if not local:
        return int(rng.integers(0, n))
    return int(np.clip(i + rng.choice([-1, 1]) * rng.integers(1, window + 1), 0, n - 1))


def _random(
    graph: PoseGraph, n_false: int, rng: np.random.Generator, min_separation: int,
    taken: set[tuple[int, int]], agrees: Callable[[Constraint], bool],
) -> list[Constraint]:
    """The ``random`` policy, drawing pairs in batches (the random stream of earlier
    versions, so a seed gives the same false loops as before)."""
    keys = np.array(graph.keys)
    n_true = len(graph.loops)
    false: list[Constraint] = []
    while len(false) < n_false:
        need = 2 * (n_false - len(false)) + 16
        a, b = rng.choice(keys, need), rng.choice(keys, need)
        template = rng.integers(0, n_true, need)
        for i, j, k in zip(a.tolist(), b.tolist(), template.tolist(), strict=True):
            pair = (min(i, j), max(i, j))
            if abs(i - j) <= min_separation or pair in taken:
                continue
            t = graph.loops[k]
            c = Constraint(i, j, t.measurement.copy(), t.information.copy())
            if agrees(c):
                continue
            taken.add(pair)
            false.append(c)
            if len(false) == n_false:
                break
    return false


def inject_false_loops(
    graph: PoseGraph,
    ratio: float,
    rng: np.random.Generator,
    policy: str = "random",
    *,
    group_size: int = 10,
    min_separation: int = 10,
    local_window: int = LOCAL_WINDOW,
    reference: dict[int, Array] | None = None,
) -> tuple[PoseGraph, list[int]]:
    """A copy of `graph` whose loops are a fraction `ratio` false; returns the false indices.

    The loops of the copy are shuffled (false ones are not all at the end).  With
    `reference` (the outlier-free optimum, id -> pose), a drawn loop that the reference
    already obeys (whitened residual at most the chi-square 99% threshold of its dof) is
    true by chance, not false, and is drawn again; a group is then kept only if none of
    its members is.
    """
    if policy not in POLICIES:
        raise UserError(f"policy: unknown {policy!r}; choose from {', '.join(POLICIES)}")
    if not 0.0 <= ratio < 1.0:
        raise UserError(f"outlier ratio must be in [0, 1), got {ratio}")
    if group_size < 1:
        raise UserError(f"group_size must be at least 1, got {group_size}")
    if not graph.loops:
        raise UserError("the graph has no loop-closure edges to mix false ones with")
    if local_window <= min_separation and policy.startswith("local"):
        raise UserError(f"local_window ({local_window}) must exceed min_separation "
                        f"({min_separation})")
    n_true = len(graph.loops)
    n_false = round(n_true * ratio / (1.0 - ratio))
    keys = graph.keys
    n = len(keys)
    local = policy.startswith("local")
    size = group_size if policy.endswith("grouped") else 1
    chain = initial_guess(graph, "odometry") if size > 1 else graph.initial
    taken = {(min(c.i, c.j), max(c.i, c.j)) for c in graph.odometry + graph.loops}
    threshold = default_outlier_residual(graph.dim)

    def agrees(c: Constraint) -> bool:
        return reference is not None and whitened_residual(c, reference, graph.dim) <= threshold

    false: list[Constraint] = []
    if policy == "random":
        false = _random(graph, n_false, rng, min_separation, taken, agrees)
    attempts = 0
    while len(false) < n_false:
        attempts += 1
        if attempts > 1000 * (n_false + 10):
            raise UserError(f"cannot place {n_false} false loops ({policy}) in this graph")
        a = int(rng.integers(0, n))
        b = _partner(a, n, local, rng, local_window)
        t = graph.loops[int(rng.integers(0, n_true))]
        group = []
        for k in range(min(size, n_false - len(false))):
            if a + k >= n or b + k >= n:
                break
            i, j = keys[a + k], keys[b + k]
            pair = (min(i, j), max(i, j))
            if abs(i - j) <= min_separation or pair in taken or pair in group:
                break
            group.append(pair)
        if not group:
            continue
        members = []
        for i, j in zip(keys[a : a + len(group)], keys[b : b + len(group)], strict=True):
            measurement = t.measurement.copy()
            if size > 1:  # T_k = (x_a^-1 x_i)^-1 T (x_b^-1 x_j) along the odometry chain
                left = relative_pose(chain[keys[a]], chain[i], graph.dim)
                right = relative_pose(chain[keys[b]], chain[j], graph.dim)
                measurement = relative_compose(
                    relative_pose(left, t.measurement, graph.dim), right, graph.dim)
            members.append(Constraint(i, j, measurement, t.information.copy()))
        if any(agrees(c) for c in members):
            continue
        taken.update(group)
        false.extend(members)
    corrupted = PoseGraph(
        graph.dim, dict(graph.initial), list(graph.odometry), list(graph.loops), set(graph.fixed)
    )
    order = rng.permutation(n_true + n_false)
    merged = graph.loops + false
    corrupted.loops = [merged[k] for k in order]
    position = np.empty_like(order)
    position[order] = np.arange(len(order))
    return corrupted, sorted(position[n_true:].tolist())
