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
   Otherwise the matrix is computed as independent tasks, one block of rows of
   one matcher on one data set each (`evaluation.places_matrix.matrix_by_blocks`),
   in this process or, with ``cluster``, on a Dask cluster whose workers load the
   data set themselves: the same matrix, bit for bit.
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

Modules: the method names and matcher construction are in
`evaluation.places_methods`, the all-pairs matrix (one process or a pool) and its
CPU times in `evaluation.places_matrix`, the paper's figures in
`evaluation.places_paper`.  `evaluation.places_report.write_places_report` writes
``report.md`` (Tables I-III in the paper's layout, ours beside the paper's figure
for each data-set column, then the times), ``roc_<set>.png`` and ``pr_<set>.png``
(all methods on one plot per data set) and ``results.json``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, is_dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError, warn
from evaluation.place_datasets import PlaceSet
from evaluation.places_matrix import (
    BlockFailed,
    PlaceSource,
    all_pairs_matrix,
    describe_all,
    matrix_by_blocks,
    single_compare_ms,
)
from evaluation.places_methods import build_matcher, method_overrides
from evaluation.retrieval import best_fscore, bullseye, roc_auc
from loopclosure.polygon import Polygon

Array = NDArray[np.float64]
Progress = Callable[[str, int, int], None]


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
            "ms_per_pair_single": self.ms_per_pair_single,
            "config": {k: asdict(v) if is_dataclass(v) else v
                       for k, v in self.overrides.items()},
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


def _noop(stage: str, done: int, total: int) -> None:
    """Progress callback that does nothing."""


def run_places(
    places: PlaceSet,
    methods: Sequence[str],
    *,
    workers: int = 1,
    seed: int = 0,
    progress: Progress | None = None,
    source: PlaceSource | None = None,
    cluster: str | None = None,
) -> PlacesResult:
    """Every method of `methods` on one data set; unavailable/failed ones are recorded.

    `cluster` (an `evaluation.cluster` address; not with ``workers > 1``): the blocks
    of rows of every matrix run on Dask, the workers loading `source` (the data set
    `places` was loaded from).
    """
    if workers < 1:
        raise UserError(f"--workers must be at least 1, got {workers}")
    if cluster is not None and workers > 1:
        raise UserError("give either --workers N (a local process pool) or --cluster, not both")
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
                                       workers=workers, seed=seed, progress=progress,
                                       source=source, cluster=cluster)
        except BlockFailed as exc:  # its message is the error line already
            failed[name] = str(exc)
        except Exception as exc:  # a matcher's bug must not lose the other methods
            failed[name] = f"{type(exc).__name__}: {exc}"
    _warn_missing(unavailable, failed)
    return PlacesResult(
        dataset=str(description.get("name")), kind=str(description.get("kind")),
        labels=np.asarray(labels), description=description, methods=results,
        unavailable=unavailable, failed=failed, notes=notes, workers=workers, seed=seed,
    )


def _warn_missing(unavailable: dict[str, str], failed: dict[str, str]) -> None:
    """One warning for the unavailable methods and one for the failed ones."""
    if unavailable:
        warn(f"{len(unavailable)} method(s) unavailable: {', '.join(unavailable)}")
    if failed:
        warn(f"{len(failed)} method(s) failed: "
             + "; ".join(f"{k} ({v})" for k, v in failed.items()))


def run_method(
    name: str,
    polygons: Sequence[Polygon],
    labels: NDArray[np.str_],
    *,
    overrides: dict[str, Any] | None = None,
    workers: int = 1,
    seed: int = 0,
    progress: Progress | None = None,
    source: PlaceSource | None = None,
    cluster: str | None = None,
) -> MethodResult:
    """Describe, all-pairs matrix, measures and CPU times of one method (module docstring).

    With ``workers > 1`` the shapes are described here and the rows computed by a
    local process pool; otherwise the matrix is one task per block of rows
    (`evaluation.places_matrix.matrix_by_blocks`), here or on `cluster`.

    Raises whatever the matcher raises (`BlockFailed` with its error line from a
    block); `ValueError` when a distance is not finite.
    """
    progress = progress or _noop
    overrides = dict(overrides or {})
    if workers > 1:
        matcher = build_matcher(name, overrides)
        descriptors, describe_s = describe_all(name, matcher, polygons, progress)
        d, compare_s = all_pairs_matrix(name, matcher, overrides, descriptors, workers,
                                        progress, f"{name}: all pairs")
        single = None
    else:
        d, describe_s, compare_s, single = matrix_by_blocks(
            name, overrides, polygons, seed=seed, progress=progress, source=source,
            cluster=cluster)
    bad = int((~np.isfinite(d)).sum())
    if bad:  # a matcher's bug, reported as the method's failure
        raise ValueError(f"{bad} of {d.size} distances are not finite")
    if single is None:
        single = single_compare_ms(matcher, descriptors, seed)
    return _measures(name, d, labels, describe_s, compare_s, single, overrides)


def _measures(
    name: str, d: Array, labels: NDArray[np.str_], describe_s: float, compare_s: float,
    ms_compare_single: float, overrides: dict[str, Any],
) -> MethodResult:
    """Bull's eye, AUC, F-score of the ``(M, M)`` matrix `d` and the CPU times in ms of
    describing the M shapes (`describe_s`) and comparing them (`compare_s`)."""
    m = len(d)
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
        ms_compare_single=ms_compare_single,
        ms_per_pair_single=2.0 * ms_describe + ms_compare_single,
        distances=d,
        overrides=overrides,
    )


__all__ = ["MethodResult", "PlacesResult", "run_method", "run_places"]
