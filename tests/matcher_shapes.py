"""Polygons the matcher tests share: squares, random stars and blobs, noisy rooms.

Plain functions and constants (no fixtures), imported by the per-matcher test modules
and by `tests/test_matcher_contract.py`.  Every generator draws from its random source
in a fixed order, so a seed always gives the same polygon.  Lengths in metres.
"""

from __future__ import annotations

import numpy as np

from loopclosure.polygon import Polygon

SQUARE = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
"""The 2 x 2 m square about the origin."""

UNIT_SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
"""The 1 x 1 m square with a corner at the origin."""

BOX = np.array([[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]])
"""The 4 x 4 m square about the origin, from its lower left corner."""

NOTCHED = np.array(
    [[-1, -1], [3, -1], [3, 1], [2, 1], [2, -0.5], [1, -0.5], [1, 1], [-1, 1]], dtype=float
)
"""Box [-1, 3] x [-1, 1] with a notch [1, 2] x [-0.5, 1] cut from the top: the ray along +x
from the origin leaves at x = 1, re-enters at x = 2 and leaves again at x = 3."""

C_SHAPE = np.array(
    [[0, 0], [4, 0], [4, 1], [1, 1], [1, 3], [4, 3], [4, 4], [0, 4]], dtype=float
)
"""A C open to +x, 4 x 4 m: its centroid lies outside the polygon."""


def regular(n: int, radius: float) -> Polygon:
    """Regular n-gon of circumradius `radius` about the origin, vertex 0 on +x."""
    t = np.arange(n) * 2 * np.pi / n
    return Polygon(radius * np.column_stack([np.cos(t), np.sin(t)]))


def random_star(rng: np.random.Generator, n: int = 40) -> Polygon:
    """Random star-shaped polygon about the origin, radii 2-6 m (spiky)."""
    a = np.sort(rng.uniform(0, 2 * np.pi, n))
    r = rng.uniform(2, 6, n)
    return Polygon(np.column_stack([r * np.cos(a), r * np.sin(a)]))


def smooth_star(rng: np.random.Generator, n: int = 40) -> Polygon:
    """Random smooth star-shaped polygon about the origin ("a room"): radius 4 m plus 4
    harmonics of random amplitude (sigma 0.5 m) and phase."""
    a = np.sort(rng.uniform(0, 2 * np.pi, n))
    k = np.arange(1, 5)
    r = 4 + (rng.normal(0, 0.5, (4, 1)) * np.cos(k[:, None] * a + rng.uniform(0, 6, (4, 1))))
    r = r.sum(axis=0) - 3 * 4
    return Polygon(np.column_stack([r * np.cos(a), r * np.sin(a)]))


def blob(seed: int, n: int = 150) -> Polygon:
    """Random smooth star-shaped polygon, radius 3 m +- lobes of 2..6 cycles (up to 0.8 m)."""
    rng = np.random.default_rng(seed)
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    k = np.arange(2, 7)
    amp, phase = rng.uniform(-0.8, 0.8, 5), rng.uniform(0, 2 * np.pi, 5)
    r = 3.0 + (amp[:, None] * np.cos(k[:, None] * ang[None, :] + phase[:, None])).sum(axis=0)
    return Polygon(np.column_stack([r * np.cos(ang), r * np.sin(ang)]))


def lobed_star(
    lobes: int, amp: float, n: int = 200, scale: float = 5.0, seed: int = 0, noise: float = 0.0
) -> Polygon:
    """Star-shaped 'room' around the origin: r = scale (1 + amp sin(lobes a) + 0.2 cos a),
    plus Gaussian range noise of `noise` * scale."""
    rng = np.random.default_rng(seed)
    ang = np.linspace(-np.pi, np.pi, n, endpoint=False)
    r = scale * (1.0 + amp * np.sin(lobes * ang + 0.3) + 0.2 * np.cos(ang))
    r = r + rng.normal(0.0, noise * scale, n)
    return Polygon(np.column_stack([r * np.cos(ang), r * np.sin(ang)]))


_ROOMS = {
    0: np.array([[0, 0], [8, 0], [8, 5], [0, 5]], float),  # rectangle room
    1: np.array([[0, 0], [8, 0], [8, 3], [3, 3], [3, 8], [0, 8]], float),  # L room
    2: np.array([[0, 0], [12, 0], [12, 2], [0, 2]], float),  # corridor
}


def room(
    kind: int, rng: np.random.Generator, noise: float = 0.03, random_start: bool = False
) -> Polygon:
    """One of three kinds of place (0 rectangle, 1 L, 2 corridor), 120 boundary samples
    with vertex noise `noise` [m], a random pose, and with `random_start` a random first
    vertex (so a matcher must find the cyclic correspondence)."""
    pts = Polygon(_ROOMS[kind]).resample(120)
    if random_start:
        pts = np.roll(pts, rng.integers(120), axis=0)
    pts = pts + rng.normal(0, noise, (120, 2))
    return Polygon(pts).rotated(rng.uniform(-np.pi, np.pi)).translated(rng.normal(0, 1, 2))
