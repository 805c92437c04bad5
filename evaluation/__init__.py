"""Metrics (retrieval, loop closures, trajectory, relations) and benchmark runners.

Metrics: `retrieval`, `loop_metrics`, `trajectory_error`, `relations_metric`,
`robustness`.  Each benchmark is a runner module with its steps beside it:

- ``bench places``: `places_benchmark` (runner), `places_methods`, `places_matrix`,
  `places_paper`, `places_report`, on the sets of `place_datasets`;
- ``bench stripes``: `stripes_benchmark` (runner), `stripes_config`, `stripes_methods`,
  `stripes_tasks`, `stripes_ranking`, `stripes_result`, `stripes_paper`, `stripes_objects`,
  `stripes_retrieval`, `stripes_report`; ``bench landmarks``: `landmarks_benchmark`;
- ``bench slam``: `slam_benchmark` (runner), `slam_input`, `slam_methods`,
  `slam_reference`, `loop_verdicts`, `slam_report`;
- ``bench loops``: `loop_bench` (runner), `loop_bench_input`, `loop_bench_truth`,
  `loop_bench_report`;
- ``batch`` (many logs mapped, here or on a cluster): `batch`, on the engine of
  `cluster`;
- the demo report of ``loopclosure run``: `demo_report`.

The commands are in `cli` (registered through the ``loopclosure.commands`` entry
point) and `cli_places`, `cli_stripes`, `cli_slam`, `cli_loops`, `cli_batch`;
reports use `report` and `plots`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from data.lazy_exports import lazy_exports

if TYPE_CHECKING:
    from evaluation.loop_metrics import LoopMetrics, LoopProposal, evaluate_loops
    from evaluation.relations_metric import RelationsMetric, relations_metric
    from evaluation.retrieval import best_fscore, bullseye, roc_auc
    from evaluation.robustness import RobustnessResult, inject_false_loops, run_robustness
    from evaluation.trajectory_error import TrajectoryErrors, trajectory_errors

# The metrics a library user needs, loaded on first use (the CLI registers the
# commands of this package at every start and must not pay for gtsam or matplotlib).
_HOMES = {
    "LoopMetrics": "evaluation.loop_metrics",
    "LoopProposal": "evaluation.loop_metrics",
    "evaluate_loops": "evaluation.loop_metrics",
    "RelationsMetric": "evaluation.relations_metric",
    "relations_metric": "evaluation.relations_metric",
    "best_fscore": "evaluation.retrieval",
    "bullseye": "evaluation.retrieval",
    "roc_auc": "evaluation.retrieval",
    "RobustnessResult": "evaluation.robustness",
    "inject_false_loops": "evaluation.robustness",
    "run_robustness": "evaluation.robustness",
    "TrajectoryErrors": "evaluation.trajectory_error",
    "trajectory_errors": "evaluation.trajectory_error",
}

__getattr__, __dir__ = lazy_exports(__name__, globals(), _HOMES)

__all__ = [
    "LoopMetrics",
    "LoopProposal",
    "RelationsMetric",
    "RobustnessResult",
    "TrajectoryErrors",
    "best_fscore",
    "bullseye",
    "evaluate_loops",
    "inject_false_loops",
    "relations_metric",
    "roc_auc",
    "run_robustness",
    "trajectory_errors",
]
