"""The report `loopclosure run` prints after its embedded demo: the run against ground truth.

The demo maps a simulated run (`data.sim.SimulatedRun`), whose true trajectory is
known, so the run can be measured as it ends:

- ATE (`evaluation.trajectory_error.trajectory_errors`: RMSE [m] after rigid
  alignment, stamps associated within 0.01 s) of the per-scan trajectory against
  the ground truth, before loop closure (the front end's odometry poses) and after
  (the optimised poses);
- precision and recall of the loop closures (`evaluation.loop_metrics.evaluate_loops`,
  its defaults: 2 m, 0.2 m, 2 deg) against the ground truth: every candidate the run
  verified is a proposal stamped with its two scans' stamps, scored by the geometric
  check's fitness, accepted when the check accepted it and the final GNC kept it.

`demo_reporter` is the run reporter (`slam.cli.run_command.add_run_reporter`) that
`evaluation.cli.register` adds: it reports on simulated runs only and puts the
figures under ``"demo"`` in ``summary.json``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from slam.cli.run_command import RunReport


def demo_figures(result: Any, ground_truth: Any) -> dict[str, Any]:
    """ATE before / after loop closure [m] and loop precision / recall of a run.

    Args:
        result: the `slam.pipeline.MappingResult` of the run.
        ground_truth: the true trajectory (`data.types.Trajectory`, stamped like the scans).
    """
    from data.types import Trajectory
    from evaluation.loop_metrics import LoopProposal, evaluate_loops
    from evaluation.trajectory_error import trajectory_errors

    gt = ground_truth
    after = trajectory_errors(Trajectory.from_xytheta(result.scan_stamps, result.scan_poses), gt)
    before = trajectory_errors(
        Trajectory.from_xytheta(result.scan_stamps, result.odometry_poses), gt
    )
    proposals = [
        LoopProposal(e.stamp_match, e.stamp_query, e.candidate.relative,
                     e.candidate.verification.fitness if e.candidate.verification else 0.0,
                     e.candidate.accepted and not e.rejected_by_gnc)
        for e in result.loops
    ]
    stamps = np.array([k.stamp for k in result.keyframes])
    loops = evaluate_loops(proposals, gt, stamps)
    return {
        "ate_before_loop_closure_m": before.ate_rmse,
        "ate_after_loop_closure_m": after.ate_rmse,
        "loop_precision": loops.precision,
        "loop_recall": loops.recall,
        "loops_true_positive": loops.true_positives,
        "loops_false_positive": loops.false_positives,
    }


def demo_lines(figures: dict[str, Any]) -> list[str]:
    """The two lines printed under the run's summary line."""
    return [
        f"ATE against ground truth: {figures['ate_before_loop_closure_m']:.4f} m before loop "
        f"closure, {figures['ate_after_loop_closure_m']:.4f} m after",
        f"loop closures: precision {figures['loop_precision']:.3f}, recall "
        f"{figures['loop_recall']:.3f} ({figures['loops_true_positive']} true, "
        f"{figures['loops_false_positive']} false)",
    ]


def demo_reporter(result: Any, source: Any, out: Path) -> RunReport | None:
    """The demo report of a run of a simulated source; None for any other source."""
    from data.sim import SimulatedRun

    if not isinstance(source, SimulatedRun):
        return None
    figures = demo_figures(result, source.ground_truth)
    return RunReport("demo", figures, tuple(demo_lines(figures)))
