"""The place-recognition paper's benchmark (Tables I-III): every matcher on a place set.

Paper: Kosnar, Vonasek, Kulich, Preucil, "Comparison of shape matching techniques
for place recognition" (``papers/shape-matching-place-recognition.txt``), Section III.B.

Protocol, per method (a matcher name of `loopclosure.matchers`, or ``cascade``):

1. **Describe** every shape once (`Matcher.describe`), timed with
   `time.process_time` (CPU seconds of this process, all its threads).
2. **All pairs.**  ``D[i] = distances(describe(shape i), stack(all descriptors))``
   for every query i: the full ``(M, M)`` matrix (self-distances included).  With
   ``workers > 1`` the rows are split into chunks computed by a
   `concurrent.futures.ProcessPoolExecutor` (``forkserver`` start on POSIX, so no
   worker is forked from a process running the progress bar's thread); each worker
   builds its own matcher and stack from the descriptors once (pool initializer)
   and reports the CPU time of its rows, so the compare time is CPU time
   whatever the number of workers.  The matrix is the same as with one worker.
   (As with any non-fork start method, a script that calls this with
   ``workers > 1`` must guard its entry point with ``if __name__ == "__main__"``;
   the ``loopclosure`` console script does.)
3. **Measures** (`evaluation.retrieval`), as the paper defines them: Bull's eye
   [%] (2n nearest, n = class size, the query itself counted as in the MPEG-7
   convention), area under the ROC curve of the pair decision "same place" by
   distance threshold, and the best balanced F-score of the precision-recall
   curve.  Pairs use the symmetrised matrix ``(D + D.T) / 2``.
4. **Times** [ms, CPU]:
   ``ms_describe`` = describe time / M;
   ``ms_compare`` = (stack + all-pairs) time / M^2, the batched compare cost per
   pair as this benchmark runs it;
   ``ms_per_pair`` = 2 ``ms_describe`` + ``ms_compare``: time to compare two
   places including the creation of both descriptors (Table I's definition);
   ``ms_compare_single`` = mean CPU time of one unbatched ``distance(a, b)`` call
   over up to 50 random pairs (the paper compared one pair at a time), and
   ``ms_per_pair_single`` = 2 ``ms_describe`` + ``ms_compare_single``.

Scale invariance is turned on (``scale_invariant=True``) for every matcher that
has the option when the data set asks for it (MPEG-7), as customary there; it is
off on the place sets (rooms differ only in scale).

A method whose module is missing (or does not define its class yet) is reported as
*unavailable* with the reason; one that raises or returns non-finite distances is
reported as *failed* with the error.  Neither stops the other methods.

`write_places_report` writes ``report.md`` (Tables I-III in the paper's layout,
ours beside the paper's figure for each data-set column, then the times),
``roc_<set>.png`` and ``pr_<set>.png`` (all methods on one plot per data set) and
``results.json``.
"""

from __future__ import annotations

import math
import multiprocessing
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from importlib import import_module
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError, warn
from evaluation.place_datasets import PlaceSet
from evaluation.retrieval import best_fscore, bullseye, curves, roc_auc
from loopclosure.matchers import MATCHER_NAMES, Matcher, matcher_class
from loopclosure.polygon import Polygon

Array = NDArray[np.float64]
Progress = Callable[[str, int, int], None]

ALL_METHODS: tuple[str, ...] = tuple(dict.fromkeys((*MATCHER_NAMES, "cascade")))
"""Every method `--methods all` runs: the paper's eight in its order, then the cascade."""

_CASCADE = ("loopclosure.cascade", "CascadeMatcher")

# ----------------------------------------------------------------- the paper's figures

PAPER_COLUMNS: tuple[str, ...] = ("box", "surface", "mpeg7", "robot")
COLUMN_TITLES = {"box": "Box", "surface": "Surface", "mpeg7": "MPEG-7", "robot": "Robot"}
PAPER_ROW_NAMES = {
    "fft": "Fft", "integral": "Integral", "ring": "Ring", "shape-context": "Shapecontext",
    "scanline": "Scanline", "mrm": "MRM", "tangent": "Tangent", "flirt": "Flirt",
}

PAPER_BULLSEYE: dict[str, tuple[float, float, float, float]] = {
    "fft": (78.54, 57.43, 65.40, 72.22),
    "integral": (83.24, 50.38, 48.21, 51.99),
    "ring": (98.80, 52.34, 34.84, 81.20),
    "shape-context": (92.35, 70.95, 63.72, 35.37),
    "scanline": (67.59, 50.48, 41.42, 38.98),
    "mrm": (97.20, 60.52, 77.95, 81.76),
    "tangent": (39.08, 58.94, 18.38, 30.37),
    "flirt": (97.84, 31.99, 16.12, 43.01),
}
"""Table I: Bull's eye [%] on Box, Surface, MPEG-7 (all 1,400 shapes), Robot."""

PAPER_TIME_MS: dict[str, float] = {
    "fft": 0.52, "integral": 1.60, "ring": 4.46, "shape-context": 10.47,
    "scanline": 70.79, "mrm": 87.63, "tangent": 15.33, "flirt": 191.23,
}
"""Table I: time [ms] to compare two places including both descriptors (robot set, one
core of a 3.1 GHz Xeon)."""

PAPER_AUC: dict[str, tuple[float, float, float, float]] = {
    "fft": (0.89, 0.73, 0.89, 0.90),
    "integral": (0.91, 0.72, 0.85, 0.85),
    "ring": (0.97, 0.74, 0.80, 0.89),
    "shape-context": (0.93, 0.81, 0.85, 0.68),
    "scanline": (0.86, 0.67, 0.76, 0.71),
    "mrm": (0.98, 0.75, 0.91, 0.93),
    "tangent": (0.65, 0.77, 0.60, 0.65),
    "flirt": (0.98, 0.59, 0.59, 0.70),
}
"""Table II: area under the ROC curve."""

PAPER_FSCORE: dict[str, tuple[float, float, float, float]] = {
    "fft": (0.62, 0.49, 0.57, 0.54),
    "integral": (0.66, 0.43, 0.42, 0.40),
    "ring": (0.86, 0.53, 0.32, 0.68),
    "shape-context": (0.80, 0.61, 0.62, 0.36),
    "scanline": (0.47, 0.43, 0.25, 0.33),
    "mrm": (0.89, 0.54, 0.68, 0.70),
    "tangent": (0.28, 0.44, 0.10, 0.24),
    "flirt": (0.91, 0.35, 0.20, 0.37),
}
"""Table III: best balanced F-score."""


def paper_figure(table: dict[str, tuple[float, ...]], method: str, kind: str) -> float | None:
    """The paper's figure of `method` on data-set `kind`, or None (e.g. the cascade)."""
    row = table.get(method)
    if row is None or kind not in PAPER_COLUMNS:
        return None
    return row[PAPER_COLUMNS.index(kind)]


# ----------------------------------------------------------------------- methods


def parse_methods(text: str) -> list[str]:
    """Method names from ``"all"`` or a comma-separated list (order kept, duplicates dropped)."""
    parts = [p.strip().lower() for p in text.split(",") if p.strip()]
    if not parts:
        raise UserError("--methods needs at least one method (or all)")
    if "all" in parts:
        if parts != ["all"]:
            raise UserError(f"--methods: 'all' cannot be combined with names, got {text!r}")
        return list(ALL_METHODS)
    unknown = [p for p in parts if p not in ALL_METHODS]
    if unknown:
        raise UserError(
            f"unknown method(s) {', '.join(unknown)}: choose all or any of "
            + ",".join(ALL_METHODS)
        )
    return list(dict.fromkeys(parts))


def method_class(name: str) -> type[Matcher]:
    """The matcher class of `name`; ImportError/AttributeError when its module is absent."""
    try:
        return matcher_class(name)
    except KeyError:
        if name != "cascade":
            raise
    module, cls = _CASCADE
    return getattr(import_module(module), cls)


def build_matcher(name: str, overrides: dict[str, Any]) -> Matcher:
    """``method_class(name)(**overrides)``."""
    return method_class(name)(**overrides)


def method_overrides(name: str, scale_invariant: bool) -> tuple[dict[str, Any], str | None]:
    """Config overrides for `name` on a data set, and a note when one could not be applied.

    Raises ImportError/AttributeError when the method is unavailable.
    """
    cls = method_class(name)
    if not scale_invariant:
        return {}, None
    try:
        cls(scale_invariant=True)
    except TypeError:
        return {}, f"{name} has no scale_invariant option: run as configured"
    return {"scale_invariant": True}, None


# ----------------------------------------------------------------------- results


@dataclass(slots=True)
class MethodResult:
    """Measures and CPU times of one method on one data set (module docstring)."""

    name: str
    bullseye: float
    auc: float
    fscore: float
    ms_per_pair: float
    ms_describe: float
    ms_compare: float
    ms_compare_single: float
    ms_per_pair_single: float
    distances: Array = field(repr=False)
    overrides: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """The JSON figures (no distance matrix)."""
        return {
            "bullseye": self.bullseye, "auc": self.auc, "fscore": self.fscore,
            "ms_per_pair": self.ms_per_pair, "ms_describe": self.ms_describe,
            "ms_compare": self.ms_compare, "ms_compare_single": self.ms_compare_single,
            "ms_per_pair_single": self.ms_per_pair_single, "config": self.overrides,
        }


@dataclass(slots=True)
class PlacesResult:
    """All methods on one data set."""

    dataset: str
    kind: str
    labels: NDArray[np.str_]
    description: dict[str, Any]
    methods: dict[str, MethodResult]
    unavailable: dict[str, str]
    failed: dict[str, str]
    notes: list[str]
    workers: int
    seed: int

    @property
    def shapes(self) -> int:
        return len(self.labels)

    @property
    def classes(self) -> int:
        return len(np.unique(self.labels))

    def to_json(self) -> dict[str, Any]:
        """``{"dataset", "shapes", "classes", "methods": {NAME: {...}}, ...}``."""
        return {
            "dataset": self.dataset,
            "kind": self.kind,
            "shapes": self.shapes,
            "classes": self.classes,
            "methods": {k: v.to_json() for k, v in self.methods.items()},
            "unavailable": list(self.unavailable),
            "unavailable_reasons": self.unavailable,
            "failed": self.failed,
            "notes": self.notes,
            "workers": self.workers,
            "seed": self.seed,
            "description": self.description,
        }


# ----------------------------------------------------------------------- workers

_WORKER: dict[str, Any] = {}


def _init_worker(name: str, overrides: dict[str, Any], descriptors: list[Any]) -> None:
    """Pool initializer: this worker's own matcher and stack (timed once)."""
    matcher = build_matcher(name, overrides)
    t0 = time.process_time()
    stacked = matcher.stack(descriptors)
    _WORKER.update(matcher=matcher, stacked=stacked, descriptors=descriptors,
                   stack_s=time.process_time() - t0, stack_reported=False)


def _worker_rows(start: int, stop: int) -> tuple[int, Array, float, float]:
    """Rows ``start:stop`` of the distance matrix, their CPU seconds, and the stack's once."""
    m, stacked, descs = _WORKER["matcher"], _WORKER["stacked"], _WORKER["descriptors"]
    t0 = time.process_time()
    block = np.stack([np.asarray(m.distances(descs[i], stacked), dtype=float)
                      for i in range(start, stop)])
    cpu = time.process_time() - t0
    stack_s = 0.0 if _WORKER["stack_reported"] else _WORKER["stack_s"]
    _WORKER["stack_reported"] = True
    return start, block, cpu, stack_s


def _pool_context() -> multiprocessing.context.BaseContext:
    """``forkserver`` (POSIX) with this module preloaded, so workers fork ready-imported."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["__main__", __name__])
    return ctx


def _matrix_parallel(
    name: str, overrides: dict[str, Any], descriptors: list[Any], workers: int,
    progress: Progress, label: str,
) -> tuple[Array, float]:
    """All-pairs matrix over `workers` processes; CPU seconds summed over the workers.

    The stack time is counted once per worker that reported rows, divided by the
    number of such workers (each builds the same stack).
    """
    m = len(descriptors)
    size = max(1, math.ceil(m / (workers * 8)))
    chunks = [(a, min(a + size, m)) for a in range(0, m, size)]
    out = np.empty((m, m))
    cpu, stack_total, stacks = 0.0, 0.0, 0
    done = 0
    with ProcessPoolExecutor(max_workers=workers, mp_context=_pool_context(),
                             initializer=_init_worker,
                             initargs=(name, overrides, descriptors)) as pool:
        futures = [pool.submit(_worker_rows, a, b) for a, b in chunks]
        for fut in as_completed(futures):
            start, block, c, s = fut.result()
            out[start:start + len(block)] = block
            cpu += c
            if s > 0:
                stack_total += s
                stacks += 1
            done += len(block)
            progress(label, done, m)
    return out, cpu + (stack_total / stacks if stacks else 0.0)


def _matrix_serial(
    matcher: Matcher, descriptors: list[Any], progress: Progress, label: str
) -> tuple[Array, float]:
    """All-pairs matrix in this process, and its CPU seconds (stack included)."""
    m = len(descriptors)
    out = np.empty((m, m))
    t0 = time.process_time()
    stacked = matcher.stack(descriptors)
    cpu = time.process_time() - t0
    step = max(1, m // 50)
    for i, d in enumerate(descriptors):  # one batched query per row (the protocol)
        t0 = time.process_time()
        out[i] = matcher.distances(d, stacked)
        cpu += time.process_time() - t0
        if (i + 1) % step == 0 or i + 1 == m:
            progress(label, i + 1, m)
    return out, cpu


def _single_compare_ms(
    matcher: Matcher, descriptors: list[Any], seed: int, pairs: int = 50
) -> float:
    """Mean CPU [ms] of one unbatched ``distance(a, b)`` over random pairs ``a != b``."""
    m = len(descriptors)
    rng = np.random.default_rng(seed)
    i = rng.integers(0, m, size=pairs)
    j = (i + rng.integers(1, m, size=pairs)) % m
    t0 = time.process_time()
    for a, b in zip(i, j, strict=True):  # deliberately unbatched: one pair at a time
        matcher.distance(descriptors[a], descriptors[b])
    return 1e3 * (time.process_time() - t0) / pairs


def _noop(stage: str, done: int, total: int) -> None:
    """Progress callback that does nothing."""


def run_method(
    name: str,
    polygons: Sequence[Polygon],
    labels: NDArray[np.str_],
    *,
    overrides: dict[str, Any] | None = None,
    workers: int = 1,
    seed: int = 0,
    progress: Progress | None = None,
) -> MethodResult:
    """Describe, all-pairs matrix, measures and CPU times of one method (module docstring).

    Raises whatever the matcher raises; `ValueError` when a distance is not finite.
    """
    progress = progress or _noop
    overrides = dict(overrides or {})
    matcher = build_matcher(name, overrides)
    m = len(polygons)
    descriptors: list[Any] = []
    describe_s = 0.0
    step = max(1, m // 20)
    for start in range(0, m, step):  # timed in slices so the progress bar moves
        t0 = time.process_time()
        descriptors += [matcher.describe(p) for p in polygons[start:start + step]]
        describe_s += time.process_time() - t0
        progress(f"{name}: describe", len(descriptors), m)
    label = f"{name}: all pairs"
    if workers > 1:
        d, compare_s = _matrix_parallel(name, overrides, descriptors, workers, progress, label)
    else:
        d, compare_s = _matrix_serial(matcher, descriptors, progress, label)
    bad = int((~np.isfinite(d)).sum())
    if bad:
        raise ValueError(f"{bad} of {d.size} distances are not finite")
    single = _single_compare_ms(matcher, descriptors, seed)
    ms_describe = 1e3 * describe_s / m
    ms_compare = 1e3 * compare_s / (m * m)
    return MethodResult(
        name=name,
        bullseye=bullseye(d, labels),
        auc=roc_auc(d, labels),
        fscore=best_fscore(d, labels),
        ms_per_pair=2.0 * ms_describe + ms_compare,
        ms_describe=ms_describe,
        ms_compare=ms_compare,
        ms_compare_single=single,
        ms_per_pair_single=2.0 * ms_describe + single,
        distances=d,
        overrides=overrides,
    )


def run_places(
    places: PlaceSet,
    methods: Sequence[str],
    *,
    workers: int = 1,
    seed: int = 0,
    progress: Progress | None = None,
) -> PlacesResult:
    """Every method of `methods` on one data set; unavailable/failed ones are recorded."""
    if workers < 1:
        raise UserError(f"--workers must be at least 1, got {workers}")
    polygons, labels, description = places
    scale_invariant = bool(description.get("scale_invariant", False))
    results: dict[str, MethodResult] = {}
    unavailable: dict[str, str] = {}
    failed: dict[str, str] = {}
    notes: list[str] = []
    for name in methods:  # one step per method
        try:
            overrides, note = method_overrides(name, scale_invariant)
        except (ImportError, AttributeError) as exc:
            unavailable[name] = f"{type(exc).__name__}: {exc}"
            continue
        if note:
            notes.append(note)
        try:
            results[name] = run_method(name, polygons, labels, overrides=overrides,
                                       workers=workers, seed=seed, progress=progress)
        except Exception as exc:  # a matcher's bug must not lose the other methods
            failed[name] = f"{type(exc).__name__}: {exc}"
    if unavailable:
        warn(f"{len(unavailable)} method(s) unavailable: {', '.join(unavailable)}")
    if failed:
        warn(f"{len(failed)} method(s) failed: "
             + "; ".join(f"{k} ({v})" for k, v in failed.items()))
    return PlacesResult(
        dataset=str(description.get("name")), kind=str(description.get("kind")),
        labels=np.asarray(labels), description=description, methods=results,
        unavailable=unavailable, failed=failed, notes=notes, workers=workers, seed=seed,
    )


# ----------------------------------------------------------------------- output


def json_document(results: Sequence[PlacesResult]) -> dict[str, Any]:
    """One data set: its ``to_json()``; several: ``{"datasets": [...]}``."""
    if len(results) == 1:
        return results[0].to_json()
    return {"datasets": [r.to_json() for r in results]}


def _fmt(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def summary_lines(result: PlacesResult) -> list[str]:
    """Plain-text table of one data set: ours vs the paper for every method."""
    k = result.kind
    head = (f"{result.dataset}: {result.shapes} shapes, {result.classes} classes, "
            f"workers {result.workers}")
    lines = [head, f"{'method':<14}{'bullseye':>18}{'AUC':>14}{'F-score':>14}"
                   f"{'ms/pair':>18}{'describe':>10}{'compare':>10}",
             f"{'':<14}{'ours / paper':>18}{'ours / paper':>14}{'ours / paper':>14}"
             f"{'ours / paper':>18}{'ms':>10}{'ms':>10}"]
    for name, r in result.methods.items():
        lines.append(
            f"{name:<14}"
            f"{r.bullseye:>9.2f} / {_fmt(paper_figure(PAPER_BULLSEYE, name, k), 2):>6}"
            f"{r.auc:>7.3f} / {_fmt(paper_figure(PAPER_AUC, name, k), 2):>4}"
            f"{r.fscore:>7.3f} / {_fmt(paper_figure(PAPER_FSCORE, name, k), 2):>4}"
            f"{r.ms_per_pair:>9.4f} / {_fmt(PAPER_TIME_MS.get(name), 2):>6}"
            f"{r.ms_describe:>10.4f}{r.ms_compare:>10.4f}"
        )
    for name, why in result.unavailable.items():
        lines.append(f"{name:<14}unavailable ({why})")
    for name, why in result.failed.items():
        lines.append(f"{name:<14}failed ({why})")
    return lines


def _row_order(results: Sequence[PlacesResult]) -> list[str]:
    names: list[str] = []
    for r in results:
        names += [*r.methods, *r.unavailable, *r.failed]
    return list(dict.fromkeys(names))


def _cell(result: PlacesResult, name: str, attr: str, digits: int) -> str:
    if name in result.methods:
        return f"{getattr(result.methods[name], attr):.{digits}f}"
    if name in result.unavailable:
        return "n/a"
    if name in result.failed:
        return "failed"
    return "-"


def _column_title(result: PlacesResult, results: Sequence[PlacesResult]) -> str:
    title = COLUMN_TITLES.get(result.kind, result.kind)
    if sum(r.kind == result.kind for r in results) > 1:
        title += f" ({result.dataset})"
    return title


def paper_tables(results: Sequence[PlacesResult]) -> dict[str, str]:
    """Markdown Tables I, II, III: per data set, our figure then the paper's."""
    from evaluation.report import table

    names = _row_order(results)
    timing = next((r for r in results if r.kind == "robot"), results[-1])
    out: dict[str, str] = {}
    specs = [("I", "bullseye", PAPER_BULLSEYE, 2), ("II", "auc", PAPER_AUC, 3),
             ("III", "fscore", PAPER_FSCORE, 3)]
    for number, attr, paper, digits in specs:
        headers = ["Method"]
        for r in results:
            title = _column_title(r, results)
            headers += [f"{title} ours", f"{title} paper"]
        if number == "I":
            headers += [f"Time [ms] ours ({_column_title(timing, results)})", "Time [ms] paper"]
        rows = []
        for name in names:
            row = [PAPER_ROW_NAMES.get(name, name)]
            for r in results:
                row += [_cell(r, name, attr, digits),
                        _fmt(paper_figure(paper, name, r.kind), 2)]
            if number == "I":
                row += [_cell(timing, name, "ms_per_pair", 4), _fmt(PAPER_TIME_MS.get(name), 2)]
            rows.append(row)
        out[number] = table(headers, rows)
    return out


def timing_table(results: Sequence[PlacesResult]) -> str:
    """Markdown table of every CPU time [ms] per data set, with the paper's Table I time."""
    from evaluation.report import table

    headers = ["Method", "data set", "ms/pair (batched)", "ms/pair (one pair)",
               "describe", "compare (batched)", "compare (one pair)", "paper ms/pair",
               "paper / ours (one pair)"]
    rows = []
    for r in results:
        for name, m in r.methods.items():
            paper = PAPER_TIME_MS.get(name)
            ratio = None if paper is None else paper / max(m.ms_per_pair_single, 1e-12)
            rows.append([name, _column_title(r, results), f"{m.ms_per_pair:.4f}",
                         f"{m.ms_per_pair_single:.4f}", f"{m.ms_describe:.4f}",
                         f"{m.ms_compare:.5f}", f"{m.ms_compare_single:.4f}",
                         _fmt(paper, 2), _fmt(ratio, 1)])
    return table(headers, rows)


def _thin(x: Array, y: Array, n: int = 2000) -> tuple[Array, Array]:
    """At most `n` points of a curve, first and last kept (plots stay light)."""
    if len(x) <= n:
        return x, y
    idx = np.unique(np.linspace(0, len(x) - 1, n).round().astype(int))
    return x[idx], y[idx]


def plot_result(result: PlacesResult, out: Path, stem: str) -> tuple[Path, Path]:
    """``roc_<stem>.png`` and ``pr_<stem>.png`` of every method of `result`."""
    from evaluation.plots import plot_curves

    roc: dict[str, tuple[Array, Array]] = {}
    pr: dict[str, tuple[Array, Array]] = {}
    for name, m in result.methods.items():
        c = curves(m.distances, result.labels)
        roc[f"{name} (AUC {m.auc:.3f})"] = _thin(np.r_[0.0, c.fpr], np.r_[0.0, c.tpr])
        pr[f"{name} (F {m.fscore:.3f})"] = _thin(c.recall, c.precision)
    title = f"{COLUMN_TITLES.get(result.kind, result.kind)}: {result.shapes} shapes"
    p1 = plot_curves(out / f"roc_{stem}.png", roc, "false positive rate",
                     "true positive rate", f"ROC, {title}", diagonal=True)
    p2 = plot_curves(out / f"pr_{stem}.png", pr, "recall", "precision",
                     f"precision-recall, {title}")
    return p1, p2


def _dataset_section(result: PlacesResult) -> str:
    d = result.description
    lines = [f"- `{result.dataset}`: {result.shapes} shapes in {result.classes} classes "
             f"(sizes {min(d['class_sizes'].values())}-{max(d['class_sizes'].values())}), "
             f"scale invariant: {d.get('scale_invariant')}, seed {result.seed}, "
             f"workers {result.workers}."]
    if d.get("rule"):
        lines.append(f"  Rule: {d['rule']}.")
    for log, f in d.get("logs", {}).items():
        lines.append(
            f"  - {log}: {f['scans']} scans ({f['beams']} beams over {f['fov_deg']} deg, "
            f"{f['virtual_scans']} virtual 360-degree scans), {f['places']} places, scans per "
            f"place {f['scans_per_place']}, passes {f['passes_per_place']}, heading spread "
            f"{f['heading_spread_deg']} deg"
        )
    for name, why in result.unavailable.items():
        lines.append(f"  - {name}: unavailable ({why})")
    for name, why in result.failed.items():
        lines.append(f"  - {name}: failed ({why})")
    lines += [f"  - note: {n}" for n in result.notes]
    return "\n".join(lines)


def write_places_report(out: Path, results: Sequence[PlacesResult]) -> dict[str, Path]:
    """``report.md``, ROC and P-R PNGs per data set, ``results.json`` in `out`."""
    from evaluation.report import image, write_report
    from slam.cli.common import write_json

    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, Path] = {}
    plots: list[str] = []
    seen: dict[str, int] = {}
    for r in results:
        seen[r.kind] = seen.get(r.kind, 0) + 1
        stem = r.kind if seen[r.kind] == 1 else f"{r.kind}{seen[r.kind]}"
        if r.methods:
            roc, pr = plot_result(r, out, stem)
            files[f"roc_{stem}"], files[f"pr_{stem}"] = roc, pr
            plots.append(f"{_column_title(r, results)}:\n\n" + image(roc, out, "ROC") + " "
                         + image(pr, out, "precision-recall"))
    tables = paper_tables(results)
    mpeg7_note = ("The paper's MPEG-7 column is on all 1,400 shapes; ours is on the folder "
                  "given (e.g. the 200-shape subset). ")
    protocol = (
        "Every shape is compared with every shape (`evaluation/places_benchmark.py`). "
        "Bull's eye counts same-class shapes among the 2n nearest (n = class size, query "
        "included); AUC and F-score over all unordered pairs of the symmetrised matrix. "
        "Times are CPU time (`time.process_time`) per comparison: batched = "
        "2 x describe + (stack + all-pairs `distances`) / M^2; one pair = 2 x describe + "
        "one `distance(a, b)`. The paper's time is on its robot set, one core of a "
        "3.1 GHz Xeon. " + (mpeg7_note if any(r.kind == "mpeg7" for r in results) else "")
    )
    sections = [
        ("Data sets", "\n".join(_dataset_section(r) for r in results)),
        ("Protocol", protocol),
        ("Table I: Bull's eye [%] and time per comparison [ms]", tables["I"]),
        ("Table II: area under ROC", tables["II"]),
        ("Table III: best F-score", tables["III"]),
        ("CPU times [ms]", timing_table(results)),
        ("ROC and precision-recall", "\n\n".join(plots) or "no method ran"),
    ]
    doc = json_document(results)
    doc["paper"] = {"columns": list(PAPER_COLUMNS), "bullseye": PAPER_BULLSEYE,
                    "auc": PAPER_AUC, "fscore": PAPER_FSCORE, "time_ms": PAPER_TIME_MS}
    write_json(out / "results.json", doc)
    files["results"] = out / "results.json"
    files["report"] = write_report(out / "report.md", "Place recognition: the paper's "
                                   "Tables I-III reproduced", sections)
    return files


__all__ = [
    "ALL_METHODS",
    "PAPER_AUC",
    "PAPER_BULLSEYE",
    "PAPER_COLUMNS",
    "PAPER_FSCORE",
    "PAPER_TIME_MS",
    "MethodResult",
    "PlacesResult",
    "build_matcher",
    "json_document",
    "method_class",
    "paper_figure",
    "paper_tables",
    "parse_methods",
    "run_method",
    "run_places",
    "summary_lines",
    "timing_table",
    "write_places_report",
]
