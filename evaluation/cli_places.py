"""`loopclosure bench places`: the place-recognition paper's Tables I-III on one or more sets.

``register(bench)`` adds the ``places`` command to the ``bench`` command group (wired in
by `evaluation.cli`).  Contract::

    loopclosure bench places --dataset box|surface|mpeg7:DIR|robot:DIR
        --methods fft,integral,ring,shape-context,tangent,scanline,mrm,flirt,cascade|all
        [--workers N | --cluster ADDRESS] [--seed N] [--range-cap M] [--out DIR] [--json]

``--dataset`` may be given several times (one column per data set in the report's
tables).  ``--json`` prints one JSON object ``{"dataset", "shapes", "classes",
"methods": {NAME: {"bullseye", "auc", "fscore", "ms_per_pair", "ms_describe",
"ms_compare", ...}}, "unavailable": [...], ...}`` (several data sets:
``{"datasets": [...]}``).  ``--out DIR`` writes ``report.md``, ``roc_<set>.png``,
``pr_<set>.png`` and ``results.json``.  ``--cluster`` (`evaluation.cluster`) computes
each matrix as Dask tasks, one matcher x data set block of rows each (the unit of
work), the workers loading the data set themselves; the figures are the same and the
matrices identical.  A progress bar goes to stderr.  Bad input
(unknown method or data set, empty or missing folder, workers < 1) raises
`data.errors.UserError`, which the entry point prints as one ``error:`` line (exit 2).
"""

from __future__ import annotations

from contextlib import nullcontext
from pathlib import Path
from typing import Annotated

import typer

from data.atomic_write import output_dir
from data.errors import UserError
from evaluation.cluster import ClusterOption
from slam.cli.common import stage_progress


def _no_progress(stage: str, done: int, total: int) -> None:
    return None


def places(
    dataset: Annotated[
        list[str],
        typer.Option("--dataset", help="box, surface, mpeg7:DIR or robot:DIR (repeatable)."),
    ],
    methods: Annotated[
        str,
        typer.Option("--methods", help="Comma-separated: fft,integral,ring,shape-context,"
                     "tangent,scanline,mrm,flirt,cascade; or all."),
    ] = "all",
    workers: Annotated[
        int, typer.Option("--workers", help="Processes for the all-pairs distance matrix.")
    ] = 1,
    seed: Annotated[
        int, typer.Option("--seed", help="Seed of the simulated worlds and robot scan caps.")
    ] = 0,
    out: Annotated[
        Path | None,
        typer.Option("--out", help="Folder for report.md, results.json, ROC/P-R plots."),
    ] = None,
    range_cap: Annotated[
        float | None,
        typer.Option("--range-cap", help="robot:DIR places: readings and open space "
                     "farther than this [m] are placed at it (default: the whole "
                     "30 m virtual scan)."),
    ] = None,
    cluster: ClusterOption = None,
    json: Annotated[bool, typer.Option("--json", help="Print one JSON object on stdout.")] = False,
) -> None:
    """Every shape matcher on place data sets: Bull's eye, ROC AUC, F-score, time (Tables I-III).

    With ``--cluster`` every block of rows of a matcher's all-pairs matrix is one Dask
    task (the same figures; only the seconds differ).
    """
    from evaluation.cluster import parse_cluster
    from evaluation.place_datasets import RobotPlacesConfig, dataset_kind, load_dataset
    from evaluation.places_benchmark import run_places
    from evaluation.places_matrix import PlaceSource
    from evaluation.places_methods import parse_methods
    from evaluation.places_report import json_document, summary_lines, write_places_report
    from slam.cli.common import print_json

    names = parse_methods(methods)
    parse_cluster(cluster)  # a bad --cluster fails before any data set is loaded
    if workers < 1:
        raise UserError(f"--workers must be at least 1, got {workers}")
    if cluster is not None and workers > 1:
        raise UserError("give either --workers N (a local process pool) or --cluster, not both")
    if seed < 0:
        raise UserError(f"--seed must be >= 0, got {seed}")
    robot = RobotPlacesConfig(range_cap=range_cap)  # a bad --range-cap fails here
    if not dataset:
        raise UserError("--dataset is required: box, surface, mpeg7:DIR or robot:DIR")
    for spec in dataset:  # check every spec before the (slow) loading starts
        dataset_kind(spec)
    if out is not None:
        output_dir(out)  # a bad --out fails now, not after the runs
    results = []
    # one live display at a time: with a cluster, the engine's bar over the tasks
    bars = stage_progress() if cluster is None else nullcontext(_no_progress)
    with bars as update:
        for spec in dataset:
            update(f"loading {spec}", 0, 1)
            place_set = load_dataset(spec, seed=seed, robot=robot)
            update(f"loading {spec}", 1, 1)
            source = PlaceSource(spec, seed, str(Path.cwd()), range_cap)
            results.append(run_places(place_set, names, workers=workers, seed=seed,
                                      progress=update, source=source, cluster=cluster))
    paths = write_places_report(out, results) if out is not None else {}
    if json:
        doc = json_document(results)
        if paths:
            doc["outputs"] = {k: str(v) for k, v in paths.items()}
        print_json(doc)
        return
    for r in results:
        for line in summary_lines(r):
            typer.echo(line)
    if paths:
        typer.echo(f"report: {paths['report']}")


def register(bench: typer.Typer) -> None:
    """Add ``places`` to the ``bench`` command group."""
    bench.command("places")(places)
