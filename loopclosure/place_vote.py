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

Keypoints (`vote_keypoints`): FLIRT interest points of the place's polygon with the
boundary sampled every ``step`` metres (not a fixed number of samples whatever the
perimeter, so the detection scales do not change with how much open space a
viewpoint sees), the ``max_features`` strongest, those farther than ``max_range``
from the sensor dropped (far, viewpoint-made edges do not repeat between passes);
class = concave (1) or convex (0) + 2 x the detection scale's octave above 0.3 m
(0..2), 6 classes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from loopclosure.matchers.flirt import FlirtConfig, FlirtMatcher
from loopclosure.polygon import Polygon

Array = NDArray[np.float64]
TWO_PI = 2.0 * np.pi
CHUNK_PLACES = 128
"""Places counted together by the vote (`place_vote_kernel.fullest_cells`): their
counter, ``CHUNK_PLACES`` x cells per place x 4 bytes, stays in cache."""
TABLE_PLACES = 64
"""A block of at least this many places keeps a table of where each key starts
(``n_keys + 1`` offsets) instead of being binary-searched per query."""


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
    stop_share: float = 0.0

    def __post_init__(self) -> None:
        steps = (self.length_step, self.angle_step, self.theta_step, self.translation_step)
        if not all(np.isfinite(s) and s > 0 for s in steps):
            raise UserError("pair vote: every step must be a positive number")
        if not (0 <= self.min_length < self.max_length and self.max_translation > 0):
            raise UserError("pair vote: need 0 <= min_length < max_length and "
                            "max_translation > 0")
        if not (np.isfinite(self.stop_share) and self.stop_share >= 0):
            raise UserError("pair vote: stop_share must be >= 0 (0: no stop-list)")
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
    def n_keys(self) -> int:
        """Number of distinct pair keys (every key is in ``[0, n_keys)``)."""
        n_length = int(np.floor(self.max_length / self.length_step)) + 1
        return n_length * self.n_angle ** 2 * self.n_labels ** 2

    @property
    def n_translation(self) -> int:
        return 2 * int(np.ceil(self.max_translation / self.translation_step)) + 1


def vote_keypoints(polygon: Polygon, step: float = 0.2, max_range: float = 15.0,
                   max_features: int = 80) -> tuple[Array, Array, NDArray[np.int64]]:
    """Keypoints of one place for the vote (module docstring, Keypoints).

    Args:
        polygon: the place in its sensor frame [m].
        step: boundary sampling step [m] (``n_samples`` = perimeter / step, clipped
            to 64 .. 4096).
        max_range: keypoints farther from the sensor are dropped [m].
        max_features: strongest interest points kept before the range cut.

    Returns:
        ``(points (F, 2) [m], orientations (F,) [rad], labels (F,) in 0..5)``.
    """
    v = np.asarray(polygon.vertices, float)
    perimeter = float(np.hypot(*(np.roll(v, -1, axis=0) - v).T).sum())
    n = int(np.clip(round(perimeter / step), 64, 4096))
    f = FlirtMatcher(FlirtConfig(n_samples=n, max_features=max_features)).describe(polygon)
    p, o = np.asarray(f.points, float).reshape(-1, 2), np.asarray(f.orientations, float)
    octave = np.clip(np.floor(np.log2(np.maximum(f.scales, 1e-9) / 0.3)), 0, 2)
    lab = (np.asarray(f.responses) < 0).astype(np.int64) + 2 * octave.astype(np.int64)
    keep = np.hypot(p[:, 0], p[:, 1]) <= max_range
    return p[keep], o[keep], lab[keep]


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

    The postings are held in key-sorted blocks of 1, 2, 4, ... places (a binary
    counter: adding a place makes a block of its own pairs, then merges the last two
    blocks while the older holds no more places than the newer), so an insertion
    costs O(log M) merges of its postings amortised and a query looks each key up in
    O(log M) blocks (a block of ``TABLE_PLACES`` or more by a table of key starts).
    Per posting: key, place row, ``R(-phi) p`` of its first keypoint [m] and its
    direction phi [rad] (`place_vote_kernel`).

    Stop-list (``stop_share`` > 0): a query skips a key whose postings number more
    than ``stop_share`` times the places stored (a key so common it says little
    about which place, as text retrieval drops its most frequent words)."""

    def __init__(self, config: PairVoteConfig | None = None) -> None:
        self.config = config or PairVoteConfig()
        # (places, keys, rows, u, v, phi, key starts or None), key-sorted
        self._blocks: list[tuple] = []
        self._pairs: list[int] = []

    def __len__(self) -> int:
        return len(self._pairs)

    @property
    def postings(self) -> int:
        """Stored pairs (postings) over every place."""
        return int(sum(self._pairs))

    def add(self, points: Array, orientations: Array,
            labels: NDArray[np.integer] | None = None) -> int:
        """Store one place (its row is the number of places stored before it)."""
        keys, a, phi = pair_keys(points, orientations, self.config, True, labels)
        row = len(self._pairs)
        p = np.asarray(points, float).reshape(-1, 2)[a]
        c, s = np.cos(phi), np.sin(phi)
        u = c * p[:, 0] + s * p[:, 1]  # R(-phi) p
        v = -s * p[:, 0] + c * p[:, 1]
        order = np.argsort(keys, kind="stable")
        self._blocks.append((1, keys[order], np.full(len(keys), row, np.int32), u[order],
                             v[order], phi[order], None))
        self._pairs.append(len(keys))
        while len(self._blocks) > 1 and self._blocks[-2][0] <= self._blocks[-1][0]:
            new = self._blocks.pop()
            old = self._blocks.pop()
            at = _merge_order(old[1], new[1])
            merged = [np.concatenate((x, y))[at] for x, y in zip(old[1:6], new[1:6],
                                                                    strict=True)]
            places = old[0] + new[0]
            starts = (np.searchsorted(merged[0], np.arange(self.config.n_keys + 1))
                      .astype(np.int64) if places >= TABLE_PLACES else None)
            self._blocks.append((places, *merged, starts))
        return row

    def _ranges(self, block: tuple, look: NDArray[np.int64]
                ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Posting range ``lo .. hi`` in `block` of every key of `look` (keys outside
        ``[0, n_keys)`` have none): from the block's table of key starts, or by
        binary search in a small block."""
        starts = block[6]
        if starts is None:
            return (np.searchsorted(block[1], look, side="left"),
                    np.searchsorted(block[1], look, side="right"))
        n_keys = self.config.n_keys
        inside = (look >= 0) & (look < n_keys)
        at = np.clip(look, 0, n_keys - 1)
        lo, hi = starts[at], starts[at + 1]
        hi[~inside] = lo[~inside]
        return lo, hi

    def scores(self, points: Array, orientations: Array,
               labels: NDArray[np.integer] | None = None) -> Array:
        """``(len(self),)`` vote score of every stored place for the query keypoints."""
        from loopclosure.place_vote_kernel import fullest_cells, vote_block

        cfg = self.config
        out = np.zeros(len(self))
        qkeys, qa, qphi = pair_keys(points, orientations, cfg, False, labels)
        if not len(qkeys) or not self._blocks:
            return out
        na2 = cfg.n_angle ** 2 * cfg.n_labels ** 2
        shifts = np.arange(-cfg.length_slack, cfg.length_slack + 1) * na2
        look = (qkeys[None, :] + shifts[:, None]).ravel()
        owner = np.tile(np.arange(len(qkeys)), len(shifts))
        ranges = [self._ranges(b, look) for b in self._blocks]
        count = sum(hi - lo for lo, hi in ranges)
        if cfg.stop_share > 0:
            common = count > cfg.stop_share * len(self)
            if common.any():
                for lo, hi in ranges:
                    hi[common] = lo[common]
                count = np.where(common, 0, count)
        total = int(count.sum())
        if total == 0:
            return out
        p = np.asarray(points, float).reshape(-1, 2)[qa[owner]]
        ph = qphi[owner]
        cos, sin = np.cos(ph), np.sin(ph)
        nt, n_theta = cfg.n_translation, cfg.n_theta
        n_cells = n_theta * nt * nt
        if len(self) * n_cells >= 2 ** 31:
            raise UserError("pair vote: too many places for 32-bit vote codes")
        codes = np.empty(total, np.int32)
        n = 0
        max_t2 = float(cfg.max_translation) ** 2
        qx, qy = p[:, 0].copy(), p[:, 1].copy()
        for (lo, hi), b in zip(ranges, self._blocks, strict=True):
            n = vote_block(lo, hi, ph, cos, sin, qx, qy, b[2], b[3], b[4], b[5], max_t2,
                           float(cfg.theta_step), n_theta, float(cfg.translation_step),
                           nt, codes, n)
        best = np.zeros(len(self), np.int64)
        fullest_cells(codes, n, len(self), n_cells, CHUNK_PLACES, best)
        out[:] = best
        if cfg.normalise:
            out /= np.sqrt(np.maximum(np.asarray(self._pairs, float), 1.0))
        return out


def _merge_order(a: NDArray[np.int64], b: NDArray[np.int64]) -> NDArray[np.int64]:
    """Stable merge order of two key-sorted arrays (`place_vote_kernel.merge_sorted`)."""
    from loopclosure.place_vote_kernel import merge_sorted

    return merge_sorted(a, b)


__all__ = ["PairVoteConfig", "PairVoteIndex", "pair_keys", "vote_keypoints"]
