"""Selected entries of H^-1 (`slam.selected_inverse`) against a dense inverse, and the
innovation blocks built on them against the full-solve path."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from slam import innovation
from slam.group_recheck import joint_costs, loop_groups
from slam.innovation import InnovationTest
from slam.selected_inverse import SelectedInverse
from tests.test_segment_variance import _laps, _solved


def _spd(n: int = 40, seed: int = 1) -> sp.csc_matrix:
    a = sp.random(n, n, density=0.08, random_state=seed)
    return (a.T @ a + sp.eye(n)).tocsc()


@pytest.mark.parametrize(("case", "symmetric"),
                         [("spd", True), ("spd", False), ("pivoted", True), ("pivoted", False)])
def test_entries_and_blocks_equal_the_dense_inverse(case: str, symmetric: bool) -> None:
    if case == "spd":  # the symmetric LU of `slam.least_squares.factor_information`
        h = _spd()
        lu = splu(h, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                  options={"SymmetricMode": True})
    else:  # a non-symmetric matrix whose LU pivots off the diagonal
        h = (sp.random(40, 40, density=0.08, random_state=2)
             + 5.0 * sp.eye(40, k=7) + 5.0 * sp.eye(40, k=-33)).tocsc()
        lu = splu(h)
    assert np.array_equal(lu.perm_r, lu.perm_c) == (case == "spd")
    dense = np.linalg.inv(h.toarray())
    # A claim of symmetry is used only with one permutation for rows and columns (the
    # pivoted case falls back to solving by U^T).
    selected = SelectedInverse(lu, symmetric=symmetric)
    rows, cols = np.random.default_rng(0).integers(0, 40, (2, 300))
    np.testing.assert_allclose(selected.entries(rows, cols), dense[rows, cols],
                               rtol=0, atol=1e-13)
    a, b = np.array([0, 3, 30, 3, 37]), np.array([6, 0, 34, 0, 37])
    blocks = selected.blocks(a, b, 3)
    assert blocks.shape == (5, 3, 3)
    for t in range(5):
        np.testing.assert_allclose(blocks[t], dense[a[t]:a[t] + 3, b[t]:b[t] + 3],
                                   rtol=0, atol=1e-13)
    assert selected.blocks(np.zeros(0, int), np.zeros(0, int), 3).shape == (0, 3, 3)


def _laps_test():
    graph, _ = _laps(n=120, every=3)
    factors, _ = graph.factor_graph()
    values = _solved(graph)
    test = InnovationTest(factors, values, graph.keys, 3)
    unit = [graph.between_factor(lp) for lp in graph.loops]
    # A dense reference: H = A^T A of the whitened Jacobian (columns: poses in sorted-key
    # order, as in `InnovationTest`), inverted.
    rows, cols, data = factors.linearize(values).sparseJacobian_()
    keep = cols <= test.n  # 1-based; the last column is the right-hand side
    jac = np.zeros((int(rows.max()), test.n))
    np.add.at(jac, (rows[keep].astype(int) - 1, cols[keep].astype(int) - 1), data[keep])
    return graph, test, unit, np.linalg.inv(jac.T @ jac)


def _dense_gram(test: InnovationTest, unit, cov: np.ndarray) -> np.ndarray:
    """``M = B H^-1 B^T`` of every factor of `unit`, with the dense ``H^-1``."""
    _, bi, bj, ci, cj = test._linearised(unit)
    out = []
    for q in range(len(bi)):
        big = np.zeros((3, test.n))
        big[:, ci[q]:ci[q] + 3] += bi[q]
        big[:, cj[q]:cj[q] + 3] += bj[q]
        out.append(big @ cov @ big.T)
    return np.array(out)


def test_innovation_blocks_equal_the_dense_reference_and_the_full_solves(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    _, test, unit, cov = _laps_test()
    b, gram = test.blocks(unit)
    reference = _dense_gram(test, unit, cov)
    np.testing.assert_allclose(gram, reference, rtol=1e-9, atol=1e-12)
    monkeypatch.setattr(innovation, "SELECTED_INVERSE", False)
    b_old, gram_old = test.blocks(unit)
    np.testing.assert_array_equal(b, b_old)
    np.testing.assert_allclose(gram, gram_old, rtol=1e-9, atol=1e-12)


def test_joint_costs_equal_the_full_solves(monkeypatch: pytest.MonkeyPatch) -> None:
    graph, test, unit, _ = _laps_test()
    groups = [g for g in loop_groups(graph.loops, range(len(unit)), window=3) if len(g) > 1]
    groups += [[0, 5, 17], [2]]  # loops far apart, and a single loop
    new = [joint_costs(test, unit, groups, removal=r) for r in (True, False)]
    monkeypatch.setattr(innovation, "SELECTED_INVERSE", False)
    old = [joint_costs(test, unit, groups, removal=r) for r in (True, False)]
    np.testing.assert_allclose(new, old, rtol=1e-9)


@pytest.mark.parametrize("count", [5, 12, 40])
def test_gains_from_selected_entries_equal_the_full_solves(
    monkeypatch: pytest.MonkeyPatch, count: int,
) -> None:
    _, test, unit, cov = _laps_test()
    candidates = unit[:count]
    monkeypatch.setattr(innovation, "SELECTED_GAINS_POSES", (0, 10**9))
    new = test.gains(candidates)
    monkeypatch.setattr(innovation, "SELECTED_GAINS_POSES", (0, 0))
    old = test.gains(candidates)
    np.testing.assert_array_equal(new.b, old.b)
    np.testing.assert_array_equal(new.ri, old.ri)
    np.testing.assert_array_equal(new.rj, old.rj)
    np.testing.assert_allclose(new.Y, old.Y, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(new.M, old.M, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(new.M, _dense_gram(test, candidates, cov), rtol=1e-9,
                               atol=1e-12)
