"""numba kernel of the keypoint-pair vote (`loopclosure.place_vote`): one query's votes
over one sorted block of postings, accumulated in a dense counter per (place, cell).

For every looked-up query pair i (key range ``lo[i] .. hi[i]`` of the block) and every
stored pair s in it, the rigid transform of the stored place's frame into the query's
(module docstring of `place_vote`):

    theta = wrap(phi_q - phi_s),     t = p_q - R(phi_q) (u_s, v_s)

with ``(u_s, v_s) = R(-phi_s) p_s`` stored (so ``R(theta) p_s = R(phi_q) R(-phi_s) p_s``
costs no trigonometry per posting).  A transform with ``|t| <= max_translation``
votes for the cell ``(floor(theta / theta_step), floor(t / translation_step))`` of
its place; the place's score is its fullest cell's count.  The counter is shared
between queries and left zero: the cells a query touched are recorded and reset.

numba is imported with this module (the index imports it on first use).
"""

from __future__ import annotations

import numba
import numpy as np

TWO_PI = 2.0 * np.pi


@numba.njit(cache=True, nogil=True)
def vote_block(lo, hi, qphi, qcos, qsin, qx, qy, srows, su, sv, sphi, max_t2,
               theta_step, n_theta, t_step, nt, counter, best, touched, n_touched):
    """Add one block's votes to `counter` ``(rows * n_cells,)`` and `best` ``(rows,)``.

    Args:
        lo, hi: ``(L,)`` posting range in the block of each looked-up query pair.
        qphi, qcos, qsin, qx, qy: ``(L,)`` that pair's direction [rad], its cosine and
            sine, and its first keypoint's position [m].
        srows, su, sv, sphi: the block's postings: place row, ``R(-phi_s) p_s`` [m],
            direction phi_s [rad].
        max_t2: squared largest translation [m^2]; theta_step [rad], t_step [m];
            n_theta, nt: cells per angle and per translation axis.
        counter, best: votes per (row, cell) and each row's fullest cell (updated).
        touched, n_touched: indices of the non-zero counter cells and their number.

    Returns:
        The new number of touched cells.
    """
    half = nt // 2
    n_cells = n_theta * nt * nt
    for i in range(lo.shape[0]):
        a, b = lo[i], hi[i]
        if a >= b:
            continue
        pq, c, s, x, y = qphi[i], qcos[i], qsin[i], qx[i], qy[i]
        for j in range(a, b):
            tx = x - (c * su[j] - s * sv[j])
            ty = y - (s * su[j] + c * sv[j])
            if tx * tx + ty * ty > max_t2:
                continue
            theta = pq - sphi[j]
            theta = theta - TWO_PI * np.floor(theta / TWO_PI)
            tb = int(np.floor(theta / theta_step)) % n_theta
            xb = int(np.floor(tx / t_step)) + half
            yb = int(np.floor(ty / t_step)) + half
            xb = min(max(xb, 0), nt - 1)
            yb = min(max(yb, 0), nt - 1)
            row = srows[j]
            cell = row * n_cells + (tb * nt + xb) * nt + yb
            v = counter[cell] + 1
            counter[cell] = v
            if v == 1:
                touched[n_touched] = cell
                n_touched += 1
            if v > best[row]:
                best[row] = v
    return n_touched


@numba.njit(cache=True, nogil=True)
def reset_cells(counter, touched, n_touched):
    """Zero the counter cells a query touched."""
    for i in range(n_touched):
        counter[touched[i]] = 0


@numba.njit(cache=True, nogil=True)
def merge_sorted(ka, kb):
    """Stable merge order of two key-sorted arrays: indices into ``concat(ka, kb)``
    (equal keys: `ka`'s first), O(len(ka) + len(kb))."""
    na, nb = ka.shape[0], kb.shape[0]
    out = np.empty(na + nb, np.int64)
    i = j = n = 0
    while i < na and j < nb:
        if kb[j] < ka[i]:
            out[n] = na + j
            j += 1
        else:
            out[n] = i
            i += 1
        n += 1
    while i < na:
        out[n] = i
        i += 1
        n += 1
    while j < nb:
        out[n] = na + j
        j += 1
        n += 1
    return out
