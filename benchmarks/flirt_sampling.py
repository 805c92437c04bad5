"""Benchmark: FLIRT's contour-sampling option in `loopclosure bench loops`, default vs option.

Run from the repository root::

    python benchmarks/flirt_sampling.py LOG (--relations FILE | --reference-from-log)
        [--variant NAME:FIELD=VALUE,...] [--stages ...] [--set KEY=VALUE ...]
        [--max-queries N] [--json FILE]

The log is read once; then, in this one process, ``bench loops`` (`evaluation.loop_bench`,
the CLI's runner, odometry noise 0 with ``--reference-from-log``) runs once with the
default FLIRT and once per ``--variant`` with those `FlirtConfig` fields (e.g.
``m02:sample_step=0.2,max_range=29``).  The place database builds its matchers from
`loopclosure.matchers` by name with no per-matcher options, so the variant's fields are
given by the matcher class that name resolves to, replaced here for that run
(``loopclosure.matchers.flirt.FlirtMatcher``); each run maps the log again, since every
keyframe is described at insertion.  ``--set`` changes the pipeline's config for every
run (e.g. ``loops.database.verifiers=flirt,mrm`` with ``loops.database.fusion=rank``).

Printed per run: R@100P / R@99P / AP / top-1 recall / ms per query of every row and
the final row (after the geometric check), and the FLIRT keypoints' repeatability:
the median over revisit queries of the share of the query's own-view keypoints with a
keypoint of its nearest true place within 0.5 m once that place's are moved into the
query's frame by the reference poses (and the median count of such keypoints).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import evaluation.loop_bench as loop_bench  # noqa: E402
import loopclosure.matchers.flirt as flirt_module  # noqa: E402
from evaluation.loop_bench import loop_benchmark, parse_stages  # noqa: E402
from evaluation.loop_bench_input import LoopSource  # noqa: E402
from evaluation.loop_bench_report import json_document, table_rows  # noqa: E402
from loopclosure.matchers.flirt import FlirtConfig, FlirtMatcher  # noqa: E402
from slam.config import PipelineConfig  # noqa: E402
from slam.config_io import apply_overrides  # noqa: E402

_CAPTURED: dict[str, Any] = {}
_ORIGINAL_MAPPING = loop_bench._mapping


def _capturing_mapping(source: Any, inp: Any, config: Any, progress: Any) -> Any:
    """`loop_bench._mapping`, keeping the mapper for the repeatability figure."""
    out = _ORIGINAL_MAPPING(source, inp, config, progress)
    _CAPTURED["mapper"] = out[0]
    return out


def flirt_class(fields: dict[str, Any]) -> type[FlirtMatcher]:
    """A `FlirtMatcher` whose defaults are `FlirtConfig` with `fields`."""
    class Variant(FlirtMatcher):
        def __init__(self, config: FlirtConfig | None = None, **overrides: Any) -> None:
            super().__init__(config, **{**fields, **overrides})
    return Variant


def parse_variant(text: str) -> tuple[str, dict[str, Any]]:
    """``NAME:FIELD=VALUE,...`` -> name, typed `FlirtConfig` fields."""
    name, _, rest = text.partition(":")
    types = {f: type(getattr(FlirtConfig(), f)) for f in FlirtConfig.__slots__}
    out: dict[str, Any] = {}
    for item in (i for i in rest.split(",") if i):
        key, value = item.split("=", 1)
        out[key] = types[key](value)
    FlirtConfig(**out)  # validates
    return name, out


def repeatability(bench: Any, mapper: Any, radius: float = 0.5) -> tuple[float, float, float]:
    """Median share and count of a revisit query's own-view FLIRT keypoints repeated
    within `radius` [m] by its nearest true place (module docstring), and the median
    keypoint count of a query (NaN without FLIRT among the stages)."""
    db = mapper.detector.database
    if "flirt" not in db.matchers:
        return float("nan"), float("nan"), float("nan")
    ref = np.asarray(bench.reference, float)
    share, count, size = [], [], []
    for row, k in enumerate(bench.query_keys.tolist()):
        j = int(bench.nearest[row, 0])
        if not bench.has_revisit[row] or j < 0 or k not in db or j not in db:
            continue
        pa, pb = db.descriptors(k)["flirt"].points, db.descriptors(j)["flirt"].points
        if not len(pa) or not len(pb):
            continue
        a, b = ref[k], ref[j]
        cb, sb = np.cos(b[2]), np.sin(b[2])
        world = pb @ np.array([[cb, sb], [-sb, cb]]) + b[:2]
        ca, sa = np.cos(a[2]), np.sin(a[2])
        local = (world - a[:2]) @ np.array([[ca, -sa], [sa, ca]])
        d = np.hypot(*(pa[:, None, :] - local[None]).transpose(2, 0, 1))
        hit = d.min(axis=1) <= radius
        share.append(hit.mean())
        count.append(hit.sum())
        size.append(len(pa))
    if not share:
        return float("nan"), float("nan"), float("nan")
    return float(np.median(share)), float(np.median(count)), float(np.median(size))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log")
    ap.add_argument("--relations")
    ap.add_argument("--reference-from-log", action="store_true")
    ap.add_argument("--variant", action="append", default=[])
    ap.add_argument("--no-default", action="store_true", help="skip the default run")
    ap.add_argument("--stages")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--max-queries", type=int)
    ap.add_argument("--json", type=Path, help="write every run's bench loops document here")
    args = ap.parse_args()
    config = apply_overrides(PipelineConfig(), args.set)
    rows = parse_stages(args.stages, config)
    source = LoopSource(args.log, relations=args.relations,
                        reference_from_log=args.reference_from_log,
                        odometry_noise=0 if args.reference_from_log else None,
                        folder=str(Path.cwd()))
    inp = source.open()
    runs = [] if args.no_default else [("default", {})]
    runs += [parse_variant(v) for v in args.variant]
    loop_bench._mapping = _capturing_mapping
    docs = {}
    for name, fields in runs:
        flirt_module.FlirtMatcher = flirt_class(fields) if fields else FlirtMatcher
        try:
            bench = loop_benchmark(inp, config, stages=rows, max_queries=args.max_queries)
        finally:
            flirt_module.FlirtMatcher = FlirtMatcher
        share, count, size = repeatability(bench, _CAPTURED.pop("mapper"))
        print(f"== {Path(args.log).name} {name} {fields}: {len(bench.query_keys)} queries, "
              f"{bench.revisits} revisits; keypoints repeated at 0.5 m (median share, count, "
              f"per query) {share:.2f}, {count:.0f}, {size:.0f}", flush=True)
        print("   row: R@100P R@99P AP top1 ms", flush=True)
        for r in table_rows(bench):
            print("   " + " ".join(r), flush=True)
        doc = json_document(bench)
        doc["repeatability"] = {"share": share, "count": count, "keypoints": size}
        doc["flirt_fields"] = fields
        docs[name] = doc
    if args.json is not None:
        args.json.write_text(json.dumps(docs, indent=1, default=float))


if __name__ == "__main__":
    main()
