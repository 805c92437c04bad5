"""Compiled FLIRT RANSAC: `flirt.FlirtMatcher`'s matching steps 1-5 as one numba loop.

The numpy version scores every hypothesis of every database entry as one array
operation; for the place search's few entries per query (about ten) the arrays are
small and numpy's per-call overhead dominates (dozens of calls per query, a few
milliseconds in all).  This kernel walks each entry once with the same arithmetic
(the equations are in `loopclosure.matchers.flirt`'s docstring):

1. compatible pairs (scale ratio within `scale_ratio`), each query feature's `k`
   nearest by descriptor distance (ties: the lower stacked index first, as a
   stable sort), the guided-matching gate (descriptor distance no larger than the
   k-th candidate's) and the tie-breaker ``d * 1e-6 / d_max``;
2. hypotheses from the fixed correspondence pairs, with the length, distinct-feature
   and orientation tests; ``theta``, ``t`` [polygon units, rad] mapping the entry's
   frame into the query's;
3. the MSAC cost ``sum_i min_k min(e_ik^2, 1)``; the lowest cost on the grid of
   ``quantum`` wins, the first hypothesis among equal quantised costs (so the
   order of the floating-point sums cannot flip a tie);
4. guided matching, weighted Procrustes refit (weights ``1 / tau^2``), twice, and the
   guided matching again;
5. the one-to-one inliers and the distance in [0, 2].

Only the order of floating-point sums and the library of ``sin``, ``cos`` and
``atan2`` differ from numpy's, so the results agree to rounding.  Three shortcuts
change no result: the scale test ``|log(s_a / s_b)| <= log(scale_ratio)`` is
decided by comparing the ratio with ``scale_ratio^-+1`` except within a relative
1e-9 of them (`_compatible`); a hypothesis whose pair orientations disagree with
its rotation by a margin of 1e-9 in the cosine (the rotation's cosine and sine
taken as the normalised dot and cross products, equal to ``cos`` and ``sin`` of
the ``atan2`` to rounding) is dropped before the trigonometry; and the guided
matching walks each query feature's allowed features from a list made once per
entry instead of testing every stacked feature.  The descriptor
distances (a matrix product) stay in numpy and come in as `dd`.

numba is imported with this module, which `flirt` loads on first use; kernels are
cached on disk (``cache=True``).
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True)
def _guided(qp, qo, pts, ori, th, tx, ty, tau_all, alist, acount, tie, cos_tol, e, match):
    """Guided matching of one entry under ``(th, tx, ty)``: fills ``e`` and ``match`` (Q,).
    ``alist[q, :acount[q]]``: the stacked features query feature q may match, in
    increasing order (the allowed ones of step 1)."""
    c, s = math.cos(th), math.sin(th)
    n_q = alist.shape[0]
    for q in range(n_q):
        best_v = np.inf
        best_e = np.inf
        best_f = 0
        for u in range(acount[q]):
            f = alist[q, u]
            if math.cos(qo[q] - ori[f] - th) < cos_tol:
                continue
            ex = (c * pts[f, 0] - s * pts[f, 1] + tx) - qp[q, 0]
            ey = (s * pts[f, 0] + c * pts[f, 1] + ty) - qp[q, 1]
            ef = math.sqrt(ex * ex + ey * ey) / tau_all[q, f]
            v = ef + tie[q, f]
            if v < best_v:
                best_v, best_e, best_f = v, ef, f
        e[q] = best_e
        match[q] = best_f


@numba.njit(cache=True)
def _procrustes(qp, pts, match, inl, weight, th, tx, ty):
    """Weighted rigid fit ``q ~ R p + t`` on the inliers (`flirt._procrustes`).

    The transform is kept unless the inliers hold two distinct points on both sides.
    """
    n_q = qp.shape[0]
    first = -1
    spread_p = spread_q = False
    sw = 0.0
    mqx = mqy = mpx = mpy = 0.0
    for q in range(n_q):
        if inl[q]:
            w = weight[q]
            p = pts[match[q]]
            if first < 0:
                first = q
            else:
                f = pts[match[first]]
                spread_p = spread_p or p[0] != f[0] or p[1] != f[1]
                spread_q = spread_q or qp[q, 0] != qp[first, 0] or qp[q, 1] != qp[first, 1]
            sw += w
            mqx += w * qp[q, 0]
            mqy += w * qp[q, 1]
            mpx += w * p[0]
            mpy += w * p[1]
    if not (spread_p and spread_q):
        return th, tx, ty
    sw = max(sw, 2.2250738585072014e-308)
    mqx, mqy, mpx, mpy = mqx / sw, mqy / sw, mpx / sw, mpy / sw
    sxx = sxy = 0.0
    for q in range(n_q):
        if inl[q]:
            w = weight[q]
            p = pts[match[q]]
            dqx, dqy = qp[q, 0] - mqx, qp[q, 1] - mqy
            dpx, dpy = p[0] - mpx, p[1] - mpy
            sxx += w * (dpx * dqx + dpy * dqy)
            sxy += w * (dpx * dqy - dpy * dqx)
    new_th = math.atan2(sxy, sxx)
    c, s = math.cos(new_th), math.sin(new_th)
    return new_th, mqx - (c * mpx - s * mpy), mqy - (s * mpx + c * mpy)


@numba.njit(cache=True)
def euclidean_distances(qq, dn, cross):
    """``(M, Q, F)`` Euclidean beta-grid distances ``sqrt(max(|a|^2 + |b|^2 - 2 a.b,
    0))`` from the query's squared norms ``qq`` (Q,), the stacked features' ``dn``
    (M, F) and the products ``cross`` (M, F, Q) (`flirt.FlirtMatcher`'s descriptor
    distance, step 1): numpy's broadcast expression in one pass, the same operations
    in the same order (``(qq + dn) - 2 cross``, the maximum keeping a NaN), so the
    same bits, without its four temporaries and the transposed copy."""
    m, width, n_q = cross.shape
    out = np.empty((m, n_q, width))
    for r in range(m):
        for q in range(n_q):
            for f in range(width):
                x = qq[q] + dn[r, f] - 2.0 * cross[r, f, q]
                out[r, q, f] = math.sqrt(x if (x >= 0.0 or x != x) else 0.0)
    return out


@numba.njit(cache=True, inline="always")
def _compatible(x, gate, lo_in, hi_in, lo_out, hi_out):
    """``|log x| <= gate``: decided by comparisons where `x` lies clearly inside
    (``lo_in..hi_in``) or outside (beyond ``lo_out..hi_out``) of ``exp(-+gate)``
    (margins of 1e-9 relative, far above the rounding of ``log`` and ``exp``), by
    the logarithm itself in between: the same answer as the logarithm everywhere."""
    if lo_in < x < hi_in:
        return True
    if x < lo_out or x > hi_out:
        return False
    return abs(math.log(x)) <= gate


@numba.njit(cache=True)
def flirt_entries(
    qp, qs, qo, dd, pts, scl, ori, valid, counts, hi, ha, hj, hb,
    k, log_scale_ratio, cos_tol, inlier_factor, d_max, min_inliers, quantum,
):  # fmt: skip
    """Steps 1-5 for every stacked entry (module docstring).

    Args: query points ``qp`` (Q, 2), scales ``qs`` (Q,), orientations ``qo`` (Q,)
    [polygon units, rad]; descriptor distances ``dd`` (M, Q, F); the stack's points
    (M, F, 2), scales, orientations, validity (M, F) and feature counts (M,); the
    hypotheses' correspondence pairs ``(hi, ha), (hj, hb)`` (H,) each; the matcher's
    parameters; the cost grid ``quantum`` of step 3.

    Returns ``dist`` (M,), ``pose`` (M, 3) [x, y, theta], ``mean_e`` (M,), and for the
    inlier pairs the final residuals ``e`` (M, Q), matches (M, Q), inlier mask
    (M, Q) and each stacked feature's best residual ``best_e`` (M, F).
    """
    m, width = valid.shape
    n_q = qp.shape[0]
    n_h = hi.shape[0]
    dist = np.empty(m)
    pose = np.zeros((m, 3))
    mean_e = np.zeros(m)
    e_out = np.empty((m, n_q))
    match_out = np.zeros((m, n_q), dtype=np.intp)
    inl_out = np.zeros((m, n_q), dtype=np.bool_)
    best_out = np.full((m, width), np.inf)
    cand = np.empty((n_q, k), dtype=np.intp)
    cand_d = np.empty((n_q, k))
    alist = np.zeros((n_q, width), dtype=np.intp)
    acount = np.zeros(n_q, dtype=np.intp)
    nfin = np.zeros(n_q, dtype=np.intp)
    tie = np.zeros((n_q, width))
    tau_all = np.ones((n_q, width))  # set per entry where read (step 1)
    cpx = np.empty((n_q, k))
    cpy = np.empty((n_q, k))
    tau = np.empty((n_q, k))
    rel_c = np.empty((n_q, k))
    rel_s = np.empty((n_q, k))
    weight = np.empty(n_q)
    inl = np.zeros(n_q, dtype=np.bool_)
    gate = log_scale_ratio + 1e-12
    # |log x| <= gate decided without the logarithm away from the two bounds.
    e_hi = math.exp(gate)
    lo_in, hi_in = (1.0 + 1e-9) / e_hi, e_hi * (1.0 - 1e-9)
    lo_out, hi_out = (1.0 - 1e-9) / e_hi, e_hi * (1.0 + 1e-9)
    inv_tau2 = np.empty((n_q, k))
    # The query side of every hypothesis (the same for all entries).
    hvq = np.empty((n_h, 3))
    for h in range(n_h):
        vqx, vqy = qp[hj[h], 0] - qp[hi[h], 0], qp[hj[h], 1] - qp[hi[h], 1]
        hvq[h, 0], hvq[h, 1], hvq[h, 2] = vqx, vqy, math.sqrt(vqx * vqx + vqy * vqy)
    for r in range(m):
        # 1. Compatible pairs, k nearest (stable), gate and tie-breaker.
        look_sum = 0.0
        for q in range(n_q):
            for kk in range(k):
                cand_d[q, kk] = np.inf  # stays inf where fewer than k features
            filled = 0
            for f in range(width):
                ok = valid[r, f] and _compatible(qs[q] / scl[r, f], gate, lo_in, hi_in,
                                                 lo_out, hi_out)
                v = dd[r, q, f] if ok else np.inf
                tie[q, f] = v  # the masked distance, until the gate is known
                # Insert after every kept value <= v (stable order).
                if filled < k:
                    pos = filled
                    filled += 1
                elif v < cand_d[q, k - 1]:
                    pos = k - 1
                else:
                    continue
                while pos > 0 and cand_d[q, pos - 1] > v:
                    cand_d[q, pos] = cand_d[q, pos - 1]
                    cand[q, pos] = cand[q, pos - 1]
                    pos -= 1
                cand_d[q, pos] = v
                cand[q, pos] = f
            for kk in range(filled, k):  # fewer stacked features than k
                cand[q, kk] = cand[q, 0]
            kth = -np.inf
            for kk in range(k):
                if np.isfinite(cand_d[q, kk]) and cand_d[q, kk] > kth:
                    kth = cand_d[q, kk]
            acount[q] = 0
            for f in range(width):
                v = tie[q, f]
                if v <= kth:  # false where incompatible: v = inf, kth finite
                    alist[q, acount[q]] = f
                    acount[q] += 1
                    # tau of the pairs guided matching may use (every candidate is
                    # one of them); the others' are never read.
                    tau_all[q, f] = inlier_factor * math.sqrt(qs[q] * scl[r, f])
                    tie[q, f] = v * (1e-6 / d_max)
                else:
                    tie[q, f] = 0.0
            # cand_d[q] is sorted with its infinite entries last.
            nfin[q] = 0
            while nfin[q] < k and np.isfinite(cand_d[q, nfin[q]]):
                nfin[q] += 1
            for kk in range(k):
                f = cand[q, kk]
                cpx[q, kk] = pts[r, f, 0]
                cpy[q, kk] = pts[r, f, 1]
                tau[q, kk] = tau_all[q, f]
                inv_tau2[q, kk] = 1.0 / (tau[q, kk] * tau[q, kk])
                rel_c[q, kk] = math.cos(qo[q] - ori[r, f])
                rel_s[q, kk] = math.sin(qo[q] - ori[r, f])
            look_sum += cand_d[q, 0] if np.isfinite(cand_d[q, 0]) else d_max

        # 2-3. Hypotheses and their MSAC cost; the lowest wins, the first on ties.
        found = False
        best_q = np.inf  # the winner's quantised cost
        stop = np.inf  # a partial cost above this cannot quantise below best_q
        th = tx = ty = 0.0
        for h in range(n_h):
            i, a, j, b = hi[h], ha[h], hj[h], hb[h]
            if not (np.isfinite(cand_d[i, a]) and np.isfinite(cand_d[j, b])):
                continue
            if cand[i, a] == cand[j, b]:
                continue
            vqx, vqy, len_q = hvq[h, 0], hvq[h, 1], hvq[h, 2]
            vpx, vpy = cpx[j, b] - cpx[i, a], cpy[j, b] - cpy[i, a]
            len_p = math.sqrt(vpx * vpx + vpy * vpy)
            if not (abs(len_q - len_p) <= tau[i, a] + tau[j, b] and len_q > 0):
                continue
            cross = vpx * vqy - vpy * vqx
            dot = vpx * vqx + vpy * vqy
            norm = len_p * len_q
            if norm > 0.0:
                # cos and sin of theta to rounding: a pair clearly turned too far
                # (by a margin far above that rounding) is dropped before the
                # trigonometry; the exact test below decides the rest.
                ca, sa = dot / norm, cross / norm
                if rel_c[i, a] * ca + rel_s[i, a] * sa < cos_tol - 1e-9:
                    continue
                if rel_c[j, b] * ca + rel_s[j, b] * sa < cos_tol - 1e-9:
                    continue
            theta = math.atan2(cross, dot)
            c, s = math.cos(theta), math.sin(theta)
            if rel_c[i, a] * c + rel_s[i, a] * s < cos_tol:
                continue
            if rel_c[j, b] * c + rel_s[j, b] * s < cos_tol:
                continue
            mpx, mpy = 0.5 * (cpx[i, a] + cpx[j, b]), 0.5 * (cpy[i, a] + cpy[j, b])
            mqx, mqy = 0.5 * (qp[i, 0] + qp[j, 0]), 0.5 * (qp[i, 1] + qp[j, 1])
            htx = mqx - (c * mpx - s * mpy)
            hty = mqy - (s * mpx + c * mpy)
            cost = 0.0
            for q in range(n_q):
                low = 1.0
                for kk in range(nfin[q]):
                    if rel_c[q, kk] * c + rel_s[q, kk] * s < cos_tol:
                        continue
                    ex = c * cpx[q, kk] - s * cpy[q, kk] + (htx - qp[q, 0])
                    ey = s * cpx[q, kk] + c * cpy[q, kk] + (hty - qp[q, 1])
                    e2 = (ex * ex + ey * ey) * inv_tau2[q, kk]
                    if e2 < low:
                        low = e2
                cost += low
                if cost >= stop:
                    break  # cannot win: later terms are >= 0
            cost_q = np.rint(cost / quantum)
            if cost_q < best_q:
                found, best_q = True, cost_q
                stop = (best_q + 1.0) * quantum
                th, tx, ty = theta, htx, hty

        # 4. Guided matching and refits.
        e = e_out[r]
        match = match_out[r]
        for _ in range(2):
            _guided(qp, qo, pts[r], ori[r], th, tx, ty, tau_all, alist, acount, tie,
                    cos_tol, e, match)
            for q in range(n_q):
                inl[q] = found and e[q] < 1.0
                t_q = tau_all[q, match[q]]
                weight[q] = 1.0 / (t_q * t_q)
            th, tx, ty = _procrustes(qp, pts[r], match, inl, weight, th, tx, ty)
        _guided(qp, qo, pts[r], ori[r], th, tx, ty, tau_all, alist, acount, tie,
                cos_tol, e, match)

        # 5. One-to-one inliers and the distance.
        best = best_out[r]
        for q in range(n_q):
            inl_out[r, q] = found and e[q] < 1.0
            if inl_out[r, q] and e[q] < best[match[q]]:
                best[match[q]] = e[q]
        n_in = 0
        sum_e = 0.0
        for f in range(width):
            if best[f] < 1.0:
                n_in += 1
                sum_e += best[f]
        me = sum_e / n_in if n_in > 0 else 0.0
        frac = min(max(2.0 * n_in / max(n_q + counts[r], 1), 0.0), 1.0)
        score = frac * (1.0 - 0.5 * me)
        n_min = min(min_inliers, min(n_q, counts[r]))
        look = min(max(look_sum / (max(n_q, 1) * d_max), 0.0), 1.0) if n_q > 0 else 1.0
        if n_in >= max(n_min, 1):
            d = 1.0 - score
        else:
            d = 2.0 - 0.5 * score - 0.5 * (1.0 - look)
        dist[r] = min(max(d, 0.0), 2.0)
        pose[r, 0], pose[r, 1], pose[r, 2] = tx, ty, th
        mean_e[r] = me
    return dist, pose, mean_e, e_out, match_out, inl_out, best_out


__all__ = ["euclidean_distances", "flirt_entries"]
