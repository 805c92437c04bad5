"""Keypoint-pair vote: places that share a rigidly consistent part, however small.

A place is a set of oriented keypoints in its sensor frame (FLIRT interest points:
position p [m] and outward normal angle o [rad], `loopclosure.matchers.flirt_features`).
A global descriptor of the whole place (the surface-pair histogram) changes when two
passes see different parts of a room; a vote over local structure does not, as long
as a few keypoints are seen by both (the idea of Geometrical FLIRT Phrases, Tipaldi
et al. 2013, and of GLARE's landmark pairs, Himstedt et al. 2014; written from their
descriptions, no code of theirs was read).

Pair key.  For two keypoints a, b with ``l = |p_b - p_a|`` in
[``min_length``, ``max_length``] and direction ``phi = atan2(p_b - p_a)``:

    key(a, b) = (floor(l / length_step),
                 floor(wrap(o_a - phi) / angle_step),
                 floor(wrap(o_b - phi) / angle_step))

invariant to rotation and translation of the frame (``wrap`` to [0, 2 pi)).  Stored
places keep both directions of every pair (a, b) and (b, a); a query looks its pairs
up in one direction, with the length bins ``b - length_slack .. b + length_slack``
(default 1: a length on a bin edge still finds its match).  Optional parts of the
key: a class per keypoint in ``[0, n_labels)`` (e.g. convex or concave and the
detection scale's octave), and ``neighbours`` > 0 pairs a keypoint only with its
that many nearest (fewer pairs, fewer postings per query).

Vote.  A query pair (a, b) matched to a stored pair (a', b') of place j gives the
rigid transform of j's frame into the query's:

    theta = phi_q - phi_s,      t = p_a - R(theta) p_a'

and votes once for the cell ``(j, floor(theta / theta_step), floor(t / translation_step))``
(transforms with ``|t| > max_translation`` are dropped: a revisit is a keyframe a few
metres away).  Place j's score is its fullest cell's count, divided by
``sqrt(pairs_j)`` when ``normalise`` (a place with many keypoints collects more chance
votes), so a place scores by the largest set of pair matches that agree on one pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError

Array = NDArray[np.float64]
TWO_PI = 2.0 * np.pi


@dataclass(slots=True, frozen=True)
class PairVoteConfig:
    """Parameters of the pair vote (module docstring); lengths [m], angles [rad]."""

    min_length: float = 0.5
    max_length: float = 10.0
    length_step: float = 0.25
    angle_step: float = np.pi / 6
    theta_step: float = np.pi / 12
    translation_step: float = 0.75
    max_translation: float = 3.0
    normalise: bool = True
    neighbours: int = 0
    n_labels: int = 6
    length_slack: int = 1

    def __post_init__(self) -> None:
        steps = (self.length_step, self.angle_step, self.theta_step, self.translation_step)
        if not all(np.isfinite(s) and s > 0 for s in steps):
            raise UserError("pair vote: every step must be a positive number")
        if not (0 <= self.min_length < self.max_length and self.max_translation > 0):
            raise UserError("pair vote: need 0 <= min_length < max_length and "
                            "max_translation > 0")
        if self.neighbours < 0 or self.n_labels < 1 or self.length_slack < 0:
            raise UserError("pair vote: need neighbours >= 0, n_labels >= 1 and "
                            "length_slack >= 0")

    @property
    def n_angle(self) -> int:
        return int(np.ceil(TWO_PI / self.angle_step))

    @property
    def n_theta(self) -> int:
        return int(np.ceil(TWO_PI / self.theta_step))

    @property
    def n_translation(self) -> int:
        return 2 * int(np.ceil(self.max_translation / self.translation_step)) + 1


def pair_keys(points: Array, orientations: Array, config: PairVoteConfig,
              both_directions: bool, labels: NDArray[np.integer] | None = None
              ) -> tuple[NDArray[np.int64], NDArray[np.intp], Array]:
    """Keys of the keypoint pairs of one place (module docstring).

    Args:
        points: ``(F, 2)`` keypoint positions [m]; orientations: ``(F,)`` [rad].
        both_directions: every pair as (a, b) and (b, a) (stored side), else a < b.
        labels: ``(F,)`` class of each keypoint in ``[0, n_labels)`` (e.g. convex or
            concave), part of the key; None: all 0.

    Returns:
        ``(keys, a, phi)``: key of each pair (one int64), index of its first keypoint
        and its direction phi [rad].
    """
    p = np.asarray(points, float).reshape(-1, 2)
    o = np.asarray(orientations, float).ravel()
    lab = (np.zeros(len(p), np.int64) if labels is None
           else np.clip(np.asarray(labels, np.int64).ravel(), 0, config.n_labels - 1))
    pair = ~np.eye(len(p), dtype=bool)
    if config.neighbours and len(p) > config.neighbours + 1:
        dist = np.hypot(*(p[:, None, :] - p[None, :, :]).transpose(2, 0, 1))
        np.fill_diagonal(dist, np.inf)
        near = np.zeros_like(pair)
        rank = np.argsort(dist, axis=1, kind="stable")[:, : config.neighbours]
        near[np.repeat(np.arange(len(p)), config.neighbours), rank.ravel()] = True
        pair &= near | near.T
    if not both_directions:
        pair &= np.triu(np.ones_like(pair), 1)
    i, j = np.nonzero(pair)
    d = p[j] - p[i]
    length = np.hypot(d[:, 0], d[:, 1])
    keep = (length >= config.min_length) & (length <= config.max_length)
    i, j, d, length = i[keep], j[keep], d[keep], length[keep]
    phi = np.arctan2(d[:, 1], d[:, 0])
    na = config.n_angle
    a1 = np.floor(np.mod(o[i] - phi, TWO_PI) / config.angle_step).astype(np.int64) % na
    a2 = np.floor(np.mod(o[j] - phi, TWO_PI) / config.angle_step).astype(np.int64) % na
    lb = np.floor(length / config.length_step).astype(np.int64)
    nl = config.n_labels
    key = ((lb * na + a1) * na + a2) * nl * nl + lab[i] * nl + lab[j]
    return key, i.astype(np.intp), phi


class PairVoteIndex:
    """Inverted index of the stored places' pair keys; `scores` votes a query.

    The postings are one array sorted by key, rebuilt (O(P log P), P stored pairs)
    on the first query after an insertion: fit for a database filled once and then
    asked, not yet for one that grows between queries."""

    def __init__(self, config: PairVoteConfig | None = None) -> None:
        self.config = config or PairVoteConfig()
        self._parts: list[tuple] = []
        self._pairs: list[int] = []
        self._built: tuple | None = None

    def __len__(self) -> int:
        return len(self._pairs)

    def add(self, points: Array, orientations: Array,
            labels: NDArray[np.integer] | None = None) -> int:
        """Store one place (its row is the number of places stored before it)."""
        keys, a, phi = pair_keys(points, orientations, self.config, True, labels)
        row = len(self._pairs)
        p = np.asarray(points, float).reshape(-1, 2)[a]
        self._parts.append((keys, np.full(len(keys), row, np.int64), p, phi))
        self._pairs.append(len(keys))
        self._built = None
        return row

    def _index(self) -> tuple:
        if self._built is None:
            if self._parts:
                keys, rows, p, phi = (np.concatenate(c) for c in zip(*self._parts,
                                                                     strict=True))
            else:
                keys, rows, p, phi = (np.zeros(0, np.int64), np.zeros(0, np.int64),
                                      np.zeros((0, 2)), np.zeros(0))
            order = np.argsort(keys, kind="stable")
            self._built = (keys[order], rows[order], p[order], phi[order])
        return self._built

    def scores(self, points: Array, orientations: Array,
               labels: NDArray[np.integer] | None = None) -> Array:
        """``(len(self),)`` vote score of every stored place for the query keypoints."""
        cfg = self.config
        out = np.zeros(len(self))
        skeys, srows, sp, sphi = self._index()
        qkeys, qa, qphi = pair_keys(points, orientations, cfg, False, labels)
        if not len(qkeys) or not len(skeys):
            return out
        na2 = cfg.n_angle ** 2 * cfg.n_labels ** 2
        shifts = np.arange(-cfg.length_slack, cfg.length_slack + 1) * na2
        look = (qkeys[None, :] + shifts[:, None]).ravel()
        owner = np.tile(np.arange(len(qkeys)), len(shifts))
        lo = np.searchsorted(skeys, look, side="left")
        hi = np.searchsorted(skeys, look, side="right")
        n = hi - lo
        total = int(n.sum())
        if total == 0:
            return out
        q = np.repeat(owner, n)
        s = np.repeat(lo - np.cumsum(n) + n, n) + np.arange(total)
        theta = np.mod(qphi[q] - sphi[s], TWO_PI)
        c, si = np.cos(theta), np.sin(theta)
        qp = np.asarray(points, float).reshape(-1, 2)[qa[q]]
        tx = qp[:, 0] - (c * sp[s, 0] - si * sp[s, 1])
        ty = qp[:, 1] - (si * sp[s, 0] + c * sp[s, 1])
        keep = np.hypot(tx, ty) <= cfg.max_translation
        nt = cfg.n_translation
        half = nt // 2
        tb = np.floor(theta[keep] / cfg.theta_step).astype(np.int64) % cfg.n_theta
        xb = np.clip(np.floor(tx[keep] / cfg.translation_step).astype(np.int64) + half, 0, nt - 1)
        yb = np.clip(np.floor(ty[keep] / cfg.translation_step).astype(np.int64) + half, 0, nt - 1)
        rows = srows[s[keep]]
        cell = ((rows * cfg.n_theta + tb) * nt + xb) * nt + yb
        cells, counts = np.unique(cell, return_counts=True)
        np.maximum.at(out, cells // (cfg.n_theta * nt * nt), counts.astype(float))
        if cfg.normalise:
            out /= np.sqrt(np.maximum(np.asarray(self._pairs, float), 1.0))
        return out


__all__ = ["PairVoteConfig", "PairVoteIndex", "pair_keys"]
