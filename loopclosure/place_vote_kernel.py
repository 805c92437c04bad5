"""numba kernel of the keypoint-pair vote (`loopclosure.place_vote`): one query's votes
over one sorted block of postings, accumulated in a dense counter per (place, cell).

For every looked-up query pair i (key range ``lo[i] .. hi[i]`` of the block) and every
stored pair s in it, the rigid transform of the stored place's frame into the query's
(module docstring of `place_vote`):

    theta = wrap(phi_q - phi_s),     t = p_q - R(phi_q) (u_s, v_s)

with ``(u_s, v_s) = R(-phi_s) p_s`` stored (so ``R(theta) p_s = R(phi_q) R(-phi_s) p_s``
costs no trigonometry per posting).  A transform with ``|t| <= max_translation``
votes for the cell ``(floor(theta / theta_step), floor(t / translation_step))`` of
its place; the place's score is its fullest cell's count.  The votes are written as
one integer code per vote (`vote_block`) and counted by blocks of places
(`fullest_cells`): a dense counter over every place and cell would be touched at
random, one cache miss per vote.

numba is imported with this module (the index imports it on first use).
"""

from __future__ import annotations

import numba
import numpy as np

TWO_PI = 2.0 * np.pi


@numba.njit(cache=True, nogil=True)
def vote_block(lo, hi, qphi, qcos, qsin, qx, qy, srows, su, sv, sphi, max_t2,
               theta_step, n_theta, t_step, nt, codes, n):
    """Append one block's votes to `codes` as ``row * n_cells + cell``.

    Args:
        lo, hi: ``(L,)`` posting range in the block of each looked-up query pair.
        qphi, qcos, qsin, qx, qy: ``(L,)`` that pair's direction [rad], its cosine and
            sine, and its first keypoint's position [m].
        srows, su, sv, sphi: the block's postings: place row, ``R(-phi_s) p_s`` [m],
            direction phi_s [rad].
        max_t2: squared largest translation [m^2]; theta_step [rad], t_step [m];
            n_theta, nt: cells per angle and per translation axis.
        codes, n: the votes so far and their number.

    Returns:
        The new number of votes.
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
            xb = min(max(int(np.floor(tx / t_step)) + half, 0), nt - 1)
            yb = min(max(int(np.floor(ty / t_step)) + half, 0), nt - 1)
            codes[n] = srows[j] * n_cells + (tb * nt + xb) * nt + yb
            n += 1
    return n


@numba.njit(cache=True, nogil=True)
def fullest_cells(codes, n, n_rows, n_cells, chunk_rows, best):
    """``best[row]`` = the largest count of one code among ``codes[:n]`` of that row.

    The codes are first partitioned by blocks of `chunk_rows` rows (one counting
    pass and one scatter), then counted block by block in a dense counter of
    ``chunk_rows * n_cells`` cells small enough to stay in cache, and the counter is
    zeroed behind each block: O(n + rows) and no memory kept between queries."""
    span = chunk_rows * n_cells
    n_chunks = (n_rows + chunk_rows - 1) // chunk_rows
    starts = np.zeros(n_chunks + 1, np.int64)
    for i in range(n):
        starts[codes[i] // span + 1] += 1
    for c in range(n_chunks):
        starts[c + 1] += starts[c]
    at = starts[:-1].copy()
    part = np.empty(n, codes.dtype)
    for i in range(n):
        c = codes[i] // span
        part[at[c]] = codes[i]
        at[c] += 1
    counter = np.zeros(span, np.int32)
    for c in range(n_chunks):
        base = c * span
        for i in range(starts[c], starts[c + 1]):
            local = part[i] - base
            v = counter[local] + 1
            counter[local] = v
            row = part[i] // n_cells
            if v > best[row]:
                best[row] = v
        for i in range(starts[c], starts[c + 1]):
            counter[part[i] - base] = 0


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
