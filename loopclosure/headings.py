"""Heading hypotheses: the one heading convention of the plugin, and its producers.

Convention
----------
Every heading hypothesis in the plugin is **the heading of the query in the stored
frame**:

    theta = heading(query sensor) - heading(stored sensor)        [rad, in [-pi, pi)]

i.e. the rotation part of the pose of the query keyframe in the stored keyframe's
frame, the rotation ICP estimates when the query (source) is registered onto the
stored keyframe (target): ``IcpResult.pose[2]`` of `loopclosure.registration`.  A
point ``p`` seen by the query is seen by the stored keyframe at ``R(theta) p + t``:
the stored polygon ~ ``R(theta)`` . the query polygon about their centroids.
`loopclosure.multi_start.initial_guesses` takes these angles as the headings of its
start poses unchanged.

Producers (all return best first):

- `headings_from_polar_grids`: from polar occupancy grids of the two places about
  their sensor origins (`polar_occupancy`: rings x bearing sectors, the layout of
  Scan Context, Kim & Kim, IROS 2018), by the circular cross-correlation of the
  grids along the bearing axis summed over the rings; vectorised over K stored
  keyframes.  The sensor origins of a revisit are at most metres apart, and the
  grid keeps *where* along each bearing the surfaces are, so it finds the heading
  where a range function about the centroid (which open space drags by metres)
  does not; the place database puts these hypotheses first.
- `headings_from_range_functions`: from polygon range functions
  (`loopclosure.matchers.fft.FFTDescriptor.range_function`: range about the centroid
  per angle bin, in the sensor frame's orientation), vectorised over K stored
  keyframes; the place database's hypotheses for every candidate
  (`loopclosure.place_match.PlaceMatch.headings`).
- `heading_hypotheses`: from two point sets (source = query, target = stored), by
  the cross-correlation of their range functions seen from each frame's origin
  (`range_function`: nearest return per bearing sector), or of their histograms of
  normal directions (`direction_histogram`; translation invariant, each peak gives
  two headings, ``phi`` and ``phi + pi``); the odometry front end's search.

`loopclosure.matchers.fft.heading_from_range_functions(a, b)` (one pair, the FFT
matcher's own) returns heading(a) - heading(b): called as ``(query, stored)`` it is
in this convention too.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from data import se2
from data.errors import UserError
from loopclosure.registration import IcpConfig, as_points, estimate_normals

Array = NDArray[np.float64]



def _circular_peaks(c: Array) -> Array:
    """Rows of circular correlations with every entry that is not a local maximum of
    its row (cyclically) set to -inf; a row with a flat maximum (no strict peak) keeps
    its argmax, as the scalar version."""
    peak = (c >= np.roll(c, 1, axis=1)) & (c > np.roll(c, -1, axis=1))
    flat = ~peak.any(axis=1)
    peak[flat, np.argmax(c[flat], axis=1)] = True
    return np.where(peak, c, -np.inf)


def _parabolic_peaks(c: Array, top: NDArray[np.intp]) -> tuple[Array, Array, Array]:
    """Sub-sample offsets of the peaks ``c[row, top[row]]`` of circular correlation
    rows, by a parabola through each peak and its two neighbours.

    Returns ``(delta, c0, slope)``, each shaped like `top`: the offset in samples
    (in [-0.5, 0.5]; 0 where the parabola opens upwards), the correlation at the peak
    and ``c[left] - c[right]``; the parabola's maximum is ``c0 - slope * delta / 4``.
    """
    rows = np.arange(len(c))[:, None]
    c0 = c[rows, top]
    cl = np.roll(c, 1, axis=1)[rows, top]
    cr = np.roll(c, -1, axis=1)[rows, top]
    curv = cl - 2.0 * c0 + cr
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(curv < 0, 0.5 * (cl - cr) / curv, 0.0)
    return np.clip(np.nan_to_num(delta), -0.5, 0.5), c0, cl - cr

def range_function(points: ArrayLike, bins: int) -> Array:
    """``(bins,)`` nearest range per bearing sector seen from the origin [m]; 0 if empty.

    Sector ``k`` covers bearings ``[-pi + k * 2 pi / bins, -pi + (k + 1) * 2 pi / bins)``.
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    out = np.full(bins, np.inf)
    if len(pts):
        bearing = np.arctan2(pts[:, 1], pts[:, 0])
        sector = np.clip(((bearing + np.pi) / (2 * np.pi) * bins).astype(int), 0, bins - 1)
        np.minimum.at(out, sector, np.hypot(pts[:, 0], pts[:, 1]))
    out[~np.isfinite(out)] = 0.0
    return out


def direction_histogram(normals: Array, bins: int) -> Array:
    """``(bins,)`` histogram of normal directions modulo pi (sign-free), unit-sum.

    Bin ``k`` covers ``[k pi / bins, (k + 1) pi / bins)``.
    """
    ang = np.mod(np.arctan2(normals[:, 1], normals[:, 0]), np.pi)
    hist = np.bincount(np.clip((ang / np.pi * bins).astype(int), 0, bins - 1), minlength=bins)
    hist = hist.astype(float)
    total = hist.sum()
    return hist / total if total > 0 else hist


def _circular_correlation(f: Array, g: Array) -> Array:
    """``c[k] = sum_i f[i] g[i + k]`` (circular), by FFT, after removing the means."""
    f = f - f.mean()
    g = g - g.mean()
    return np.fft.irfft(np.conj(np.fft.rfft(f)) * np.fft.rfft(g), n=len(f))


def _peaks(corr: Array, count: int, separation: int) -> NDArray[np.intp]:
    """Indices of up to `count` highest circular local maxima, `separation` bins apart."""
    n = len(corr)
    order = np.argsort(-corr, kind="stable")
    chosen: list[int] = []
    for k in order[: max(4 * count * separation, count)]:  # a few candidates only
        if all(min(abs(k - c), n - abs(k - c)) >= separation for c in chosen):
            chosen.append(int(k))
            if len(chosen) == count:
                break
    return np.array(chosen, dtype=np.intp)


def heading_hypotheses(
    source: ArrayLike,
    target: ArrayLike,
    *,
    count: int = 4,
    bins: int = 360,
    method: str = "range",
    config: IcpConfig | None = None,
) -> Array:
    """Candidate headings [rad] of the source frame in the target frame, best first.

    ``method="range"``: peaks of the circular cross-correlation of the range
    functions (`range_function`) of the source and the target, each seen from its
    frame's origin: a source scanned at heading theta sees at bearing phi what the
    target sees at ``phi + theta``.  Good when the two origins are close (keyframes
    of a loop closure).  ``method="normals"``: peaks of the correlation of the
    direction histograms of the PCA normals (`direction_histogram`, modulo pi;
    translation invariant); each peak phi yields ``phi`` and ``phi + pi``.
    Peaks are at least 10 degrees apart; the result is wrapped to ``[-pi, pi)``.
    """
    src = as_points(source, "source points")
    tgt = as_points(target, "target points")
    if method == "range":
        corr = _circular_correlation(range_function(src, bins), range_function(tgt, bins))
        sep = max(1, round(bins / 36))
        idx = _peaks(corr, count, sep)
        return se2.wrap_angle(idx * 2.0 * np.pi / bins)
    if method == "normals":
        cfg = config or IcpConfig()
        heads: list[float] = []
        hists = []
        for pts in (src, tgt):
            normals, ok, _ = estimate_normals(pts, cKDTree(pts), cfg)
            hists.append(direction_histogram(normals[ok], bins // 2))
        corr = _circular_correlation(hists[0], hists[1])
        sep = max(1, round(bins / 36))
        for k in _peaks(corr, max(1, (count + 1) // 2), sep):
            phi = k * np.pi / (bins // 2)
            heads.extend([phi, phi + np.pi])
        return se2.wrap_angle(np.array(heads[:count]))
    raise UserError(f"unknown heading method {method!r}: choose 'range' or 'normals'")


def polar_occupancy(
    points: ArrayLike, rings: int, sectors: int, max_range: float
) -> NDArray[np.bool_]:
    """``(rings, sectors)`` occupancy of polar cells about the origin by `points` [m].

    Cell ``(i, k)``: ranges ``[i, i + 1) * max_range / rings`` and bearings
    ``[-pi + k * 2 pi / sectors, -pi + (k + 1) * 2 pi / sectors)``; True when a point
    falls in it.  Points at or beyond `max_range` are left out.
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    grid = np.zeros((rings, sectors), dtype=bool)
    if len(pts):
        r = np.hypot(pts[:, 0], pts[:, 1])
        use = np.isfinite(r) & (r < max_range)
        ring = np.minimum((r[use] * (rings / max_range)).astype(np.int64), rings - 1)
        bearing = np.arctan2(pts[use, 1], pts[use, 0])
        sector = ((bearing + np.pi) * (sectors / (2 * np.pi))).astype(np.int64) % sectors
        grid[ring, sector] = True
    return grid


def headings_from_polar_grids(
    query_grid: ArrayLike, stored_grids: ArrayLike, n: int, separation: int = 3
) -> tuple[Array, Array]:
    """Up to `n` headings of the query in the frame of each of K stored keyframes.

    With G^q and G^j the ``(R, S)`` occupancy grids (`polar_occupancy`) of the query
    and of stored keyframe j, the correlation of the query with the stored grid
    turned by k sectors,

        c_j[k] = sum_i sum_s G^j[i, s] G^q[i, s + k] / (|G^q| |G^j|)      in [0, 1]

    (circular in s, by FFT along the sectors), peaks where the query sees at bearing
    phi + k 2 pi / S what keyframe j sees at phi: the heading of the query in j's
    frame is then ``-k 2 pi / S``.  The `n` highest circular local maxima at least
    `separation` sectors apart, each refined by a parabola through its neighbours.

    Args:
        query_grid: ``(R, S)`` grid of the query.
        stored_grids: ``(K, R, S)`` grids of K stored keyframes.
        n: hypotheses per keyframe.
        separation: least distance of two hypotheses [sectors].

    Returns:
        ``(headings, scores)``, each ``(K, n)``: heading [rad] in [-pi, pi) of the query
        in the stored frame (module docstring) and c at that peak; rows by decreasing
        score; missing hypotheses (an empty grid, fewer peaks) have score -inf.
    """
    q = np.asarray(query_grid, dtype=float)
    g = np.asarray(stored_grids, dtype=float)
    if g.ndim == 2:
        g = g[None]
    k, rings, sectors = g.shape
    if q.shape != (rings, sectors):
        raise UserError(f"polar grids disagree: query {q.shape}, stored {g.shape}")
    denom = np.sqrt(float((q * q).sum()) * np.einsum("kij,kij->k", g, g))
    spec = (np.conj(np.fft.rfft(g, axis=2)) * np.fft.rfft(q, axis=1)[None]).sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.fft.irfft(spec, n=sectors, axis=1) / denom[:, None]
    valid = denom > 0
    c[~valid] = 0.0
    masked = _circular_peaks(c)
    order = np.argsort(-masked, axis=1, kind="stable")
    m = min(n, sectors)
    top = np.zeros((k, m), dtype=np.intp)
    ok = np.zeros((k, m), dtype=bool)
    for row in range(k):  # K candidates (about 10), a few peaks each
        chosen: list[int] = []
        for idx in order[row]:
            if not np.isfinite(masked[row, idx]):
                break
            if all(min(abs(idx - c0), sectors - abs(idx - c0)) >= separation for c0 in chosen):
                chosen.append(int(idx))
                if len(chosen) == m:
                    break
        top[row, : len(chosen)] = chosen
        ok[row, : len(chosen)] = True
    delta, c0, slope = _parabolic_peaks(c, top)
    heading = se2.wrap_angle(-(top + delta) * (2.0 * np.pi / sectors))
    score = np.clip(c0 - 0.25 * slope * delta, 0.0, 1.0)
    ok &= valid[:, None]
    score = np.where(ok, score, -np.inf)
    order = np.argsort(-score, axis=1, kind="stable")
    heading = np.take_along_axis(np.where(ok, heading, 0.0), order, 1)
    return heading, np.take_along_axis(score, order, 1)


def headings_from_range_functions(
    query_range: ArrayLike, stored_ranges: ArrayLike, n: int
) -> tuple[Array, Array]:
    """Up to `n` headings of the query in the frame of each of K stored keyframes.

    Circular cross-correlation (by FFT) of the query's range function with each
    stored one, normalised to a Pearson correlation; its `n` highest local maxima,
    each refined by a parabola through the peak and its two neighbours.

    Args:
        query_range: ``(B,)`` range function [m] of the query (`FFTDescriptor.range_function`).
        stored_ranges: ``(K, B)`` range functions of K stored keyframes.
        n: hypotheses per keyframe.

    Returns:
        ``(headings, scores)``, each ``(K, n)``: heading [rad] in [-pi, pi) of the query
        in the stored frame (module docstring) and the Pearson correlation at that
        peak; rows sorted by decreasing score; missing peaks (fewer than n local
        maxima, or a constant range function) have score -inf and heading 0.  The
        first hypothesis is exactly ``-heading_from_range_functions(stored, query)``
        (= ``heading_from_range_functions(query, stored)`` up to rounding).
    """
    q = np.asarray(query_range, dtype=float)
    r = np.atleast_2d(np.asarray(stored_ranges, dtype=float))
    k, b = r.shape
    if q.shape != (b,):
        raise UserError(
            f"range functions disagree: query_range {q.shape}, stored_ranges {r.shape}"
        )
    qc = q - q.mean()
    rc = r - r.mean(axis=1, keepdims=True)
    denom = np.sqrt(float(qc @ qc) * np.einsum("ij,ij->i", rc, rc))
    spec = np.conj(np.fft.rfft(rc, axis=1)) * np.fft.rfft(qc)[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.fft.irfft(spec, n=b, axis=1) / denom[:, None]
    valid = denom > 1e-12 * b
    c[~valid] = 0.0
    masked = _circular_peaks(c)
    m = min(n, b)
    top = np.argsort(-masked, axis=1, kind="stable")[:, :m]
    rows = np.arange(k)[:, None]
    delta, c0, slope = _parabolic_peaks(c, top)
    # The correlation peaks at the rotation taking the stored range function onto the
    # query's (query ~ R(rotation) . stored), in (-pi, pi]; the heading of the query in
    # the stored frame is its negative (exact).
    angle = (top + delta) * (2.0 * np.pi / b)
    angle = (angle + np.pi) % (2.0 * np.pi) - np.pi
    angle[angle == -np.pi] = np.pi
    score = np.clip(c0 - 0.25 * slope * delta, -1.0, 1.0)
    ok = np.isfinite(masked[rows, top]) & valid[:, None]
    score = np.where(ok, score, -np.inf)
    angle = np.where(ok, angle, 0.0)
    invalid_rows = ~valid
    if invalid_rows.any():  # undefined heading: one hypothesis 0 rad with score 0
        score[invalid_rows, 0] = 0.0
    return -angle, score
