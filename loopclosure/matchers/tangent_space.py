"""Tangent space (turning function) matcher.

Paper: Kosnar, Vonasek, Kulich, Preucil, "Comparison of shape matching techniques for
place recognition" (``papers/shape-matching-place-recognition.txt``), Section II.A.4
("Tangent Space"), after its reference [13] (tangent space of polygons as used by
Latecki & Lakamper, "Shape similarity measure based on correspondence of visual parts",
PAMI 2000) and the turning-function metric of E. M. Arkin, L. P. Chew, D. P.
Huttenlocher, K. Kedem, J. S. B. Mitchell, "An efficiently computable metric for
comparing polygonal shapes", PAMI 13(3), 1991.

Equations (plain text)
----------------------
Turning function.  The boundary is resampled to n points equally spaced by arc length
(from vertex 0); edge k (point k to k+1) has direction angle a_k, unwrapped so that
consecutive angles differ by the exterior (turning) angle in (-pi, pi].  The turning
function is the step function Theta(s) = a_k for s in [k/n, (k+1)/n): the accumulated
tangent angle against the normalised arc length s in [0, 1).  Continued past s = 1 it
grows by the total turning T (2 pi for a simple counter-clockwise polygon):
Theta(s + 1) = Theta(s) + T.

Distance.  The paper:  s(P, Q) = min over start points t and rotations theta of

    integral_0^1 |Theta_P(s + t) - Theta_Q(s) + theta| ds   (L1, ``norm="l1"``, default),

Arkin et al.'s metric is the L2 version (``norm="l2"``):

    d(P, Q) = ( min_{t, theta} integral_0^1 (Theta_P(s + t) - Theta_Q(s) + theta)^2 ds )^(1/2).

With the periodic part Theta~(s) = Theta(s) - T s, Theta_P(s + t) - Theta_Q(s) =
Theta~_P(s + t) - Theta~_Q(s) + (T t + T_P s - T_Q s) and for T_P = T_Q the bracket is a
constant absorbed by theta.  For L2 the optimal theta is the mean difference (Arkin's
closed form), so on the n-sample grid

    d^2(t) = (1/n) [ sum P~^2 + sum Q~^2 - 2 corr(t) ] - (mean P~ - mean Q~)^2,
    corr(t) = sum_s P~(s + t) Q~(s),

for all n shifts t at once by one FFT cross-correlation; `distances` stores the FFTs of
the database rows and is O(M n log n) for M entries (the winning shift's distance is then
recomputed directly as the standard deviation of the differences, free of
cancellation).  For L1 the optimal theta is minus the median difference; `distances`
evaluates every shift for every entry with ``np.median`` over (entries x shifts x
samples) arrays, O(M n^2), in chunks of entries that keep each array near 2 million
values.

Scale.  The turning function is scale invariant by construction (normalised arc
length).  Places must not be (rooms differing only in size are different places), so
with ``scale_invariant=False`` (default) the distance adds

    scale_weight * |log(perimeter_P / perimeter_Q)|,

and with ``scale_invariant=True`` it is the pure turning-function distance (MPEG-7).

Rotation invariance is exact (a rotation adds a constant to Theta, absorbed by theta);
the start point is found among the n sample shifts.

Parameters (`TangentConfig`)
----------------------------
- ``n_points`` n = 64: arc-length samples of the turning function.  Resampling also
  low-passes the laser noise that would otherwise make the raw turning function of a
  360-vertex scan polygon a random walk; the L1 search costs O(n^2) per pair.
- ``norm`` = "l1": the paper's formula (optimal rotation = median, all n shifts), or
  "l2": Arkin's metric (closed-form rotation, FFT over shifts: O(n log n) per pair).
- ``scale_invariant`` = False, ``scale_weight`` = 1.0 [rad per unit log-ratio]: weight
  of the perimeter term when not scale invariant.

Departures from the paper
-------------------------
- Start points are the n arc-length samples, not every vertex (Arkin's exact
  algorithm); with n = 64 the best start is within 1/128 of the perimeter.
- The perimeter term when not scale invariant (see Scale).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
import scipy.fft
from numpy.typing import NDArray

from data.errors import UserError
from loopclosure.matchers.base import Matcher
from loopclosure.polygon import Polygon

Array = NDArray[np.float64]

_CHUNK_VALUES = 2_000_000


@dataclass(slots=True, frozen=True)
class TangentConfig:
    """Parameters of the tangent space matcher (see module docstring).

    Attributes:
        n_points: arc-length samples n of the turning function.
        norm: ``"l1"`` (paper as written, default) or ``"l2"`` (Arkin).
        scale_invariant: pure turning-function distance, no perimeter term.
        scale_weight: weight of |log perimeter ratio| when not scale invariant.
    """

    n_points: int = 64
    norm: str = "l1"
    scale_invariant: bool = False
    scale_weight: float = 1.0

    def __post_init__(self) -> None:
        if self.n_points < 4:
            raise UserError(f"n_points must be >= 4, got {self.n_points}")
        if self.norm not in ("l1", "l2"):
            raise UserError(f"norm must be 'l1' or 'l2', got {self.norm!r}")
        if not (np.isfinite(self.scale_weight) and self.scale_weight >= 0):
            raise UserError(f"scale_weight must be a finite number >= 0, got {self.scale_weight}")


@dataclass(slots=True, frozen=True)
class TangentDescriptor:
    """Turning function of one polygon.

    Attributes:
        periodic: ``(n,)`` Theta(k / n) - T k / n [rad], the periodic part.
        turning: ``(n,)`` Theta(k / n) [rad], the unwrapped edge angles.
        log_perimeter: log of the perimeter [log m].
    """

    periodic: Array
    turning: Array
    log_perimeter: float


@dataclass(slots=True, frozen=True)
class TangentStack:
    """Turning functions packed for `TangentMatcher.distances`.

    Attributes:
        periodic: ``(M, n)`` periodic parts.
        spectra: ``(M, n // 2 + 1)`` their real FFTs (used by the L2 norm).
        log_perimeter: ``(M,)`` log perimeters.
    """

    periodic: Array
    spectra: NDArray[np.complex128]
    log_perimeter: Array

    def __len__(self) -> int:
        return len(self.periodic)


def turning_function(points: Array) -> tuple[Array, float]:
    """Unwrapped edge angles ``(n,)`` [rad] of a closed ``(n, 2)`` point loop, and total turn T.

    Edge k runs from point k to point k+1 (wrapping).  T is the sum of the n exterior
    angles, each in (-pi, pi] (2 pi for a simple counter-clockwise loop).
    """
    p = np.asarray(points, dtype=float)
    e = np.concatenate([p[1:], p[:1]]) - p
    ang = np.arctan2(e[:, 1], e[:, 0])
    turn = np.concatenate([ang[1:], ang[:1]]) - ang
    turn -= 2.0 * np.pi * np.round(turn / (2.0 * np.pi))
    theta = ang[0] + np.concatenate([[0.0], np.cumsum(turn[:-1])])
    return theta, float(turn.sum())


class TangentSpaceMatcher(Matcher):
    """Turning function, min over start point and rotation (Arkin L2 or paper L1)."""

    name = "tangent"
    rotation_invariant = True

    def __init__(self, config: TangentConfig | None = None, **overrides: Any) -> None:
        cfg = config or TangentConfig()
        known = {f.name for f in fields(TangentConfig)}
        unknown = set(overrides) - known
        if unknown:
            raise UserError(
                f"unknown TangentConfig fields: {', '.join(sorted(unknown))} "
                f"(known: {', '.join(sorted(known))})"
            )
        self.config = replace(cfg, **overrides)

    def describe(self, polygon: Polygon) -> TangentDescriptor:
        """Turning function sampled at n arc-length points from vertex 0."""
        n = self.config.n_points
        theta, total = turning_function(polygon.resample(n))
        periodic = theta - total * (np.arange(n) / n)
        return TangentDescriptor(periodic, theta, float(np.log(polygon.perimeter)))

    def stack(self, descriptors: Sequence[TangentDescriptor]) -> TangentStack:
        """Rows, their FFTs and log perimeters."""
        n = self.config.n_points
        if len(descriptors) == 0:
            z = np.zeros(0)
            return TangentStack(np.zeros((0, n)), np.zeros((0, n // 2 + 1), complex), z)
        x = np.stack([d.periodic for d in descriptors])
        lp = np.array([d.log_perimeter for d in descriptors])
        return TangentStack(x, scipy.fft.rfft(x, axis=1), lp)

    def distances(self, query: TangentDescriptor, stacked: TangentStack) -> Array:
        """``(M,)`` turning-function distances (plus the perimeter term if not scale invariant)."""
        cfg = self.config
        q = query.periodic
        n = len(q)
        if len(stacked) == 0:
            return np.zeros(0)
        if cfg.norm == "l2":
            # corr[m, t] = sum_s q(s + t) x_m(s)
            corr = scipy.fft.irfft(scipy.fft.rfft(q)[None, :] * np.conj(stacked.spectra),
                                   n=n, axis=1)
            # The best shift per entry; its distance is recomputed directly (the
            # expansion above cancels: identical shapes must give exactly 0).
            best = corr.argmax(axis=1)
            diff = q[(best[:, None] + np.arange(n)[None, :]) % n] - stacked.periodic
            d = np.sqrt(np.var(diff, axis=1))
        else:
            shifted = q[(np.arange(n)[:, None] + np.arange(n)[None, :]) % n]  # (t, s)
            chunk = max(1, _CHUNK_VALUES // (n * n))
            d = np.empty(len(stacked))
            for lo in range(0, len(stacked), chunk):
                x = stacked.periodic[lo : lo + chunk]
                diff = shifted[None, :, :] - x[:, None, :]  # (m, t, s)
                diff -= np.median(diff, axis=2, keepdims=True)
                np.abs(diff, out=diff)
                d[lo : lo + chunk] = diff.mean(axis=2).min(axis=1)
        if not cfg.scale_invariant:
            d = d + cfg.scale_weight * np.abs(query.log_perimeter - stacked.log_perimeter)
        return d

    def distance(self, a: TangentDescriptor, b: TangentDescriptor) -> float:
        """Turning-function distance of two descriptors (same code as `distances`)."""
        return float(self.distances(a, self.stack([b]))[0])
