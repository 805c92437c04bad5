"""FLIRT place matcher: interest points, beta-grids and RANSAC (the feature-based baseline).

Reference: G. D. Tipaldi and K. O. Arras, "FLIRT - Interest regions for 2D range
data", ICRA 2010, as summarised in Section II.B ("Feature-based method") of Kosnar,
Vonasek, Kulich, Preucil, "Comparison of shape matching techniques for place
recognition" (``papers/shape-matching-place-recognition.txt``): curvature-detector
interest points, beta-grid descriptors, and place recognition by RANSAC between two
scans, the re-projection error as the measure, and "different place" when the inlier
set is smaller than n_min.  Written from the papers; no FLIRTLib code was read or used.
Detection and description are in `loopclosure.matchers.flirt_features` (see its
docstring for those equations and parameters).

Matching one query scan A (features a_i) with a database scan B (features b_j):

1. Descriptor distance between beta-grids, Euclidean (default) or symmetric
   chi-squared on the bin occupancies:

        eucl(a, b) = sqrt(sum_j (occ_a,j - occ_b,j)^2)
        chi2(a, b) = sum_j (occ_a,j - occ_b,j)^2 / (occ_a,j + occ_b,j)

   (Euclidean is the default because it batches as a matrix product.  The bins'
   variances are part of the descriptor but not of this distance.)
   Pairs whose scales differ by more than `scale_ratio` are not compatible (the
   transform is rigid, so a feature keeps its scale).  Each a_i keeps its
   `candidates` nearest compatible b_j (k-NN, not only the nearest: repetitive
   structure such as box corners gives near-identical descriptors).

2. RANSAC hypotheses from 2 correspondences (a_i -> b_p, a_j -> b_q):

        theta = atan2(cross(b_q - b_p, a_j - a_i), dot(b_q - b_p, a_j - a_i))
        t     = (a_i + a_j) / 2 - R(theta) (b_p + b_q) / 2

   mapping B's frame into A's (``a ~ R b + t``).  A hypothesis is dropped when the
   two pair lengths differ by more than tau_i + tau_j, when b_p = b_q, or when a
   correspondence's orientations disagree with theta by more than
   `orientation_tolerance`.  All pairs are tried when there are at most
   `max_hypotheses`, otherwise a fixed seeded sample of them (deterministic).

3. Score (MSAC, all hypotheses and all database entries as one array operation):

        cost = sum_i min_k min(e_ik^2, 1),   e_ik = |a_i - (R b_k + t)| / tau_ik,
        tau_ik = inlier_factor * sqrt(sigma_i sigma_k)

   over a_i's candidates b_k with consistent orientation.  The lowest cost wins,
   compared on a grid of `COST_QUANTUM` so that costs equal up to the rounding of
   their sums (a symmetric shape's mirrored hypotheses) tie, and the first
   hypothesis among tied costs wins in every implementation.

4. Refinement: guided matching (a_i may now pair with any b_j whose descriptor
   distance is no larger than its k-th candidate's, ties included, so symmetric
   shapes still match one to one), a least-squares rigid fit (2D Procrustes,
   weights 1 / tau^2) on the inliers, twice, and the guided matching again.
   Inliers are the one-to-one pairs with e < 1 (each b_j keeps its best a_i).

5. Distance in [0, 2], 0 for identical scans, monotone in match quality:

        f = 2 n_in / (n_A + n_B)             (inlier fraction, 1 when all match)
        s = f (1 - mean(e over inliers) / 2)  (the re-projection error lowers it)
        d = 1 - s                            if n_in >= n_min (same place)
        d = 2 - s / 2 - (1 - g) / 2          otherwise (declared different)

   with n_min = min(min_inliers, n_A, n_B) (a triangle has only 3 points to
   match) and g in [0, 1] the mean over A's features of the nearest compatible
   beta-grid distance, divided by its largest possible value (sqrt(bins) for
   Euclidean, bins for chi2): pairs that RANSAC rejects are still ranked, by
   their partial geometric agreement and their appearance, always after every
   accepted pair.

Rotation invariance: descriptors are oriented by the feature normals and the
RANSAC transform absorbs any rotation, so the distance does not change when a
polygon is rotated about the sensor origin (the viewpoint of the ray tracing).
Rotating or shifting a scan about another point moves the viewpoint relative to
the shape, which changes the free-space evidence as it would for a real sensor.
Scale: not invariant by default (the transform
is rigid; rooms that differ only in scale do not match); `scale_invariant=True`
divides each polygon by sqrt(area) first (MPEG-7).

Departures from the paper: the distance combines the inlier fraction and the
re-projection error (the paper uses the error with the n_min threshold) so that it
is finite, 0 for identical scans and usable for ranking; k-NN candidates and the
guided final matching replace a single nearest-neighbour correspondence; MSAC
scoring replaces plain inlier counting (same optimum, deterministic ties).  The
distance is asymmetric in general (A's features search B's); the ROC and P-R
measures of evaluation.retrieval symmetrise it.

Parameters (`FlirtConfig`; the detection ones are forwarded to
`FlirtFeatureConfig`, among them the contour-sampling option sample_step,
max_samples, max_range, max_jump and border_sigmas, off by default): descriptor_distance
["euclidean" | "chi2"],
candidates [3], scale_ratio [2.0], orientation_tolerance [0.6 rad],
inlier_factor [0.5, tau per unit scale], max_hypotheses [400], min_inliers [4,
the paper's n_min], seed [0], compiled [True: steps 1-5 run in the numba kernel
of `loopclosure.matchers.flirt_kernel`, which gives the same results to rounding,
and the beta-grids' counts in `loopclosure.matchers.flirt_grid_kernel`; False: the
numpy arrays below].
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data.errors import UserError
from loopclosure.matchers.base import Matcher
from loopclosure.matchers.flirt_features import (
    FlirtFeatureConfig,
    FlirtFeatures,
    describe_polygon,
)
from loopclosure.polygon import Polygon

Array = NDArray[np.float64]
IntArray = NDArray[np.intp]

_WORK = 1_500_000  # elements per hypothesis-scoring array (bounds memory per chunk)
COST_QUANTUM = 1e-9  # MSAC costs closer than this tie (step 3); costs are O(1..1000)


@dataclass(slots=True)
class FlirtConfig:
    """All FLIRT parameters (detection, beta-grid and RANSAC); see the module docstrings."""

    # Detection and description (flirt_features).
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
    # Contour sampling (flirt_features; 0: off, the defaults above unchanged).
    sample_step: float = 0.0
    max_samples: int = 4096
    max_range: float = 0.0
    max_jump: float = 0.0
    border_sigmas: float = 2.0
    # Matching.
    descriptor_distance: str = "euclidean"
    candidates: int = 3
    scale_ratio: float = 2.0
    orientation_tolerance: float = 0.6
    inlier_factor: float = 0.5
    max_hypotheses: int = 400
    min_inliers: int = 4
    seed: int = 0
    # Matching steps 1-5 by the numba kernel of `flirt_kernel` and the beta-grid
    # counts by `flirt_grid_kernel` (False: numpy).
    compiled: bool = True

    def __post_init__(self) -> None:
        if self.descriptor_distance not in ("chi2", "euclidean"):
            raise UserError(
                f"descriptor_distance must be chi2 or euclidean, got {self.descriptor_distance!r}"
            )
        if self.candidates < 1 or self.max_hypotheses < 1 or self.min_inliers < 1:
            raise UserError(
                "candidates, max_hypotheses and min_inliers must be >= 1, got "
                f"{self.candidates}, {self.max_hypotheses} and {self.min_inliers}"
            )
        if self.scale_ratio < 1 or self.inlier_factor <= 0 or self.orientation_tolerance <= 0:
            raise UserError(
                "need scale_ratio >= 1, inlier_factor > 0, orientation_tolerance > 0 [rad], got "
                f"{self.scale_ratio}, {self.inlier_factor} and {self.orientation_tolerance}"
            )
        self.features()  # validates the detection parameters

    def features(self) -> FlirtFeatureConfig:
        """The detection / description part of the config."""
        names = {f.name for f in fields(FlirtFeatureConfig)}
        return FlirtFeatureConfig(**{n: getattr(self, n) for n in names})


@dataclass(slots=True)
class FlirtStack:
    """Database of FLIRT descriptors, padded to ``F`` features per entry.

    Attributes:
        points: ``(M, F, 2)``; scales, orientations: ``(M, F)``;
        occupancy: ``(M, F, bins)``; valid: ``(M, F)`` real (not padding) features;
        counts: ``(M,)`` features per entry.
    """

    points: Array
    scales: Array
    orientations: Array
    occupancy: Array
    valid: NDArray[np.bool_]
    counts: IntArray

    def __len__(self) -> int:
        return len(self.counts)


@dataclass(slots=True)
class FlirtMatch:
    """Result of RANSAC between a query scan A and a database scan B.

    Attributes:
        pose: ``(3,)`` (x, y, theta) [polygon units, rad]: the pose of B's sensor
            frame in A's, i.e. ``p_A = R(theta) p_B + (x, y)`` (``data.se2``
            ``between(pose_A, pose_B)``); in unscaled polygon units even when
            scale invariant.
        inliers: ``(K, 2)`` index pairs (feature of A, feature of B).
        residual: mean normalised re-projection error e of the inliers (0..1).
        distance: the matcher distance (module docstring, step 5).
    """

    pose: Array
    inliers: IntArray
    residual: float
    distance: float


class FlirtMatcher(Matcher):
    """FLIRT: curvature interest points, beta-grid descriptors, RANSAC (module docstring)."""

    name = "flirt"
    rotation_invariant = True

    def __init__(self, config: FlirtConfig | None = None, **overrides: Any) -> None:
        cfg = config or FlirtConfig()
        if overrides:
            known = {f.name for f in fields(FlirtConfig)}
            unknown = set(overrides) - known
            if unknown:
                raise UserError(
                    f"unknown FLIRT option(s): {', '.join(sorted(unknown))} "
                    f"(known: {', '.join(sorted(known))})"
                )
            cfg = FlirtConfig(**{**{n: getattr(cfg, n) for n in known}, **overrides})
        self.config = cfg
        self._features = cfg.features()
        self._hypotheses: dict[int, tuple[IntArray, IntArray, IntArray, IntArray]] = {}
        bins = self._features.rings * self._features.sectors
        # Largest beta-grid distance (occupancies in (0, 1)): per-bin chi2 <= 1, so
        # chi2 <= bins; Euclidean <= sqrt(bins).
        self._d_max = float(bins if cfg.descriptor_distance == "chi2" else np.sqrt(bins))

    # ------------------------------------------------------------------ describe
    def describe(self, polygon: Polygon) -> FlirtFeatures:
        """Interest points and beta-grids of `polygon` (see flirt_features)."""
        return describe_polygon(polygon, self._features)

    def stack(self, descriptors: Sequence[FlirtFeatures]) -> FlirtStack:
        """Pad the descriptors into a `FlirtStack` (at least one feature column)."""
        m = len(descriptors)
        nb = self._features.rings * self._features.sectors
        width = max([len(d) for d in descriptors] + [1])
        points = np.zeros((m, width, 2))
        scales = np.ones((m, width))
        orient = np.zeros((m, width))
        occ = np.full((m, width, nb), 0.5)
        valid = np.zeros((m, width), dtype=bool)
        counts = np.zeros(m, dtype=np.intp)
        for row, d in enumerate(descriptors):
            n = len(d)
            counts[row] = n
            valid[row, :n] = True
            points[row, :n] = d.points
            scales[row, :n] = d.scales
            orient[row, :n] = d.orientations
            occ[row, :n] = d.occupancy
        return FlirtStack(points, scales, orient, occ, valid, counts)

    # ------------------------------------------------------------------ compare
    def distance(self, a: FlirtFeatures, b: FlirtFeatures) -> float:
        """Distance of scan `b` to query `a` (module docstring, step 5)."""
        return float(self.distances(a, self.stack([b]))[0])

    def distances(self, query: FlirtFeatures, stacked: FlirtStack) -> Array:
        """``(M,)`` distances of `query` to every stacked scan (vectorised over entries)."""
        return self._run(query, stacked)[0]

    def match(self, a: FlirtFeatures, b: FlirtFeatures) -> FlirtMatch:
        """RANSAC transform, inlier set and distance of scan `b` seen from query `a`."""
        dist, pose, pairs, resid = self._run(a, self.stack([b]), want_pairs=True)
        unit_a = a.unit
        pose0 = pose[0].copy()
        if self.config.scale_invariant:
            # p_A / u_A = R p_B / u_B + t  ->  report the rigid part in A's units.
            pose0[:2] *= unit_a
        return FlirtMatch(pose0, pairs[0], float(resid[0]), float(dist[0]))

    # ------------------------------------------------------------------ internals
    def _hypothesis_indices(self, n_query: int) -> tuple[IntArray, IntArray, IntArray, IntArray]:
        """Fixed (seeded) correspondence pairs ``(i, a), (j, b)`` tried by RANSAC.

        They depend only on the query's feature count, so each count's set is drawn
        once per matcher and reused.
        """
        cached = self._hypotheses.get(n_query)
        if cached is not None:
            return cached
        k = self.config.candidates
        iu, ju = np.triu_indices(n_query, 1)
        total = len(iu) * k * k
        if total <= self.config.max_hypotheses:
            flat = np.arange(total)
        else:
            rng = np.random.default_rng(self.config.seed)
            flat = np.sort(rng.choice(total, size=self.config.max_hypotheses, replace=False))
        pair, rest = np.divmod(flat, k * k)
        ca, cb = np.divmod(rest, k)
        hyp = (iu[pair], ca, ju[pair], cb)
        self._hypotheses[n_query] = hyp
        return hyp

    def _descriptor_distances(self, query: FlirtFeatures, occ: Array) -> Array:
        """``(M, Q, F)`` beta-grid distances of query features to stacked features."""
        q = query.occupancy
        if self.config.descriptor_distance == "euclidean":
            qq = np.einsum("qb,qb->q", q, q)
            dd = np.einsum("mfb,mfb->mf", occ, occ)
            cross = np.matmul(occ, q.T).transpose(0, 2, 1)
            return np.sqrt(np.maximum(qq[None, :, None] + dd[:, None, :] - 2.0 * cross, 0.0))
        diff = q[None, :, None, :] - occ[:, None, :, :]
        return np.einsum("mqfb,mqfb->mqf", diff, diff / (q[None, :, None, :] + occ[:, None]))

    def _run(
        self, query: FlirtFeatures, stacked: FlirtStack, want_pairs: bool = False
    ) -> tuple[Array, Array, list[IntArray], Array]:
        m_total = len(stacked)
        n_q = len(query)
        k = self.config.candidates
        hyp = self._hypothesis_indices(n_q)
        n_h = max(len(hyp[0]), 1)
        width = stacked.points.shape[1]
        bins = self._features.rings * self._features.sectors
        per_entry = max(n_h * n_q * k, n_q * width * bins)
        chunk = max(1, _WORK // max(per_entry, 1))
        dist = np.empty(m_total)
        pose = np.zeros((m_total, 3))
        resid = np.zeros(m_total)
        pairs: list[IntArray] = []
        for start in range(0, m_total, chunk):
            sl = slice(start, min(start + chunk, m_total))
            d, p, pr, r = self._run_chunk(query, stacked, sl, hyp, want_pairs)
            dist[sl], pose[sl], resid[sl] = d, p, r
            pairs.extend(pr)
        return dist, pose, pairs, resid

    def _run_chunk(
        self,
        query: FlirtFeatures,
        st: FlirtStack,
        sl: slice,
        hyp: tuple[IntArray, IntArray, IntArray, IntArray],
        want_pairs: bool,
    ) -> tuple[Array, Array, list[IntArray], Array]:
        cfg = self.config
        if cfg.compiled:
            return self._run_chunk_compiled(query, st, sl, hyp, want_pairs)
        k = cfg.candidates
        pts, scl, ori = st.points[sl], st.scales[sl], st.orientations[sl]
        valid, counts = st.valid[sl], st.counts[sl]
        m, width = valid.shape
        n_q = len(query)
        qp, qs, qo = query.points, query.scales, query.orientations

        # 1. Descriptor distances with scale gating, k nearest candidates.
        dd = self._descriptor_distances(query, st.occupancy[sl])  # (m, Q, F)
        log_ratio = np.abs(np.log(qs[None, :, None] / scl[:, None, :]))
        ok = valid[:, None, :] & (log_ratio <= np.log(cfg.scale_ratio) + 1e-12)
        dd = np.where(ok, dd, np.inf)
        order = np.argsort(dd, axis=2, kind="stable")
        if width < k:
            order = np.concatenate([order, np.repeat(order[..., :1], k - width, axis=2)], axis=2)
        cand = order[..., :k]  # (m, Q, k)
        cand_d = np.take_along_axis(dd, cand, axis=2)
        if width < k:
            cand_d[..., width:] = np.inf
        cand_ok = np.isfinite(cand_d)
        kth = np.where(cand_ok, cand_d, -np.inf).max(axis=2)  # (m, Q) gate of guided matching
        allowed = ok & (dd <= kth[..., None])
        tie = np.where(allowed, dd, 0.0) * (1e-6 / self._d_max)

        rows = np.arange(m)[:, None, None]
        cp = pts[rows, cand]  # (m, Q, k, 2)
        cs = scl[rows, cand]
        co = ori[rows, cand]
        tau = cfg.inlier_factor * np.sqrt(qs[None, :, None] * cs)  # (m, Q, k)
        inv_tau2 = 1.0 / tau**2

        # 2. Hypotheses from pairs of correspondences.
        cos_tol = np.cos(cfg.orientation_tolerance)
        rel_c = np.cos(qo[None, :, None] - co)  # (m, Q, k) orientation change per candidate
        rel_s = np.sin(qo[None, :, None] - co)
        hi, ha, hj, hb = hyp
        found = np.zeros(m, dtype=bool)
        th = np.zeros(m)
        tt = np.zeros((m, 2))
        if len(hi):
            q_i, q_j = qp[hi], qp[hj]  # (H, 2)
            p_i = cp[:, hi, ha]  # (m, H, 2)
            p_j = cp[:, hj, hb]
            vq = q_j - q_i
            vp = p_j - p_i
            len_q = np.sqrt(vq[:, 0] ** 2 + vq[:, 1] ** 2)
            len_p = np.sqrt(vp[..., 0] ** 2 + vp[..., 1] ** 2)
            good = (
                cand_ok[:, hi, ha]
                & cand_ok[:, hj, hb]
                & (cand[:, hi, ha] != cand[:, hj, hb])
                & (np.abs(len_q[None] - len_p) <= tau[:, hi, ha] + tau[:, hj, hb])
                & (len_q[None] > 0)
            )
            mg, hg = np.nonzero(good)
            vpg = vp[mg, hg]
            vqg = vq[hg]
            theta = np.arctan2(
                vpg[:, 0] * vqg[:, 1] - vpg[:, 1] * vqg[:, 0],
                vpg[:, 0] * vqg[:, 0] + vpg[:, 1] * vqg[:, 1],
            )  # (G,)
            c, s = np.cos(theta), np.sin(theta)
            # Both correspondences must turn their orientation by theta.
            agree = (rel_c[mg, hi[hg], ha[hg]] * c + rel_s[mg, hi[hg], ha[hg]] * s >= cos_tol) & (
                rel_c[mg, hj[hg], hb[hg]] * c + rel_s[mg, hj[hg], hb[hg]] * s >= cos_tol
            )
            mg, hg, c, s, theta = mg[agree], hg[agree], c[agree], s[agree], theta[agree]
            mid_p = 0.5 * (p_i[mg, hg] + p_j[mg, hg])
            mid_q = 0.5 * (q_i[hg] + q_j[hg])
            tx = mid_q[:, 0] - (c * mid_p[:, 0] - s * mid_p[:, 1])
            ty = mid_q[:, 1] - (s * mid_p[:, 0] + c * mid_p[:, 1])
            # 3. MSAC cost of every hypothesis over every candidate correspondence.
            cg, sg = c[:, None, None], s[:, None, None]
            px, py = cp[mg, :, :, 0], cp[mg, :, :, 1]  # (G, Q, k)
            ex = cg * px - sg * py + (tx[:, None, None] - qp[None, :, None, 0])
            ey = sg * px + cg * py + (ty[:, None, None] - qp[None, :, None, 1])
            e2 = (ex * ex + ey * ey) * inv_tau2[mg]
            ok_g = (rel_c[mg] * cg + rel_s[mg] * sg >= cos_tol) & cand_ok[mg]
            e2 = np.where(ok_g, np.minimum(e2, 1.0), 1.0)
            cost = e2.min(axis=2).sum(axis=1)  # (G,)
            if len(cost):
                order = np.lexsort((np.rint(cost / COST_QUANTUM), mg))
                rows_found, first = np.unique(mg[order], return_index=True)
                pick = order[first]
                found[rows_found] = True
                th[rows_found] = theta[pick]
                tt[rows_found] = np.column_stack([tx[pick], ty[pick]])

        # 4. Guided matching, least-squares refit, guided matching again.
        sig = np.sqrt(qs[None, :, None] * scl[:, None, :])  # (m, Q, F)
        tau_all = cfg.inlier_factor * sig
        for _ in range(2):
            e, match = self._guided(qp, qo, pts, ori, th, tt, tau_all, allowed, tie)
            inl = (e < 1.0) & found[:, None]
            weight = 1.0 / np.take_along_axis(tau_all, match[..., None], axis=2)[..., 0] ** 2
            th, tt = _procrustes(qp, pts, match, inl, weight, th, tt)
        e, match = self._guided(qp, qo, pts, ori, th, tt, tau_all, allowed, tie)
        inl = (e < 1.0) & found[:, None]

        # One-to-one: each stacked feature keeps its best query feature.
        best_e = np.full((m, width), np.inf)
        rr, qq = np.nonzero(inl)
        np.minimum.at(best_e, (rr, match[rr, qq]), e[rr, qq])
        keep = best_e < 1.0
        n_in = keep.sum(axis=1)
        mean_e = np.where(
            n_in > 0, np.where(keep, best_e, 0.0).sum(axis=1) / np.maximum(n_in, 1), 0
        )
        frac = np.clip(2.0 * n_in / np.maximum(n_q + counts, 1), 0.0, 1.0)
        score = frac * (1.0 - 0.5 * mean_e)
        n_min = np.minimum(cfg.min_inliers, np.minimum(n_q, counts))
        # Appearance of unmatched pairs: mean nearest beta-grid distance per bin (0..1).
        nearest = np.where(cand_ok[..., 0], cand_d[..., 0], self._d_max)
        look = np.clip(nearest.sum(axis=1) / (max(n_q, 1) * self._d_max), 0.0, 1.0)
        if n_q == 0:
            look = np.ones(m)
        unmatched = 2.0 - 0.5 * score - 0.5 * (1.0 - look)
        dist = np.where(n_in >= np.maximum(n_min, 1), 1.0 - score, unmatched)
        dist = np.clip(dist, 0.0, 2.0)
        pose = np.column_stack([tt, th])
        pairs = _inlier_pairs(e, match, inl, best_e) if want_pairs else []
        return dist, pose, pairs, mean_e

    def _run_chunk_compiled(
        self,
        query: FlirtFeatures,
        st: FlirtStack,
        sl: slice,
        hyp: tuple[IntArray, IntArray, IntArray, IntArray],
        want_pairs: bool,
    ) -> tuple[Array, Array, list[IntArray], Array]:
        """`_run_chunk` by the numba kernel of `flirt_kernel` (same steps, same results)."""
        from loopclosure.matchers.flirt_kernel import euclidean_distances, flirt_entries

        cfg = self.config
        occ = st.occupancy[sl]
        if cfg.descriptor_distance == "euclidean":
            q = query.occupancy
            dd = euclidean_distances(np.einsum("qb,qb->q", q, q),
                                     np.einsum("mfb,mfb->mf", occ, occ), np.matmul(occ, q.T))
        else:
            dd = self._descriptor_distances(query, occ)
        hi, ha, hj, hb = (np.ascontiguousarray(h, dtype=np.intp) for h in hyp)
        dist, pose, mean_e, e, match, inl, best_e = flirt_entries(
            np.ascontiguousarray(query.points, dtype=float).reshape(-1, 2),
            np.ascontiguousarray(query.scales, dtype=float),
            np.ascontiguousarray(query.orientations, dtype=float),
            np.ascontiguousarray(dd, dtype=float),
            np.ascontiguousarray(st.points[sl]),
            np.ascontiguousarray(st.scales[sl]),
            np.ascontiguousarray(st.orientations[sl]),
            np.ascontiguousarray(st.valid[sl]),
            np.ascontiguousarray(st.counts[sl], dtype=np.intp),
            hi, ha, hj, hb,
            cfg.candidates,
            float(np.log(cfg.scale_ratio)),
            float(np.cos(cfg.orientation_tolerance)),
            float(cfg.inlier_factor),
            self._d_max,
            cfg.min_inliers,
            COST_QUANTUM,
        )  # fmt: skip
        pairs = _inlier_pairs(e, match, inl, best_e) if want_pairs else []
        return dist, pose, pairs, mean_e

    def _guided(
        self,
        qp: Array,
        qo: Array,
        pts: Array,
        ori: Array,
        th: Array,
        tt: Array,
        tau_all: Array,
        allowed: NDArray[np.bool_],
        tie: Array,
    ) -> tuple[Array, IntArray]:
        """Best allowed stacked feature of every query feature under each entry's transform.

        The geometrically nearest allowed feature wins; `tie` ``(m, Q, F)`` (a tiny
        multiple of the descriptor distance) breaks ties between features at the
        same place, e.g. one corner detected at two scales.  Returns ``e`` ``(m, Q)``
        normalised residuals (inf when none allowed) and the chosen stacked feature
        index ``(m, Q)``.
        """
        c, s = np.cos(th)[:, None], np.sin(th)[:, None]
        wx = c * pts[..., 0] - s * pts[..., 1] + tt[:, 0:1]  # (m, F)
        wy = s * pts[..., 0] + c * pts[..., 1] + tt[:, 1:2]
        ex = wx[:, None, :] - qp[None, :, 0:1]
        ey = wy[:, None, :] - qp[None, :, 1:2]
        e = np.sqrt(ex * ex + ey * ey) / tau_all  # (m, Q, F)
        turn = np.cos(qo[None, :, None] - ori[:, None, :] - th[:, None, None])
        e = np.where(allowed & (turn >= np.cos(self.config.orientation_tolerance)), e, np.inf)
        match = np.argmin(e + tie, axis=2)
        return np.take_along_axis(e, match[..., None], axis=2)[..., 0], match


def _inlier_pairs(
    e: Array, match: IntArray, inl: NDArray[np.bool_], best_e: Array
) -> list[IntArray]:
    """Per entry, the one-to-one ``(K, 2)`` inlier pairs (query feature, stacked feature).

    Each stacked feature keeps the query feature of its best residual (the lower
    query index on ties).
    """
    pairs: list[IntArray] = []
    for row in range(len(inl)):
        qs_in = np.nonzero(inl[row])[0]
        js = match[row, qs_in]
        first = e[row, qs_in] == best_e[row, js]
        qs_in, js = qs_in[first], js[first]
        _, uniq = np.unique(js, return_index=True)
        pairs.append(np.column_stack([qs_in[uniq], js[uniq]]).astype(np.intp))
    return pairs


def _procrustes(
    qp: Array,
    pts: Array,
    match: IntArray,
    inl: NDArray[np.bool_],
    weight: Array,
    th: Array,
    tt: Array,
) -> tuple[Array, Array]:
    """Weighted least-squares rigid fit ``q ~ R p + t`` on each entry's inliers (>= 2).

    `weight` ``(m, Q)`` is 1 / tau^2 of each pair (position uncertainty grows with
    scale).  An entry keeps its transform unless its inliers hold at least two
    distinct points on both sides (one point fixes no rotation: the fit's
    ``atan2`` would return rounding noise).
    Returns (theta, t).
    """
    w = np.where(inl, weight, 0.0)  # (m, Q)
    p = np.take_along_axis(pts, match[..., None], axis=1)  # (m, Q, 2)
    first = np.argmax(inl, axis=1)
    p_first = np.take_along_axis(p, first[:, None, None], axis=1)  # (m, 1, 2)
    q_first = qp[first][:, None]
    refit = ((p != p_first).any(axis=2) & inl).any(axis=1) & (
        (qp[None] != q_first).any(axis=2) & inl
    ).any(axis=1)
    nn = np.maximum(w.sum(axis=1), np.finfo(float).tiny)[:, None]
    mq = (w[..., None] * qp[None]).sum(axis=1) / nn
    mp = (w[..., None] * p).sum(axis=1) / nn
    dq = qp[None] - mq[:, None]
    dp = p - mp[:, None]
    sxx = (w * (dp[..., 0] * dq[..., 0] + dp[..., 1] * dq[..., 1])).sum(axis=1)
    sxy = (w * (dp[..., 0] * dq[..., 1] - dp[..., 1] * dq[..., 0])).sum(axis=1)
    new_th = np.arctan2(sxy, sxx)
    c, s = np.cos(new_th), np.sin(new_th)
    new_t = mq - np.column_stack([c * mp[:, 0] - s * mp[:, 1], s * mp[:, 0] + c * mp[:, 1]])
    th = np.where(refit, new_th, th)
    tt = np.where(refit[:, None], new_t, tt)
    return th, tt


__all__ = ["FlirtConfig", "FlirtMatch", "FlirtMatcher", "FlirtStack"]
