"""The free-space models side by side of `benchmarks/refused_places.py`, by hand."""

from __future__ import annotations

import numpy as np
import pytest

from data import se2
from loopclosure.free_space import RangeImage
from tests.helpers import load_benchmark


def _ranges(scans: list[np.ndarray]) -> np.ndarray:
    return np.array([RangeImage(s).ranges for s in scans], np.float32)


def test_every_model_and_the_conflicts_classes_at_one_pose() -> None:
    rp = load_benchmark("refused_places")
    # The candidate: (5, 0) seen by a scan at its origin, (2, 2) by a scan at (2, -2)
    # facing +y.  The query: (5, 0) and (1, 1), both seen by one scan at its origin.
    side = np.array([2.0, -2.0, np.pi / 2])
    c_pts = np.array([[5.0, 0.0], [2.0, 2.0]])
    cand = rp.Side(c_pts, np.vstack([np.zeros(3), side]),
                   _ranges([c_pts[:1], se2.transform_points(se2.inverse(side), c_pts[1:])]),
                   720, 2)
    q_pts = np.array([[5.0, 0.0], [1.0, 1.0]])
    query = rp.Side(q_pts, np.zeros((1, 3)), _ranges([q_pts]), 720, 2)
    out = rp.models_at(query, cand, np.zeros(3), 0.1, 0.3)
    # (5, 0) is a hit both ways.  (1, 1) lies before the candidate's (2, 2) seen from
    # its origin, (1): a conflict; no scan of the candidate cast a ray through it:
    # invented, none under (1') / (4) / (5); 1.41 m from the candidate's points: not a
    # near miss.  (2, 2) lies behind the query's (1, 1): nothing.
    assert out["hits"] == 2
    assert out["k"] == pytest.approx(2 / 3) and out["kn"] == pytest.approx(2 / 3)
    for m in ("s", "w", "ks", "kw"):
        assert out[m] == 1.0
    assert (out["conflicts"], out["invented"], out["near"], out["change"], out["far"],
            out["c_in_q"]) == (1, 1, 0, 0, 0, 0)
    # The other way round the query's (1, 1) is the candidate's, and the conflict is
    # the candidate's point in the query's free space.
    back = rp.models_at(cand, query, np.zeros(3), 0.1, 0.3)
    assert back["hits"] == 2 and back["k"] == pytest.approx(2 / 3)
    assert (back["conflicts"], back["c_in_q"]) == (1, 1)
