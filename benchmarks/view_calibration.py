"""Benchmark: one logistic model per view of the loop detector, fitted and compared.

Run from the repository root::

    python benchmarks/view_calibration.py LOG[:RELATIONS] ... [--fit NAME ...]
        [--cache DIR] [--set KEY=VALUE ...]

Every log is mapped as ``loopclosure bench loops`` maps it (`evaluation.loop_bench`; a
log without ``:RELATIONS`` is a corrected log: its logged poses are the reference and
its odometry the drifting one of seed 0), and every keyframe queries, as the
benchmark's ``fused`` row does, its own view's database and, when it has one, the wide
view's (`loopclosure.keyframe_store`), each over the eligible older keyframes with a
reference pose.  Of each view's answer the candidates among the prefilter's K best
(``prefilter_rank < top_k``) give labelled pairs: the features
``log(d_s / scale_s + eps)`` of `loopclosure.fusion` (that database's scales at the
query) and whether the stored keyframe lies within 2 m of the query by the reference,
the pairs `loopclosure.place_config.DEFAULT_LOGISTIC` was fitted on.

`fit_logistic` (ridge 1) fits one model per view on the logs named by ``--fit`` (file
names without extension, e.g. ``freiburg-101-corrected``; default: all) and prints
them as `LogisticFusion`.  Then, per log, the fused top-1 proposal of every query is
judged (correct: within 2 m) under these choices of view: the own view alone, the wide
view alone (the own where there is none), the two merged by the database's score as
the detector merges them (``shared``: both scored by the database's logistic), merged
with the wide view scored by the fitted wide model (``per-view``, as
``loops.view_calibration=per-view``), and with both views scored by their fitted
models (``both refitted``), or the view whose best place stands out more from its
best other place (``distinct``: the larger difference of their score logits, no
fit); the ``(held out)`` rows fit on every other log given, ``path (held out)`` with
a third feature of the wide model: the log path length [m] of the keyframes its map
holds (by the reference poses).
Printed: recall@1 over the revisits, recall at 100% precision and average precision
over the score threshold (`evaluation.loop_bench_truth`).  ``--cache DIR`` keeps each log's pairs
(``DIR/NAME.npz``) and reads them instead of mapping again.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evaluation.loop_bench import mapped_input  # noqa: E402
from evaluation.loop_bench_input import LoopSource  # noqa: E402
from evaluation.loop_bench_truth import average_precision, pr_curve, recall_at_precision  # noqa: E402
from loopclosure.fusion import LogisticFusion, fit_logistic, log_features  # noqa: E402
from loopclosure.place_database import PlaceDatabase  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402
from slam.config_io import apply_overrides  # noqa: E402

RADIUS = 2.0  # a revisit / a correct place: within this of the query [m]
VIEWS = ("own", "wide")


def _rows(matches: list, stages: tuple[str, ...], scales: dict[str, float], ref: np.ndarray,
          k: int, query: int, top_k: int) -> np.ndarray:
    """``(n, S + 5)`` rows of one view's answer: features, score, same place, rank, query,
    stored key."""
    if not matches:
        return np.zeros((0, len(stages) + 5))
    d = np.array([[m.distances[s] for s in stages] for m in matches], float)
    f = log_features(d, [scales[s] for s in stages])
    keys = np.array([int(m.key) for m in matches], np.intp)
    same = np.hypot(*(ref[keys, :2] - ref[k, :2]).T) <= RADIUS
    rank = np.array([m.prefilter_rank for m in matches], float)
    score = np.array([m.score for m in matches], float)
    out = np.column_stack([f, score, same, rank, np.full(len(keys), query), keys])
    return out[rank < top_k] if top_k else out


def collect(log: str, relations: str | None, config: PipelineConfig) -> dict[str, np.ndarray]:
    """Per view, the rows (`_rows`) of every query of `log` (module docstring), and
    ``revisit``: whether each query has one."""
    source = LoopSource(str(Path(log).resolve()), relations=relations,
                        reference_from_log=relations is None,
                        odometry_noise=None if relations else 0, folder=str(Path.cwd()))
    mapper, _, ref = mapped_input(source, config)
    det, src, wide_src = mapper.detector, mapper.detector.database, mapper.detector.wide_database
    cfg = src.config
    stages = cfg.stages
    db = PlaceDatabase(cfg, matchers=src.matchers)
    wide = None if wide_src is None else PlaceDatabase(wide_src.config, matchers=src.matchers)
    covered = np.isfinite(ref).all(axis=1)
    keys, wide_keys = np.zeros(0, np.intp), np.zeros(0, np.intp)
    rows: dict[str, list[np.ndarray]] = {v: [] for v in VIEWS}
    revisit: list[bool] = []
    path: list[float] = []  # log path length [m] of each query's wide view
    steps = np.nan_to_num(np.r_[0.0, np.hypot(*np.diff(ref[:, :2], axis=0).T)])
    along = np.cumsum(steps)  # path from keyframe 0 by the reference [m]
    n_wide = config.loops.wide_keyframes
    for k in range(len(ref)):
        if k in src:
            db.add_descriptors(k, src.descriptors(k))
            keys = np.append(keys, k)
            if wide is not None and k in wide_src:
                wide.add_descriptors(k, wide_src.descriptors(k))
                wide_keys = np.append(wide_keys, k)
        if not covered[k] or k not in src:
            continue
        older = keys < k
        mask = np.zeros(len(keys), bool)
        mask[older] = det.eligible(k)[keys[older]] & covered[keys[older]]
        if not mask.any():
            continue
        q = len(revisit)
        revisit.append(bool((np.hypot(*(ref[keys[mask], :2] - ref[k, :2]).T) <= RADIUS).any()))
        wk = det.wide_key(k)
        wk = k if wk is None else wk
        path.append(float(np.log(max(along[wk] - along[max(wk - n_wide, 0)], 0.5))))
        own = db.query(src.descriptors(k), allowed=mask, headings=False)
        rows["own"].append(_rows(own, stages, db.scales, ref, k, q, 0))
        asked = det.wide_key(k)
        if wide is not None and asked is not None and asked in wide:
            w = wide.query_stored(asked, allowed=np.isin(wide_keys, keys[mask]))
            rows["wide"].append(_rows(w, stages, wide.scales, ref, k, q, 0))
    width = len(stages) + 5
    out = {v: np.vstack(r) if r else np.zeros((0, width)) for v, r in rows.items()}
    out["revisit"] = np.array(revisit, bool)
    out["path"] = np.array(path, float)
    return out


def features(data: dict[str, np.ndarray], view: str, names: tuple[str, ...],
             stages: tuple[str, ...]) -> np.ndarray:
    """``(n, len(names))`` features of `view`'s rows: a stage's log distance, or
    ``path``, the log path length of the query's wide view."""
    r = data[view]
    return np.column_stack([data["path"][r[:, -2].astype(np.intp)] if n == "path"
                            else r[:, stages.index(n)] for n in names])


def training(data: dict[str, np.ndarray], view: str, top_k: int, names: tuple[str, ...],
             stages: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Features `names` and labels of `view`'s candidates among the prefilter's `top_k`."""
    r = data[view]
    keep = r[:, -3] < top_k
    return features(data, view, names, stages)[keep], r[keep, -4].astype(bool)


def top1(data: dict[str, np.ndarray], choice: str, models: dict[str, LogisticFusion],
         stages: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """``(score, correct)`` of every query's top-1 under `choice` (module docstring):
    ``own``, ``wide``, ``merged`` (the higher of the two views' best) or ``distinct``
    (the view whose best stands out more from its best other place, a stored key more
    than 5 keys from the best: the larger logit difference), every view's
    candidates scored by its model of `models` (features in the order of `stages`)."""
    n = len(data["revisit"])
    best = {v: (np.full(n, -np.inf), np.zeros(n, bool)) for v in VIEWS}
    margin = {v: np.full(n, -np.inf) for v in VIEWS}
    for v in VIEWS:
        r = data[v]
        if not len(r):
            continue
        score = models[v].probability(features(data, v, models[v].names, stages))
        q = r[:, -2].astype(np.intp)
        order = np.lexsort((-score, q))  # by query, best score first
        first = order[np.r_[True, q[order][1:] != q[order][:-1]]]
        best[v][0][q[first]] = score[first]
        best[v][1][q[first]] = r[first, -4].astype(bool)
        top_key = np.full(n, -10**9)
        top_key[q[first]] = r[first, -1]
        logit = np.log(np.clip(score, 1e-12, 1.0) / np.clip(1.0 - score, 1e-12, 1.0))
        other = np.full(n, np.log(1e-12))  # no other place: the floor of the logit
        far = np.abs(r[:, -1] - top_key[q]) > 5
        np.maximum.at(other, q[far], logit[far])
        margin[v][q[first]] = logit[first] - other[q[first]]
    own, wide = best["own"], best["wide"]
    if choice == "own":
        return own
    has_wide = np.isfinite(wide[0])
    if choice == "wide":
        return np.where(has_wide, wide[0], own[0]), np.where(has_wide, wide[1], own[1])
    take = wide[0] > own[0]  # ties: the own view, as `merge_views`
    if choice == "distinct":
        take = margin["wide"] > margin["own"]
    return np.where(take, wide[0], own[0]), np.where(take, wide[1], own[1])


def figures(score: np.ndarray, correct: np.ndarray, revisit: np.ndarray) -> str:
    curve = pr_curve(score, correct, int(revisit.sum()))
    r1 = float((correct & np.isfinite(score)).sum()) / max(int(revisit.sum()), 1)
    return (f"R@1 {r1:.3f}  R@100%P {recall_at_precision(curve, 1.0):.3f}  "
            f"AP {average_precision(curve):.3f}")


def fit(logs: list[dict[str, np.ndarray]], top_k: int, stages: tuple[str, ...],
        path: bool = False) -> dict[str, LogisticFusion]:
    """One model per view fitted on the pooled candidates of `logs` (features: the
    stages, and with `path` the wide view's log path length too)."""
    out = {}
    for v in VIEWS:
        names = (*stages, "path") if path and v == "wide" else stages
        f, y = zip(*(training(d, v, top_k, names, stages) for d in logs), strict=True)
        out[v] = fit_logistic(np.vstack(f), np.concatenate(y), names=names, ridge=1.0)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("logs", nargs="+", metavar="LOG[:RELATIONS]")
    ap.add_argument("--fit", nargs="*", default=None, metavar="NAME")
    ap.add_argument("--cache", type=Path)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args()
    config = apply_overrides(PipelineConfig(), args.set)
    cfg = config.loops.database
    data: dict[str, dict[str, np.ndarray]] = {}
    for item in args.logs:
        log, _, relations = item.partition(":")
        name = Path(log).name.split(".")[0]
        cached = args.cache / f"{name}.npz" if args.cache else None
        if cached is not None and cached.exists():
            with np.load(cached) as z:
                data[name] = {k: z[k] for k in z.files}
        else:
            data[name] = collect(log, relations or None, config)
            if cached is not None:
                cached.parent.mkdir(parents=True, exist_ok=True)
                np.savez_compressed(cached, **data[name])
    fit_names = args.fit if args.fit else list(data)
    models = fit([data[n] for n in fit_names], cfg.top_k, cfg.stages)
    print(f"fitted on {', '.join(fit_names)}:")
    for v, m in models.items():
        print(f"  {v}: {m}")
    for name, d in data.items():
        held = fit([data[n] for n in data if n != name], cfg.top_k, cfg.stages) \
            if len(data) > 1 else None
        rev = d["revisit"]
        print(f"{name}: {len(rev)} queries, {int(rev.sum())} revisits")
        shared = dict.fromkeys(VIEWS, cfg.logistic)
        rows = [("own", top1(d, "own", shared, cfg.stages)),
                ("wide", top1(d, "wide", shared, cfg.stages)),
                ("shared", top1(d, "merged", shared, cfg.stages)),
                ("per-view", top1(d, "merged", {"own": cfg.logistic, "wide": models["wide"]},
                                  cfg.stages)),
                ("both refitted", top1(d, "merged", models, cfg.stages)),
                ("distinct", top1(d, "distinct", shared, cfg.stages))]
        if held is not None:
            others = [data[n] for n in data if n != name]
            with_path = fit(others, cfg.top_k, cfg.stages, path=True)["wide"]
            rows += [("per-view (held out)", top1(
                d, "merged", {"own": cfg.logistic, "wide": held["wide"]}, cfg.stages)),
                ("both refitted (held out)", top1(d, "merged", held, cfg.stages)),
                ("path (held out)", top1(
                    d, "merged", {"own": cfg.logistic, "wide": with_path}, cfg.stages))]
            print(f"  path model without it: {with_path}")
        for label, (score, correct) in rows:
            print(f"  {label:25s} {figures(score, correct, rev)}")


if __name__ == "__main__":
    main()
