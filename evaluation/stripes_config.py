"""The parameters of the stripes benchmark (`StripesBenchmarkConfig`).

Which baselines and fused rows run, the simulated scanner, and every method's
descriptor parameters (`evaluation.stripes_benchmark` describes the rows).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from data.errors import UserError
from data.stripe_scanner import ScannerConfig
from loopclosure.stripes import (
    DEFAULT_VERIFIERS,
    SC_VERIFIERS,
    CanonicalConfig,
    DescriptorConfig,
    ProfileConfig,
    ReliefConfig,
    SurfaceConfig,
)
from loopclosure.stripes.fusion import (
    DEFAULT_MEAN,
    DEFAULT_SCALING,
    LOCAL_NEIGHBOUR,
    MEANS,
    SCALINGS,
)

#: Baselines run by default (the paper's shape context and two more silhouette methods).
DEFAULT_BASELINES: tuple[str, ...] = ("shape-context", "mrm", "fft")


@dataclass(slots=True)
class StripesBenchmarkConfig:
    """Parameters of `run_stripes_benchmark`.

    Attributes:
        seed: seed of the scanner's random poses and noise (and of the Daily set).
        scans_per_object: independent scans of every object.
        k: deepest retrieval position (the paper: 10).
        baselines: silhouette matchers to compare (names of `loopclosure.matchers`).
        scanner: the simulated scanner.
        descriptor: stripe descriptor parameters.
        silhouette_smooth: contour smoothing of the silhouettes [px].
        profile: stripe profile parameters (the ``profile`` row and the fused matcher).
        fused: silhouette verifiers of the ``fused`` row (profile, relief, surface
            context and these; empty: no fused row).
        fused_sc: silhouette verifiers of the ``fused-sc`` row (empty: no such row).
        relief: relief parameters (the ``relief`` row and the ``fused-relief`` row).
        fused_relief: silhouette verifiers of the ``fused-relief`` row, the profile and
            the relief verified by them (empty: no such row).
        surface: surface-context parameters (the ``surface`` row, ``fused-stripes``
            and ``fused``).
        canonical: canonical-profile parameters (the ``canonical`` row and
            ``fused-stripes``).
        scaling: how ``fused-stripes`` and ``fused`` make each part unitless:
            ``"local"`` (local scaling) or ``"median"`` (per-query median); the
            ``fused-sc`` and ``fused-relief`` rows keep the median.
        neighbour: neighbour rank of local scaling.
        mean: how ``fused-stripes`` and ``fused`` average the unitless parts:
            ``"geometric"`` or ``"arithmetic"`` (`loopclosure.stripes.combine`); the
            ``fused-sc`` and ``fused-relief`` rows keep the arithmetic mean.
    """

    seed: int = 0
    scans_per_object: int = 1
    k: int = 10
    baselines: tuple[str, ...] = DEFAULT_BASELINES
    scanner: ScannerConfig = field(default_factory=ScannerConfig)
    descriptor: DescriptorConfig = field(default_factory=DescriptorConfig)
    silhouette_smooth: float = 1.0
    profile: ProfileConfig = field(default_factory=ProfileConfig)
    fused: tuple[str, ...] = DEFAULT_VERIFIERS
    fused_sc: tuple[str, ...] = SC_VERIFIERS
    relief: ReliefConfig = field(default_factory=ReliefConfig)
    fused_relief: tuple[str, ...] = SC_VERIFIERS
    surface: SurfaceConfig = field(default_factory=SurfaceConfig)
    canonical: CanonicalConfig = field(default_factory=CanonicalConfig)
    scaling: str = DEFAULT_SCALING
    neighbour: int = LOCAL_NEIGHBOUR
    mean: str = DEFAULT_MEAN

    def __post_init__(self) -> None:
        if self.scaling not in SCALINGS:
            raise UserError(f"unknown scaling {self.scaling!r}; known: {', '.join(SCALINGS)}")
        if self.mean not in MEANS:
            raise UserError(f"unknown mean {self.mean!r}; known: {', '.join(MEANS)}")
        if self.neighbour < 1:
            raise UserError(f"--neighbour must be at least 1, got {self.neighbour}")

    def to_json(self) -> dict[str, Any]:
        """Plain dict of every parameter."""

        return {
            "seed": self.seed,
            "scans_per_object": self.scans_per_object,
            "k": self.k,
            "baselines": list(self.baselines),
            "scanner": asdict(self.scanner),
            "descriptor": asdict(self.descriptor),
            "silhouette_smooth": self.silhouette_smooth,
            "profile": asdict(self.profile),
            "fused": list(self.fused),
            "fused_sc": list(self.fused_sc),
            "relief": asdict(self.relief),
            "fused_relief": list(self.fused_relief),
            "surface": asdict(self.surface),
            "canonical": asdict(self.canonical),
            "scaling": self.scaling,
            "neighbour": self.neighbour,
            "mean": self.mean,
        }
