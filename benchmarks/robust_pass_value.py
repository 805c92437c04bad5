"""Diagnosis: which of the robust back end's passes change a decision, and what each costs.

Run from the repository root::

    python benchmarks/robust_pass_value.py input_INTEL_g2o.g2o [--data DIR] [--scale 1]
        [--policy random] [--ratio 50] [--seed 0] [--cache DIR] [--without]

Runs `slam.optimize.optimize` (``gnc``, incremental, from the odometry chain, as the
sweep does) with its stages wrapped, and prints per stage its CPU seconds
(``time.process_time``) and prefix solves (iSAM2 `IsamPrefix.solve` calls and batch
`StickySolver` solves): the fast path, every admission pass of the odometry ladder
(label, finished or given up behind the best, its loops after `refine_tls`: false kept,
true rejected, loops that differ from the chosen candidate and from the final result,
stated TLS cost), the calibrated choice (the index it picks and its offered-back loops),
every `bar_search` trial (kept or not), the polish and the segment re-check.  With
``--without``: the choice is made again without each candidate in turn (same inputs,
in the same process): a candidate whose removal leaves the choice and its loops as they
are changed no decision (the refine solves' warm starts apart).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import ClassVar

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import slam.admission as admission
import slam.consistency as consistency
import slam.isam_prefix as isam_prefix
import slam.least_squares as least_squares
import slam.optimize as optimize_module
from benchmarks.robust_cell import cell_outcome, cell_parser, read_cell
from benchmarks.robust_confirm_ab import _head
from slam.optimize import optimize

COUNTS = {"isam": 0, "batch": 0}
STAGES: list[list] = []  # [name, cpu, isam, batch, note]


class Stage:
    """Charges the CPU seconds and solves spent inside it to `name` (nested stages are
    charged to the inner one only)."""

    stack: ClassVar[list[Stage]] = []

    def __init__(self, name: str) -> None:
        self.row = [name, 0.0, 0, 0, ""]
        STAGES.append(self.row)

    def __enter__(self) -> Stage:
        if Stage.stack:
            Stage.stack[-1]._pause()
        Stage.stack.append(self)
        self._resume()
        return self

    def __exit__(self, *exc) -> None:  # type: ignore[no-untyped-def]
        self._pause()
        Stage.stack.pop()
        if Stage.stack:
            Stage.stack[-1]._resume()

    def _resume(self) -> None:
        self._t, self._i, self._b = time.process_time(), COUNTS["isam"], COUNTS["batch"]

    def _pause(self) -> None:
        self.row[1] += time.process_time() - self._t
        self.row[2] += COUNTS["isam"] - self._i
        self.row[3] += COUNTS["batch"] - self._b


def main() -> None:
    parser = cell_parser(__doc__.split("\n")[0])
    parser.add_argument("--without", action="store_true")
    args = parser.parse_args()
    graph, reference, corrupted, is_false = read_cell(args)
    optimize(_head(corrupted, 200), "none", "gnc", init="odometry", gnc_start="incremental")

    solve, inner = isam_prefix.IsamPrefix.solve, least_squares.StickySolver._solve

    def counted_solve(self):  # type: ignore[no-untyped-def]
        COUNTS["isam"] += 1
        return solve(self)

    def counted_inner(self, factors, values):  # type: ignore[no-untyped-def]
        COUNTS["batch"] += 1
        return inner(self, factors, values)

    isam_prefix.IsamPrefix.solve = counted_solve  # type: ignore[method-assign]
    least_squares.StickySolver._solve = counted_inner  # type: ignore[method-assign]

    names: dict[int, str] = {}  # id(pass) -> label
    init, resumed, advance = (admission.AdmissionPass.__init__, admission.AdmissionPass.resumed,
                              admission.AdmissionPass.advance)

    def label(run) -> str:  # type: ignore[no-untyped-def]
        if id(run) not in names:
            first = corrupted.odometry[0].information[0, 0]
            ratio = run.graph.odometry[0].information[0, 0] / first
            names[id(run)] = f"{run.gate} x{ratio:.3g} barred {len(run.barred)}"
        return names[id(run)]

    def init_traced(self, *a, **kw):  # type: ignore[no-untyped-def]
        init(self, *a, **kw)
        label(self)

    def resumed_traced(self, *a, **kw):  # type: ignore[no-untyped-def]
        run = resumed(self, *a, **kw)
        label(run)
        return run

    def advance_traced(self, *a, **kw):  # type: ignore[no-untyped-def]
        with Stage(f"pass {label(self)}"):
            return advance(self, *a, **kw)

    admission.AdmissionPass.__init__ = init_traced  # type: ignore[method-assign]
    admission.AdmissionPass.resumed = resumed_traced  # type: ignore[method-assign]
    admission.AdmissionPass.advance = advance_traced  # type: ignore[method-assign]

    current = {"run": None}
    finish, refine = consistency._finish_unless_behind, consistency.refine_tls
    candidates: list = []

    def finish_traced(run, best, *a):  # type: ignore[no-untyped-def]
        current["run"] = run
        done = finish(run, best, *a)
        if not done:
            candidates.append((label(run), None, None))
        return done

    def refine_traced(g, values, weights, **kw):  # type: ignore[no-untyped-def]
        with Stage(f"refine {label(current['run'])}"):
            out = refine(g, values, weights, **kw)
        candidates.append((label(current["run"]), out[1], kw.get("barred", ())))
        return out

    consistency._finish_unless_behind = finish_traced
    consistency.refine_tls = refine_traced

    choose = optimize_module.choose_and_offer_back
    choice: dict = {}

    def choose_traced(g, cands, **kw):  # type: ignore[no-untyped-def]
        with Stage("choice"):
            out = choose(g, cands, **kw)
        choice.update(pick=out[0], offered=out[1], cands=list(cands), kw=kw)
        if args.without:
            for k in range(len(cands)):
                rest = [c for n, c in enumerate(cands) if n != k]
                with Stage(f"choice without {k} (diagnosis)"):
                    alt = choose(g, rest, **{**kw, "factor": []})
                pick = alt[0] if alt[0] < 0 or alt[0] < k else alt[0] + 1
                w = alt[1] if alt[1] is not None else (
                    rest[alt[0]][1] if alt[0] >= 0 else None)
                choice.setdefault("without", []).append((k, pick, w))
        return out

    optimize_module.choose_and_offer_back = choose_traced

    bar = consistency.bar_search

    def bar_traced(*a, **kw):  # type: ignore[no-untyped-def]
        with Stage("bar_search"):
            out = bar(*a, **kw)
        choice["bar"] = out
        return out

    consistency.bar_search = bar_traced
    polish = consistency.polish

    def polish_traced(*a, **kw):  # type: ignore[no-untyped-def]
        with Stage("polish"):
            return polish(*a, **kw)

    consistency.polish = polish_traced
    fast, recheck = optimize_module._clean_optimum, optimize_module._segment_rechecked

    def fast_traced(*a, **kw):  # type: ignore[no-untyped-def]
        with Stage("fast path"):
            return fast(*a, **kw)

    def recheck_traced(*a, **kw):  # type: ignore[no-untyped-def]
        with Stage("segment re-check"):
            return recheck(*a, **kw)

    optimize_module._clean_optimum = fast_traced
    optimize_module._segment_rechecked = recheck_traced

    name = f"{args.graph} x{args.scale:g} {args.policy} {args.ratio:g}% seed {args.seed}"
    cpu = time.process_time()
    with Stage("other"):
        result = optimize(corrupted, "none", "gnc", init="odometry", gnc_start="incremental")
    cpu = time.process_time() - cpu
    out = cell_outcome(graph, reference, corrupted, is_false, result.poses)
    final = result.loop_weights if result.loop_weights is not None else None
    print(f"{name}: ATE {out.ate:.3g} m, {len(out.false_obeyed)} F ({out.consistent}), "
          f"{out.true_rejected} T, {cpu:.1f} s CPU, solver {result.solver}", flush=True)
    totals: dict[str, list] = {}
    for row in STAGES:
        key = row[0]
        t = totals.setdefault(key, [0.0, 0, 0])
        t[0] += row[1]
        t[1] += row[2]
        t[2] += row[3]
    for key, (t, i, b) in totals.items():
        print(f"  stage {key}: {t:.1f} s CPU, {i} iSAM2, {b} batch")
    chosen = None
    if choice.get("cands"):
        pick = choice["pick"]
        chosen = choice["offered"] if choice["offered"] is not None else (
            choice["cands"][pick][1] if pick >= 0 else None)
        print(f"  choice: pick {pick} of {len(choice['cands'])}, offered back "
              f"{choice['offered'] is not None}, stated costs "
              f"{[round(float(c[2]), 2) for c in choice['cands']]}")
    n = 0
    for lab, w, barred in candidates:
        if w is None:
            print(f"  candidate {lab}: given up behind the best")
            continue
        kept = w > 0.5
        line = (f"  candidate {lab}{' (bar trial)' if len(barred) else f' #{n}'}: "
                f"false kept {int((kept & is_false).sum())}, true rejected "
                f"{int((~kept & ~is_false).sum())}")
        if chosen is not None:
            line += f", differs from chosen {int(((chosen > 0.5) != kept).sum())}"
        if final is not None:
            line += f", from final {int(((final > 0.5) != kept).sum())}"
        print(line)
        n += 0 if len(barred) else 1
    for k, pick, w in choice.get("without", []):
        same = (w is not None and chosen is not None
                and bool(((w > 0.5) == (chosen > 0.5)).all()))
        print(f"  without candidate #{k}: pick {pick}, chosen loops the same {same}")
    if "bar" in choice and final is not None:
        print(f"  bar_search: {choice['bar'].gate}")


if __name__ == "__main__":
    main()
