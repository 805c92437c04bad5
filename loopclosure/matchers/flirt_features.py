"""FLIRT interest points and beta-grid descriptors of a polygon (detection + description).

Reference: G. D. Tipaldi and K. O. Arras, "FLIRT - Interest regions for 2D range
data", ICRA 2010 (ref. [3] of Kosnar, Vonasek, Kulich, Preucil, "Comparison of
shape matching techniques for place recognition",
``papers/shape-matching-place-recognition.txt``, Section II.B, which summarises it).
Written from the papers' descriptions; no FLIRTLib code was read or used.  The full
text of the ICRA paper was not available to us, so where the summary leaves a choice
open the choice is ours and is stated below.  This module does the per-scan work
(`describe`); RANSAC matching is in `loopclosure.matchers.flirt`.

Frames and units: the polygon is in the sensor frame, lengths in its units (metres
for scans, pixels for MPEG-7), angles in radians.  Every length parameter below is
relative to the polygon's own sampling step ``h = perimeter / n_samples``, so the
defaults work in any unit; absolute positions stay in the polygon's frame, which
keeps the RANSAC rigid transform metric (not scale invariant).

1. Geodesic parametrisation.  The closed boundary is resampled to ``n_samples``
   points ``c(s)`` equally spaced by arc length (the "geodesic coordinate" of the
   FLIRT curvature detector), ``s = 0 .. n_samples - 1`` from vertex 0.

2. Multi-scale curve.  ``c_sigma(s) = (c * g_sigma)(s)``, a circular convolution
   with the Gaussian ``g_sigma(u) = exp(-u^2 / (2 sigma^2)) / (sqrt(2 pi) sigma)``
   (done in the Fourier domain), for the scales
   ``sigma_l = sigma_0 * 2^(l / levels_per_octave)`` [samples], ``l = 0 .. L-1``,
   up to ``n_samples * max_scale_fraction``.  Tangent ``t_sigma = c_sigma' / |c_sigma'|``
   and outward normal ``n_sigma = (t_y, -t_x)`` (counter-clockwise boundary).

3. Curvature detector.  The summary's criterion "the scale sigma equals the
   inverse of the local curvature of the smoothed signal" is implemented as a
   characteristic-scale selection (in the manner of Lindeberg's scale-normalised
   operators and Unnikrishnan & Hebert's multi-scale displacement operator):
   smoothing moves a point of curvature ``kappa`` inwards by
   ``d = (c - c_sigma) . n_sigma ~ kappa sigma^2 / 2``, and the scale-normalised
   displacement

        delta(s, sigma) = ((c(s) - c_sigma(s)) . n_sigma(s)) / (sigma h)

   is dimensionless: on a circle of radius r it peaks at ``sigma ~ 1.6 r``
   (``sigma ~ 1 / kappa``); at a corner with interior angle ``alpha`` it is
   ``2 cos(alpha / 2) / sqrt(2 pi)`` (0.564 for a right angle) until neighbouring
   structure enters the kernel.  Positive delta is convex, negative concave.
   Interest points are the strict local maxima of ``|delta|`` over position and
   scale (3 x 3 neighbourhood, circular in s; the first and last scale levels
   are compared one-sided) with ``|delta| >= min_response``; the strongest
   ``max_features`` are kept.  A point's position is the raw boundary point
   ``c(s)``, its scale ``sigma = sigma_l h`` [length], its orientation the
   angle of ``n_sigma(s)``.  Shapes with fewer than ``min_features`` detections
   (a circle has none) get ``min_features + 1`` evenly spaced fallback points at
   the middle scale, so every polygon has a defined, finite descriptor.

4. Beta-grid descriptor.  Around each interest point a polar tessellation of
   radius ``R = support_factor * sigma`` with ``rings`` equal-width rings and
   ``sectors`` sectors, sector 0 centred on the point's normal (rotation
   invariant).
   The polygon is treated as a dense scan: every ``beam_stride``-th of the
   ``n_samples`` boundary points is a beam end point seen from a viewpoint ``v``
   (`viewpoint`: the sensor origin when it lies inside the polygon or is one of
   its vertices, as for every scan polygon, else the area centroid; MPEG-7
   contours in image coordinates use the centroid).  For bin j: ``hits_j`` =
   beams ending in j (the interest point's own sample excluded: it has no
   direction); ``misses_j`` = beams whose segment from v to its end point passes
   through j without ending there, each beam counted once per bin (ray tracing,
   sampled at ``chord_samples`` evenly spaced points of the chord through the
   support disc).  With the Beta prior ``Beta(a0, b0)`` the occupancy posterior is
   ``Beta(hits + a0, misses + b0)``:

        occ_j = (hits_j + a0) / (hits_j + misses_j + a0 + b0)
        var_j = occ_j (1 - occ_j) / (hits_j + misses_j + a0 + b0 + 1)

   Bins no beam reaches keep the prior (occ = 0.5 with the default a0 = b0 = 1,
   and the largest variance): unknown space.

Departures from the paper (and why): FLIRT segments a scan into connected
components at range jumps and works on the beam points; here the input is a
closed polygon (the project's common shape model), so the whole boundary,
jump edges included, is one closed curve and is resampled uniformly (needed for
arbitrary polygons and MPEG-7 contours with few or very many vertices).  The
orientation of a point is the smoothed normal at its own scale (our choice:
deterministic and exactly rotation covariant).  The ray tracing samples each
chord at a fixed number of points instead of walking the grid exactly (bins
narrower than the sample spacing near the centre can miss a beam).
Scales are relative to the sampling step so that one set of defaults serves
metres and pixels.

Parameters (`FlirtFeatureConfig`, defaults in brackets): n_samples [256 boundary
samples], sigma_0 [1.5 samples], levels_per_octave [3], max_scale_fraction [1/8:
largest sigma as a fraction of the perimeter], min_response [0.15, dimensionless],
max_features [40], min_features [3], support_factor [2.0: grid radius per unit
sigma], rings [4], sectors [12], prior_hit / prior_miss [1, 1: Beta prior
pseudo-counts], chord_samples [8 per chord], beam_stride [2: 128 beams],
viewpoint ["auto" | "origin" | "centroid"], scale_invariant [False: when True the
polygon is first divided by sqrt(area)], compiled [True: the hit and miss counts of
step 4 come from the numba kernel of `loopclosure.matchers.flirt_grid_kernel`,
equal to the numpy version's but where a chord sample sits on a bin border].

Contour sampling (an option; off by default, when the steps above are unchanged):
sample_step [0: off; length units, e.g. 0.2 m] resamples the boundary every
``sample_step`` by arc length, ``N = clip(round(perimeter / sample_step), 16,
max_samples)`` samples instead of ``n_samples`` whatever the perimeter, so that the
step h, and with it every scale in length units, does not change with how much open
space a viewpoint sees.  max_range [0: off; length units] drops the boundary's edges
with an end at or beyond ``max_range`` from the sensor origin (no-return beams placed
at the range cap, and the jump edges that lead to them), and max_jump [0: off; length
units] the edges whose ends' ranges differ by more than ``max_jump`` (depth jumps
between a near and a far surface, where FLIRT splits a scan into segments): the
curve is still smoothed
whole (step 2), but no interest point is taken on a dropped edge's samples or within
``border_sigmas * sigma`` samples (arc length) of one, where the smoothing kernel
reaches into them (FLIRT's detector works on the scan's connected segments and drops
what the cap made), and a dropped sample is neither a beam end of the beta-grids nor
a fallback point (step 4: the samples of kept edges only).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from loopclosure.matchers.flirt_sampling import border_distance, kept_samples, sample_count
from loopclosure.polygon import Polygon

Array = NDArray[np.float64]

_STRICT = 1e-9  # relative margin of a strict local maximum (flat responses give none)


@dataclass(slots=True)
class FlirtFeatureConfig:
    """Detector and beta-grid parameters (see the module docstring for the equations).

    Attributes:
        n_samples: boundary points after arc-length resampling (also the beams).
        sigma_0: smallest Gaussian scale [samples].
        levels_per_octave: scale levels per doubling of sigma.
        max_scale_fraction: largest scale as a fraction of the perimeter.
        min_response: smallest |delta| (scale-normalised displacement) of a point.
        max_features: keep at most this many strongest interest points.
        min_features: fewer detections than this switch to evenly spaced points.
        support_factor: beta-grid radius R = support_factor * sigma.
        rings: equal-width rings of the beta-grid.
        sectors: angular sectors of the beta-grid.
        prior_hit: Beta prior pseudo-count of hits (a0).
        prior_miss: Beta prior pseudo-count of misses (b0).
        chord_samples: ray-tracing samples per beam chord through a support disc.
        beam_stride: every beam_stride-th boundary sample is a beam of the beta-grid.
        viewpoint: "auto" (sensor origin if inside the polygon, else centroid),
            "origin" or "centroid": where the beams of the ray tracing start.
        scale_invariant: divide the polygon by sqrt(area) first.
        compiled: count the beta-grids' hits and misses with the numba kernel of
            `loopclosure.matchers.flirt_grid_kernel` (False: numpy).
        sample_step: boundary sampling step [length] (0: `n_samples` samples whatever
            the perimeter; module docstring, contour sampling).
        max_samples: most samples of a boundary sampled by `sample_step`.
        max_range: edges with an end at or beyond this distance from the sensor
            origin are dropped [length] (0: none dropped).
        max_jump: edges whose ends' ranges from the sensor origin differ by more
            than this are dropped [length] (depth jumps; 0: none dropped).
        border_sigmas: with `max_range` or `max_jump`, interest points closer than this many
            sigma (arc length) to a dropped edge's sample are not taken.
    """

    n_samples: int = 256
    sigma_0: float = 1.5
    levels_per_octave: int = 3
    max_scale_fraction: float = 0.125
    min_response: float = 0.15
    max_features: int = 40
    min_features: int = 3
    support_factor: float = 2.0
    rings: int = 4
    sectors: int = 12
    prior_hit: float = 1.0
    prior_miss: float = 1.0
    chord_samples: int = 8
    beam_stride: int = 2
    viewpoint: str = "auto"
    scale_invariant: bool = False
    compiled: bool = True
    sample_step: float = 0.0
    max_samples: int = 4096
    max_range: float = 0.0
    max_jump: float = 0.0
    border_sigmas: float = 2.0

    def __post_init__(self) -> None:
        if self.n_samples < 16 or self.max_samples < 16:
            raise UserError(
                f"n_samples and max_samples must be >= 16, got {self.n_samples} and "
                f"{self.max_samples}"
            )
        if not (np.isfinite(self.sample_step) and self.sample_step >= 0):
            raise UserError(f"sample_step must be >= 0 (0: off), got {self.sample_step}")
        if not (np.isfinite(self.max_range) and self.max_range >= 0):
            raise UserError(f"max_range must be >= 0 (0: off), got {self.max_range}")
        if not (np.isfinite(self.max_jump) and self.max_jump >= 0):
            raise UserError(f"max_jump must be >= 0 (0: off), got {self.max_jump}")
        if not (np.isfinite(self.border_sigmas) and self.border_sigmas >= 0):
            raise UserError(f"border_sigmas must be >= 0, got {self.border_sigmas}")
        if self.viewpoint not in ("auto", "origin", "centroid"):
            raise UserError(f"viewpoint must be auto, origin or centroid, got {self.viewpoint!r}")
        if min(self.rings, self.sectors, self.levels_per_octave, self.max_features) < 1:
            raise UserError(
                "rings, sectors, levels_per_octave and max_features must be >= 1, got "
                f"{self.rings}, {self.sectors}, {self.levels_per_octave} and {self.max_features}"
            )
        if self.sigma_0 <= 0 or self.support_factor <= 0 or self.max_scale_fraction <= 0:
            raise UserError(
                "sigma_0, support_factor and max_scale_fraction must be > 0, got "
                f"{self.sigma_0}, {self.support_factor} and {self.max_scale_fraction}"
            )
        if self.prior_hit <= 0 or self.prior_miss <= 0:
            raise UserError(
                f"prior_hit and prior_miss must be > 0, got {self.prior_hit} and {self.prior_miss}"
            )


@dataclass(slots=True)
class FlirtFeatures:
    """Interest points of one polygon and their beta-grids (the FLIRT descriptor).

    Attributes:
        points: ``(F, 2)`` positions in the (possibly normalised) polygon frame.
        scales: ``(F,)`` detection scale sigma [length units of `points`].
        orientations: ``(F,)`` angle of the outward normal at the point [rad].
        responses: ``(F,)`` signed scale-normalised displacement delta (0 for fallback).
        occupancy: ``(F, rings * sectors)`` posterior mean occupancy per bin.
        evidence: ``(F, rings * sectors)`` float32: ``a + b`` of each bin's Beta
            posterior (hits + misses + a0 + b0); with `occupancy` it gives the
            posterior variance (`variance`).  Kept instead of the variance, which no
            distance uses, at half its size: a place database holds one per keyframe.
        step: arc-length sampling step h of the polygon [length units].
        unit: factor that was divided out of the coordinates (1 unless scale invariant).
    """

    points: Array
    scales: Array
    orientations: Array
    responses: Array
    occupancy: Array
    evidence: NDArray[np.float32]
    step: float
    unit: float = 1.0

    def __len__(self) -> int:
        return len(self.points)

    @property
    def variance(self) -> Array:
        """``(F, rings * sectors)`` posterior variance per bin (module docstring, step 4)."""
        return self.occupancy * (1.0 - self.occupancy) / (self.evidence.astype(float) + 1.0)


def scale_levels(config: FlirtFeatureConfig) -> Array:
    """Gaussian scales ``sigma_l`` [samples] of the detector's scale space."""
    top = config.n_samples * config.max_scale_fraction
    n = int(np.floor(config.levels_per_octave * np.log2(max(top / config.sigma_0, 1.0)))) + 1
    return config.sigma_0 * 2.0 ** (np.arange(max(n, 3)) / config.levels_per_octave)


_LEVELS: dict[tuple[int, float, int, float], Array] = {}


def _levels(config: FlirtFeatureConfig) -> Array:
    """`scale_levels` of the config, made once per (n_samples, sigma_0,
    levels_per_octave, max_scale_fraction); the array is shared: read it only."""
    key = (config.n_samples, config.sigma_0, config.levels_per_octave,
           config.max_scale_fraction)
    cached = _LEVELS.get(key)
    if cached is None:
        if len(_LEVELS) > 16:
            _LEVELS.clear()
        cached = _LEVELS[key] = scale_levels(config)
    return cached


def smoothed_curves(curve: Array, sigmas: Array) -> tuple[Array, Array]:
    """Gaussian-smoothed closed curve and its derivative at every scale.

    Args:
        curve: ``(N, 2)`` closed curve sampled uniformly by arc length.
        sigmas: ``(L,)`` scales [samples].

    Returns:
        ``(L, N, 2)`` smoothed points and ``(L, N, 2)`` derivatives d/ds [per sample].
    """
    smooth, deriv = _smoothed_complex(curve, sigmas)
    return (
        np.stack([smooth.real, smooth.imag], axis=-1),
        np.stack([deriv.real, deriv.imag], axis=-1),
    )


_FILTERS: dict[tuple[int, bytes], tuple[Array, Array]] = {}


def _filters(n: int, sigmas: Array) -> tuple[Array, Array]:
    """The Gaussians ``exp(-(sigma_l w)^2 / 2)`` ``(L, N)`` and ``i w`` ``(1, N)`` of the
    frequencies w [rad per sample] of an N-sample curve, made once per (N, scales)."""
    key = (n, np.asarray(sigmas, float).tobytes())
    cached = _FILTERS.get(key)
    if cached is None:
        w = 2.0 * np.pi * np.fft.fftfreq(n)  # rad per sample
        # Stored complex (imaginary part 0): the product with the complex spectrum is
        # the one numpy makes after casting a real factor, without the cast per call.
        cached = (np.exp(-0.5 * (sigmas[:, None] * w[None, :]) ** 2).astype(complex),
                  1j * w[None, :])
        if len(_FILTERS) > 16:
            _FILTERS.clear()
        _FILTERS[key] = cached
    return cached


def _smoothed_complex(curve: Array, sigmas: Array) -> tuple[Array, Array]:
    """`smoothed_curves` as complex ``x + i y`` ``(L, N)`` arrays: the curve's spectrum
    times each Gaussian, and that times ``i w`` for the derivative, both inverted by one
    batched inverse FFT (the same values as two)."""
    gauss, iw = _filters(len(curve), sigmas)
    spec = np.fft.fft(curve[:, 0] + 1j * curve[:, 1])
    both = np.empty((2, *gauss.shape), complex)
    np.multiply(spec[None, :], gauss, out=both[0])
    np.multiply(both[0], iw, out=both[1])
    both = np.fft.ifft(both, axis=2)
    return both[0], both[1]


def _local_maxima(a: Array) -> NDArray[np.bool_]:
    """Strict maxima of ``(L, N)`` responses over the 3 x 3 (scale, circular position)
    box (`flirt_peak_kernel`, compiled: the same mask as `_local_maxima_numpy`)."""
    # numba loads on first use: importing the matchers stays light.
    from loopclosure.matchers.flirt_peak_kernel import local_maxima_kernel

    return local_maxima_kernel(np.ascontiguousarray(a, dtype=float), 1.0 + _STRICT,
                               _STRICT * np.finfo(float).tiny)


def _local_maxima_numpy(a: Array) -> NDArray[np.bool_]:
    """`_local_maxima` in numpy (the reference of the compiled kernel)."""
    big = np.full((a.shape[0] + 2, a.shape[1]), -np.inf)
    big[1:-1] = a
    best = np.full(a.shape, -np.inf)
    for dl in (-1, 0, 1):
        rows = big[1 + dl : 1 + dl + a.shape[0]]
        for ds in (-1, 0, 1):
            if dl == 0 and ds == 0:
                continue
            best = np.maximum(best, np.roll(rows, -ds, axis=1))
    return a > best * (1.0 + _STRICT) + _STRICT * np.finfo(float).tiny


def _resampled(polygon: Polygon, n: int, compiled: bool) -> tuple[Array, float]:
    """``(n, 2)`` arc-length samples of the boundary (`Polygon.resample`, a new array)
    and the perimeter (`Polygon.perimeter`) [length]; compiled
    (`flirt_curve_kernel.resample_kernel`): the same bits in one pass."""
    if not compiled:
        return polygon.resample(n), polygon.perimeter
    # numba loads on first use: importing the matchers stays light.
    from loopclosure.matchers.flirt_curve_kernel import resample_kernel

    curve, lengths = resample_kernel(polygon.vertices, n)
    return curve, float(lengths.sum())


def _viewpoint(polygon: Polygon, mode: str, unit: float, compiled: bool = False) -> Array:
    """Where the beta-grids' beams start (module docstring, step 4) [length / unit];
    compiled (`flirt_curve_kernel.origin_view_kernel`): the same test in one loop."""
    if mode == "origin":
        return np.zeros(2)
    if mode == "centroid":
        return polygon.centroid() / unit
    if compiled:
        from loopclosure.matchers.flirt_curve_kernel import origin_view_kernel

        return np.zeros(2) if origin_view_kernel(polygon.vertices) else polygon.centroid() / unit
    v = polygon.vertices
    size = float(np.abs(v).max())
    on_vertex = bool(np.min(np.abs(v).max(axis=1)) <= 1e-9 * size)  # scans < 360 deg
    if on_vertex or polygon.contains(np.zeros((1, 2)))[0]:
        return np.zeros(2)
    return polygon.centroid() / unit


def detect(curve: Array, step: float, config: FlirtFeatureConfig) -> tuple[Array, Array, Array]:
    """Curvature-detector interest points of a uniformly resampled closed curve.

    Returns:
        ``idx`` ``(F,)`` sample indices, ``level`` ``(F,)`` scale-level indices and
        ``delta`` ``(L, N)`` scale-normalised displacements (dimensionless).
    """
    sigmas = scale_levels(config)
    smooth, deriv = _smoothed_complex(curve, sigmas)
    return _detect(curve, step, sigmas, smooth, deriv, config)


def _responses(curve: Array, step: float, sigmas: Array, smooth: Array, deriv: Array
               ) -> Array:
    """``(L, N)`` scale-normalised displacements delta (module docstring, step 3) of the
    curve from its complex smoothed copies and derivatives ``(L, N)``
    (`flirt_peak_kernel.responses_kernel`, compiled: `_responses_numpy`'s bits)."""
    # numba loads on first use: importing the matchers stays light.
    from loopclosure.matchers.flirt_peak_kernel import responses_kernel

    return responses_kernel(np.ascontiguousarray(curve, dtype=float), smooth, deriv,
                            np.ascontiguousarray(sigmas, dtype=float), float(step))


def _responses_numpy(curve: Array, step: float, sigmas: Array, smooth: Array, deriv: Array
                     ) -> Array:
    """`_responses` in numpy (the reference of the compiled kernel)."""
    smooth = np.stack([smooth.real, smooth.imag], axis=-1)
    deriv = np.stack([deriv.real, deriv.imag], axis=-1)
    speed = np.linalg.norm(deriv, axis=-1)
    speed = np.where(speed > 0, speed, 1.0)
    normal = np.stack([deriv[..., 1], -deriv[..., 0]], axis=-1) / speed[..., None]
    disp = np.einsum("lnk,lnk->ln", curve[None] - smooth, normal)
    return disp / (sigmas[:, None] * step)


def _detect(
    curve: Array,
    step: float,
    sigmas: Array,
    smooth: Array,
    deriv: Array,
    config: FlirtFeatureConfig,
) -> tuple[Array, Array, Array]:
    """`detect` from the complex smoothed curves and derivatives ``(L, N)``."""
    delta = _responses(curve, step, sigmas, smooth, deriv)
    if config.compiled:
        # numba loads on first use: importing the matchers stays light.
        from loopclosure.matchers.flirt_peak_kernel import peak_candidates_kernel

        level, idx, value = peak_candidates_kernel(
            delta, float(config.min_response), 1.0 + _STRICT, _STRICT * np.finfo(float).tiny)
    else:
        mag = np.abs(delta)
        peak = _local_maxima(mag) & (mag >= config.min_response)
        level, idx = np.nonzero(peak)
        value = mag[level, idx]
    order = np.argsort(-value, kind="stable")[: config.max_features]
    return idx[order], level[order], delta


def describe_polygon(polygon: Polygon, config: FlirtFeatureConfig) -> FlirtFeatures:
    """Interest points and beta-grids of `polygon` (module docstring, steps 1-4)."""
    cfg = config
    unit = float(np.sqrt(polygon.area)) if cfg.scale_invariant else 1.0
    if cfg.sample_step > 0 or cfg.max_range > 0 or cfg.max_jump > 0:
        return _describe_sampled(polygon, cfg, unit)
    curve, perimeter = _resampled(polygon, cfg.n_samples, cfg.compiled)
    curve /= unit
    step = perimeter / unit / cfg.n_samples
    sigmas = _levels(cfg)
    smooth, deriv = _smoothed_complex(curve, sigmas)
    idx, level, delta = _detect(curve, step, sigmas, smooth, deriv, cfg)
    return _features(polygon, cfg, unit, curve, step, sigmas, deriv, delta, idx, level,
                     np.arange(cfg.n_samples), np.arange(0, cfg.n_samples, cfg.beam_stride))


def _describe_sampled(polygon: Polygon, cfg: FlirtFeatureConfig, unit: float) -> FlirtFeatures:
    """`describe_polygon` with the contour-sampling option (module docstring): N from
    `sample_count`, and with `max_range` the dropped edges' samples and their borders
    excluded from detection, fallback points and beams."""
    n = sample_count(polygon, cfg.sample_step, cfg.n_samples, cfg.max_samples, unit)
    curve = polygon.resample(n) / unit
    step = polygon.perimeter / unit / n
    sized = replace(cfg, n_samples=n)
    sigmas = scale_levels(sized)
    smooth, deriv = _smoothed_complex(curve, sigmas)
    delta = _responses(curve, step, sigmas, smooth, deriv)
    mag = np.abs(delta)
    peak = _local_maxima(mag) & (mag >= cfg.min_response)
    if cfg.max_range > 0 or cfg.max_jump > 0:
        kept = kept_samples(polygon, n, cfg.max_range, cfg.max_jump)
        clear = border_distance(kept)[None, :] > cfg.border_sigmas * sigmas[:, None]
        peak &= clear & kept[None, :]
    else:
        kept = np.ones(n, dtype=bool)
    level, idx = np.nonzero(peak)
    order = np.argsort(-mag[level, idx], kind="stable")[: cfg.max_features]
    pool = np.flatnonzero(kept) if kept.any() else np.arange(n)
    beams = np.flatnonzero(kept)[:: cfg.beam_stride] if not kept.all() else \
        np.arange(0, n, cfg.beam_stride)
    return _features(polygon, cfg, unit, curve, step, sigmas, deriv, delta, idx[order],
                     level[order], pool, beams)


def _features(polygon: Polygon, cfg: FlirtFeatureConfig, unit: float, curve: Array,
              step: float, sigmas: Array, deriv: Array, delta: Array, idx: Array,
              level: Array, pool: Array, beams: Array) -> FlirtFeatures:
    """The interest points at samples `idx` of scale levels `level` (strongest first),
    their orientations (the normal ``(t_y, -t_x)`` of the smoothed tangent) and
    beta-grids cast from the samples `beams`.  Fewer than ``min_features`` points: the
    fallback of ``min_features + 1`` samples spread evenly over `pool` at the middle
    level, with zero response."""
    if len(idx) < cfg.min_features:
        k = cfg.min_features + 1
        idx = pool[(np.arange(k) * len(pool)) // k]
        level = np.full(k, len(sigmas) // 2)
        responses = np.zeros(k)
    else:
        responses = delta[level, idx]
    tangent = deriv[level, idx]
    orient = np.arctan2(-tangent.real, tangent.imag)  # angle of (t_y, -t_x)
    points = curve[idx]
    scales = sigmas[level] * step
    view = _viewpoint(polygon, cfg.viewpoint, unit, cfg.compiled)
    occ, evidence = beta_grids(points, scales, orient, curve[beams], view, cfg)
    return FlirtFeatures(points, scales, orient, responses, occ, evidence, float(step), unit)


def _bins(
    x: Array, y: Array, radius: Array, orient: Array, rings: int, sectors: int
) -> NDArray[np.intp]:
    """Bin index of offsets ``(x, y)`` in polar grids of `radius`, `orient` (broadcast).

    Ring ``floor(r / radius * rings)`` (clipped to the outer ring), sector
    ``floor(((atan2(y, x) - orient) mod 2 pi) * sectors / 2 pi + 1/2) mod sectors``:
    sector 0 is centred on the orientation, so with an even number of sectors the
    tangent directions (+-90 degrees, where the neighbouring boundary lies) fall in
    the middle of a sector, not on a border that rounding could flip.
    bin = ring * sectors + sector.
    """
    r = np.sqrt(x * x + y * y)
    ring = np.minimum((r * (rings / radius)).astype(np.int32), rings - 1)
    turns = (np.arctan2(y, x) - orient) * (sectors / (2.0 * np.pi)) + (2 * sectors + 0.5)
    sector = turns.astype(np.int32)
    sector %= sectors
    ring *= sectors
    ring += sector
    return ring


def beta_grids(
    points: Array,
    scales: Array,
    orientations: Array,
    ends: Array,
    view: Array,
    config: FlirtFeatureConfig,
) -> tuple[Array, NDArray[np.float32]]:
    """Beta-grid occupancy mean and evidence ``(F, rings * sectors)`` by ray tracing.

    The evidence is ``a + b`` of each bin's Beta posterior (float32): the variance is
    ``occ (1 - occ) / (evidence + 1)`` (module docstring, step 4).

    Args:
        points: ``(F, 2)`` grid centres; scales ``(F,)`` sigma [length];
            orientations ``(F,)`` angle of bin 0's axis [rad].
        ends: ``(B, 2)`` beam end points (boundary samples) [length].
        view: ``(2,)`` viewpoint every beam starts from [length].
        config: grid size, support factor and Beta prior.
    """
    cfg = config
    n_feat = len(points)
    nb = cfg.rings * cfg.sectors
    radius = cfg.support_factor * scales
    if cfg.compiled:
        # numba loads on first use: importing the matchers stays light.
        from loopclosure.matchers.flirt_grid_kernel import beta_grid_counts, beta_posterior

        hits, misses = beta_grid_counts(
            np.ascontiguousarray(points, dtype=float).reshape(-1, 2),
            np.ascontiguousarray(radius, dtype=float),
            np.ascontiguousarray(orientations, dtype=float),
            np.ascontiguousarray(ends, dtype=float).reshape(-1, 2),
            np.ascontiguousarray(view, dtype=float).reshape(2),
            cfg.rings, cfg.sectors, cfg.chord_samples,
        )
        return beta_posterior(hits, misses, float(cfg.prior_hit), float(cfg.prior_miss))
    # Hits: end points inside each support disc.
    ex = ends[None, :, 0] - points[:, 0:1]  # (F, B)
    ey = ends[None, :, 1] - points[:, 1:2]
    d2 = ex * ex + ey * ey
    # The interest point's own sample (distance 0) has no direction: it is left out.
    inside = (d2 < radius[:, None] ** 2) & (d2 > 0.0)
    f_hit, b_hit = np.nonzero(inside)
    hit_bin = _bins(
        ex[f_hit, b_hit],
        ey[f_hit, b_hit],
        radius[f_hit],
        orientations[f_hit],
        cfg.rings,
        cfg.sectors,
    )
    hits = np.bincount(f_hit * nb + hit_bin, minlength=n_feat * nb).reshape(n_feat, nb)
    end_bin = np.full(inside.shape, -1, dtype=np.intp)
    end_bin[f_hit, b_hit] = hit_bin
    # Misses: chord of each beam (view -> end) through each support disc.
    d = ends - view  # (B, 2)
    w = view[None, :] - points  # (F, 2)
    a = np.einsum("bk,bk->b", d, d)
    a = np.where(a > 0, a, 1.0)
    b2 = w @ d.T  # (F, B): half of the linear coefficient of |w + t d|^2 = R^2
    c = np.einsum("fk,fk->f", w, w)[:, None] - radius[:, None] ** 2
    disc = b2**2 - a[None, :] * c
    root = np.sqrt(np.maximum(disc, 0.0))
    t0 = np.maximum((-b2 - root) / a[None, :], 0.0)
    t1 = np.minimum((-b2 + root) / a[None, :], 1.0)
    f_ch, b_ch = np.nonzero((disc > 0) & (t1 > t0))
    misses = np.zeros(n_feat * nb)
    if len(f_ch):
        k = cfg.chord_samples
        frac = (np.arange(k) + 0.5) / k
        t_lo = t0[f_ch, b_ch][:, None]
        tt = t_lo + (t1[f_ch, b_ch][:, None] - t_lo) * frac[None, :]  # (P, k)
        sx = w[f_ch, 0:1] + tt * d[b_ch, 0:1]
        sy = w[f_ch, 1:2] + tt * d[b_ch, 1:2]
        sbin = _bins(
            sx, sy, radius[f_ch][:, None], orientations[f_ch][:, None], cfg.rings, cfg.sectors
        )
        # A beam that ends inside the disc is a hit (not a miss) in its end bin.
        sbin[sbin == end_bin[f_ch, b_ch][:, None]] = -1
        # Each beam counts once per bin it crosses: count the starts of runs of equal bins.
        start = np.ones(sbin.shape, dtype=bool)
        start[:, 1:] = sbin[:, 1:] != sbin[:, :-1]
        start &= sbin >= 0
        rows, _ = np.nonzero(start)
        misses = np.bincount(f_ch[rows] * nb + sbin[start], minlength=n_feat * nb)
    return _posterior(hits, misses.reshape(n_feat, nb), cfg)


def _posterior(
    hits: Array, misses: Array, cfg: FlirtFeatureConfig
) -> tuple[Array, NDArray[np.float32]]:
    """Occupancy mean ``(hits + a0) / (hits + misses + a0 + b0)`` and evidence
    ``hits + misses + a0 + b0`` (float32) of the Beta posterior (module docstring)."""
    alpha = hits + cfg.prior_hit
    total = alpha + misses + cfg.prior_miss
    return alpha / total, total.astype(np.float32)
