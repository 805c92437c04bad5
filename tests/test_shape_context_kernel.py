"""The compiled Hungarian method gives, to the bit, the sum of the textbook loop.

`shape_context_kernel._hungarian` visits only the columns off the path tree and defers
each column's ``minv -= delta``; the reference below is the textbook loop over all
columns (Kuhn-Munkres with potentials, as the kernel was first written) in plain
Python floats, which round as the compiled float64 code does.  Equal sums to the bit
mean the same assignment was chosen among equally cheap ones.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from loopclosure.matchers.shape_context_kernel import assignment_cost


def textbook_assignment_cost(c: np.ndarray) -> float:
    """Sum of matched costs by the textbook loop (greedy start, then one shortest
    augmenting path per free row, every column scanned and updated at each step)."""
    c = [[float(x) for x in row] for row in c]
    n = len(c)
    inf = math.inf
    u, v = [0.0] * (n + 1), [0.0] * (n + 1)
    p, way = [0] * (n + 1), [0] * (n + 1)
    for i in range(1, n + 1):
        u[i] = min(c[i - 1])
    for j in range(1, n + 1):
        best = inf
        for i in range(1, n + 1):
            r = c[i - 1][j - 1] - u[i]
            if r < best:
                best = r
        v[j] = best
    matched = [False] * (n + 1)
    for i in range(1, n + 1):
        for j in range(1, n + 1):
            if p[j] == 0 and c[i - 1][j - 1] - u[i] - v[j] <= 0.0:
                p[j] = i
                matched[i] = True
                break
    for f in [i for i in range(1, n + 1) if not matched[i]]:
        p[0] = f
        j0 = 0
        minv = [inf] * (n + 1)
        used = [False] * (n + 1)
        while True:
            used[j0] = True
            i0 = p[j0]
            delta, j1 = inf, 0
            for j in range(1, n + 1):
                if not used[j]:
                    cur = c[i0 - 1][j - 1] - u[i0] - v[j]
                    if cur < minv[j]:
                        minv[j] = cur
                        way[j] = j0
                    if minv[j] < delta:
                        delta = minv[j]
                        j1 = j
            for j in range(n + 1):
                if used[j]:
                    u[p[j]] += delta
                    v[j] -= delta
                else:
                    minv[j] -= delta
            j0 = j1
            if p[j0] == 0:
                break
        while True:
            j1 = way[j0]
            p[j0] = p[j1]
            j0 = j1
            if j0 == 0:
                break
    total = 0.0
    for j in range(1, n + 1):
        total += c[p[j] - 1][j - 1]
    return total


@pytest.mark.parametrize("levels", [0, 7, 2])
def test_compiled_assignment_equals_the_textbook_loop_to_the_bit(levels: int) -> None:
    """Random costs; with `levels`, rounded to that many sevenths (many equally cheap
    assignments: which one is chosen shows in the sum; 2: mostly zeros)."""
    rng = np.random.default_rng(15 + levels)
    for _ in range(40):
        n = int(rng.integers(1, 50))
        c = rng.random((n, n))
        if levels:
            c = np.round(c * levels) / 7
        assert assignment_cost(c) == textbook_assignment_cost(c)


def test_compiled_assignment_equals_the_textbook_loop_on_shape_context_costs() -> None:
    """Costs of real shape-context histograms (integer counts: many exact ties)."""
    from loopclosure.matchers.shape_context import ShapeContextMatcher
    from loopclosure.matchers.shape_context_kernel import chi2_costs
    from tests.matcher_shapes import blob

    m = ShapeContextMatcher(kernel="numba", n_points=30)
    a = m.describe(blob(1))
    db = np.stack([m.describe(blob(s)) for s in (2, 3, 4)])
    for c in chi2_costs(a, db, m._table):
        assert assignment_cost(c) == textbook_assignment_cost(c)
