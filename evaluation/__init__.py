"""Metrics (retrieval, loop closures, trajectory, relations) and benchmark runners.

Metrics: `retrieval`, `loop_metrics`, `trajectory_error`, `relations_metric`,
`robustness`.  Each benchmark is a runner module with its steps beside it:

- ``bench places``: `places_benchmark` (runner), `places_methods`, `places_matrix`,
  `places_paper`, `places_report`, on the sets of `place_datasets`;
- ``bench stripes``: `stripes_benchmark` (runner), `stripes_objects`,
  `stripes_retrieval`, `stripes_report`; ``bench landmarks``: `landmarks_benchmark`;
- ``bench slam``: `slam_benchmark` (runner), `slam_input`, `slam_methods`,
  `slam_reference`, `loop_verdicts`, `slam_report`;
- the demo report of ``loopclosure run``: `demo_report`.

The commands are in `cli` (registered through the ``loopclosure.commands`` entry
point) and `cli_places`, `cli_stripes`, `cli_slam`; reports use `report` and `plots`.
"""
