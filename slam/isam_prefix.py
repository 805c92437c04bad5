"""The solved prefix of the time-ordered admission, kept by one gtsam ISAM2.

`slam.admission.AdmissionPass` re-solves its accepted prefix after every admission
round; `IsamPrefix` makes those solves incremental updates (re-eliminating only what
the new factors and relinearised poses touch), and `isam_or_batch` hands a pass over
to damped batch solves once iSAM2's undamped updates stop converging.  A factor handed
over with a tag can be taken out again (`IsamPrefix.remove`: gtsam's
``removeFactorIndices``), so a pass that turns an admission back keeps its iSAM2.  Units: tangent
coordinates of the poses (`RELINEARIZE`), gtsam error units.
"""

from __future__ import annotations

import gtsam

from slam.least_squares import StickySolver

RELINEARIZE = 1e-3  # iSAM2 relinearisation threshold of the prefix (tangent units)


class IsamPrefix:
    """The solved prefix of `admit_incrementally`, kept by one gtsam ISAM2.

    Factors and poses are handed over once (`add`, `insert`), and tagged factors taken
    out again (`remove`: iSAM2 drops them from its factor graph and re-eliminates the
    cliques of their variables); `solve` updates iSAM2 with
    them and repeats ``update`` until no variable is relinearised any more (at most
    `max_updates`), so each solve re-eliminates only the part of the Bayes tree that the
    new factors and the relinearised poses touch, instead of a batch solve of the whole
    prefix.  Cholesky factorisation; when it finds the system indeterminate (Intel's
    near-singular information matrices), iSAM2 is rebuilt once with QR from every factor
    it was given and its latest estimate.

    iSAM2's updates are undamped Gauss-Newton steps.  When admitted false loops fold the
    prefix, they stop converging: every update relinearises every pose and the estimate
    oscillates (M3500 at half false loops: all `max_updates` updates of each later solve
    relinearise the whole prefix).  `converged` is then False, and `admit_incrementally`
    finishes that pass with damped batch solves (`isam_or_batch`).
    """

    def __init__(self, max_updates: int = 20) -> None:
        self.factorization = "CHOLESKY"
        self._isam = self._new()
        self._all = gtsam.NonlinearFactorGraph()  # every factor handed over, for a rebuild
        self._all_tags: list[object] = []  # the tag of each factor of `_all` (None: untagged)
        self._tags: list[object] = []  # the tag of each factor of `_factors`
        self._index: dict[object, int] = {}  # iSAM2's factor index of each tagged factor
        self._remove: list[object] = []  # tags of the factors the next `solve` takes out
        self._estimate = gtsam.Values()
        self._factors = gtsam.NonlinearFactorGraph()
        self._values = gtsam.Values()
        self.max_updates = max_updates
        self.converged = True  # the last `solve` stopped relinearising within max_updates

    def _new(self) -> gtsam.ISAM2:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(RELINEARIZE)
        params.relinearizeSkip = 1
        params.setFactorization(self.factorization)
        return gtsam.ISAM2(params)

    @classmethod
    def of(cls, factors: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> IsamPrefix:
        """A new prefix holding `factors` (untagged) at `values` (every variable of
        `factors` and no other), to be solved by the next `solve`."""
        prefix = cls()
        for n in range(factors.size()):
            prefix.add(factors.at(n))
        prefix._values = gtsam.Values(values)
        return prefix

    def copy(self) -> IsamPrefix:
        """An independent copy (gtsam's ISAM2 copy constructor copies the Bayes tree: the
        copy and the original updated alike give the same estimates, bit for bit)."""
        other = IsamPrefix.__new__(IsamPrefix)
        other.factorization = self.factorization
        other._isam = gtsam.ISAM2(self._isam)
        other._all = gtsam.NonlinearFactorGraph(self._all)
        other._all_tags = list(self._all_tags)
        other._tags = list(self._tags)
        other._index = dict(self._index)
        other._remove = list(self._remove)
        other._estimate = gtsam.Values(self._estimate)
        other._factors = gtsam.NonlinearFactorGraph(self._factors)
        other._values = gtsam.Values(self._values)
        other.max_updates = self.max_updates
        other.converged = self.converged
        return other

    @property
    def estimate(self) -> gtsam.Values:
        """The estimate of the last `solve` (empty before the first)."""
        return self._estimate

    def add(self, factor: gtsam.NonlinearFactor, tag: object = None) -> None:
        """Hand `factor` over at the next `solve`; a `tag` (hashable, unique) lets
        `remove` take it out later."""
        self._factors.add(factor)
        self._tags.append(tag)

    def remove(self, tags: object) -> None:
        """Take the factors of `tags` (given to `add`) out at the next `solve`."""
        self._remove.extend(tags)

    def holds(self, tags: object) -> bool:
        """True when every factor of `tags` was handed over with its tag and is still
        held (so `remove` can take it out)."""
        pending = set(self._tags)
        return all(t in self._index or t in pending for t in tags)

    def insert(self, key: int, pose: object) -> None:
        self._values.insert(key, pose)

    def solve(self) -> gtsam.Values:
        factors, values, tags = self._factors, self._values, self._tags
        self._factors, self._values, self._tags = gtsam.NonlinearFactorGraph(), gtsam.Values(), []
        removed, self._remove = set(self._remove), []
        indices = [self._index.pop(t) for t in removed]
        if removed:  # `_all` without the removed factors (rare: a rebuild needs it)
            kept = [n for n, t in enumerate(self._all_tags) if t is None or t not in removed]
            old, self._all = self._all, gtsam.NonlinearFactorGraph()
            for n in kept:
                self._all.add(old.at(n))
            self._all_tags = [self._all_tags[n] for n in kept]
        for k in range(factors.size()):
            self._all.add(factors.at(k))
        self._all_tags.extend(tags)
        try:
            self._converge(factors, values, tags, indices)
        except RuntimeError:  # gtsam IndeterminateLinearSystemException
            if self.factorization == "QR":
                raise
            self.factorization = "QR"
            self._isam = self._new()
            start = gtsam.Values(self._estimate)
            start.insert_or_assign(values)
            self._converge(self._all, start, self._all_tags, [])
        self._estimate = self._isam.calculateEstimate()
        return self._estimate

    def _converge(self, factors: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                  tags: list[object], remove: list[int]) -> None:
        result = self._isam.update(factors, values, remove)
        self._index.update((t, int(n)) for t, n in zip(tags, result.getNewFactorsIndices(),
                                                         strict=True) if t is not None)
        if remove:
            # An update relinearises by the step of the system before it: after a
            # removal that step is small and says nothing of the factor taken out.
            result = self._isam.update()
        for _ in range(self.max_updates):
            if result.getVariablesRelinearized() == 0:
                self.converged = True
                return
            result = self._isam.update()
        self.converged = result.getVariablesRelinearized() == 0


def isam_or_batch(
    isam: IsamPrefix, solve: StickySolver, factors: gtsam.NonlinearFactorGraph,
    current: gtsam.Values,
) -> tuple[gtsam.Values, IsamPrefix | None]:
    """The prefix solved by `isam`, or, when its updates did not converge, by `solve` on
    the accepted graph `factors` from the better of iSAM2's estimate and `current`; the
    second value is the iSAM2 to use next (None: batch solves for the rest of the pass)."""
    estimate = isam.solve()
    if isam.converged:
        return estimate, isam
    start = estimate if factors.error(estimate) < factors.error(current) else current
    return solve(factors, start), None
