"""Batch mapping: many logs or bags, each mapped as `loopclosure run` maps one.

`expand_inputs` turns the command line's inputs into a list of files: a file is
taken as given; a folder that is a ROS 2 bag is one input; any other folder gives
the logs and bags inside it (`INPUT_SUFFIXES`, not recursive, sorted by name); a
pattern with ``*``, ``?`` or ``[`` is globbed (sorted).  Each input is mapped into
``OUT/<name>/``, where ``<name>`` is its file name without the format suffixes
(``intel-corrected.log.gz`` -> ``intel-corrected``; a name seen before gets ``-2``,
``-3``, ...).

`map_input` is the task: it runs on a worker (or here, serially), reads its
input from the path in its `BatchJob`, maps it with `slam.pipeline.Mapper`, writes
every output file with `slam.results.write_results` (the files of `loopclosure run`,
its ``config.yaml`` included) and returns one small row for ``batch.json``.  Where
the job names a relations file or a reference trajectory, the row also holds the
relations error (`evaluation.relations_metric`) of the written ``trajectory.tum``
or its ATE (`evaluation.trajectory_error`, rigid alignment); an evaluation that
cannot be made (no stamp in common) leaves the mapping result and says why in
``eval_error``.

A row (``batch.json``: ``{"runs": [row, ...], ...}``, one per input, input order):
``input``, ``name``, ``out``, ``status`` (``done``, ``failed``, ``interrupted``),
``error`` (null or the one error line), ``scans``, ``keyframes``, ``loops_accepted``,
``loops_proposed``, ``wall_s`` (mapping and writing [s]), ``peak_rss_mb`` (the
peak resident memory of the process while it mapped this input [MB]; on Linux the
peak is reset before each input, elsewhere it is the process's peak so far),
``relations`` (`RelationsMetric.to_json` or null), ``relations_file``, ``ate``
(``{"rmse_m", "mean_m", "max_m", "matched"}`` or null), ``reference_file``,
``eval_error``.
"""

from __future__ import annotations

import glob
import itertools
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from data.errors import UserError

INPUT_SUFFIXES = (".clf", ".log", ".bag", ".db3", ".mcap")
"""Files of a folder input that are mapped (optionally compressed: ``.gz``, ``.bz2``)."""
COMPRESSION_SUFFIXES = (".gz", ".bz2")
REFERENCE_SUFFIXES = (".tum", ".txt")
"""``--reference-dir`` is searched for ``<name><suffix>`` in this order."""


@dataclass(frozen=True, slots=True)
class BatchJob:
    """One input of a batch: what a worker needs to map it (paths, not data).

    `config` is the `slam.config.PipelineConfig` of every run; `relations` and
    `reference` are the evaluation files of this input, if any; `limit` maps only the
    first that many scans (None: all).
    """

    input: Path
    name: str
    out: Path
    config: Any
    topic: str | None = None
    odom_topic: str | None = None
    strict: bool = False
    write_map: bool = True
    limit: int | None = None
    relations: Path | None = None
    reference: Path | None = None


@dataclass(slots=True)
class BatchResult:
    """The rows of a batch (input order) and whether Ctrl-C cut it short."""

    rows: list[dict[str, Any]] = field(default_factory=list)
    interrupted: bool = False
    wall_s: float = 0.0
    cluster: str = "in-process (serial)"

    @property
    def failed(self) -> int:
        return sum(r["status"] != "done" for r in self.rows)

    def to_json(self) -> dict[str, Any]:
        return {"runs": self.rows, "interrupted": self.interrupted, "wall_s": self.wall_s,
                "cluster": self.cluster, "inputs": len(self.rows), "failed": self.failed}


# -- inputs ----------------------------------------------------------------------------


def _is_log_or_bag(path: Path) -> bool:
    name = path.name.lower()
    for c in COMPRESSION_SUFFIXES:
        name = name.removesuffix(c)
    return name.endswith(INPUT_SUFFIXES)


def _is_ros2_bag(path: Path) -> bool:
    return path.is_dir() and (path / "metadata.yaml").is_file()


def expand_inputs(inputs: Sequence[str | Path]) -> list[Path]:
    """The files (and ROS 2 bag folders) that `inputs` name (module docstring).

    Raises `UserError` when a pattern or a folder names nothing to map.  A path
    that does not exist is kept: its run fails with the reader's error line.
    """
    found: list[Path] = []
    for text in map(str, inputs):
        if any(c in text for c in "*?["):
            matches = sorted(Path(p) for p in glob.glob(text))
            if not matches:
                raise UserError(f"{text}: the pattern matches no file")
            found += [p for p in matches if not p.is_dir() or _is_ros2_bag(p)]
            continue
        path = Path(text)
        if path.is_dir() and not _is_ros2_bag(path):
            inside = sorted(
                p for p in path.iterdir()
                if not p.name.startswith(".")
                and ((p.is_file() and _is_log_or_bag(p)) or _is_ros2_bag(p))
            )
            if not inside:
                raise UserError(f"{path}: the folder holds no log or bag "
                                f"({', '.join(INPUT_SUFFIXES)}, optionally .gz/.bz2)")
            found += inside
        else:
            found.append(path)
    if not found:
        raise UserError("no input to map")
    return found


def run_name(path: Path) -> str:
    """The output folder name of an input: its file name less the format suffixes."""
    name = path.name
    for c in COMPRESSION_SUFFIXES:
        if name.lower().endswith(c):
            name = name[: -len(c)]
    for s in INPUT_SUFFIXES:
        if name.lower().endswith(s):
            name = name[: -len(s)]
    return name or path.name


def unique_names(paths: Iterable[Path]) -> list[str]:
    """`run_name` of each path, with ``-2``, ``-3`` ... appended to a name seen before."""
    seen: dict[str, int] = {}
    names = []
    for p in paths:
        base = run_name(p)
        seen[base] = seen.get(base, 0) + 1
        names.append(base if seen[base] == 1 else f"{base}-{seen[base]}")
    return names


def find_evaluation_file(folder: Path | None, name: str, suffixes: Sequence[str]) -> Path | None:
    """``folder/<name><suffix>`` for the first suffix that exists, or None."""
    if folder is None:
        return None
    for s in suffixes:
        candidate = folder / f"{name}{s}"
        if candidate.is_file():
            return candidate
    return None


def make_jobs(
    inputs: Sequence[Path],
    out: Path,
    config: Any,
    *,
    relations_dir: Path | None = None,
    reference_dir: Path | None = None,
    **options: Any,
) -> list[BatchJob]:
    """One `BatchJob` per input, into ``out/<name>/`` (`options`: the `BatchJob` fields
    `topic`, `odom_topic`, `strict`, `write_map`, `limit`)."""
    for label, folder in (("--relations-dir", relations_dir), ("--reference-dir", reference_dir)):
        if folder is not None and not folder.is_dir():
            raise UserError(f"{label} {folder}: no such folder")
    return [
        BatchJob(
            input=path, name=name, out=out / name, config=config,
            relations=find_evaluation_file(relations_dir, name, (".relations",)),
            reference=find_evaluation_file(reference_dir, name, REFERENCE_SUFFIXES),
            **options,
        )
        for path, name in zip(inputs, unique_names(inputs), strict=True)
    ]


# -- the task --------------------------------------------------------------------------


def map_input(job: BatchJob) -> dict[str, Any]:
    """Map one input as `loopclosure run` does and return its ``batch.json`` row.

    Runs where the engine puts it (a worker, or this process).  Raises `UserError`
    for a bad input (the engine turns it into the row's error line).  A run that
    Ctrl-C cut short (only possible in-process) writes what was mapped, then
    re-raises `KeyboardInterrupt` so that the batch stops.
    """
    from data.atomic_write import output_dir
    from data.sources import open_source
    from slam.config_io import dump_config
    from slam.memory import peak_rss_since_reset_mb, reset_peak_rss
    from slam.pipeline import Mapper
    from slam.results import write_results

    reset = reset_peak_rss()
    start = time.perf_counter()
    source = open_source(job.input, topic=job.topic, odom_topic=job.odom_topic,
                         strict=job.strict)
    output_dir(job.out)
    dump_config(job.config, job.out / "config.yaml")
    scans = source if job.limit is None else itertools.islice(source, job.limit)
    result = Mapper(job.config).run(scans)
    summary = write_results(job.out, result, str(job.input),
                            wall_s=time.perf_counter() - start, write_map=job.write_map,
                            map_config=job.config.map)
    if summary.get("interrupted"):
        raise KeyboardInterrupt
    row = {
        "scans": summary["scans"],
        "keyframes": summary["keyframes"],
        "loops_proposed": summary["loops_proposed"],
        "loops_accepted": summary["loops_accepted"],
        "wall_s": summary["wall_s"],
        "peak_rss_mb": peak_rss_since_reset_mb(reset),
    }
    row.update(_evaluate(job, job.out / "trajectory.tum"))
    return row


def _evaluate(job: BatchJob, trajectory: Path) -> dict[str, Any]:
    """The relations error and ATE of the written trajectory, where the job has files."""
    figures: dict[str, Any] = {"relations": None, "ate": None, "eval_error": None}
    if job.relations is None and job.reference is None:
        return figures
    errors = []
    if not trajectory.is_file():
        figures["eval_error"] = f"{job.out}: no trajectory.tum written (no scan mapped)"
        return figures
    from data.trajectory_io import read_tum

    estimate = read_tum(trajectory)
    if job.relations is not None:
        from data.relations import read_relations
        from evaluation.relations_metric import relations_metric

        try:
            metric = relations_metric(estimate, read_relations(job.relations))
            if metric.relations_used:
                figures["relations"] = metric.to_json()
            else:
                errors.append(f"{job.relations}: no relation has both stamps in the trajectory")
        except UserError as exc:
            errors.append(str(exc))
    if job.reference is not None:
        from evaluation.trajectory_error import trajectory_errors

        try:
            e = trajectory_errors(estimate, read_tum(job.reference))
            figures["ate"] = {"rmse_m": e.ate_rmse, "mean_m": e.ate_mean, "max_m": e.ate_max,
                              "matched": e.matched}
        except UserError as exc:
            errors.append(str(exc))
    figures["eval_error"] = "; ".join(errors) or None
    return figures


# -- the batch -------------------------------------------------------------------------


def _row(job: BatchJob, status: str, value: dict[str, Any] | None, error: str | None
         ) -> dict[str, Any]:
    row: dict[str, Any] = {
        "input": str(job.input), "name": job.name, "out": str(job.out), "status": status,
        "error": error, "scans": None, "keyframes": None, "loops_proposed": None,
        "loops_accepted": None, "wall_s": None, "peak_rss_mb": None, "relations": None,
        "relations_file": None if job.relations is None else str(job.relations),
        "ate": None, "reference_file": None if job.reference is None else str(job.reference),
        "eval_error": None,
    }
    row.update(value or {})
    return row


def run_batch(
    jobs: Sequence[BatchJob], cluster: str | None = None, *, progress: bool = True
) -> BatchResult:
    """Map every job on the engine `cluster` names (`evaluation.cluster`); rows in job order."""
    from evaluation.cluster import Engine

    start = time.perf_counter()
    result = BatchResult()
    with Engine(cluster) as engine:
        result.cluster = engine.spec.describe()
        for outcome in engine.map(map_input, jobs, description="batch", progress=progress):
            result.rows.append(_row(outcome.item, outcome.status, outcome.value, outcome.error))
            result.interrupted |= outcome.status == "interrupted"
    result.wall_s = time.perf_counter() - start
    return result


def write_batch(out: Path, result: BatchResult) -> tuple[Path, Path]:
    """``out/batch.json`` and ``out/batch.md`` (one row per input); returns both paths."""
    from evaluation.report import table, write_report
    from slam.json_io import write_json

    write_json(out / "batch.json", result.to_json())
    headers = ["run", "input", "scans", "keyframes", "loops", "wall [s]", "peak [MB]",
               "relations trans [m]", "relations rot [deg]", "ATE rmse [m]", "error"]
    body = []
    for r in result.rows:
        rel, ate = r["relations"] or {}, r["ate"] or {}
        body.append([
            r["name"], _cell(r["input"]), r["scans"], r["keyframes"], r["loops_accepted"],
            r["wall_s"], r["peak_rss_mb"], rel.get("trans_abs_mean"), rel.get("rot_abs_mean_deg"),
            ate.get("rmse_m"), _cell(r["error"] or r["eval_error"] or ""),
        ])
    state = "interrupted: " if result.interrupted else ""
    intro = (f"{state}{len(result.rows)} inputs, {result.failed} not mapped; "
             f"{result.cluster}; {result.wall_s:.1f} s wall time.  Each input's results are "
             "in the folder of its name; relations error: mean absolute error of the "
             "relations (Kümmerle et al. 2009); ATE: RMSE after rigid alignment.")
    md = write_report(out / "batch.md", "Batch mapping", [("Runs", intro + "\n\n" +
                                                          table(headers, body))])
    return out / "batch.json", md


def _cell(text: str) -> str:
    """`text` safe in a markdown table cell (one line, no column separator)."""
    return " ".join(text.split()).replace("|", "\\|")
