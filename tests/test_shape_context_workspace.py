"""`shape_context_kernel._workspace`: the work arrays `distances` and `all_pairs` share."""

from __future__ import annotations

import numpy as np

from loopclosure.matchers.shape_context_kernel import _pair, _workspace, harmonic_table


def test_the_workspace_has_the_shapes_and_types_of_the_assignment():
    full, u, v, p, way, minv, used, visited, key, row = _workspace(3)
    assert full.shape == (3, 3) and full.dtype == np.float64
    for a in (u, v, minv, key, row):
        assert a.shape == (4,) and a.dtype == np.float64
    for a in (p, way, visited):
        assert a.shape == (4,) and a.dtype == np.int64
    assert used.shape == (4,) and used.dtype == np.bool_


def test_a_pair_solved_in_the_workspace_costs_what_is_worked_out_by_hand():
    # Two shapes of 2 points, 2 bins; counts A = [[1, 0], [0, 1]], B = A[::-1].
    # h = A / (n - 1) = A: row 0 of a against row 1 of b is the same histogram (cost 0),
    # against row 0 the two bins differ wholly: 1/2 (1 + 1) = 1.  The optimal assignment
    # pairs equal rows, the dummy with the dummy: mean cost 0.
    a = np.array([[1, 0], [0, 1]], dtype=np.uint16)
    b_t = np.ascontiguousarray(a[::-1].T)
    table = harmonic_table(1)
    sums = a.sum(axis=1).astype(np.float64)
    work = _workspace(2 + 1)
    assert _pair(a, b_t, sums, sums, table, 1, 0.25, *work) == 0.0
    # Disjoint bins: every real pair costs 1.  Assignments of the 3 x 3 matrix with
    # one dummy (0.25 against a real point, 0 against the dummy): both real pairs and
    # dummy-dummy, 1 + 1 + 0 = 2; or one real pair, a real row on the dummy column and
    # the dummy row on a real column, 1 + 0.25 + 0.25 = 1.5, the optimum: mean 0.75.
    c = np.array([[1, 0, 0, 0], [0, 1, 0, 0]], dtype=np.uint16)
    d_t = np.ascontiguousarray(np.array([[0, 0, 1, 0], [0, 0, 0, 1]], dtype=np.uint16).T)
    sums_c = c.sum(axis=1).astype(np.float64)
    assert _pair(c, d_t, sums_c, sums_c, table, 1, 0.25, *_workspace(3)) == 0.75
