"""Warm starts of related least-squares solves (`slam.warm_starts`) and their use by the
calibrated choice and `refine_tls`: the same decisions as from the own starts."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from slam import calibrated_choice as choice_module
from slam.calibrated_choice import calibrated_choices
from slam.consistency import refine_tls, tls_cost
from slam.least_squares import StickySolver
from slam.optimize import optimize
from slam.warm_starts import WarmStarts
from tests.test_recheck import loose_square_candidates


def _prior_at_origin() -> gtsam.NonlinearFactorGraph:
    """One unit-information prior on pose 0 at the origin: error 0.5 (x^2 + y^2 + t^2)."""
    factors = gtsam.NonlinearFactorGraph()
    factors.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(), gtsam.noiseModel.Unit.Create(3)))
    return factors


def _at(x: float) -> gtsam.Values:
    values = gtsam.Values()
    values.insert(0, gtsam.Pose2(x, 0.0, 0.0))
    return values


def test_the_start_is_the_held_solution_of_least_error() -> None:
    factors = _prior_at_origin()
    held = WarmStarts([_at(2.0)])
    near = held.hold(_at(0.5))  # error 0.125 against the own start's 0.5 and 2.0
    assert near.atPose2(0).x() == 0.5 and len(held.values) == 2
    assert held.start(factors, _at(1.0)).atPose2(0).x() == 0.5
    assert held.start(factors, _at(0.1)).atPose2(0).x() == 0.1  # the own start is nearer
    # Ties keep the own start: -0.5 costs what 0.5 does.
    assert held.start(factors, _at(-0.5)).atPose2(0).x() == -0.5
    assert WarmStarts().start(factors, _at(3.0)).atPose2(0).x() == 3.0


@pytest.mark.parametrize("warm", [False, True])
def test_the_calibrated_choice_is_the_same_from_warm_starts(
    monkeypatch: pytest.MonkeyPatch, warm: bool
) -> None:
    loose, _, candidates = loose_square_candidates()
    held: list[int] = []
    hold = WarmStarts.hold
    monkeypatch.setattr(WarmStarts, "hold",
                        lambda self, values: held.append(1) or hold(self, values))
    monkeypatch.setattr(choice_module, "WARM_STARTS", warm)
    choices = calibrated_choices(loose, candidates, solver=StickySolver())
    assert choices is not None
    assert (choices.stated, choices.stiff) == (1, 1)  # as `test_recheck` hand-checks it
    assert choices.stiff_factor < 0.1
    assert (len(held) > 0) == warm  # every calibrated solve held when warm, none when not
    monkeypatch.setattr(choice_module, "WARM_STARTS", not warm)
    other = calibrated_choices(loose, candidates, solver=StickySolver())
    assert other is not None and (other.stated, other.stiff) == (1, 1)
    assert other.stiff_factor == pytest.approx(choices.stiff_factor, rel=1e-4)


def test_refine_tls_from_warm_starts_decides_the_same_loops() -> None:
    loose, start, _ = loose_square_candidates()
    none = np.zeros(len(loose.loops))  # from the odometry's solution: every loop re-decided
    plain, plain_w = refine_tls(loose, start, none)
    starts = WarmStarts()
    warm, warm_w = refine_tls(loose, start, none, starts=starts)
    np.testing.assert_array_equal(warm_w, plain_w)
    assert plain_w[-1] == 0.0 and plain_w[:-1].all()  # the true loops in, the false one out
    assert len(starts.values) == 2  # the odometry alone, then with the true loops
    # Refined again from the odometry's solution with the true loops: the held solution
    # of that very graph is the start, and the result is the first refinement's.
    again, again_w = refine_tls(loose, start, plain_w, starts=starts)
    np.testing.assert_array_equal(again_w, plain_w)
    assert len(starts.values) == 3
    for k in loose.keys:
        for other in (warm, again):
            np.testing.assert_allclose(other.atPose2(k).translation(),
                                       plain.atPose2(k).translation(), atol=1e-6)
    # `solved`: the given solution is held as it is, and nothing is solved.
    held = WarmStarts()
    same, same_w = refine_tls(loose, plain, plain_w, solved=True, starts=held)
    assert same is plain and held.values == [plain]
    np.testing.assert_array_equal(same_w, plain_w)


def test_a_candidate_judged_at_its_own_factor_is_not_solved_again(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from slam.variance_components import with_information_scaled
    from tests.test_backend import _square_graph

    # Odometry stated far stiffer than its noise: both candidates' own factors are capped
    # at 1, so judging one at the other's factor is its own (already solved) graph.
    graph, _ = _square_graph(noise=0.02, laps=2)
    stiff = with_information_scaled(graph, 1000.0)
    start = stiff.gtsam_values(optimize(stiff, "none", init="odometry").poses)
    n = len(stiff.loops)
    candidates = []
    for w in (np.ones(n), np.r_[np.ones(n - 1), 0.0]):
        values, weights = refine_tls(stiff, start, w, barred=[] if w[-1] else [n - 1])
        candidates.append((values, weights, tls_cost(stiff, values)))
    outcomes, calls = {}, {}
    for warm in (False, True):
        monkeypatch.setattr(choice_module, "WARM_STARTS", warm)
        solver = StickySolver(memo=0)
        counted: list[int] = []
        solve = solver._solve
        monkeypatch.setattr(solver, "_solve",
                            lambda f, v, solve=solve, counted=counted: counted.append(1)
                            or solve(f, v))
        outcomes[warm] = calibrated_choices(stiff, candidates, solver=solver)
        calls[warm] = len(counted)
    assert outcomes[True] == outcomes[False]
    assert outcomes[True].stated_factor == outcomes[True].stiff_factor == 1.0
    # One `own_factor` round per candidate (capped at once); cold (and without a memo),
    # the judgement solves the other candidate again at factor 1.
    assert calls[True] == 2 and calls[False] == 2 + 1
