"""Shape context matcher: log-polar histograms, chi^2 costs, optimal assignment.

Paper: Kosnar, Vonasek, Kulich, Preucil, "Comparison of shape matching techniques for
place recognition" (``papers/shape-matching-place-recognition.txt``), Section II.A.3
("Shape context"), which cites the original method: S. Belongie, J. Malik and J.
Puzicha, "Shape matching and object recognition using shape contexts", IEEE Trans. PAMI
24(4):509-522, 2002.

Descriptor (``describe``), for a polygon P:

1. ``n = n_points`` points ``p_i`` sampled on the boundary, equally spaced by arc
   length (`Polygon.resample`).
2. For every ordered pair (i, j), i != j: the distance ``r_ij = |p_j - p_i|``, divided
   by the reference distance ``r0`` (the mean of all r_ij when ``scale_invariant``,
   else the fixed ``mean_distance`` [m]), and the angle of ``p_j - p_i`` measured
   from the local tangent direction at ``p_i`` (Belongie's rotation-invariant
   option: the tangent is the direction of ``p_{i+s} - p_{i-s}``,
   ``s = tangent_span`` samples).
3. The shape context of p_i is the histogram ``h_i(k)`` of the pairs (i, j) over
   ``n_radial`` log-spaced radial bins with edges
   ``r_inner * (r_outer / r_inner)^(t / (n_radial - 1))``, t = 0..n_radial-1
   (points closer than ``r_inner`` go to the innermost bin, points beyond
   ``r_outer`` are left out, as in Belongie's implementation) times
   ``n_angular`` equal angular bins; normalised by ``n - 1`` so a histogram sums to
   the fraction of points within ``r_outer``.
   Descriptor: the ``(n, n_radial * n_angular)`` array of point counts (uint16;
   the histogram is counts / (n - 1)).

Invariance: distances and tangent-relative angles are intrinsic, so the descriptor
is invariant to rotation and translation without any reference point (up to a
count moving to a neighbouring bin when an angle lies within rounding of a bin
edge); the start sample only permutes rows, which the assignment ignores.

Matching (``distance``):

- Cost of matching p_i of shape a with q_j of shape b (Belongie's eq. 1, chi^2):
  ``C_ij = 1/2 sum_k (h_i(k) - g_j(k))^2 / (h_i(k) + g_j(k))`` (terms with a zero
  denominator are 0).  Computed as ``1/2 sum_k (h + g) - 2 sum_k h g / (h + g)``.
- Optimal one-to-one assignment pi minimising ``sum_i C_{i, pi(i)}``
  (`scipy.optimize.linear_sum_assignment`, the Hungarian / Jonker-Volgenant
  method).  With ``dummy_fraction > 0`` the cost matrix is padded with
  ``round(dummy_fraction * n)`` dummy rows and columns of cost ``dummy_cost``
  (Belongie's outlier handling): a point whose best real match costs more than
  ``dummy_cost`` is matched to a dummy instead.
- Distance = the paper's sum of matched costs, divided by n (the mean matched
  chi^2 cost, in [0, 1]).

Parameters (`ShapeContextConfig`):
    n_points: n, boundary samples (default 100, as Belongie uses on MPEG-7).
    n_radial: radial bins (default 5).  n_angular: angular bins (default 12).
    r_inner, r_outer: innermost and outer radial edge, in units of r0
        (defaults 1/8 and 2, Belongie's values).
    mean_distance: r0 [m] when not scale invariant (default 4.0 m, the mean
        pairwise boundary distance of a room of about 8 x 8 m).
    tangent_span: s [samples] of the tangent estimate (default 2).
    dummy_fraction: dummy nodes as a fraction of n (default 0: none).
    dummy_cost: chi^2 cost of a dummy match (default 0.25, Belongie's eps_d).
    scale_invariant: r0 = mean pairwise distance (default False).
    chunk: database entries per vectorised chi^2 block in `distances` (default 16;
        memory bound only).
    kernel: how pairs are compared: ``"blas"`` (default; the float32 factor product
        and scipy's assignment below) or ``"numba"`` (`shape_context_kernel`: the
        exact float64 chi^2 from a table of ``a b / (a + b)`` over the non-zero bins
        and a compiled Hungarian method, the same optimum; distances agree with
        ``"blas"`` to the float32 rounding, about 1e-7; `pairwise` then solves each
        unordered pair once, the costs being symmetric).

Batched comparison: the chi^2 costs of the query against a whole stack come
from one matrix product.  With integer counts a, b (h = a / (n-1)), the only
non-separable part of chi^2 is the kernel ``f(a, b) = a b / (a + b)``; its
(n x n) table is symmetric with exponentially decaying eigenvalues, so
``f(a, b) = sum_r w_r V_r(a) V_r(b)`` holds to 1e-9 (count units) with rank 14 for n = 100
(`_harmonic_factors` picks the rank).  Hence
``sum_k h_i(k) g_j(k) / (h_i(k) + g_j(k)) = (1/(n-1)) sum_{k,r} w_r V_r(a_ik) V_r(b_jk)``,
one float32 product of an (n, bins * rank) matrix with the stack's
(M * n, bins * rank) features (`stack` builds them once); the float32 rounding
(about 1e-7 of a cost) is the only approximation.  The assignment is solved per
pair: the Hungarian method is an augmenting-path algorithm with no useful
vectorisation over independent problems, and scipy's C implementation is an exact
solver.  The chi^2 product is a BLAS call: time it with one BLAS thread
(OPENBLAS_NUM_THREADS=1), as the paper's single-core timings are.  With
``kernel="numba"`` (`shape_context_kernel`) both steps are compiled instead: the
costs exactly (float64, a table of ``f(a, b)`` over each row's non-zero bins) and
the assignment by the Hungarian method in the same loop, with no per-pair Python
call; `pairwise` then solves each unordered pair once.

Departures from the paper, and why:
- Rotation invariance through tangent-relative angles (Belongie's option) is always
  on: laser places are seen at any heading.
- Not scale invariant by default (rooms differ only in scale): radii are divided
  by a fixed metric r0 instead of the mean pairwise distance.
- No thin-plate-spline iterations, bending energy or appearance term: the paper
  defines the distance as the sum of matched costs only.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from data.errors import UserError
from loopclosure.matchers.base import Matcher
from loopclosure.polygon import Polygon

Array = NDArray[np.float64]

#: Implementations of the pair comparison (`ShapeContextConfig.kernel`).
KERNELS: tuple[str, ...] = ("blas", "numba")


@dataclass(slots=True)
class ShapeContextConfig:
    """Parameters of the shape-context matcher (see module docstring for units)."""

    n_points: int = 100
    n_radial: int = 5
    n_angular: int = 12
    r_inner: float = 0.125
    r_outer: float = 2.0
    mean_distance: float = 4.0
    tangent_span: int = 2
    dummy_fraction: float = 0.0
    dummy_cost: float = 0.25
    scale_invariant: bool = False
    chunk: int = 16
    kernel: str = "blas"

    def __post_init__(self) -> None:
        if self.n_points < 4:
            raise UserError(f"n_points must be >= 4, got {self.n_points}")
        if self.n_radial < 1 or self.n_angular < 1:
            raise UserError(
                f"n_radial and n_angular must be >= 1, got {self.n_radial} and {self.n_angular}"
            )
        if not 0 < self.r_inner < self.r_outer:
            raise UserError(f"need 0 < r_inner < r_outer, got {self.r_inner}, {self.r_outer}")
        if not self.mean_distance > 0:
            raise UserError(f"mean_distance must be > 0 [m], got {self.mean_distance}")
        if not 1 <= self.tangent_span < self.n_points // 2:
            raise UserError(f"tangent_span must be in [1, n_points/2), got {self.tangent_span}")
        if not 0 <= self.dummy_fraction <= 1:
            raise UserError(f"dummy_fraction must be in [0, 1], got {self.dummy_fraction}")
        if self.chunk < 1:
            raise UserError(f"chunk must be >= 1, got {self.chunk}")
        if self.kernel not in KERNELS:
            raise UserError(f"kernel must be one of {', '.join(KERNELS)}, got {self.kernel!r}")


def _harmonic_factors(max_count: int, tol: float = 1e-9) -> tuple[Array, Array]:
    """Low-rank factors of the kernel ``f(a, b) = a b / (a + b)`` on counts 0..max_count.

    Returns ``(V, w)`` with ``f(a, b) = sum_r w_r V[a, r] V[b, r]`` to within `tol`
    (absolute, in count units; eigendecomposition of the symmetric kernel matrix,
    whose eigenvalues decay exponentially: rank 12 gives 5e-8 for counts up to 99).
    """
    c = np.arange(max_count + 1, dtype=float)
    s = c[:, None] + c[None, :]
    f = np.divide(c[:, None] * c[None, :], s, out=np.zeros_like(s), where=s > 0)
    w, v = np.linalg.eigh(f)
    order = np.argsort(-np.abs(w))
    w, v = w[order], v[:, order]
    for rank in range(1, len(w) + 1):
        approx = (v[:, :rank] * w[:rank]) @ v[:, :rank].T
        if np.abs(approx - f).max() < tol:
            break
    return v[:, :rank], w[:rank]


@dataclass(slots=True)
class ShapeContextStack:
    """Stacked shape contexts for `ShapeContextMatcher.distances`.

    Attributes:
        features: ``(M, n, bins * rank)`` float32 factor features of the counts
            (``(M, n, 0)`` with the numba kernel, which reads `counts`).
        mass: ``(M, n)`` histogram sums (fraction of points within r_outer).
        counts: ``(M, n, bins)`` point counts (the descriptors; numba kernel only).
    """

    features: NDArray[np.float32]
    mass: Array
    counts: NDArray[np.uint16] | None = None


class ShapeContextMatcher(Matcher):
    """Belongie's shape context with tangent-relative angles (see module docstring)."""

    name = "shape-context"
    rotation_invariant = True

    def __init__(self, config: ShapeContextConfig | None = None, **overrides: object) -> None:
        cfg = config or ShapeContextConfig()
        if overrides:
            known = {f.name for f in fields(ShapeContextConfig)}
            unknown = set(overrides) - known
            if unknown:
                raise UserError(
                    f"unknown shape-context option(s): {', '.join(sorted(unknown))} "
                    f"(known: {', '.join(sorted(known))})"
                )
            cfg = replace(cfg, **overrides)  # type: ignore[arg-type]
        self.config = cfg
        self._edges = np.geomspace(cfg.r_inner, cfg.r_outer, cfg.n_radial)
        n = cfg.n_points
        self._diag = np.eye(n, dtype=bool)
        self._off = ~self._diag
        # Flat histogram index of row i starts at i * bins (constant grid of `describe`).
        self._row_offsets = np.repeat(np.arange(n, dtype=np.intp) * self.n_bins, n).reshape(n, n)
        v, w = _harmonic_factors(cfg.n_points - 1)
        self._basis = v.astype(np.float32)  # (n, rank): count -> factor features
        self._weighted = (v * w).astype(np.float32)
        self._kernel = None
        if cfg.kernel == "numba":
            from loopclosure.matchers import shape_context_kernel

            self._kernel = shape_context_kernel
            self._table = shape_context_kernel.harmonic_table(n - 1)

    @property
    def symmetric_pairwise(self) -> bool:
        """`pairwise` solves each unordered pair once (the numba kernel)."""
        return self._kernel is not None

    def _n_dummy(self) -> int:
        return round(self.config.dummy_fraction * self.config.n_points)

    @property
    def n_bins(self) -> int:
        """Histogram length ``n_radial * n_angular``."""
        return self.config.n_radial * self.config.n_angular

    def describe(self, polygon: Polygon) -> NDArray[np.uint16]:
        """``(n, n_radial * n_angular)`` shape-context histograms as point counts (uint16).

        The normalised histogram of the module docstring is ``counts / (n - 1)``.
        """
        cfg = self.config
        n = cfg.n_points
        p = polygon.resample(n)
        z = p[:, 0] + 1j * p[:, 1]
        dz = z[None, :] - z[:, None]  # [i, j] = p_j - p_i
        r = np.abs(dz)
        r0 = float(r[self._off].mean()) if cfg.scale_invariant else cfg.mean_distance
        r /= max(r0, np.finfo(float).tiny)
        s = cfg.tangent_span
        zz = np.concatenate((z[-s:], z, z[:s]))  # zz[i + s] = z[i], cyclic
        tangent = zz[2 * s :] - zz[: -2 * s]  # p_{i+s} - p_{i-s}
        unit = np.exp(-1j * np.angle(tangent))  # rotates the tangent at p_i onto +x
        dz *= unit[:, None]
        theta = np.angle(dz)  # angle from the tangent, in [-pi, pi]
        # theta % 2 pi, exactly: angles in [-pi, 0) get 2 pi added (as np.remainder does).
        np.add(theta, 2 * np.pi, out=theta, where=theta < 0)
        theta *= cfg.n_angular / (2 * np.pi)
        ab = theta.astype(np.intp)
        np.minimum(ab, cfg.n_angular - 1, out=ab)
        # Radial bins [0, e_0), [e_0, e_1), ..., [e_{R-2}, e_{R-1}); beyond e_{R-1} left out.
        # The bin index (searchsorted, side="right") is the number of edges <= r; points
        # beyond the outer edge go to a discarded overflow slot.
        edges = self._edges
        flat = self._row_offsets + ab
        for e in edges[:-1]:
            flat += (r >= e) * cfg.n_angular
        outside = r >= edges[-1]
        outside |= self._diag
        flat[outside] = n * self.n_bins
        counts = np.bincount(flat.ravel(), minlength=n * self.n_bins + 1)[:-1]
        return counts.reshape(n, self.n_bins).astype(np.uint16)

    def _features(self, counts: NDArray[np.uint16], table: NDArray[np.float32]) -> NDArray:
        """``(..., n, bins * rank)`` factor features of count histograms."""
        f = table[counts.astype(np.intp)]  # (..., n, bins, rank)
        return f.reshape(*counts.shape[:-1], -1)

    def stack(self, descriptors: Sequence[NDArray[np.uint16]]) -> ShapeContextStack:
        """Factor features ``(M, n, bins * rank)`` and histogram masses ``(M, n)``."""
        n = self.config.n_points
        if not descriptors:
            rank = self._basis.shape[1]
            return ShapeContextStack(
                np.zeros((0, n, self.n_bins * rank), dtype=np.float32), np.zeros((0, n)),
                np.zeros((0, n, self.n_bins), dtype=np.uint16),
            )
        counts = np.stack([np.asarray(d) for d in descriptors])
        mass = counts.sum(axis=2) / (n - 1)
        if self._kernel is not None:
            empty = np.zeros((len(counts), n, 0), dtype=np.float32)
            return ShapeContextStack(empty, mass, np.ascontiguousarray(counts, np.uint16))
        return ShapeContextStack(self._features(counts, self._basis), mass)

    def distance(self, a: NDArray[np.uint16], b: NDArray[np.uint16]) -> float:
        """Mean chi^2 cost of the optimal assignment between two descriptors."""
        return float(self.distances(a, self.stack([b]))[0])

    def _assign(self, cost: Array) -> float:
        """Sum of matched costs of one ``(n, n)`` cost matrix (with dummies if configured)."""
        cfg = self.config
        n_dummy = round(cfg.dummy_fraction * len(cost))
        c = cost.astype(float)
        if n_dummy:
            n = len(c)
            full = np.full((n + n_dummy, n + n_dummy), cfg.dummy_cost)
            full[:n, :n] = c
            full[n:, n:] = 0.0
            c = full
        rows, cols = linear_sum_assignment(c)
        return float(c[rows, cols].sum())

    def chi2_costs(self, query: NDArray[np.uint16], stacked: ShapeContextStack) -> Array:
        """``(M, n, n)`` chi^2 costs ``C_ij`` of the query's points against each entry's."""
        if self._kernel is not None:
            return self._kernel.chi2_costs(self._counts(query), stacked.counts, self._table)
        n = self.config.n_points
        m = len(stacked.mass)
        q = self._features(np.asarray(query), self._weighted)  # (n, bins * rank)
        db = stacked.features.reshape(m * n, -1)
        harmonic = (q @ db.T).reshape(n, m, n).transpose(1, 0, 2) / np.float32(n - 1)
        q_mass = np.asarray(query).sum(axis=1) / (n - 1)
        total = 0.5 * (q_mass[None, :, None] + stacked.mass[:, None, :])
        return np.maximum(total - 2.0 * harmonic, 0.0)

    def distances(self, query: NDArray[np.uint16], stacked: ShapeContextStack) -> Array:
        """``(M,)`` distances of `query` to every stacked descriptor."""
        cfg = self.config
        if self._kernel is not None:
            return self._kernel.distances(self._counts(query), stacked.counts, self._table,
                                          self._n_dummy(), float(cfg.dummy_cost))
        m = len(stacked.mass)
        out = np.empty(m)
        for lo in range(0, m, cfg.chunk):  # chunks bound memory; each chunk is vectorised
            part = ShapeContextStack(
                stacked.features[lo : lo + cfg.chunk], stacked.mass[lo : lo + cfg.chunk]
            )
            costs = self.chi2_costs(query, part)
            out[lo : lo + len(costs)] = [self._assign(c) for c in costs]
        return np.clip(out / cfg.n_points, 0.0, None)

    def _counts(self, descriptor: NDArray[np.uint16]) -> NDArray[np.uint16]:
        return np.ascontiguousarray(descriptor, dtype=np.uint16)

    def pairwise(self, descriptors: Sequence[NDArray[np.uint16]]) -> Array:
        """``(M, M)`` matrix of all distances; with the numba kernel each unordered pair
        is solved once and mirrored (equal to the row-by-row matrix to rounding)."""
        if self._kernel is None:
            return super().pairwise(descriptors)
        stacked = self.stack(descriptors)
        return self._kernel.all_pairs(stacked.counts, self._table, self._n_dummy(),
                                      float(self.config.dummy_cost))
