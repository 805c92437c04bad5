"""`loopclosure bench stripes` and `loopclosure bench landmarks`.

``register(bench)`` adds both commands to the ``bench`` command group (wired in by
`evaluation.cli`).  Bad input raises `data.errors.UserError` / `DataError`, which the
entry point prints as one ``error:`` line with exit status 2.  Progress bars go to
stderr, results to stdout (``--json``: one JSON document).  ``--cluster``
(`evaluation.cluster`) runs each matcher of ``bench stripes`` (the unit of work: one
matcher on the scanned set) and each seed of ``bench landmarks`` as one Dask task,
the workers building their inputs themselves; the figures are the same.
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


def _bars(cluster: str | None):
    """The stage bars, or none with a cluster (the engine shows its bar over the tasks:
    one live display at a time)."""
    return stage_progress() if cluster is None else nullcontext(_no_progress)


def _names(text: str | None) -> tuple[str, ...] | None:
    """Comma-separated names (``none`` or empty: no names); None stays None."""
    if text is None:
        return None
    parts = tuple(p.strip() for p in text.split(",") if p.strip())
    return () if parts in ((), ("none",)) else parts


def stripes(
    dataset: Annotated[
        str | None, typer.Option("--dataset", help="Built-in data set: daily-sim.")
    ] = None,
    meshes: Annotated[
        Path | None, typer.Option("--meshes", help="Folder of meshes (.ply/.obj/.stl[.gz]).")
    ] = None,
    labels: Annotated[
        Path | None,
        typer.Option("--labels", help="CSV 'file,class' for --meshes (default: YCB classes)."),
    ] = None,
    units: Annotated[
        str,
        typer.Option("--units", help="Units of --meshes: auto (mm when the largest extent "
                     "is above 2, else m), m, cm or mm."),
    ] = "auto",
    up_axis: Annotated[
        str, typer.Option("--up-axis", help="Model axis of --meshes that points up: z, y or x.")
    ] = "z",
    scans_per_object: Annotated[
        int, typer.Option("--scans-per-object", help="Independent scans of every object.")
    ] = 1,
    seed: Annotated[int, typer.Option("--seed", help="Seed of poses, noise and Daily set.")] = 0,
    per_class: Annotated[
        int, typer.Option("--per-class", help="daily-sim: instances per class.")
    ] = 10,
    classes: Annotated[
        str | None, typer.Option("--classes", help="daily-sim: comma-separated classes.")
    ] = None,
    step: Annotated[
        float, typer.Option("--step", help="Laser advance between frames, metres.")
    ] = 0.0008,
    yaw_range: Annotated[
        float,
        typer.Option("--yaw-range", help="Object yaw drawn in +-DEG per scan (180: any "
                     "pose on the table; with --scans-per-object 2 the different-pose "
                     "figures then compare unrelated poses)."),
    ] = 15.0,
    baselines: Annotated[
        str,
        typer.Option("--baselines", help="Comma-separated silhouette matchers ('none': none)."),
    ] = "shape-context,mrm,fft",
    fused: Annotated[
        str,
        typer.Option("--fused", help="Silhouette verifiers of the fused matcher, the "
                     "default: profile, relief, surface context and these ('none': no "
                     "fused row; fft,ring: the microsecond verifiers)."),
    ] = "shape-context-50",
    fused_sc: Annotated[
        str,
        typer.Option("--fused-sc", help="Silhouette verifiers of the fused-sc row, the "
                     "profile verified by shape context ('none': no fused-sc row; "
                     "shape-context-50: 50 points, compiled kernel; shape-context: 100 "
                     "points)."),
    ] = "shape-context-50",
    fused_relief: Annotated[
        str,
        typer.Option("--fused-relief", help="Silhouette verifiers of the fused-relief row, "
                     "the profile and the relief (depth below the top, ring by ring) "
                     "verified by them ('none': no fused-relief row)."),
    ] = "shape-context-50",
    scaling: Annotated[
        str,
        typer.Option("--scaling", help="How the fused and fused-stripes rows make each "
                     "part unitless: local (each distance over sqrt(s_q s_j), s the "
                     "distance to the --neighbour-th nearest other object) or median "
                     "(over its per-query median)."),
    ] = "local",
    neighbour: Annotated[
        int, typer.Option("--neighbour", help="Neighbour rank of --scaling local.")
    ] = 5,
    mean: Annotated[
        str,
        typer.Option("--mean", help="How the fused and fused-stripes rows average their "
                     "unitless parts: geometric (each part counts by ratios) or "
                     "arithmetic."),
    ] = "geometric",
    stripe_count: Annotated[
        int | None,
        typer.Option("--stripe-count", help="Describe each object by at most N evenly "
                     "spaced stripes (default: all, the paper)."),
    ] = None,
    scale_free: Annotated[
        bool,
        typer.Option("--scale-free", help="Stripe points in units of the object's mean "
                     "stripe width (default: pixels, the paper)."),
    ] = False,
    out: Annotated[
        Path | None, typer.Option("--out", help="Write report.md, results.json, PNGs here.")
    ] = None,
    cluster: ClusterOption = None,
    json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """The stripes paper's Table I / II, Bull's eye and timing, with silhouette baselines.

    With ``--cluster`` every matcher is one Dask task (the same figures; only the seconds
    differ).
    """
    from dataclasses import replace

    from data.stripe_scanner import DAILY_CLASSES, ScannerConfig
    from data.stripe_scanner.meshes import check_conventions
    from evaluation.cluster import parse_cluster
    from evaluation.stripes_benchmark import (
        PAPER_TABLE_I,
        StripesBenchmarkConfig,
        StripesSource,
        baseline_matcher,
        run_stripes_benchmark,
    )
    from evaluation.stripes_objects import daily_objects, mesh_folder_objects
    from evaluation.stripes_report import write_stripes_report
    from loopclosure.stripes import DescriptorConfig
    from slam.cli.common import print_json

    parse_cluster(cluster)  # a bad --cluster fails before any work
    if (dataset is None) == (meshes is None):
        raise UserError("give exactly one of --dataset daily-sim or --meshes DIR")
    if dataset is not None and dataset != "daily-sim":
        raise UserError(f"unknown --dataset {dataset!r}; available: daily-sim")
    if labels is not None and meshes is None:
        raise UserError("--labels needs --meshes")
    if meshes is not None and classes is not None:
        raise UserError("--classes is for --dataset daily-sim only")
    check_conventions(units, up_axis)
    if not step > 0:
        raise UserError(f"--step must be positive, got {step}")
    if seed < 0:
        raise UserError(f"--seed must be non-negative, got {seed}")
    if scans_per_object < 1:
        raise UserError(f"--scans-per-object must be at least 1, got {scans_per_object}")
    if out is not None:
        output_dir(out)  # a bad --out fails now, not after the runs
    if not 0 <= yaw_range <= 180:
        raise UserError(f"--yaw-range must be within 0..180 degrees, got {yaw_range}")
    if stripe_count is not None and stripe_count < 2:
        raise UserError(f"--stripe-count must be at least 2, got {stripe_count}")
    names = _names(baselines) or ()
    verifiers = _names(fused) or ()
    sc_verifiers = _names(fused_sc) or ()
    relief_verifiers = _names(fused_relief) or ()
    for name in (*names, *verifiers, *sc_verifiers, *relief_verifiers):
        try:
            baseline_matcher(name)  # unknown names fail here, before any work
        except ImportError:
            pass  # registered but not importable yet: skipped with a warning later
    cfg = StripesBenchmarkConfig(
        seed=seed,
        scans_per_object=scans_per_object,
        baselines=names,
        scanner=replace(ScannerConfig(), step=step, yaw_range_deg=yaw_range),
        descriptor=DescriptorConfig(stripe_count=stripe_count, scale_free=scale_free),
        fused=verifiers,
        fused_sc=sc_verifiers,
        fused_relief=relief_verifiers,
        scaling=scaling,
        neighbour=neighbour,
        mean=mean,
    )
    if meshes is not None:
        objects = mesh_folder_objects(meshes, labels, units=units, up=up_axis)
        source = StripesSource(daily=False, meshes=str(meshes), units=units, up=up_axis,
                               labels=str(labels) if labels is not None else None,
                               folder=str(Path.cwd()))
    else:
        chosen = _names(classes) or DAILY_CLASSES
        objects = daily_objects(seed, per_class, chosen)
        source = StripesSource(daily=True, seed=seed, per_class=per_class,
                               classes=_names(classes))
    with _bars(cluster) as progress:
        result = run_stripes_benchmark(objects, cfg, progress, source=source, cluster=cluster)
    paths = write_stripes_report(result, out) if out is not None else {}
    js = result.to_json()
    if paths:
        js["outputs"] = {k: str(v) for k, v in paths.items()}
    if json:
        print_json(js)
        return
    typer.echo(f"{js['dataset']}: {js['objects']} objects, {js['scans']} scans, "
               f"{js['classes']} classes")
    for name, r in result.methods().items():
        counts = " ".join(f"{c:3d}" for c in r.top_counts.tolist())
        pose = r.different_pose
        other_pose = (f"   different pose: other {pose['other_object']:.3f} instance "
                      f"{pose['instance']:.3f}" if pose else "")
        typer.echo(f"  {name:14s} top-10 {counts}   bull's eye {r.bullseye:5.1f} %   "
                   f"NN {r.nn_precision:.3f} (other objects {r.nn_precision_other:.3f})   "
                   f"{r.seconds:.2f} s{other_pose}")
    paper = " ".join(f"{c:3d}" for c in PAPER_TABLE_I["Our"])
    typer.echo(f"  paper 'Our'    top-10 {paper}   0.0375 h (Matlab)")
    for method, key in (("stripes", "wins_and_losses"), ("profile", "profile_wins_and_losses")):
        for name, wl in js[key].items():
            typer.echo(f"  {method} vs {name}: better on {', '.join(wl['wins']) or '-'}; "
                       f"worse on {', '.join(wl['losses']) or '-'}")
    if paths:
        typer.echo(f"  report: {paths['report']}")


def _seed_list(seed: int, seeds: str | None) -> list[int]:
    if seeds is None:
        values = [seed]
    else:
        try:
            values = [int(v) for v in seeds.split(",") if v.strip()]
        except ValueError:
            raise UserError(f"--seeds must be comma-separated integers, got {seeds!r}") from None
        if not values:
            raise UserError("--seeds needs at least one seed")
    for v in values:
        if v < 0:
            raise UserError(f"--seed must be non-negative, got {v}")
    return list(dict.fromkeys(values))


def _precision_text(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


def landmarks(
    seed: Annotated[int, typer.Option("--seed", help="Seed of world, motion and noise.")] = 0,
    seeds: Annotated[
        str | None,
        typer.Option("--seeds", help="Several seeds, comma-separated (one run each; "
                     "with --out one subfolder seed-N each)."),
    ] = None,
    laps: Annotated[float, typer.Option("--laps", help="Laps of the figure-eight route.")] = 2.0,
    out: Annotated[
        Path | None, typer.Option("--out", help="Write report.md, results.json, PNGs here.")
    ] = None,
    cluster: ClusterOption = None,
    json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
) -> None:
    """Recognised objects as landmarks: recognition precision and ATE with / without them.

    With ``--cluster`` every seed is one Dask task (the same figures; only the seconds
    differ).  ``--seeds 0,1,2`` runs several seeds (``--json``: ``{"runs": [...]}``).
    """
    from evaluation.cluster import parse_cluster
    from evaluation.landmarks_benchmark import LandmarksCell, run_landmarks_cells
    from slam.cli.common import print_json
    from slam.json_io import write_json
    from slam.landmarks import LandmarkRunConfig

    parse_cluster(cluster)  # a bad --cluster fails before any work
    chosen = _seed_list(seed, seeds)
    if not laps > 0:
        raise UserError(f"--laps must be positive, got {laps}")
    if out is not None:
        output_dir(out)  # a bad --out fails now, not after the runs
        if cluster is not None:
            out = out.resolve()  # the workers write into it from their own folders
    cfg = LandmarkRunConfig(laps=laps)
    many = seeds is not None
    folders = [None if out is None else str(out / f"seed-{s}" if many else out) for s in chosen]
    cells = [LandmarksCell(s, cfg, f) for s, f in zip(chosen, folders, strict=True)]
    with _bars(cluster) as progress:
        docs = run_landmarks_cells(cells, cluster=cluster, progress=progress)
    doc = {"runs": docs} if many else docs[0]
    if many and out is not None:
        doc["outputs"] = {"results": str(write_json(out / "results.json", doc))}
    if json:
        print_json(doc)
        return
    for js in docs:
        typer.echo(
            f"landmarks (seed {js['seed']}): {js['clusters']} object clusters, "
            f"{js['recognitions']} recognitions, precision "
            f"{_precision_text(js['recognition_precision'])}, recall "
            f"{js['recognition_recall']:.3f}, {js['landmarks']} landmarks"
        )
        typer.echo(f"  ATE without landmarks {js['ate_without_m']:.3f} m, with landmarks "
                   f"{js['ate_with_m']:.3f} m")
        if "outputs" in js:
            typer.echo(f"  report: {js['outputs']['report']}")


def register(bench: typer.Typer) -> None:
    """Add ``stripes`` and ``landmarks`` to the ``bench`` command group."""
    bench.command("stripes")(stripes)
    bench.command("landmarks")(landmarks)
