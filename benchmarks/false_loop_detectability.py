"""Benchmark: which injected false loops any loop-by-loop test could reject, and what the
back end obeys.

Run from the repository root::

    python benchmarks/false_loop_detectability.py [--data DIR] [--stated] [--no-segments]
        [--no-groups] [--candidates] CASE [CASE ...]
        # CASE = graph.g2o:scale:policy:ratio:seed, ratio in [0, 1)

For each case the graph's odometry information is multiplied by ``scale``, false loops
are injected as `eval robustness` does (`evaluation.outlier_policies.inject_false_loops`
against the clean optimum) and the robust back end (`slam.optimize` ``gnc``, incremental;
with ``--stated`` choosing among its candidates by the stated TLS cost instead of
`slam.calibrated_choice.calibrated_choice`) solves it from the odometry chain, first without the
final segment re-check (``admission``), then, unless ``--no-segments``, with it.  Printed
per solve: ATE against the clean optimum [m], false loops obeyed, true loops rejected,
``tls_gap`` (stated TLS cost of the result less the clean optimum's), seconds; between
the two, the segment re-check of the admission (`slam.segment_recheck.segment_recheck`): the
segment variance factors, the re-check's seconds, its gate, and every suspect (false or
true) with its leave-one-out innovation ``rho`` under the segment-calibrated odometry
and its innovation ``delta`` against the graph without the suspects, and every group
of agreeing loops the group test (`slam.group_recheck.group_recheck`; off with ``--no-groups``)
tested, with its false members, its joint leave-group-out innovation ``rho_G``, its
joint innovation ``delta_G`` against the graph without the round's suspect groups and
its gate (gtsam error units); then the
false loops that are *consistent with the outlier-free graph*: innovation ``delta``
against it (anchors, odometry and the loops the clean optimum obeys, linearised there,
`slam.consistency.admission_costs`, gtsam error units) below the TLS threshold ``c``,
and ``delta_odo``, the same against the anchors and odometry alone (the odometry's
covariance over the span the loop closes); with, for each, its span in ids, its
whitened residual at the clean optimum and under the result, and whether the result
obeys it.  Every obeyed false loop is listed.  Last, the largest leave-one-out
innovation of the graph's own true loops at the clean optimum (``0.5 b^T (I - M)^-1 b``,
`slam.loop_recheck.removal_costs`): a false loop whose ``delta`` is below it is more
consistent with the map than that true loop.

With ``--candidates``, first the candidates the time-ordered admission chooses among
(`slam.consistency.incremental_tls`'s rungs and gates, refined; the same loops listed
once): stated TLS cost, false loops kept, true loops left out, ATE against the clean
optimum [m], the odometry variance factor its own loops support
(`slam.calibrated_choice.own_factor`: estimate, redundancy and 99 % upper bound,
`Calibrated.upper_bound`), and the one `slam.calibrated_choice.calibrated_choice` picks.
A candidate bent by false loops shows a factor far above an outlier-free one's; when the
choice still picks it, the bent candidate is a fixed point of the choice's
iteration.  Then a trial of another choice (diagnostic only, not the back end's): ``A``
the calibrated choice's pick, ``B`` the candidate whose own factor has the smallest
upper bound; ``A`` *bends* ``B``'s segments when, over the segments of 100 poses where
``B`` has redundancy (`slam.segment_variance`), the pooled factor of ``A``'s odometry
residuals over ``B``'s exceeds Fisher's ``F`` 0.99 quantile; if so, ``B``'s loops are
solved under merged segment factors (``B``'s where it has redundancy, ``A``'s elsewhere)
and ``A``'s other loops offered back (innovation alone below ``c``, then
`slam.consistency.greedy_admission`); printed: the F statistic, the loops offered and
admitted (false among them) and the outcome's false loops kept and true loops left out.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import gtsam
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from scipy.special import fdtri

from data.g2o import read_g2o
from evaluation.outlier_policies import inject_false_loops
from evaluation.robustness import aligned_position_error, clean_optimum
from slam.calibrated_choice import calibrated_choice, own_factor
from slam.consistency import (
    InnovationTest,
    admission_costs,
    greedy_admission,
    incremental_tls,
    tls_cost,
    tls_threshold,
)
from slam.least_squares import StickySolver
from slam.loop_recheck import removal_costs
from slam.optimize import default_outlier_residual, initial_guess, optimize
from slam.pose_graph import PoseGraph, pose_dof, poses_from_values, whitened_residual
from slam.segment_recheck import segment_recheck
from slam.segment_variance import SegmentFactors, calibrated_odometry, segment_factors
from slam.variance_components import with_information_scaled


def _fixed(graph: PoseGraph) -> gtsam.NonlinearFactorGraph:
    factors = gtsam.NonlinearFactorGraph()
    for k in graph.anchor_keys():
        factors.add(graph.prior_factor(k))
    for c in graph.odometry:
        factors.add(graph.between_factor(c))
    return factors


def _solved(
    corrupted: PoseGraph, ref: dict, is_false: np.ndarray, stated: bool, segments: bool,
    label: str, groups: bool = True,
) -> tuple[object, np.ndarray]:
    """The back end's solution of `corrupted` and the whitened residual of every loop under
    it; prints its line (module docstring)."""
    dim = corrupted.dim
    threshold = default_outlier_residual(dim)
    start = time.perf_counter()
    solution = optimize(corrupted, "none", "gnc", init="odometry", gnc_start="incremental",
                        calibrated=not stated, segments=segments, groups=groups)
    seconds = time.perf_counter() - start
    res = np.array([whitened_residual(lp, solution.poses, dim) for lp in corrupted.loops])
    gap = (tls_cost(corrupted, corrupted.gtsam_values(solution.poses))
           - tls_cost(corrupted, corrupted.gtsam_values(ref)))
    print(f"{label}: ATE {aligned_position_error(solution.poses, ref, dim):.4f} m, "
          f"false obeyed {(is_false & (res <= threshold)).sum()}/{is_false.sum()}, "
          f"true rejected {(~is_false & (res > threshold)).sum()}, tls_gap {gap:.2f}, "
          f"{seconds:.1f} s ({solution.solver})")
    return solution, res


def _candidates(graph: PoseGraph, ref: dict, is_false: np.ndarray) -> None:
    """Prints the admission's candidates and the calibrated choice (module docstring)."""
    seen: dict = {}

    def capture(g: PoseGraph, candidates: list, **kwargs) -> int:
        seen.update(candidates=candidates, kwargs=kwargs)
        seen["pick"] = calibrated_choice(g, candidates, **kwargs)
        return seen["pick"]

    incremental_tls(graph, graph.gtsam_values(initial_guess(graph, "odometry")), choose=capture)
    if "candidates" not in seen:
        print("  candidates: one run finished (nothing to choose)")
        return
    unit, solver = seen["kwargs"]["unit"], seen["kwargs"].get("solver") or StickySolver()
    listed: set[bytes] = set()
    owns = {}
    for n, (values, weights, cost) in enumerate(seen["candidates"]):
        kept = np.asarray(weights) > 0.5
        if kept.tobytes() in listed:
            continue
        listed.add(kept.tobytes())
        own = owns[n] = own_factor(graph, values, weights, unit=unit, solver=solver,
                                   with_gains=False)
        ate = aligned_position_error(poses_from_values(values, graph.dim), ref, graph.dim)
        print(f"  candidate {n}: stated TLS cost {cost:.2f}, false in {(kept & is_false).sum()}, "
              f"true out {(~kept & ~is_false).sum()}, ATE {ate:.4f} m; own odometry factor "
              f"{own.estimate:.3g} (redundancy {own.redundancy:.1f}, upper bound "
              f"{own.upper_bound():.3g})")
    print(f"  calibrated choice: candidate {seen['pick']}")
    _stiff_trial(graph, seen["candidates"], seen["pick"], owns, unit, solver, is_false)


def _stiff_trial(
    graph: PoseGraph, candidates: list, a: int, owns: dict, unit: list, solver: StickySolver,
    is_false: np.ndarray,
) -> None:
    """The trial choice of the module docstring: stiffest candidate, F test, offer back."""
    b = min(owns, key=lambda n: owns[n].upper_bound())
    if b == a or (np.asarray(candidates[a][1]) > 0.5).tobytes() == (
            np.asarray(candidates[b][1]) > 0.5).tobytes():
        print(f"  stiffest candidate {b}: the same loops as the choice")
        return
    (va, wa, _), (vb, wb, _) = candidates[a], candidates[b]
    wa, wb = np.asarray(wa) > 0.5, np.asarray(wb) > 0.5
    fa, fb = segment_factors(graph, va, wa), segment_factors(graph, vb, wb)
    on = (fb.redundancy >= 1.0) & (fa.redundancy > 0.0)
    ra, rb = float(fa.redundancy[on].sum()), float(fb.redundancy[on].sum())
    if not on.any():
        print(f"  stiffest candidate {b}: no segment where both have redundancy")
        return
    sa = float((fa.raw[on] * fa.redundancy[on]).sum()) / ra
    sb = float((fb.raw[on] * fb.redundancy[on]).sum()) / rb
    quantile = float(fdtri(ra, rb, 0.99))
    print(f"  stiffest candidate {b}: on its {on.sum()} calibrated segments the choice's "
          f"factor {sa:.3g} vs {sb:.3g}, F {sa / sb:.2f} (0.99 quantile {quantile:.2f})")
    if not sa / sb > quantile:
        return
    merged = SegmentFactors(np.where(fb.redundancy >= 1.0, fb.factors, fa.factors), fb.raw,
                            fb.redundancy, fb.pooled, fb.segment)
    fixed = gtsam.NonlinearFactorGraph()
    for k in graph.anchor_keys():
        fixed.add(graph.prior_factor(k))
    for o in calibrated_odometry(graph, merged):
        fixed.add(graph.between_factor(o))
    for k in np.flatnonzero(wb):
        fixed.add(unit[k])
    test = InnovationTest(fixed, solver(fixed, vb), graph.keys, pose_dof(graph.dim))
    offer = np.flatnonzero(wa & ~wb)
    c = tls_threshold(graph.dim)
    admitted = np.zeros(0, dtype=np.int64)
    if len(offer):
        offer = offer[admission_costs(test.gains([unit[k] for k in offer])) < c]
    if len(offer):
        picked, _ = greedy_admission(test.gains([unit[k] for k in offer]), c)
        admitted = offer[picked]
    kept = wb.copy()
    kept[admitted] = True
    print(f"  offered back {len(offer)} of the choice's other loops ({is_false[offer].sum()} "
          f"false), admitted {len(admitted)} ({is_false[admitted].sum()} false): false in "
          f"{(kept & is_false).sum()}, true out {(~kept & ~is_false).sum()}")


def main() -> None:
    root = Path(__file__).resolve().parents[1]
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=root.parent / "shared" / "data" / "g2o")
    parser.add_argument("--stated", action="store_true")
    parser.add_argument("--no-segments", action="store_true")
    parser.add_argument("--no-groups", action="store_true")
    parser.add_argument("--candidates", action="store_true")
    parser.add_argument("cases", nargs="+")
    args = parser.parse_args()
    graphs: dict[tuple[str, float], tuple[PoseGraph, dict]] = {}
    for case in args.cases:
        name, scale, policy, ratio, seed = case.split(":")
        key = (name, float(scale))
        if key not in graphs:
            graph = PoseGraph.from_g2o(read_g2o(args.data / name))
            if float(scale) != 1.0:
                graph = with_information_scaled(graph, float(scale))
            graphs[key] = (graph, clean_optimum(graph))
        graph, ref = graphs[key]
        dof, c = pose_dof(graph.dim), tls_threshold(graph.dim)
        threshold = default_outlier_residual(graph.dim)
        values = graph.gtsam_values(ref)
        clean = _fixed(graph)
        inliers = [lp for lp in graph.loops if whitened_residual(lp, ref, graph.dim) <= threshold]
        for lp in inliers:
            clean.add(graph.between_factor(lp))
        corrupted, false_idx = inject_false_loops(
            graph, float(ratio), np.random.default_rng(int(seed)), policy, reference=ref)
        is_false = np.zeros(len(corrupted.loops), dtype=bool)
        is_false[false_idx] = True
        if args.candidates:
            print(f"{case} admission candidates:")
            _candidates(corrupted, ref, is_false)
        solution, res = _solved(corrupted, ref, is_false, args.stated, False, case + " admission")
        if not args.no_segments:
            start = time.perf_counter()
            check = segment_recheck(corrupted, corrupted.gtsam_values(solution.poses),
                                    solution.loop_weights, groups=not args.no_groups)
            seconds = time.perf_counter() - start
            if check.factors is not None:
                f = check.factors.factors
                print(f"  segment factors: pooled {check.factors.pooled:.3g}, min "
                      f"{f.min():.3g}, median {np.median(f):.3g}, max {f.max():.3g} "
                      f"({len(f)} segments); re-check {seconds:.1f} s; gate {check.gate:.2f}")
            for k, rho, delta in zip(check.suspects, check.leave_one_out, check.against_rest,
                                     strict=True):
                lp = corrupted.loops[k]
                print(f"  suspect {'false' if is_false[k] else 'true '} {lp.i}-{lp.j}: "
                      f"rho {rho:.2f} (with its own bending), delta {delta:.2f} (against the "
                      f"graph without the suspects): {'removed' if k in check.removed else 'kept'}")
            if check.groups is not None:
                g = check.groups
                print(f"  group test: {g.rounds} rounds, {len(g.removed)} loops removed, "
                      f"{len(g.readmitted)} rejected loops re-admitted")
                for t in g.tested:
                    lp = corrupted.loops[t.loops[0]]
                    print(f"  group of {len(t.loops)} ({int(is_false[t.loops].sum())} false) "
                          f"from {lp.i}-{lp.j}: rho_G {t.rho:.2f}, delta_G {t.delta:.2f}, "
                          f"gate {t.gate:.2f}: {'removed' if t.removed else 'kept'}")
            solution, res = _solved(corrupted, ref, is_false, args.stated, True,
                                    case + " segment re-check", not args.no_groups)
        false = [corrupted.loops[k] for k in false_idx]
        if not false:
            continue
        unit = [graph.between_factor(lp) for lp in false]
        delta = admission_costs(InnovationTest(clean, values, graph.keys, dof).gains(unit))
        delta_odo = admission_costs(
            InnovationTest(_fixed(graph), values, graph.keys, dof).gains(unit))
        print(f"  c = {c:.2f}; consistent with the outlier-free graph (delta < c): "
              f"{(delta < c).sum()}; with the odometry alone (delta_odo < c): "
              f"{(delta_odo < c).sum()}; median span "
              f"{np.median([abs(f.i - f.j) for f in false]):.0f}")
        for n, k in enumerate(false_idx):
            if delta[n] < c or res[k] <= threshold:
                lp = corrupted.loops[k]
                print(f"  false {lp.i}-{lp.j} span {abs(lp.i - lp.j)}: "
                      f"obeyed {res[k] <= threshold}, "
                      f"residual {whitened_residual(lp, ref, graph.dim):.2f} at the clean optimum, "
                      f"{res[k]:.2f} under the result; delta {delta[n]:.2f}, "
                      f"delta_odo {delta_odo[n]:.2f}")
        gains = InnovationTest(clean, values, graph.keys, dof).gains(
            [graph.between_factor(lp) for lp in inliers])
        loo = removal_costs(gains)
        worst = int(np.argmax(loo))
        print(f"  true loops: largest leave-one-out innovation {loo[worst]:.2f} "
              f"({inliers[worst].i}-{inliers[worst].j})")


if __name__ == "__main__":
    main()
