"""The pipeline's loop closures judged against reference poses: counts, precision, verdicts.

Every loop candidate of a run (`slam.pipeline.MappingResult.loops`) becomes a
`evaluation.loop_metrics.LoopProposal` in scan-index time (`loop_proposals`): stamps
are the two keyframes' scan indices, `relative` is the query keyframe's pose in the
match keyframe's frame (x [m], y [m], theta [rad]), the score is the geometric
check's fitness, and accepted means kept after the final GNC (or, ``before_gnc``,
accepted by the check).  `evaluate_loops` (default tolerances: 2 m, 0.2 m, 2 deg)
judges them against a keyframe reference stamped by scan index
(`evaluation.slam_reference`).

- `loop_counts`: keyframes, proposed (every candidate verified), accepted (kept
  after the final GNC), rejected by the check, rejected by GNC, by search stage;
- `loop_evaluation`: precision / recall of the final loops and ``before_gnc``;
- `loop_verdicts` / `write_loop_verdicts`: one CSV row per candidate with its
  verdict (true, false, unverifiable) and its error against the reference.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from data.atomic_write import atomic_output
from data.types import Trajectory
from evaluation.loop_metrics import LoopMetrics, LoopProposal, evaluate_loops
from slam.pipeline import MappingResult


def loop_proposals(result: MappingResult, *, after_gnc: bool = True) -> list[LoopProposal]:
    """The pipeline's loop candidates as proposals in scan-index time (stamp = scan index).

    `relative` is the query keyframe's pose in the match keyframe's frame; the score is
    the geometric check's fitness (as `loopclosure run`'s demo report); accepted means
    kept after the final GNC (`after_gnc`) or accepted by the check.
    """
    kfs = result.keyframes
    out = []
    for e in result.loops:
        c = e.candidate
        accepted = c.accepted and not (after_gnc and e.rejected_by_gnc)
        out.append(LoopProposal(
            float(kfs[c.match].scan_index), float(kfs[c.query].scan_index),
            np.asarray(c.relative, float),
            c.verification.fitness if c.verification else 0.0, accepted,
        ))
    return out


def loop_evaluation(result: MappingResult, reference: Trajectory) -> dict[str, Any]:
    """Precision / recall of the pipeline's loops against a keyframe reference (scan-index
    time, see `keyframe_reference`), final loops and ``before_gnc``."""
    kf_index = np.array([k.scan_index for k in result.keyframes], dtype=float)
    final = evaluate_loops(loop_proposals(result), reference, kf_index)
    before: LoopMetrics = evaluate_loops(loop_proposals(result, after_gnc=False), reference,
                                         kf_index)
    doc: dict[str, Any] = final.to_json()
    doc["verifiable"] = final.proposals - final.unverifiable
    doc["keyframes_with_reference"] = len(reference)
    doc["before_gnc"] = {k: before.to_json()[k] for k in
                         ("accepted", "true_positives", "false_positives", "precision", "recall")}
    return doc


LOOP_VERDICT_COLUMNS = (
    "scan_a", "scan_b", "search", "accepted", "rejected_by_gnc", "fitness",
    "reference_distance_m", "error_m", "error_deg", "verdict",
)


def loop_verdicts(result: MappingResult, reference: Trajectory) -> list[dict[str, Any]]:
    """Every loop candidate of a run judged against a keyframe reference, one row each.

    Columns `LOOP_VERDICT_COLUMNS`: the two keyframes' scan indices (older first), the
    search that proposed it, whether the check accepted it and GNC then dropped it, the check's
    fitness, the reference distance of the two poses and the error of the candidate's
    relative pose against the reference; ``verdict`` is ``true`` / ``false`` (by
    `evaluate_loops`' rule, for every candidate, accepted or not) or ``unverifiable``.
    What a user reads to see *which* loops a method let through, and by how much.
    """
    kf_index = np.array([k.scan_index for k in result.keyframes], dtype=float)
    proposals = loop_proposals(result, after_gnc=False)
    metrics = evaluate_loops(proposals, reference, kf_index)
    rows = []
    for e, p, true, err in zip(result.loops, proposals, metrics.is_true, metrics.errors,
                               strict=True):
        verifiable = bool(np.isfinite(err[0]))
        rows.append({
            "scan_a": int(p.stamp_a), "scan_b": int(p.stamp_b), "search": e.candidate.source,
            "accepted": int(e.candidate.accepted), "rejected_by_gnc": int(e.rejected_by_gnc),
            "fitness": p.score, "reference_distance_m": err[0], "error_m": err[1],
            "error_deg": err[2],
            "verdict": ("true" if true else "false") if verifiable else "unverifiable",
        })
    return rows


def write_loop_verdicts(path: Path, rows: Sequence[dict[str, Any]]) -> Path:
    """`loop_verdicts` rows as CSV (floats with 6 decimals, NaN as empty)."""
    with atomic_output(path, "w") as f:
        writer = csv.DictWriter(f, LOOP_VERDICT_COLUMNS, lineterminator="\n")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: (("" if np.isnan(v) else f"{v:.6f}") if isinstance(v, float)
                                 else v) for k, v in row.items()})
    return path


def loop_counts(result: MappingResult) -> dict[str, Any]:
    """Keyframes and loop-candidate counts of a pipeline run."""
    checked = [e for e in result.loops if e.candidate.accepted]
    gnc = sum(e.rejected_by_gnc for e in checked)
    return {
        "keyframes": len(result.keyframes),
        "proposed": len(result.loops),
        "accepted": len(checked) - gnc,
        "rejected_by_check": len(result.loops) - len(checked),
        "rejected_by_gnc": gnc,
        "by_stage": {s: sum(1 for e in checked if e.candidate.source == s
                            and not e.rejected_by_gnc) for s in ("pose", "appearance")},
    }
