"""`loopclosure.prior_screen.screen_passes`: the pose-gated check's screens stopped once
they pass, on hand-checked points; the check's result unchanged by the stop."""

from __future__ import annotations

import numpy as np
import pytest

from data import se2
from loopclosure import prior_screen
from loopclosure.fast_icp import TARGET_GRID_CELL, GridTarget, overlap_screen
from loopclosure.geometric_check import GeometricCheckConfig, verify
from loopclosure.prior_screen import screen_passes

# A straight wall along x (y = 0, x in [0, 4], every 2 cm): every point line-like.
WALL = np.column_stack([np.linspace(0.0, 4.0, 201), np.zeros(201)])
# Source points 0, 0.5, beyond the gate, and 0.2 m from the wall.
SOURCE = np.array([[1.0, 0.0], [2.0, 0.5], [3.0, 2.0], [1.5, 0.2]])
IDENTITY = np.zeros((1, 3))


def _grid(points=WALL):
    return GridTarget(points, GeometricCheckConfig().icp, TARGET_GRID_CELL, lazy=True)


def test_a_screen_that_fails_returns_the_full_maxima() -> None:
    # Score at gate 1: (1 + (1 - 0.5^2) + 0 + (1 - 0.2^2)) / 4 = 2.71 / 4; bound at
    # reach 0.55: three of four points.
    passed, score, bound = screen_passes(SOURCE, _grid(), IDENTITY, 1.0, 0.55, 0.7, 0.5)
    assert not passed
    assert score == pytest.approx(2.71 / 4, abs=1e-12) and bound == 0.75
    scores, bounds = overlap_screen(SOURCE, _grid(), IDENTITY, 1.0, 0.55)
    assert (score, bound) == (scores.max(), bounds.max())  # to the bit
    assert not screen_passes(SOURCE, _grid(), IDENTITY, 1.0, 0.55, 0.2, 0.8)[0]


def test_a_screen_stops_at_the_point_where_both_bars_are_reached() -> None:
    # After point 0: score 1/4 >= 0.2, bound 1/4 < 0.5; after point 1: 1.75/4 and 2/4.
    grid = _grid()
    passed, score, bound = screen_passes(SOURCE, grid, IDENTITY, 1.0, 0.55, 0.2, 0.5)
    assert passed and (score, bound) == (1.75 / 4, 0.5)
    # The stop left the map points near the last two source points unresolved.
    full = _grid()
    overlap_screen(SOURCE, full, IDENTITY, 1.0, 0.55)
    assert np.sum(grid.kind >= 0) < np.sum(full.kind >= 0)
    # Bars of 0 (screens off) pass before any point.
    assert screen_passes(SOURCE, _grid(), IDENTITY, 1.0, 0.55, 0.0, 0.0) == (True, 0.0, 0.0)


def test_later_guesses_and_empty_inputs() -> None:
    # The first guess puts every point 10 m away; the second on the wall.
    guesses = np.array([[0.0, 10.0, 0.0], [0.0, 0.0, 0.0]])
    passed, score, bound = screen_passes(SOURCE, _grid(), guesses, 1.0, 0.55, 0.7, 0.7)
    assert not passed and score == pytest.approx(2.71 / 4, abs=1e-12) and bound == 0.75
    # The second guess's full sums reach bars the first guess's do not.
    passed, score, bound = screen_passes(SOURCE, _grid(), guesses, 1.0, 0.55, 0.6, 0.7)
    assert passed and score == pytest.approx(2.71 / 4, abs=1e-12) and bound == 0.75
    assert screen_passes(np.zeros((0, 2)), _grid(), guesses, 1.0, 0.55, 0.2, 0.5) == (
        False, 0.0, 0.0)
    assert screen_passes(SOURCE, _grid(), np.zeros((0, 3)), 1.0, 0.55, 0.2, 0.5) == (
        False, 0.0, 0.0)


def _full_screen(source, grid, guesses, gate, reach, min_score, min_bound):
    """The screen without the stop: every point of every guess."""
    scores, bounds = overlap_screen(source, grid, guesses, gate, reach)
    s, b = float(scores.max(initial=0.0)), float(bounds.max(initial=0.0))
    return s >= min_score and b >= min_bound, s, b


def _room(pose):
    t = np.linspace(0.0, 1.0, 200)
    walls = [((0, 0), (6, 0)), ((6, 0), (6, 3)), ((6, 3), (3, 3)), ((3, 3), (3, 5)),
             ((3, 5), (0, 5)), ((0, 5), (0, 0))]
    pts = np.vstack([np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)])
                     for (x0, y0), (x1, y1) in walls])
    return se2.transform_points(se2.inverse(pose), pts)


@pytest.mark.parametrize("offset, sigma", [((0.15, -0.1, 0.05), 0.1), ((0.6, 0.4, 0.2), 0.3),
                                           ((0.1, 0.0, 0.0), 0.05), ((25.0, 0.0, 0.0), 0.3)])
def test_the_check_is_the_same_with_and_without_the_stop(monkeypatch, offset, sigma) -> None:
    """Every figure of a check from a prior (accepted, rejected, screened) is the
    same whether the screen stops or visits everything."""
    a, b = np.array([1.0, 1.0, 0.3]), np.array([1.6, 0.8, 1.1])
    cand, query = _room(a), _room(b)
    cfg = GeometricCheckConfig()
    prior = se2.compose(se2.between(a, b), np.array(offset))
    cov = np.diag([sigma, sigma, sigma / 5]) ** 2
    stopped = verify(query, None, prior=prior, prior_covariance=cov, config=cfg,
                     grid=_grid(cand))
    monkeypatch.setattr(prior_screen, "screen_passes", _full_screen)
    full = verify(query, None, prior=prior, prior_covariance=cov, config=cfg,
                  grid=_grid(cand))
    assert stopped.reason == full.reason and stopped.hypotheses == full.hypotheses
    for name in ("relative", "covariance", "degenerate_axis"):
        assert getattr(stopped, name).tobytes() == getattr(full, name).tobytes()
    assert (stopped.fitness, stopped.inlier_ratio, stopped.rms, stopped.degeneracy,
            stopped.margin) == (full.fitness, full.inlier_ratio, full.rms, full.degeneracy,
                                full.margin)
