"""The geometric checks of a query's candidates, from the pose prior or with none.

`CandidateChecks` adds to the keyframes (`loopclosure.keyframe_store`) the checks the loop
detector runs on what its two searches propose (`loopclosure.loop_detector`'s module
docstring, 2.): a candidate inside the pose gate is checked from the predicted relative
pose (`_check_prior`); an appearance candidate outside it from its place's heading
hypotheses and a centroid-aligned translation (`_check_global`), moved to a nearer
keyframe when the fit finds the query there (`_nearer_place`), judged again on longer
submaps when a corridor leaves it degenerate (`loopclosure.longer_check`), and, when no
place of the query is accepted, over the whole circle of headings (`_circle_fallback`);
the places accepted for one query must agree (`_verify_free`).  With
``check.free_space_fallback`` a fit only the scans' free space passes is accepted
only for a query no place of which passes the keyframe model (`_rescued`).  Each
check is `loopclosure.geometric_check.verify`.
"""

from __future__ import annotations

import dataclasses
from collections import OrderedDict
from collections.abc import Hashable, Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data import se2
from loopclosure.free_space import SubmapPoints
from loopclosure.geometric_check import NOT_A_REVISIT, LoopVerification, verify
from loopclosure.keyframe_store import KeyframeStore
from loopclosure.longer_check import is_degenerate, joined, recheck_longer, trailing_count
from loopclosure.loop_candidate import LoopCandidate, place_figures
from loopclosure.place_match import PlaceMatch

if TYPE_CHECKING:
    from loopclosure.grid_target import GridTarget

Array = NDArray[np.float64]
RESCUED = "accepted (free space by its scans)"
"""Reason of a check accepted by the scans' free space (`CandidateChecks._rescued`)."""


class CandidateChecks(KeyframeStore):
    """The checks of candidates (module docstring) on the stored keyframes."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        # key -> (submap version, lazy grid) for the checks from a prior (`_prior_grid`),
        # least recently used first.
        self._grids: OrderedDict[int, tuple[Hashable, GridTarget]] = OrderedDict()

    def release_caches(self) -> None:
        """Drop the cached registration targets and grids of the submaps (rebuilt on
        demand)."""
        super().release_caches()
        self._grids.clear()

    def _prior_grid(self, key: int) -> GridTarget | None:
        """The compiled ICP's lazy grid of `key`'s submap for a check from a prior
        (`loopclosure.fast_icp`), rebuilt when the submap's version changed; None when
        the check does not run the compiled ICP, or its normals would not be the
        target's (`_target`, whose `GridTarget.from_target` the check would use).

        The target computes a normal for every submap point; the lazy grid only for
        the points ICP and the overlap screen meet, with the same computation on the
        same cells (`loopclosure.fast_icp.estimate_normals_fast` puts the points in
        cells of side ``normal_radius``, this grid in cells of `TARGET_GRID_CELL`:
        when the two are equal the sorted points, their neighbours and so every
        normal are the same), so every figure of the check is the same."""
        cfg = self.config.check
        from loopclosure.fast_icp import TARGET_GRID_CELL, GridTarget  # numba on first use

        if not cfg.compiled_icp or cfg.icp.normal_radius != TARGET_GRID_CELL:
            return None
        version = None if self._submap_version is None else self._submap_version(key)
        cached = self._grids.get(key)
        if cached is not None and cached[0] == version:
            self._grids.move_to_end(key)
            return cached[1]
        grid = GridTarget(self._submap_points(key), cfg.icp, TARGET_GRID_CELL, lazy=True)
        self._grids[key] = (version, grid)
        self._grids.move_to_end(key)
        while len(self._grids) > self.config.target_cache:
            self._grids.popitem(last=False)
        return grid

    def _check_prior(
        self, key: int, cand: int, match: PlaceMatch | None, poses: Array,
        cov: Array | None, sigma: float, query_points: Array,
    ) -> LoopCandidate:
        """The check of a candidate inside the pose gate, from the predicted pose."""
        cfg = self.config
        prior = se2.between(poses[cand], poses[key])
        prior_cov = None if cov is None else 2.0 * cov
        # A prior good to better than the offset step needs no offset guesses.
        offsets = 0.0 if sigma < 0.5 * cfg.check.offsets else None
        grid = self._prior_grid(cand)
        result = verify(
            query_points, self._target(cand) if grid is None else None, prior=prior,
            prior_covariance=prior_cov, offsets=offsets, max_distance=cfg.max_distance,
            config=cfg.check, grid=grid,
        )
        distance = float(np.hypot(prior[0], prior[1]))
        if match is None:
            return LoopCandidate.checked(
                key, cand, "pose", result, predicted_distance=distance, prior=True
            )
        return LoopCandidate.checked(
            key, cand, "appearance", result, predicted_distance=distance, prior=True,
            **place_figures(match),
        )

    def verify_places(
        self, key: int, matches: Sequence[PlaceMatch], poses: ArrayLike,
        query_points: ArrayLike | None = None, allowed: ArrayLike | None = None,
    ) -> list[LoopCandidate]:
        """The geometric checks of several appearance candidates with no pose prior.

        `matches` (a database query's `PlaceMatch` list for keyframe `key`) are checked
        in order, as the global search of `detect` checks them, until `max_loops` are
        accepted, and the accepted ones must agree (`agree_distance`, module
        docstring).  `poses` ``(n, 3)`` are the map's estimates of keyframes
        ``0..n-1`` (the candidates' poses; the query's own is not used).
        `query_points` is the query's submap (``(N, 2)`` [m], its sensor frame;
        default ``submap(key)``), made of the keyframes up to `key` (their scans' free
        space with ``check.free_space_origins = "scans"``).  Each check starts from the
        match's heading hypotheses and a centroid-aligned translation, as for a
        candidate outside the pose gate (and, when none is accepted, the whole-circle
        re-checks of `circle_fallback`).  `allowed` (keys; None: every eligible
        keyframe) bounds the keyframes a check may move to when it finds the query
        nearer another one (`_nearer_place`): a benchmark's keyframes with a reference
        pose.  For benchmarks that judge the appearance search alone (no search, no
        counters).
        """
        self._check_key(key)
        for m in matches:
            self._check_key(int(m.key))
        if query_points is None:
            pts = self._submap_points(key)
        else:
            pts = np.asarray(query_points, dtype=float).reshape(-1, 2)
            if self._per_scan:  # a given submap holds the scans of keys up to `key`
                pts = SubmapPoints(pts, self.submap_free_space(key, last=key))
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        return self._verify_free(key, list(matches), pts, poses, self.config.max_loops,
                                 allowed)

    def _verify_free(
        self, key: int, matches: list[PlaceMatch], query_points: Array, poses: Array | None,
        budget: int, allowed: ArrayLike | None = None, rescue: bool = True,
    ) -> list[LoopCandidate]:
        """Checks with no prior of `matches`, in order, until `budget` are accepted
        (`allowed`: as `verify_places`); none accepted, the whole-circle re-checks
        (`_circle_fallback`); still none accepted and `rescue` (no other search of the
        query accepted a place), the first `budget` rescuable ones (`_rescued`); then
        accepted candidates in one frame that put the query more than `agree_distance`
        apart (``poses[match] * relative``) are all rejected."""
        out: list[LoopCandidate] = []
        checked: list[PlaceMatch] = []
        for m in matches:
            if sum(c.accepted for c in out) >= budget:
                break
            if not m.headings:  # a query made without them (`_appearance`)
                db, asked = self.views(key)[m.view]
                m = db.with_headings(db.descriptors(asked), [m])[0]
            c = self._check_global(key, m, query_points, poses, allowed)
            out.append(c if c.match == int(m.key) else self._same_place(c, out, poses))
            checked.append(m)
        if not any(c.accepted for c in out):
            out = self._circle_fallback(key, checked, out, query_points, poses, budget)
        if rescue and not any(c.accepted for c in out):
            out = self._rescued(key, out, budget, poses)
        accepted = [i for i, c in enumerate(out) if c.accepted]
        if poses is None or len(accepted) < 2:
            return out
        implied = {i: se2.compose(poses[out[i].match], out[i].relative)[:2] for i in accepted}
        for i in accepted:
            far = [float(np.hypot(*(implied[i] - implied[j]))) for j in accepted
                   if j != i and self._frames[out[j].match] == self._frames[out[i].match]]
            spread = max(far, default=0.0)
            if spread > self.config.agree_distance:
                out[i] = dataclasses.replace(
                    out[i], accepted=False,
                    reason=f"ambiguous places (another accepted place puts the query "
                           f"{spread:.1f} m away)")
        return out

    def _same_place(self, c: LoopCandidate, before: list[LoopCandidate],
                    poses: Array | None) -> LoopCandidate:
        """`c`, a check that moved to a nearer keyframe (`_nearer_place`), rejected
        when it landed within `place_separation` of a place accepted before it for
        this query: that place is closed (one loop per place; the places chosen for
        checking are distinct, `places`, but a move can join two)."""
        if not c.accepted or poses is None:
            return c
        for b in before:
            if (b.accepted and self._frames[b.match] == self._frames[c.match]
                    and self._distance(poses, b.match, c.match) <= self.config.place_separation):
                return dataclasses.replace(
                    c, accepted=False, reason=f"same place as the accepted keyframe {b.match}")
        return c

    def _circle_fallback(
        self, key: int, matches: list[PlaceMatch], out: list[LoopCandidate],
        query_points: Array, poses: Array | None, budget: int,
    ) -> list[LoopCandidate]:
        """The whole-circle re-checks of a query none of whose `matches` (checked, in
        order, with verdicts `out`) was accepted from its heading hypotheses.

        A place's hypotheses (`loopclosure.headings`) can all miss the heading of a
        revisit (a place seen the other way, a range function dragged by open space):
        the check then searches the wrong headings and fits a wrong pose, or none, at
        the true place.  The first `circle_fallback` places rejected for their fit
        (every verdict but "not a revisit": a check that fitted well but too far
        away has found the query elsewhere, `_nearer_place`) are checked again by
        the same rules with no hypotheses: the correlative search then covers the
        whole circle of headings at its coarse heading step
        (`loopclosure.prior_free`), the ambiguity test included (a runner-up
        anywhere on the circle counts).  An accepted re-check replaces the place's
        verdict; a rejected one leaves it.  Stops once `budget` are accepted.
        Only for the correlative check (``check.method``); the multi-start ICP check
        without hypotheses would start from one heading only."""
        cfg = self.config
        if cfg.circle_fallback <= 0 or cfg.check.method != "correlative":
            return out
        out = list(out)
        tried = accepted = 0
        for i, (m, c) in enumerate(zip(matches, out, strict=True)):
            if tried >= cfg.circle_fallback or accepted >= budget:
                break
            if c.reason.startswith(NOT_A_REVISIT):
                continue
            tried += 1
            cand = int(c.match)
            result = verify(query_points, self._target(cand), headings=None,
                            max_distance=cfg.max_distance, config=cfg.check)
            if result.rescuable and not (c.verification is not None
                                         and c.verification.rescuable):  # a refusal for a refusal
                out[i] = LoopCandidate.checked(
                    key, cand, "appearance", result,
                    predicted_distance=c.predicted_distance, **place_figures(m))
            if result.accepted:
                accepted += 1
                out[i] = LoopCandidate.checked(
                    key, cand, "appearance", result,
                    predicted_distance=c.predicted_distance, **place_figures(m))
        return out

    def _check_global(
        self, key: int, m: PlaceMatch, query_points: Array, poses: Array | None = None,
        allowed: ArrayLike | None = None,
    ) -> LoopCandidate:
        """The check of an appearance candidate from its heading hypotheses alone."""
        cfg = self.config
        cand = int(m.key)
        # Headings of the query in the candidate's frame (`loopclosure.headings`); align
        # the two places' centroids under the best one.
        headings = [h for h, _ in m.headings] or [0.0]
        # The view's description may be another keyframe's (the wide view of an older
        # one, a trail keyframe): its hypotheses and centroid into the query's frame.
        db, asked = self.views(key)[m.view] if m.view else (self.database, key)
        centroids = self._wide_centroids if db is self.wide_database else self._centroids
        own = centroids[asked]
        if asked != key and poses is not None:
            rel = se2.between(poses[key], poses[asked])  # `asked` in the query's frame
            headings = [h - float(rel[2]) for h in headings]
            own = se2.transform_points(rel, own[None, :])[0]
        c, s = np.cos(headings[0]), np.sin(headings[0])
        rot = np.array([[c, -s], [s, c]])
        translation = centroids[cand] - rot @ own
        result = verify(
            query_points, self._target(cand), headings=headings, translation=translation,
            max_distance=cfg.max_distance, config=cfg.check,
        )
        if self._trailing_map is not None and is_degenerate(result):
            nq, nc = (trailing_count(poses, k, cfg.check) for k in (key, cand))
            if min(nq, nc) > 0:
                result = recheck_longer(  # `loopclosure.longer_check`
                    result, joined(query_points, self._trailing_map(key, nq)),
                    joined(self._submap_points(cand), self._trailing_map(cand, nc)),
                    max_distance=cfg.max_distance, config=cfg.check)
        if result.reason.startswith(NOT_A_REVISIT) and poses is not None:
            cand, result = self._nearer_place(key, cand, result, query_points, poses,
                                              allowed)
        elif result.rescuable_far and poses is not None:  # the move only as a rescue
            near, second = self._nearer_place(key, cand, result, query_points, poses,
                                              allowed)
            result = (second if near == cand
                      else dataclasses.replace(result, rescue=second, rescue_at=near))
        distance = (float("nan") if poses is None or self._frames[cand] != self._frames[key]
                    else self._distance(poses, cand, key))
        return LoopCandidate.checked(
            key, cand, "appearance", result, predicted_distance=distance, **place_figures(m)
        )

    def _nearer_place(
        self, key: int, cand: int, result: LoopVerification, query_points: Array,
        poses: Array, allowed: ArrayLike | None = None,
    ) -> tuple[int, LoopVerification]:
        """A check that fits the query `result.relative` beyond `max_distance` of
        `cand` has found where the query is: the map's pose of `cand` composed with
        that relative pose.  The eligible keyframe of `cand`'s frame nearest to that
        position, when it lies within `max_distance` of it (a revisit by the map), is
        checked the same way as `cand`, with no prior, its heading hypothesis the
        heading that position implies in its frame (the same search and thresholds:
        a check from that pose as a prior would judge by the stricter fitness of
        a pose-gated ICP); its result, if accepted, replaces `cand`'s.  `allowed`
        (keys, None: all) bounds the keyframes it may move to."""
        cfg = self.config
        at = se2.compose(poses[cand], result.relative)
        eligible = self.eligible(key)
        ids = np.flatnonzero(eligible & self._described[: len(eligible)]
                             & (self._frames[: len(eligible)] == self._frames[cand]))
        if allowed is not None:
            ids = ids[np.isin(ids, np.asarray(allowed, dtype=np.int64))]
        if len(ids) == 0:
            return cand, result
        d = np.hypot(*(poses[ids, :2] - at[:2]).T)
        near = int(ids[np.argmin(d)])
        if near == cand or d.min() > cfg.max_distance:
            return cand, result
        implied = se2.between(poses[near], at)
        second = verify(query_points, self._target(near), headings=[float(implied[2])],
                        translation=implied[:2], max_distance=cfg.max_distance,
                        config=cfg.check)
        if second.accepted:
            return near, second
        if second.rescuable:  # kept aside: the default's verdict stands (`_rescued`)
            return cand, dataclasses.replace(result, rescue=second, rescue_at=near)
        return cand, result

    def _rescued(self, key: int, out: list[LoopCandidate], budget: int,
                 poses: Array | None) -> list[LoopCandidate]:
        """`out` (query `key`'s checks, in order, none accepted) with its first `budget`
        rescuable checks accepted (`GeometricCheckConfig.free_space_fallback`): fits
        every test passes once the scans' model judges their free space, the check's
        own (`LoopVerification.rescuable`) or that of the nearer keyframe it moved to
        (`LoopVerification.rescue`), skipping one at a place already rescued (within
        `place_separation`, one frame).  Only for a query with no place the keyframe
        model passes, so a rescue never displaces one."""
        out = list(out)
        taken: list[int] = []
        for i, c in enumerate(out):
            if len(taken) >= budget:
                break
            v = c.verification
            if v is None or not (v.rescuable or v.rescue is not None):
                continue  # (`rescue` accepted by (1) or rescuable: a move (5) let happen)
            match, w = (c.match, v) if v.rescuable else (v.rescue_at, v.rescue)
            if poses is not None and any(
                    self._frames[t] == self._frames[match]
                    and self._distance(poses, t, match) <= self.config.place_separation
                    for t in taken):
                continue
            w = dataclasses.replace(w, accepted=True, reason=RESCUED)
            distance = (c.predicted_distance if match == c.match else float("nan")
                        if poses is None or self._frames[match] != self._frames[key]
                        else self._distance(poses, match, key))
            out[i] = dataclasses.replace(
                c, match=match, accepted=True, reason=RESCUED, relative=w.relative,
                covariance=w.covariance, verification=w, predicted_distance=distance)
            taken.append(match)
        return out
