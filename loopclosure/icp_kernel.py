"""The compiled Gauss-Newton point-to-line ICP (numba, ``cache=True``): the kernel
behind `loopclosure.fast_icp.register_fast` and `register_target`.

Same maths as `loopclosure.registration.register` (read its module docstring for
the equations; frames, units and every figure of `IcpResult` are the same):
point-to-line rows onto line-like map points with their PCA normals, two
point-to-point rows (unit axes) onto clutter when `IcpConfig.point_to_point_clutter`
(weighted by `IcpConfig.clutter_weight`), no correspondence when the nearest map
point is neither; Cauchy / Huber / Tukey / no IRLS kernel of width
``kernel_constant * s``, ``s = max(min_residual_scale, 1.4826 median|r|)``; the
adaptive distance gate ``min(gate, max(min_correspondence_distance, gate_sigmas *
1.4826 median d))``; Gauss-Newton step ``-(H + Lambda)^-1 (g + Lambda (x - x_prior))``;
convergence on the step and a settled gate.  Medians are upper medians.  The
correspondences come from the map's cell grid (`loopclosure.grid_nearest._match`).
"""

from __future__ import annotations

import numba
import numpy as np

from loopclosure.grid_nearest import _match, _wrap
from loopclosure.kernel_cache import drop_stale

_MAD = 1.4826


@numba.njit(cache=True)
def _upper_median_abs(values, n):
    """The upper median ``sorted(|values[:n]|)[n // 2]`` (``n >= 1``), by selection
    (`np.partition`: the element a sort puts there, in linear time instead of a
    sort's ``n log n``; twice per ICP iteration)."""
    a = np.abs(values[:n])
    return np.partition(a, n // 2)[n // 2]


@numba.njit(cache=True)
def _rows(src, x, rows, lines, points, sel, jdx, pts, anchors, normals, r, jac, nrm):
    """Residuals ``r`` and Jacobian rows ``J`` at pose `x` of the given correspondences."""
    c, s = np.cos(x[2]), np.sin(x[2])
    clut = points - lines
    for k in range(rows):
        i, j = sel[k], jdx[k]
        rpx = c * src[i, 0] - s * src[i, 1]
        rpy = s * src[i, 0] + c * src[i, 1]
        qx, qy = pts[j, 0], pts[j, 1]
        if k < lines:
            n0, n1 = normals[j, 0], normals[j, 1]
            qx, qy = anchors[j, 0], anchors[j, 1]
        elif k < lines + clut:
            n0, n1 = 1.0, 0.0
        else:
            n0, n1 = 0.0, 1.0
        nrm[k, 0] = n0
        nrm[k, 1] = n1
        r[k] = n0 * (rpx + x[0] - qx) + n1 * (rpy + x[1] - qy)
        jac[k, 0] = n0
        jac[k, 1] = n1
        jac[k, 2] = n1 * rpx - n0 * rpy


@numba.njit(cache=True)
def _weights(r, rows, lines, points, scale, kernel, kconst, clutter_weight, w):
    k = kconst * scale
    for i in range(rows):
        if kernel == 0:
            wi = 1.0
        else:
            u = r[i] / k
            if kernel == 1:
                wi = 1.0 / (1.0 + u * u)
            elif kernel == 2:
                a = abs(u)
                wi = 1.0 if a <= 1.0 else 1.0 / max(a, 1e-300)
            else:
                wi = (1.0 - u * u) ** 2 if abs(u) < 1.0 else 0.0
        if i >= lines:
            wi *= clutter_weight
        w[i] = wi


@numba.njit(cache=True)
def _normal_equations(r, jac, w, rows):
    h = np.zeros((3, 3))
    g = np.zeros(3)
    for k in range(rows):
        for a in range(3):
            wa = w[k] * jac[k, a]
            g[a] += wa * r[k]
            for b in range(3):
                h[a, b] += wa * jac[k, b]
    return h, g


@numba.njit(cache=True)
def _solve3(h, g):
    """``h^-1 g`` for a symmetric positive definite ``3x3`` `h` (Cholesky; LU when
    rounding leaves a pivot that is not positive)."""
    if h[0, 0] <= 0.0:
        return np.linalg.solve(h, g)
    l00 = np.sqrt(h[0, 0])
    l10 = h[1, 0] / l00
    l20 = h[2, 0] / l00
    p11 = h[1, 1] - l10 * l10
    if p11 <= 0.0:
        return np.linalg.solve(h, g)
    l11 = np.sqrt(p11)
    l21 = (h[2, 1] - l20 * l10) / l11
    p22 = h[2, 2] - l20 * l20 - l21 * l21
    if p22 <= 0.0:
        return np.linalg.solve(h, g)
    l22 = np.sqrt(p22)
    y0 = g[0] / l00
    y1 = (g[1] - l10 * y0) / l11
    y2 = (g[2] - l20 * y0 - l21 * y1) / l22
    x2 = y2 / l22
    x1 = (y1 - l21 * x2) / l11
    x0 = (y0 - l10 * x1 - l20 * x2) / l00
    out = np.empty(3)
    out[0] = x0
    out[1] = x1
    out[2] = x2
    return out


@numba.njit(cache=True)
def _icp(src, x0, ox, oy, cell, nx, ny, start, pts, anchors, normals, kind, params, lam,
         x_prior, has_prior,
         max_iterations, gate0, min_gate, gate_sigmas, kernel, kconst, min_scale, clutter_weight,
         t_tol, r_tol, min_corr, joins, join_t, join_r):
    """Gauss-Newton ICP; returns (x, iterations, converged, ok, gate, rows, lines, points,
    sel, jdx, joined) with the correspondences to evaluate (empty-matched when not
    converged).  ``joined`` is the row of `joins` (``(K, 3)`` poses where earlier runs
    of the same problem ended) that an iterate came within `join_t` [m] and `join_r`
    [rad] of, the run stopping there; -1 when none did."""
    n = src.shape[0]
    sel = np.empty(2 * n, dtype=np.int64)
    jdx = np.empty(2 * n, dtype=np.int64)
    dist = np.empty(2 * n)
    r = np.empty(2 * n)
    w = np.empty(2 * n)
    jac = np.empty((2 * n, 3))
    nrm = np.empty((2 * n, 2))
    near = np.empty(n, dtype=np.int64)  # `_match`'s neighbours carried between iterations
    bound = np.empty(n)
    last = np.zeros(4)
    norms = np.empty(n)
    for i in range(n):
        norms[i] = np.hypot(src[i, 0], src[i, 1])
    x = x0.copy()
    gate = gate0
    iterations = 0
    converged = False
    rows = lines = points = 0
    for it in range(1, max_iterations + 1):
        iterations = it
        rows, lines, points = _match(src, x, gate, ox, oy, cell, nx, ny, start, pts, kind,
                                     sel, jdx, dist, params, normals, anchors, near, bound,
                                     last, norms)
        if points < min_corr:
            return x0.copy(), iterations, False, False, gate, rows, lines, points, sel, jdx, -1
        _rows(src, x, rows, lines, points, sel, jdx, pts, anchors, normals, r, jac, nrm)
        s = max(min_scale, _MAD * _upper_median_abs(r, rows))
        _weights(r, rows, lines, points, s, kernel, kconst, clutter_weight, w)
        h, g = _normal_equations(r, jac, w, rows)
        inv_s2 = 1.0 / (s * s)
        diff = x - x_prior
        diff[2] = _wrap(diff[2])
        for a in range(3):
            g[a] *= inv_s2
            if has_prior:
                for b in range(3):
                    g[a] += lam[a, b] * diff[b]
            for b in range(3):
                h[a, b] = h[a, b] * inv_s2 + lam[a, b]
        damp = 1e-12 * max(h[0, 0] + h[1, 1] + h[2, 2], 1e-12)
        for a in range(3):
            h[a, a] += damp
        step = -_solve3(h, g)
        x = x + step
        x[2] = _wrap(x[2])
        new_gate = min(gate, max(min_gate, gate_sigmas * _MAD * _upper_median_abs(dist, rows)))
        small = np.hypot(step[0], step[1]) < t_tol and abs(step[2]) < r_tol
        settled = new_gate >= gate * (1.0 - 1e-6)
        gate = new_gate
        if small and settled:
            converged = True
            break
        for m in range(joins.shape[0]):
            if (np.hypot(x[0] - joins[m, 0], x[1] - joins[m, 1]) < join_t
                    and abs(_wrap(x[2] - joins[m, 2])) < join_r):
                return x, iterations, False, True, gate, rows, lines, points, sel, jdx, m
    if not converged:
        rows, lines, points = _match(src, x, gate, ox, oy, cell, nx, ny, start, pts, kind,
                                     sel, jdx, dist, params, normals, anchors, near, bound,
                                     last, norms)
    return x, iterations, converged, True, gate, rows, lines, points, sel, jdx, -1


@numba.njit(cache=True)
def _figures(src, x, rows, lines, points, sel, jdx, pts, anchors, normals, kernel, kconst,
             min_scale,
             clutter_weight, fitness_tol):
    """Weighted residuals at the final pose: (h_data, wsum, wr2, inliers, rms, fitness)."""
    r = np.empty(rows)
    w = np.empty(rows)
    jac = np.empty((rows, 3))
    nrm = np.empty((rows, 2))
    _rows(src, x, rows, lines, points, sel, jdx, pts, anchors, normals, r, jac, nrm)
    s = max(min_scale, _MAD * _upper_median_abs(r, rows)) if rows > 0 else min_scale
    _weights(r, rows, lines, points, s, kernel, kconst, clutter_weight, w)
    h, _ = _normal_equations(r, jac, w, rows)
    wsum = 0.0
    wr2 = 0.0
    for k in range(rows):
        wsum += w[k]
        wr2 += w[k] * r[k] * r[k]
    clut = points - lines
    inliers = 0
    sq = 0.0
    fit = 0.0
    for k in range(points):
        if k < lines:
            rp = abs(r[k])
        else:
            rp = np.hypot(r[k], r[k + clut])
        if rp <= fitness_tol:
            inliers += 1
            sq += rp * rp
        fit += max(0.0, 1.0 - (rp / fitness_tol) ** 2)
    rms = np.sqrt(sq / inliers) if inliers > 0 else 0.0
    return h, wsum, wr2, inliers, rms, fit / src.shape[0]


@numba.njit(cache=True)
def _inv3(a):
    """``a^-1`` of a ``3x3`` matrix as `np.linalg.inv` computes it: LAPACK ``gesv``
    on the identity (numba's `np.linalg.inv` takes ``getrf`` + ``getri``, whose
    roundings differ)."""
    return np.linalg.solve(a, np.eye(3))


@numba.njit(cache=True)
def _register_kernel(src, x0, ox, oy, cell, nx, ny, start, pts, anchors, normals, kind,
                     params, prior_cov, x_prior, has_prior, max_iterations, gate0, min_gate,
                     gate_sigmas, kernel, kconst, min_scale, clutter_weight, t_tol, r_tol,
                     min_corr, fitness_tol, joins, join_t, join_r):
    """`_icp` and the figures of its result in one compiled call.

    Returns ``(status, joined, iterations, converged, points, x, cov, h_data, sigma2,
    inliers, rms, fitness, degeneracy, axis)``; ``status`` 0: a solution, 1: failed
    (too few correspondences; only ``iterations`` and ``points`` are set), 2: joined
    row ``joined`` of `joins` (only ``iterations`` is set).  The figures (module
    docstring of `loopclosure.registration`): ``sigma^2 = max(sum w r^2 / max(sum w
    - 3, 1), min_scale^2)``; covariance ``(H / sigma^2 + Lambda + 1e-12 tr(.) I)^-1``,
    symmetrised; degeneracy the smallest eigenvalue of the translation block of
    ``H`` with the rotation eliminated (Schur complement), over ``sum w``, in
    ``[0, 0.5]``, and its eigenvector.  Each step is the numpy expression of the
    reference with the same operations in the same order, and the inverses and the
    eigen-decomposition call the LAPACK routines numpy calls (``gesv``, ``syevd``
    on the lower triangle), so every figure is the same to the bit."""
    lam = np.zeros((3, 3))
    if has_prior:
        lam = _inv3(prior_cov)
    x, iterations, converged, ok, _gate, rows, lines, points, sel, jdx, joined = _icp(
        src, x0, ox, oy, cell, nx, ny, start, pts, anchors, normals, kind, params, lam,
        x_prior, has_prior, max_iterations, gate0, min_gate, gate_sigmas, kernel, kconst,
        min_scale, clutter_weight, t_tol, r_tol, min_corr, joins, join_t, join_r)
    cov = np.zeros((3, 3))
    h_data = np.zeros((3, 3))
    axis = np.zeros(2)
    if joined >= 0:
        return (2, joined, iterations, False, points, x, cov, h_data, 0.0, 0, 0.0, 0.0, 0.0,
                axis)
    if not ok or points < min_corr:
        return (1, -1, iterations, False, points, x, cov, h_data, 0.0, 0, 0.0, 0.0, 0.0,
                axis)
    h_data, wsum, wr2, inliers, rms, fitness = _figures(
        src, x, rows, lines, points, sel, jdx, pts, anchors, normals, kernel, kconst,
        min_scale, clutter_weight, fitness_tol)
    sigma2 = max(wr2 / max(wsum - 3.0, 1.0), min_scale**2)
    info = h_data / sigma2 + lam
    trace = info[0, 0] + info[1, 1] + info[2, 2]
    cov = _inv3(info + 1e-12 * max(trace, 1e-12) * np.eye(3))
    cov = 0.5 * (cov + cov.T)
    h_tt = np.empty((2, 2))
    for a in range(2):
        for b in range(2):
            h_tt[a, b] = h_data[a, b]
    if h_data[2, 2] > 1e-12:
        for a in range(2):
            for b in range(2):
                h_tt[a, b] = h_tt[a, b] - h_data[a, 2] * h_data[2, b] / h_data[2, 2]
    evals, evecs = np.linalg.eigh(h_tt)
    degeneracy = min(max(evals[0] / wsum, 0.0), 0.5) if wsum > 0 else 0.0
    axis[0] = evecs[0, 0]
    axis[1] = evecs[1, 0]
    x[2] = _wrap(x[2])
    return (0, -1, iterations, converged, points, x, cov, h_data, sigma2, inliers, rms,
            fitness, degeneracy, axis)


# numba's cache does not see edits of the callees' files (`loopclosure.kernel_cache`).
drop_stale(__name__, ("loopclosure.grid_nearest", "loopclosure.grid_target"))
