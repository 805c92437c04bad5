"""Score fusion of several matchers: reciprocal rank fusion and a calibrated logistic model.

The place database compares a query with K candidate keyframes by several matchers
(the prefilter's cheap descriptors and the verifiers' expensive ones).  Their
distances have different units and scales; fusion turns them into one score per
candidate, higher = more likely the same place.

Reciprocal rank fusion (Cormack, Clarke & Buettcher, "Reciprocal rank fusion
outperforms Condorcet and individual rank learning methods", SIGIR 2009)
-----------------------------------------------------------------------------
With r_s(j) in 1..K the rank of candidate j by the distance of matcher s (1 =
closest; ties share the lowest rank of their group) and c the rank constant,

    RRF(j) = sum_s 1 / (c + r_s(j)),     score(j) = RRF(j) / (S / (c + 1))  in (0, 1]

(S matchers; score 1 = ranked first by every matcher).  Uses orders only: no
calibration, no units, but the score of the best candidate is high whether or not
it is the same place.  Default c = 60 (the paper's value).

Logistic fusion
---------------
Features: per matcher s, the distance normalised by a scale of that matcher (the
place database uses a robust scale of its own content: the median distance of
random pairs of stored keyframes, see `loopclosure.place_database`) and
log-transformed,

    f_s = log(d_s / scale_s + eps)          (unitless; eps = 1e-3 by default)

so matchers in metres, in chi^2 units or scale invariant all become comparable and
the heavy right tail of distances is compressed.  The model is

    P(same place | f) = sigma(b + sum_s w_s f_s),     sigma(z) = 1 / (1 + exp(-z)),

a probability in [0, 1] when fitted on labelled pairs drawn like the pairs it is
applied to (the candidates of a query).  Fitting (`fit_logistic`) maximises the
ridge-penalised log-likelihood

    L(w, b) = sum_i [y_i z_i - log(1 + exp(z_i))] - (lambda / 2) ||w||^2,
    z_i = b + w . f_i

by Newton's method (iteratively reweighted least squares): gradient
g = F^T (y - p) - lambda w, Hessian H = -F^T diag(p (1 - p)) F - lambda I (no
penalty on b), step solved exactly with a backtracking line search; converges in
about 10 iterations.  The ridge keeps the weights finite on separable data.

Default coefficients (`loopclosure.place_config.DEFAULT_LOGISTIC`) and how to refit
them: see `loopclosure.cascade` (module docstring), which calibrates them on the
simulated Box data set with `loopclosure.cascade.calibrate_logistic`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError

Array = NDArray[np.float64]

DEFAULT_EPS = 1e-3
"""Offset of the log feature (unitless): distances below 0.1 % of the scale look alike."""

DEFAULT_RANK_CONSTANT = 60.0
"""Rank constant c of reciprocal rank fusion (Cormack et al. 2009)."""


def sigmoid(z: ArrayLike) -> Array:
    """Logistic function 1 / (1 + exp(-z)), overflow-free, in [0, 1]."""
    z = np.asarray(z, dtype=float)
    out = np.empty_like(z)
    pos = z >= 0
    out[pos] = 1.0 / (1.0 + np.exp(-z[pos]))
    ez = np.exp(z[~pos])
    out[~pos] = ez / (1.0 + ez)
    return out


def log_features(distances: ArrayLike, scales: ArrayLike, eps: float = DEFAULT_EPS) -> Array:
    """``f = log(d / scale + eps)`` for ``(..., S)`` distances and ``(S,)`` scales (unitless).

    Non-finite or negative distances are treated as very large / zero respectively, so a
    feature is always finite.
    """
    d = np.asarray(distances, dtype=float)
    s = np.asarray(scales, dtype=float)
    if np.any(~np.isfinite(s)) or np.any(s <= 0):
        raise UserError(f"log_features: scales must be positive and finite, got {s}")
    d = np.nan_to_num(d, nan=np.finfo(float).max, posinf=np.finfo(float).max)
    ratio = np.minimum(np.maximum(d, 0.0) / s, 1e300)
    return np.log(ratio + eps)


def ranks(distances: ArrayLike) -> Array:
    """``(S, K)`` ranks 1..K of each row's entries (ascending; ties share the lowest rank)."""
    d = np.asarray(distances, dtype=float)
    if d.ndim != 2:
        raise UserError(f"ranks: distances must be an (S, K) array, got shape {d.shape}")
    s, k = d.shape
    if k == 0:
        return np.zeros((s, 0))
    order = np.argsort(d, axis=1, kind="stable")
    sorted_d = np.take_along_axis(d, order, axis=1)
    # Rank of a sorted position = 1 + index of the first entry equal to it (min method).
    new = np.ones((s, k), bool)
    new[:, 1:] = sorted_d[:, 1:] != sorted_d[:, :-1]
    pos = np.where(new, np.arange(k)[None, :], 0)
    first = np.maximum.accumulate(pos, axis=1)
    out = np.empty((s, k))
    np.put_along_axis(out, order, first + 1.0, axis=1)
    return out


def reciprocal_rank_fusion(distances: ArrayLike, constant: float = DEFAULT_RANK_CONSTANT) -> Array:
    """``(K,)`` RRF scores in (0, 1] of K candidates from ``(S, K)`` per-matcher distances."""
    if constant < 0:
        raise UserError(f"rank fusion: constant must be >= 0, got {constant}")
    r = ranks(distances)
    s = r.shape[0]
    if s == 0:
        raise UserError("rank fusion needs at least one matcher (distances has 0 rows)")
    return (1.0 / (constant + r)).sum(axis=0) * ((constant + 1.0) / s)


@dataclass(slots=True, frozen=True)
class LogisticFusion:
    """Plain parameters of the logistic fusion model (a config section).

    Attributes:
        names: matcher (stage) names, one per feature, in feature order.
        coefficients: weight w_s of each feature (negative: larger distance, less
            likely the same place).
        intercept: bias b.
        eps: offset of the log feature ``log(d / scale + eps)``.
    """

    names: tuple[str, ...] = ()
    coefficients: tuple[float, ...] = ()
    intercept: float = 0.0
    eps: float = DEFAULT_EPS

    def __post_init__(self) -> None:
        if len(self.names) != len(self.coefficients):
            raise UserError(
                f"logistic fusion: {len(self.names)} names but {len(self.coefficients)} "
                "coefficients"
            )
        if not np.all(np.isfinite(self.coefficients)) or not np.isfinite(self.intercept):
            raise UserError("logistic fusion: coefficients and intercept must be finite")
        if not self.eps > 0:
            raise UserError(f"logistic fusion: eps must be > 0, got {self.eps}")

    def logit(self, features: ArrayLike) -> Array:
        """``(n,)`` log-odds ``b + w . f`` of ``(n, S)`` features."""
        f = np.asarray(features, dtype=float)
        if f.ndim != 2 or f.shape[1] != len(self.names):
            raise UserError(
                f"logistic fusion: features must be (n, {len(self.names)}), got shape {f.shape}"
            )
        return self.intercept + f @ np.asarray(self.coefficients, dtype=float)

    def probability(self, features: ArrayLike) -> Array:
        """``(n,)`` P(same place) in [0, 1] of ``(n, S)`` features."""
        return sigmoid(self.logit(features))

    def score(self, distances: ArrayLike, scales: ArrayLike) -> Array:
        """``(n,)`` P(same place) of ``(n, S)`` raw distances normalised by ``(S,)`` scales."""
        return self.probability(log_features(distances, scales, self.eps))


def fit_logistic(
    features: ArrayLike,
    same_place: ArrayLike,
    *,
    names: Sequence[str] | None = None,
    ridge: float = 1.0,
    eps: float = DEFAULT_EPS,
    max_iter: int = 100,
    tol: float = 1e-10,
) -> LogisticFusion:
    """Fit ``P(same | f) = sigma(b + w . f)`` to labelled pairs by ridge-penalised Newton/IRLS.

    Args:
        features: ``(n, S)`` features, usually `log_features` of per-matcher distances.
        same_place: ``(n,)`` booleans, True when the pair shows the same place.
        names: feature names (default ``f0, f1, ...``).
        ridge: lambda of the penalty ``lambda / 2 ||w||^2`` (not on the intercept).
        eps: the feature offset stored with the model (must match how `features`
            were made).
        max_iter: Newton iterations at most.
        tol: stop when the largest parameter change is below this.

    Raises:
        UserError: shapes disagree, non-finite features, or only one class present.
    """
    f = np.asarray(features, dtype=float)
    y = np.asarray(same_place, dtype=bool).astype(float)
    if f.ndim != 2 or len(f) != len(y):
        raise UserError(
            f"fit_logistic: features (n, S) and same_place (n,) disagree: {f.shape}, {y.shape}"
        )
    if not np.isfinite(f).all():
        raise UserError("fit_logistic: features must be finite")
    if y.min(initial=1.0) == y.max(initial=0.0):
        raise UserError(
            "fit_logistic: fitting needs both same-place and different-place pairs in same_place"
        )
    if ridge < 0:
        raise UserError(f"fit_logistic: ridge must be >= 0, got {ridge}")
    n, s = f.shape
    x = np.hstack([np.ones((n, 1)), f])
    penalty = np.full(s + 1, float(ridge))
    penalty[0] = 0.0

    def objective(theta: Array) -> float:
        z = x @ theta
        # log(1 + exp(z)) computed stably.
        return float(np.sum(np.logaddexp(0.0, z) - y * z) + 0.5 * penalty @ theta**2)

    theta = np.zeros(s + 1)
    prior = y.mean()
    theta[0] = np.log(prior / (1.0 - prior))
    current = objective(theta)
    for _ in range(max_iter):
        p = sigmoid(x @ theta)
        grad = x.T @ (p - y) + penalty * theta
        hess = (x * (p * (1.0 - p))[:, None]).T @ x + np.diag(penalty) + 1e-9 * np.eye(s + 1)
        step = np.linalg.solve(hess, grad)
        t = 1.0
        while t > 1e-8:
            candidate = theta - t * step
            value = objective(candidate)
            if value <= current:
                break
            t *= 0.5
        else:
            break
        change = float(np.abs(candidate - theta).max())
        theta, current = candidate, value
        if change < tol:
            break
    labels = tuple(names) if names is not None else tuple(f"f{i}" for i in range(s))
    if len(labels) != s:
        raise UserError(f"fit_logistic: {len(labels)} names for {s} features")
    return LogisticFusion(labels, tuple(float(v) for v in theta[1:]), float(theta[0]), eps)
