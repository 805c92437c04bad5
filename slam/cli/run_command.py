"""`loopclosure run`: map a log or bag (or the embedded simulated demo) and write the results.

Run reporters
-------------
Packages above `slam` in the dependency order add figures to a run without `slam`
importing them: after a run has written its results, `run` calls every reporter
registered with `add_run_reporter` as ``reporter(result, source, out)``, where
`result` is the `slam.pipeline.MappingResult`, `source` what was mapped (the
`data.sim.SimulatedRun` of the embedded demo, else the opened log or bag) and `out`
the output folder.  A reporter returns None (nothing to add) or a `RunReport`: its
`summary` goes into ``summary.json`` (and ``--json``) under its `key`, its `lines`
are printed after the run's summary line.  `evaluation` registers its demo report
(ATE and loop precision / recall against the simulator's ground truth) this way,
from the ``loopclosure.commands`` entry point; without it, `run` prints no report.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from slam.cli.common import print_json, write_json

if TYPE_CHECKING:
    from data.progress import ReadProgress

DEMO_SENSOR = {"fov_deg": 180.0, "beams": 181, "max_range": 12.0, "noise_sigma": 0.02}
"""The demo's laser: a SICK-like 180-degree scanner (the simulator's default is 360)."""
DEMO_HEADING_BIAS = 0.01
"""The demo robot's wheel odometry turns 0.01 rad per metre more than it drives
(`data.sim.OdometryNoise.heading_bias`): metres of drift over its 126 m, so that the
map before loop closure (``map_before.png``) shows what loop closure repairs."""
DEMO_FRONT_END = "wheel"
"""The demo maps with that odometry (``--odometry icp2d`` scan-matches it instead,
which on a simulated laser leaves centimetres of drift)."""


@dataclass(frozen=True, slots=True)
class RunReport:
    """What a run reporter adds: ``summary[key] = summary`` and `lines` to print."""

    key: str
    summary: dict[str, Any]
    lines: tuple[str, ...] = ()


RunReporter = Callable[[Any, Any, Path], RunReport | None]
"""``reporter(result, source, out) -> RunReport | None`` (module docstring)."""

_REPORTERS: dict[str, RunReporter] = {}


def add_run_reporter(name: str, reporter: RunReporter) -> None:
    """Call `reporter` after every run (module docstring); a second `name` replaces the first."""
    _REPORTERS[name] = reporter


def run(
    input: Annotated[
        Path | None,
        typer.Argument(help="CARMEN log or ROS bag; omit to run the embedded simulated demo."),
    ] = None,
    out: Annotated[Path, typer.Option("--out", help="Output folder.")] = Path("out"),
    topic: Annotated[str | None, typer.Option("--topic", help="Scan topic of a bag.")] = None,
    odom_topic: Annotated[
        str | None, typer.Option("--odom-topic", help="nav_msgs/Odometry topic of a bag.")
    ] = None,
    odometry: Annotated[
        str | None, typer.Option("--odometry", help="Front end: icp2d, kiss-icp or wheel.")
    ] = None,
    config: Annotated[
        Path | None, typer.Option("--config", help="YAML file of parameters (config.yaml).")
    ] = None,
    overrides: Annotated[
        list[str] | None,
        typer.Option("--set", help="Override one parameter, e.g. --set loops.local_max=2."),
    ] = None,
    saved_map: Annotated[
        Path | None,
        typer.Option("--map", help="Continue this saved map (a run's --out folder): the "
                     "input is a new session, joined to it by place recognition."),
    ] = None,
    no_map: Annotated[bool, typer.Option("--no-map", help="Skip the occupancy map.")] = False,
    strict: Annotated[bool, typer.Option("--strict", help="Malformed input is an error.")] = False,
    json: Annotated[bool, typer.Option("--json", help="Print summary.json on stdout.")] = False,
) -> None:
    """Map a log or bag: trajectory, pose graph, loop closures, occupancy map, summary.

    With ``--map DIR`` the log continues the map saved in DIR (its parameters, unless
    --config / --set say otherwise) from an unknown start pose; ``sessions.json`` says
    whether and where it was joined.
    """
    from data.atomic_write import output_dir
    from slam.config_io import dump_config
    from slam.pipeline import Mapper
    from slam.results import write_results
    from slam.session_file import read_saved_map

    saved = read_saved_map(saved_map) if saved_map is not None else None
    if input is None and odometry is None and config is None and saved is None:
        odometry = DEMO_FRONT_END
    cfg = _config(config, odometry, overrides, saved.config if saved else None)
    output_dir(out)
    dump_config(cfg, out / "config.yaml")
    source, scans, reading, source_name = _open_input(input, topic, odom_topic, strict)
    start = time.perf_counter()
    result = _run_with_progress(Mapper(cfg, saved=saved, name=source_name), scans, reading)
    summary = write_results(
        out, result, source_name, wall_s=time.perf_counter() - start, write_map=not no_map,
        map_config=cfg.map,
    )
    reports = _call_reporters(result, source, out)
    if reports:
        summary.update({r.key: r.summary for r in reports})
        write_json(out / "summary.json", summary)
    if json:
        print_json(summary)
    else:
        _print_summary(summary, out, [line for r in reports for line in r.lines])


def _config(
    config: Path | None, odometry: str | None, overrides: list[str] | None,
    saved: dict[str, Any] | None = None,
) -> Any:
    """The `PipelineConfig` of the run: defaults (or a saved map's `saved` tree), the
    `config` file, ``--odometry``, ``--set``."""
    from data.errors import UserError
    from slam.config import PipelineConfig
    from slam.config_io import apply_overrides, from_dict, load_config
    from slam.odometry import FRONT_ENDS

    if config:
        cfg = load_config(PipelineConfig, config)
    elif saved is not None:
        cfg = from_dict(PipelineConfig, saved, where="the saved map's config")
    else:
        cfg = PipelineConfig()
    if odometry:
        overrides = [f"odometry={odometry}", *(overrides or [])]
    cfg = apply_overrides(cfg, overrides or [])
    if cfg.odometry not in FRONT_ENDS:
        raise UserError(f"unknown odometry {cfg.odometry!r}; choose {', '.join(FRONT_ENDS)}")
    return cfg


def _open_input(
    input: Path | None, topic: str | None, odom_topic: str | None, strict: bool
) -> tuple[Any, Any, ReadProgress, str]:
    """``(source, scans, progress, name)`` of the input, or of the embedded demo (a
    `data.sim.SimulatedRun`, which is then the source the reporters see).  The
    progress is the reader's own (`data.sources.ScanSource.progress`): its total is
    known without a pass over the input."""
    if input is None:
        from data.progress import ReadProgress
        from data.sim import OdometryNoise, simulate_run

        typer.echo(
            "no input given: running the embedded demo (simulated box world, drifting "
            "wheel odometry)", err=True,
        )
        from slam.kernel_warm_up import warm_up_isolated

        warm_up_isolated()  # the first run after an install compiles the kernels
        demo = simulate_run(
            "box", seed=0, odometry_noise=OdometryNoise(heading_bias=DEMO_HEADING_BIAS),
            **DEMO_SENSOR,
        )
        return (demo, demo.scans, ReadProgress(len(demo.scans), "scans"),
                "simulated box world (seed 0)")
    from data.sources import open_source

    source = open_source(input, topic=topic, odom_topic=odom_topic, strict=strict)
    return source, source, source.progress(), str(input)


def _run_with_progress(mapper: Any, scans: Any, reading: ReadProgress) -> Any:
    """`mapper.run(scans)` under a progress bar: scans mapped of the input's scan
    count, exact when the reader knows it, else estimated by the reader from the
    bytes read so far (shown with ``~``) until its pass ends."""
    from rich.progress import (
        BarColumn,
        Progress,
        TaskProgressColumn,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    # A new session of a saved map says whether it is localised in the map yet.
    session = mapper.saved is not None

    def where() -> str:
        return ("  localised in the saved map" if mapper.joined
                else "  not yet localised") if session else ""

    columns = [
        TextColumn("mapping"), BarColumn(), TaskProgressColumn(),
        TextColumn("{task.fields[scans]} scans  {task.fields[kf]} keyframes  "
                   "{task.fields[loops]} loops{task.fields[where]}"),
        TimeElapsedColumn(), TimeRemainingColumn(),
    ]
    with Progress(*columns, transient=True) as bar:
        task = bar.add_task("mapping", total=None, scans="0", kf=0, loops=0, where=where())

        def progress(n: int, keyframes: int, loops: int) -> None:
            if n % 10 == 0:
                total, exact = reading.scan_total()
                count = f"{n}" if total is None else f"{n}/{'' if exact else '~'}{total}"
                bar.update(task, total=total, completed=n, scans=count, kf=keyframes,
                           loops=loops, where=where())

        return mapper.run(scans, progress=progress)


def _call_reporters(result: Any, source: Any, out: Path) -> list[RunReport]:
    """The reports of every registered reporter that has something to add, in order."""
    reports = [reporter(result, source, out) for reporter in _REPORTERS.values()]
    return [r for r in reports if r is not None]


def _print_summary(summary: dict[str, Any], out: Path, report_lines: list[str]) -> None:
    by_search = summary.get("loops_by_stage", {})
    typer.echo(
        f"{summary['scans']} scans, {summary['keyframes']} keyframes, "
        f"{summary['loops_proposed']} loop candidates, {summary['loops_accepted']} accepted "
        f"({by_search.get('appearance', 0)} proposed by the place database, "
        f"{by_search.get('pose', 0)} by the pose search), "
        f"{summary['loops_rejected_by_gnc']} rejected by GNC; {summary['wall_s']:.1f} s, "
        f"peak {summary['peak_rss_mb']:.0f} MB"
        + (f" (front-end worker {summary['peak_rss_mb_worker']:.0f} MB)"
           if summary.get("peak_rss_mb_worker") else "")
        + ("  (interrupted)" if summary.get("interrupted") else "")
    )
    sessions = summary.get("sessions", [])
    if len(sessions) > 1:
        s = sessions[-1]
        typer.echo(
            f"session {len(sessions)} joined the saved map at its keyframe "
            f"{s['joined_at_keyframe']} after {s['joined_after_m']:.1f} m "
            f"({s['loops']} loops between the sessions)" if s["joined"]
            else f"session {len(sessions)} was NOT joined to the saved map: written in "
            "its own frame"
        )
    for line in report_lines:
        typer.echo(line)
    typer.echo(f"results in {out}/")


def register(app: typer.Typer) -> None:
    """Add `run` to `app`; reporters of an app built earlier are forgotten (plugins that
    register after this add theirs again)."""
    _REPORTERS.clear()
    app.command()(run)
