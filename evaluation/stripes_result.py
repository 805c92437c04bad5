"""What the stripes benchmark measured (`StripesBenchmarkResult`) and its published JSON.

Every method's retrieval figures (`evaluation.stripes_retrieval.MethodResult`), the
per-class accuracies, the wins and losses of the stripes against each baseline, and
the CLI's JSON (`StripesBenchmarkResult.to_json`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from evaluation.stripes_config import StripesBenchmarkConfig
from evaluation.stripes_objects import ObjectSet, ScannedSet
from evaluation.stripes_paper import PAPER_SECONDS
from evaluation.stripes_retrieval import MethodResult


@dataclass(slots=True)
class StripesBenchmarkResult:
    """Everything the benchmark measured (see `to_json` for the published figures)."""

    dataset: str
    config: StripesBenchmarkConfig
    objects: ObjectSet
    scanned: ScannedSet
    stripes: MethodResult
    profile: MethodResult
    baselines: dict[str, MethodResult]
    fused: MethodResult | None
    skipped_baselines: dict[str, str]
    silhouette_seconds: float
    fused_sc: MethodResult | None = None
    relief: MethodResult | None = None
    fused_relief: MethodResult | None = None
    surface: MethodResult | None = None
    fused_stripes: MethodResult | None = None
    canonical: MethodResult | None = None

    @property
    def classes(self) -> list[str]:
        """Class names in order of first occurrence."""
        return list(dict.fromkeys(self.scanned.labels))

    def per_class(self) -> dict[str, dict[str, float]]:
        """class -> method -> Table II accuracy (stripes first)."""
        return {c: {n: r.class_accuracy[c] for n, r in self.methods().items()}
                for c in self.classes}

    def methods(self) -> dict[str, MethodResult]:
        """Every method's figures: stripes, profile, relief, surface, canonical,
        fused-stripes, fused, fused-sc and fused-relief (when run), then the baselines."""
        out = {"stripes": self.stripes, "profile": self.profile}
        for name, res in (("relief", self.relief), ("surface", self.surface),
                          ("canonical", self.canonical),
                          ("fused-stripes", self.fused_stripes), ("fused", self.fused),
                          ("fused-sc", self.fused_sc), ("fused-relief", self.fused_relief)):
            if res is not None:
                out[name] = res
        return {**out, **self.baselines}

    def wins_and_losses(
        self, margin: float = 0.005, method: str = "stripes"
    ) -> dict[str, dict[str, list[str]]]:
        """baseline -> {"wins": classes where `method` (``stripes`` or ``profile``) is
        better, "losses": worse, "ties"}."""
        mine = self.methods()[method]
        out: dict[str, dict[str, list[str]]] = {}
        for name, res in self.baselines.items():
            wins, losses, ties = [], [], []
            for c in self.classes:
                delta = mine.class_accuracy[c] - res.class_accuracy[c]
                (wins if delta > margin else losses if delta < -margin else ties).append(c)
            out[name] = {"wins": wins, "losses": losses, "ties": ties}
        return out

    def to_json(self) -> dict[str, Any]:
        """The CLI's JSON: the required keys first, then the details."""
        s = self.stripes
        return {
            "objects": len(set(self.scanned.objects.tolist())),
            "classes": len(self.classes),
            "top10_counts": s.top_counts.tolist(),
            "class_accuracy": s.class_accuracy,
            "bullseye": s.bullseye,
            "seconds": s.seconds,
            "baselines": {n: r.to_json() for n, r in self.baselines.items()},
            "profile": self.profile.to_json(),
            "fused": None if self.fused is None else self.fused.to_json(),
            "fused_sc": None if self.fused_sc is None else self.fused_sc.to_json(),
            "relief": None if self.relief is None else self.relief.to_json(),
            "fused_relief": None if self.fused_relief is None else self.fused_relief.to_json(),
            "surface": None if self.surface is None else self.surface.to_json(),
            "fused_stripes": None if self.fused_stripes is None else self.fused_stripes.to_json(),
            "canonical": None if self.canonical is None else self.canonical.to_json(),
            "different_pose": s.different_pose,
            "dataset": self.dataset,
            "scans": len(self.scanned.scans),
            "scans_per_object": self.config.scans_per_object,
            "seed": self.config.seed,
            "class_names": self.classes,
            "nn_precision": s.nn_precision,
            "top10_counts_other_objects": s.top_counts_other.tolist(),
            "class_accuracy_other_objects": s.class_accuracy_other,
            "nn_precision_other_objects": s.nn_precision_other,
            "mean_stripes_per_object": float(np.mean([len(x.stripes)
                                                      for x in self.scanned.scans])),
            "scan_seconds": self.scanned.seconds,
            "silhouette_seconds": self.silhouette_seconds,
            "paper_seconds": PAPER_SECONDS,
            "speedup_vs_paper": PAPER_SECONDS["stripes"] / max(s.seconds, 1e-12),
            "wins_and_losses": self.wins_and_losses(),
            "profile_wins_and_losses": self.wins_and_losses(method="profile"),
            "skipped_baselines": self.skipped_baselines,
            "failed_objects": {**self.objects.failed, **self.scanned.failed},
            "not_watertight": self.objects.not_watertight,
            "config": self.config.to_json(),
        }
