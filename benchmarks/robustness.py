"""Benchmark: robustness of the back end to false loop closures, on every shared pose graph.

Run from the repository root::

    python benchmarks/robustness.py [--data DIR] [--graphs a.g2o,b.g2o] [--scales 1,0.1,0.01]
        [--policies random,local,grouped,local-grouped] [--ratios 0,10,...,90] [--seeds 5]
        [--kernels gnc] [--group-size 10] [--variance-factor] [--out DIR]

For every graph (``*.g2o`` in `--data`, default ``../shared/data/g2o``), every odometry
information scaling (the graph as given and with its odometry information multiplied by
each factor: looser odometry, as many real robots state it), every policy of
`evaluation.outlier_policies`, every ratio and seed,
`evaluation.robustness.run_robustness` gives ATE against the outlier-free optimum [m],
false loops obeyed, true loops rejected and seconds. A cell *holds* when ATE < 5 cm and
no false loop is obeyed that the outlier-free graph would reject (at ratio 0: ATE < 1
mm, the clean optimum); a false loop whose innovation against the outlier-free graph is
below the TLS threshold (``false_obeyed_consistent``, `evaluation.robustness`) passes
the same test as the true loops, so only its effect, the ATE, is judged. *Strict*: no
false loop obeyed at all. A failing cell is *objective-limited* when its result has a
lower TLS objective than the clean optimum (``tls_gap < 0``, `evaluation.robustness`):
the false loops it obeys are as plausible as true ones under the stated covariances, so
no exact TLS solver would reject them. Printed: one line per graph x scaling x policy x
kernel with the *breakdown ratio*, the largest tested ratio up to which every seed holds
at every ratio, the worst ATE and the slowest seconds at that ratio, and the *solver
breakdown*, the same with objective-limited cells counted as held. A policy's ratios
stop at its first failure that is not objective-limited (both breakdowns are known by
then); ratio 0 runs one seed (the seed only permutes the loops). With
`--variance-factor`, per graph and scaling, the odometry variance factor the
outlier-free graph shows (`slam.variance_components`: actual / stated odometry variance;
tens of seconds per graph). With `--out`: every row (``rows.json``), the table
(``breakdown.json``) and one plot per graph (breakdown ratio per policy and kernel, one
group of bars per scaling).

Cells run from the cheapest graph up; M3500 cells take minutes each: bound the sweep with
`--graphs`, `--ratios` and `--seeds`.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from data.g2o import read_g2o
from evaluation.outlier_policies import POLICIES
from evaluation.robustness import clean_optimum, run_robustness
from slam.pose_graph import PoseGraph
from slam.variance_components import estimate_variance_factors, with_information_scaled

HOLD_ATE_M = 0.05
CLEAN_ATE_M = 0.001


def holds(row: dict) -> bool:
    """The goal of one cell (module docstring)."""
    if row["outlier_ratio"] == 0:
        return row["ate_vs_clean_m"] < CLEAN_ATE_M
    detectable = row["false_factors_obeyed"] - row.get("false_obeyed_consistent", 0)
    return row["ate_vs_clean_m"] < HOLD_ATE_M and detectable == 0


def strictly_holds(row: dict) -> bool:
    """`holds`, counting every false loop obeyed (module docstring)."""
    return holds(row) and (row["outlier_ratio"] == 0 or row["false_factors_obeyed"] == 0)


def objective_limited(row: dict) -> bool:
    """A failing row whose result is a better TLS solution than the clean optimum."""
    return not holds(row) and row["tls_gap"] < 0


def solver_holds(row: dict) -> bool:
    """Holds, or fails only where the TLS objective itself prefers the false loops."""
    return holds(row) or objective_limited(row)


def breakdown(
    rows: list[dict], ratios: list[float], ok=holds
) -> tuple[float | None, float, float]:
    """(largest ratio up to which every row is `ok`, worst ATE there, slowest seconds there)."""
    best, ate, seconds = None, float("nan"), float("nan")
    for r in sorted(ratios):
        at = [x for x in rows if x["outlier_ratio"] == r]
        if not at or not all(ok(x) for x in at):
            break
        best = r
        ate = max(x["ate_vs_clean_m"] for x in at)
        seconds = max(x["seconds"] for x in at)
    return best, ate, seconds


def odometry_factor(graph: PoseGraph, reference: dict) -> float:
    """Actual / stated odometry variance of the outlier-free graph, from its clean optimum."""
    values = graph.gtsam_values(reference)
    return estimate_variance_factors(graph, np.ones(len(graph.loops)), values).odometry


def plot(path: Path, table: list[dict], title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = sorted({(t["policy"], t["kernel"]) for t in table})
    scales = sorted({t["odometry_scale"] for t in table}, reverse=True)
    fig, ax = plt.subplots(figsize=(7, 4))
    width = 0.8 / max(len(series), 1)
    for n, (policy, kernel) in enumerate(series):
        ys = []
        for s in scales:
            hit = [t for t in table if (t["policy"], t["kernel"], t["odometry_scale"])
                   == (policy, kernel, s)]
            b = hit[0]["breakdown"] if hit else None
            ys.append(-5 if b is None else 100 * b)
        ax.bar(np.arange(len(scales)) + n * width, ys, width, label=f"{kernel} {policy}")
    ax.set_xticks(np.arange(len(scales)) + 0.4 - width / 2, [f"odometry x{s:g}" for s in scales])
    ax.set_ylabel("breakdown: largest % false loops held")
    ax.axhline(50, color="grey", ls="--", lw=0.6)
    ax.set_title(title)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    root = Path(__file__).resolve().parents[1]
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=root.parent / "shared" / "data" / "g2o")
    parser.add_argument("--graphs", default="", help="comma-separated file names (default all)")
    parser.add_argument("--scales", default="1,0.1,0.01")
    parser.add_argument("--policies", default=",".join(POLICIES))
    parser.add_argument("--ratios", default="0,10,20,30,40,50,60,70,80,90", help="percent")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--kernels", default="gnc")
    parser.add_argument("--group-size", type=int, default=10)
    parser.add_argument("--variance-factor", action="store_true",
                        help="also estimate the odometry variance factor of each graph")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    if not args.data.is_dir():
        sys.exit(f"no pose graphs: {args.data} is not a folder")
    names = [g for g in args.graphs.split(",") if g] or None
    files = sorted(args.data.glob("*.g2o"), key=lambda p: p.stat().st_size)
    files = [f for f in files if names is None or f.name in names]
    scales = [float(s) for s in args.scales.split(",")]
    policies = [p for p in args.policies.split(",") if p]
    ratios = sorted(float(r) / 100 for r in args.ratios.split(","))
    kernels = [k for k in args.kernels.split(",") if k]
    rows: list[dict] = []
    table: list[dict] = []
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
    for path in files:
        graph = PoseGraph.from_g2o(read_g2o(path))
        for scale in scales:
            scaled = with_information_scaled(graph, scale) if scale != 1 else graph
            start = time.perf_counter()
            reference = clean_optimum(scaled)
            factor = float("nan")
            if args.variance_factor:
                factor = odometry_factor(scaled, reference)
            print(f"{path.name} odometry x{scale:g}: clean optimum, odometry variance factor "
                  f"{factor:.4g} ({time.perf_counter() - start:.1f} s)", flush=True)
            for policy in policies:
                for kernel in kernels:
                    cell: list[dict] = []
                    for ratio in ratios:
                        at = []
                        # At ratio 0 the seed only permutes the loops: one seed will do.
                        for seed in range(args.seeds if ratio > 0 else 1):
                            (r,) = run_robustness(
                                graph, [ratio], [kernel], seed=seed, policies=[policy],
                                group_size=args.group_size, odometry_scale=scale,
                                reference=reference)
                            row = {"graph": path.name, **r.to_json()}
                            at.append(row)
                            print("  " + json.dumps(row), flush=True)
                        cell += at
                        if not all(solver_holds(x) for x in at):
                            break
                    rows += cell
                    b, ate, sec = breakdown(cell, ratios)
                    sb, _, _ = breakdown(cell, ratios, solver_holds)
                    strict, _, _ = breakdown(cell, ratios, strictly_holds)
                    line = {"graph": path.name, "odometry_scale": scale, "policy": policy,
                            "kernel": kernel, "breakdown": b, "ate_m": ate, "seconds": sec,
                            "solver_breakdown": sb, "strict_breakdown": strict,
                            "odometry_variance_factor": factor}
                    table.append(line)
                    print(_line(line), flush=True)
        if args.out:
            plot(args.out / f"{path.stem}.png", [t for t in table if t["graph"] == path.name],
                 f"robustness: {path.name}")
            (args.out / "rows.json").write_text(json.dumps(rows, indent=1))
            (args.out / "breakdown.json").write_text(json.dumps(table, indent=1))
    print("\nbreakdown (largest % false loops at which every seed holds; strict: no false "
          "loop obeyed at all; solver: counting objective-limited failures as held):")
    for t in table:
        print(_line(t))


def _line(t: dict) -> str:
    def pct(b: float | None) -> str:
        return "none" if b is None else f"{100 * b:.0f}%"

    return (f"{t['graph']:24} x{t['odometry_scale']:<5g} {t['policy']:14} {t['kernel']:6} "
            f"{pct(t['breakdown']):>5}  strict {pct(t.get('strict_breakdown')):>5}  "
            f"solver {pct(t['solver_breakdown']):>5}  "
            f"ATE {t['ate_m']:.4f} m  {t['seconds']:.1f} s")


if __name__ == "__main__":
    main()
