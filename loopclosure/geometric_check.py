"""Geometric verification of a loop-closure candidate: registration of two local submaps.

A candidate says "keyframe b (the query) is at the place of keyframe a".  The
check registers b's local submap (points in b's sensor frame) onto a's local
submap (points in a's sensor frame).

Without a pose prior and with ``method = "correlative"`` (the default) it searches
(`loopclosure.prior_free`): a correlative scan matcher scores every pose of a
lattice of translations within ``max_distance`` of 0 and of headings about each
heading hypothesis and its opposite on a likelihood grid of a's submap
(`loopclosure.correlative`), coarse then fine, and ICP refines the best lattice
peak (and a runner-up that scores close to it, for the ambiguity test below).  Such
a candidate is accepted on the rules below with a floor on the *length of surface
matched*, `min_matched_length` (fitness x the query's points at ``source_voxel`` x
``source_voxel`` [m]), instead of `min_fitness` and `min_inlier_ratio` (a fit below
either is a partial overlap, which must be well constrained), provided the
free-space consistency of the two submaps
(`loopclosure.free_space` (2): hits over hits plus points landing in space the
other submap observed as free) is at least `min_consistency`: two passes through
a place in different directions share only part of their submaps, and the part
not shared lies where the other never looked, which counts neither way.

Otherwise (a prior, or ``method = "icp"``) it runs ICP from several initial
guesses — the relative
pose predicted by the current pose estimates, or without one the heading
hypotheses of the place database (`loopclosure.headings`), each at the given
translation (e.g. the two places' centroids aligned) and, with `origin_guesses`,
at translation 0 (the two sensor origins together: the centroids of real scans
move by metres with the open space the sensor happens to see, the sensor of a
revisit is within metres of the candidate's), each with a few translation offsets
— and keeps the best run (`loopclosure.multi_start.register_multi`).

A pose-gated check first asks whether ICP would find anything to match near the
prior: the coarse overlap score of `loopclosure.multi_start.overlap_scores` (the
mean over the query's points of ``max(0, 1 - (d / g)^2)``, ``d`` the distance to
the candidate's nearest matchable point, ``g`` ICP's correspondence gate
``icp.max_correspondence_distance``) at every initial guess.  When the best guess
scores below `min_prior_overlap` no ICP runs: "no overlap at the prior".  Such
candidates (a wide pose gate outdoors, where the submaps of keyframes tens of
metres apart share nothing) made most of the checks of a log and most of its loop
detection time.  The score is measured at ICP's own gate, not at a tighter
tolerance, because a prior from drifting wheel odometry can be off by more than
the guesses' offsets, and ICP still converges from there.  The bar is half the
gated fitness threshold: a fit of fitness F has at least F of the query's points
within ``fitness_tolerance`` of a wall; at a guess ``d`` from the fit each of them
is within about ``d`` of that wall and scores at least ``1 - (d / g)^2``: at
least 0.75 for a fit within the offsets' spacing (0.5 m, g = 1 m) of a guess, so
a fit that could pass scores well above F / 2 at its best guess.

A check that passes that screen, with the compiled ICP, is then bounded on the
grid the ICP runs on (`loopclosure.fast_icp.overlap_bound`): for each guess the
share ``B`` of the query's points with a map point within `bound_reach` of where
the guess puts them.  A fit whose points lie within ``bound_reach -
fitness_tolerance`` of where a guess puts them (the guesses are spaced by
`offsets`: a fit farther from all of them is one they do not cover) has an inlier
ratio, and so a fitness, of at most that guess's ``B``.  When the best ``B`` is
below what the check accepts, ``max(fitness threshold, inlier threshold)``, no
ICP runs: "no fit within reach".  The bound costs one nearest-neighbour pass per
guess; the ICP it saves, dozens.  With the compiled ICP the two screens share that
pass, which stops as soon as both bars are reached (`loopclosure.prior_screen`: the
sums only grow, so the verdict is known then).
Headings are in the plugin's one convention (`loopclosure.headings`): the heading of
the query in the candidate's frame.

It is accepted when all of these hold (defaults in `GeometricCheckConfig`):

- ``fitness >= min_fitness``: the truncated-quadratic overlap of the two submaps;
- ``inlier_ratio >= min_inlier_ratio`` and ``rms <= max_rms`` [m];
- for a pose-gated candidate (a prior relative pose with covariance) the overlap
  thresholds are the lower ``min_fitness_gated`` / ``min_inlier_ratio_gated``: the
  prior is independent evidence, and two passes through a place in different
  directions, or logs with one scan per metre, share only a part of their submaps
  (true revisits of real logs then overlap well below `min_fitness` with poses
  right to a few centimetres); such a partial overlap must also be well
  constrained, ``degeneracy >= min_degeneracy_partial`` (a corridor seen partly
  fits off along its axis with a fair overlap and a degeneracy just above
  `min_degeneracy`, while partial true revisits are well above it);
- ``degeneracy >= min_degeneracy``: no direction left unconstrained (a corridor
  seen twice matches anywhere along its axis; with ``longer_keyframes`` the loop
  detector checks a prior-free candidate rejected by this rule or the next again on
  longer submaps, `loopclosure.longer_check`).  With ``pinned_degenerate`` a
  correlative check below either degeneracy bar is judged instead by what pins it
  along its weak axis: the surface that stops matching when the fit slides one
  ambiguity distance along that axis (`pinned_length`) must reach
  `min_matched_length`, the floor the whole fit must match, and (``pinned_cross``)
  that slide must keep more of the hits than the same slide across the axis
  (`slide_anisotropy` above 1): the hits must show the axis the information calls
  weak, or what the slide un-matches is scattered points (vegetation) that match at
  one pose only whichever way the fit moves;
- when a prior relative pose with covariance is given (a pose-gated, local
  search), the result lies within `max_prior_mahalanobis` of it;
- the best hypothesis beats the runner-up that lands at a *different* pose
  (more than `ambiguity_distance` m or `ambiguity_angle_deg` away) by at least
  `min_fitness_margin`: a symmetric room that fits two ways is ambiguous.  A weak
  best fit needs a margin of only `min_relative_margin` times its own fitness (the
  runner-up fits at most half as well, by default): outdoors, or where two passes
  see a place from different sides, the overlap fraction of true revisits is often
  0.05-0.2, and a margin in absolute fitness units would reject every such fit.
  Without a prior (the correlative check) a runner-up counts only when it is a
  plausible answer (`implausible_runner_up`): one that fails the free-space bar on
  its own, with a conflict share above the best's by more than the bar's allowance
  ``1 - min_consistency``, is not (a corridor turned round fits nearly as well, but
  its openings then face walls the other pass saw, and its walls lie in free space);
- a loop closure is a revisit: when the caller gives `max_distance` (the loop
  detector's `LoopClosureConfig.max_distance`), a relative pose longer than that
  is rejected, "not a revisit (D m apart)": the two keyframes see overlapping but
  distinct places.

The result carries the relative pose (pose of b in a's frame) and its covariance:
ICP's Gauss-Newton covariance, which is optimistic, never below `covariance_floor`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data import se2
from data.errors import UserError
from loopclosure.free_space import SCAN_FREE_SPACE, Consistency
from loopclosure.free_space_rule import expand_free_space_rule, free_space_rule_of
from loopclosure.multi_start import initial_guesses, overlap_scores, register_multi
from loopclosure.prior_free import PriorFreeConfig, match_prior_free
from loopclosure.registration import (
    FAILED_VARIANCE,
    IcpConfig,
    IcpResult,
    RegistrationTarget,
    voxel_downsample,
)

if TYPE_CHECKING:
    from loopclosure.grid_target import GridTarget

Array = NDArray[np.float64]
NOT_A_REVISIT = "not a revisit"
"""Start of the verdict of a check that fits but places the two keyframes more than
``max_distance`` apart (every other rule held)."""
DEGENERATE = "degenerate"
"""Start of the verdict of a check rejected by ``min_degeneracy``."""
PARTIAL_DEGENERATE = "partial overlap"
"""Start of the verdict of a check rejected by ``min_degeneracy_partial``."""


@dataclass(slots=True)
class GeometricCheckConfig:
    """Acceptance rule and search of the geometric check (module docstring).

    Attributes:
        min_fitness: overlap score threshold in [0, 1] (no prior: appearance candidates).
        min_inlier_ratio: inliers / source points (no prior).
        min_fitness_gated: overlap threshold of a candidate gated by a prior pose.
        min_inlier_ratio_gated: inlier ratio threshold of a gated candidate.
        min_degeneracy_partial: degeneracy a gated candidate needs when its fitness is
            below `min_fitness` (admitted by the lower gated threshold only).
        max_rms: RMS point-to-line residual of the inliers [m].
        min_degeneracy: smallest normalised translational information, 0..0.5.
        max_prior_mahalanobis: gate around a prior relative pose (local searches).
        min_fitness_margin: best minus best-at-another-pose fitness.
        min_relative_margin: a best fit below ``min_fitness_margin /
            min_relative_margin`` needs a margin of only ``min_relative_margin`` times
            its own fitness (module docstring).
        ambiguity_distance: hypotheses closer than this are the same answer [m].
        ambiguity_angle_deg: ... or closer than this in heading [deg].
        offsets: translation offsets tried around each heading [m].
        origin_guesses: without a prior, every heading is also tried at translation 0
            (the two sensor origins together: a revisit is within `max_distance` of
            its candidate), besides the given translation (module docstring).
        source_voxel: voxel of the query submap before ICP [m] (the candidate's submap
            keeps its own resolution).
        keep: guesses refined by ICP after the coarse overlap prescreen.
        min_prior_overlap: a pose-gated check whose best initial guess has a coarse
            overlap score (`loopclosure.multi_start.overlap_scores` at ICP's
            correspondence gate) below this runs no ICP and is rejected (module
            docstring: half of `min_fitness_gated`).  0 turns the screen off.
        bound_reach: radius of the overlap bound of a check from a prior (module
            docstring): the guesses' spacing `offsets` plus ICP's
            ``fitness_tolerance`` [m].  0 turns the bound off.
        method: the check without a prior: ``"correlative"`` (lattice search, then
            ICP; `loopclosure.prior_free`) or ``"icp"`` (multi-start ICP from the
            heading hypotheses at the given translation and at 0).
        min_matched_length: least length of surface the correlative check (no
            prior) must match [m]: the best run's fitness (a soft count of matched
            points over the query's points) times the query's points at
            `source_voxel`, times `source_voxel`.  The check judges partial overlap
            by its free-space consistency; this floor only refuses fits of a few
            stray points.  A length, not a share of the query: an outdoor submap
            holds many points (vegetation, far facades) the other pass never saw,
            so a true revisit may match 2-5% of them, a few metres of wall.
        min_consistency: free-space consistency the correlative check needs, in [0, 1]
            (`loopclosure.free_space`).  A look-alike place (a room of the same
            shape elsewhere, a corridor seen the other way) fits a partial overlap
            with 8-10% of its points in the other's free space; true revisits of real
            logs nearly all stay under 8% (people, doors).  Each query checks several
            places, so the bar sits above the look-alikes'.
        free_space_origins: where the free-space test's rays start
            (`loopclosure.free_space`): ``"keyframe"``, the merged submap seen from
            the keyframe's sensor (1); ``"scans"``, every scan of the submap from its
            own sensor (1'), for a query whose points carry their scans' free space
            (`loopclosure.free_space.SubmapPoints`) against a target that holds its
            own (``derived[SCAN_FREE_SPACE]``), as the loop detector's keyframe store
            provides them; a pair lacking either (a longer check's joined submaps)
            keeps (1).
        free_space_surface_cap: with ``free_space_origins = "scans"``, above 1 the
            free-space margin is measured across each scan's surface instead of along
            its ray (`loopclosure.free_space` (1''), (3)), the along-ray margin at most
            this many times ``search.free_margin`` (a wall seen at grazing incidence);
            1 (the default): along the ray (1').
        free_space_return_window: with ``free_space_origins = "scans"``, above 0 a
            point within ``search.free_margin`` of a return of the scan that saw
            through it, in this many bearing sectors either side, is not in that
            scan's free space (`loopclosure.free_space` (4)).  0 (the default): off.
        free_space_confirm: with ``free_space_origins = "scans"``, a point is in free
            space only where the keyframe model (1) calls it free as well, (1) and
            (1') (`loopclosure.free_space` (5)): no ray from the keyframe's origin
            that no scan cast, and no scan's ray beyond the merged submap's nearest
            surface.  Off (the default): the scans' model alone.
        free_space_either: with ``free_space_origins = "scans"`` and above 0, a fit
            that fails `min_consistency` under the scans' model passes the free-space
            test when its consistency under the keyframe model (1) reaches this bar
            instead: either model's bar; the runner-up test (`implausible_runner_up`)
            then judges the runs by (1) at this bar, as the keyframe model alone
            does; a pair lacking the scans' free space is judged by (1) at this bar
            too.  0 (the default): off.
        free_space_fallback: with `free_space_either`, a fit that only the scans'
            model passes (under (1) it stays below `free_space_either`) is not
            accepted by the check: it is refused for its free space as (1) alone
            refuses it, and marked `LoopVerification.rescuable` when every other test
            passes.  The loop detector accepts such fits only for a query none of
            whose places passes (1) (`loopclosure.candidate_checks`), so a query the
            keyframe model serves keeps exactly its places, its fits and its fused
            score: the scans' model adds places, it never replaces one.  Off (the
            default): either model's pass is an acceptance.
        free_space_rule: one switch for the five keys above that move together
            (`free_space_origins`, `free_space_confirm`, `min_consistency`,
            `free_space_either`, `free_space_fallback`;
            `loopclosure.free_space_rule`): ``"keys"`` (the default), each key as
            given; ``"fallback"``, the scans' model adds places only where the
            keyframe model (1) serves none.  Expanded when the config is made (the
            config then holds the rule's values and ``"keys"``): a key left at its
            default takes the rule's value, a key set otherwise is a UserError naming
            it.  `resolved_free_space_rule` says which rule the keys hold.
        plausible_runner_up: the correlative check's ambiguity test ignores a runner-up
            that the free space rules out (`implausible_runner_up`).
        search: the correlative search's parameters.
        covariance_floor: standard deviations (x [m], y [m], theta [deg]) below which
            the loop constraint's covariance never goes.
        icp: ICP parameters (wider gate than odometry: the guesses are coarser).
        longer_keyframes: a prior-free check rejected for its degeneracy is checked
            again on longer submaps, each keyframe's joined with the map of this many
            keyframes of path behind it (`loopclosure.longer_check`; the loop
            detector, given a ``trailing_map``).  0 (the default): never.
        longer_path_m: the longer submaps by path instead of a count: each joins
            the fewest keyframes behind it whose path (the map's keyframe poses)
            reaches this length [m] (`loopclosure.longer_check.trailing_count`).  A
            count of keyframes is a path of very different length from log to log
            (keyframes a few decimetres apart indoors, metres apart outdoors).  0 (the
            default): by `longer_keyframes`.  Both off by default: at 30 m the
            longer check accepts many more corridor revisits, but outdoors also a fit
            a few decimetres off whose first, short fit was already that far off
            across the corridor (the longer one agrees with it), and a few metres of
            path still fit a look-alike corridor elsewhere.
        pinned_degenerate: a correlative check below `min_degeneracy` (or, for a
            partial overlap, `min_degeneracy_partial`) is judged instead by the
            surface that pins it along its weak axis: accepted by that rule when
            sliding the fit one ambiguity distance along the axis un-matches at least
            `min_matched_length` of surface (`pinned_length`).  The degeneracy is a
            ratio: a partial overlap of a long corridor whose walls match over tens of
            metres has a small one although a door jamb or a corner pins it.  Off by
            default.
        pinned_required: a correlative check below `min_degeneracy_partial` that the
            degeneracy rules let through (a full overlap) must be pinned as well
            (`pinned_length` at least `min_matched_length`): a corridor turned round
            or slid to a look-alike stretch fits its walls fully and pins nothing.
            With `pinned_degenerate`, the pin alone judges every fit below
            `min_degeneracy_partial`.  Off by default.
        pinned_cross: with `pinned_degenerate`, a fit is held by its pin only when
            the slide along its weak axis keeps more hits than the same slide across
            it (`slide_anisotropy` > 1).  A corridor's walls keep matching along the
            corridor and none across; a fit held by scattered points (trees, poles,
            vegetation) loses them in every direction, so its slide loss says nothing
            about the weak axis.  Two more free-space tests per fit below a
            degeneracy bar, only when `pinned_degenerate` is on.
        compiled_icp: every ICP of the check by the compiled kernel
            (`loopclosure.fast_icp`: the same maths as
            `loopclosure.registration.register`, nearest neighbours in a cell grid
            of the candidate's submap made per check instead of its KD-tree).
    """

    min_fitness: float = 0.55
    min_inlier_ratio: float = 0.6
    min_fitness_gated: float = 0.3
    min_inlier_ratio_gated: float = 0.35
    min_degeneracy_partial: float = 0.1
    max_rms: float = 0.04
    min_degeneracy: float = 0.04
    max_prior_mahalanobis: float = 5.0
    min_fitness_margin: float = 0.1
    min_relative_margin: float = 0.5
    ambiguity_distance: float = 0.5
    ambiguity_angle_deg: float = 10.0
    offsets: float = 0.5
    origin_guesses: bool = True
    source_voxel: float = 0.1
    keep: int = 6
    min_prior_overlap: float = 0.15
    bound_reach: float = 0.55
    method: str = "correlative"
    min_matched_length: float = 2.0
    min_consistency: float = 0.92
    free_space_origins: str = "keyframe"
    free_space_surface_cap: float = 1.0
    free_space_return_window: int = 0
    free_space_confirm: bool = False
    free_space_either: float = 0.0
    free_space_fallback: bool = False
    free_space_rule: str = "keys"
    plausible_runner_up: bool = True
    search: PriorFreeConfig = field(default_factory=PriorFreeConfig)
    covariance_floor: tuple[float, float, float] = (0.02, 0.02, 0.5)
    icp: IcpConfig = field(
        default_factory=lambda: IcpConfig(max_correspondence_distance=1.0, max_iterations=30)
    )
    longer_keyframes: int = 0
    longer_path_m: float = 0.0
    pinned_degenerate: bool = False
    pinned_required: bool = False
    pinned_cross: bool = True
    compiled_icp: bool = True

    def __post_init__(self) -> None:
        expand_free_space_rule(self)
        if self.method not in ("correlative", "icp"):
            raise UserError(f"loops.check.method must be correlative or icp, got {self.method!r}")
        if self.free_space_origins not in ("keyframe", "scans"):
            raise UserError("loops.check.free_space_origins must be keyframe or scans, got "
                            f"{self.free_space_origins!r}")
        if not self.free_space_surface_cap >= 1.0:
            raise UserError("loops.check.free_space_surface_cap must be at least 1, got "
                            f"{self.free_space_surface_cap!r}")
        if not 0.0 <= self.free_space_either <= 1.0:
            raise UserError("loops.check.free_space_either must be in [0, 1], got "
                            f"{self.free_space_either!r}")
        if not self.free_space_return_window >= 0:
            raise UserError("loops.check.free_space_return_window must be at least 0, got "
                            f"{self.free_space_return_window!r}")

    @property
    def resolved_free_space_rule(self) -> str:
        """The rule the free-space keys hold (`loopclosure.free_space_rule`):
        ``"fallback"``, ``"default"`` (every key at its default) or ``"keys"``."""
        return free_space_rule_of(self)


@dataclass(slots=True)
class LoopVerification:
    """Outcome of one geometric check.

    Attributes:
        accepted: all acceptance tests passed.
        reason: ``"accepted"`` or the first test that failed.
        relative: ``(3,)`` pose of the query keyframe in the candidate's frame.
        covariance: ``3x3`` covariance of `relative` (floored).
        fitness, inlier_ratio, rms, degeneracy: of the best ICP run.
        margin: fitness of the best minus the best run at a different pose.
        hypotheses: number of ICP runs.
        consistency: free-space consistency of the two submaps at `relative`
            (`loopclosure.free_space`; NaN when not computed: a check from a prior or
            by multi-start ICP).
        conflict_ratio: fraction of both submaps' points in the other's free space.
        matched_length: length of surface the best run matched [m] (correlative
            check, `GeometricCheckConfig.min_matched_length`; NaN otherwise).
        degenerate_axis: ``(2,)`` unit direction of the best run's least translational
            information, the candidate's frame (zeros when no ICP ran).
        axis_length: length of matched surface facing `degenerate_axis` [m]
            (`axis_length`; correlative check, NaN otherwise).
        axis_hold: the hits of the free-space test with the fit slid by the search's
            ``axis_shift`` along `degenerate_axis` (the larger of the two ways) over
            the hits at the fit (`loopclosure.prior_free.axis_profile`; correlative
            check below a degeneracy bar, NaN otherwise).
        pinned_length: the surface that stops matching when the fit is so slid [m]
            (`pinned_length`; correlative check below a degeneracy bar, NaN otherwise).
        cross_hold: the hits kept when the fit slides the same distance across the
            axis (the better way) over the hits at the fit (NaN unless the check
            asked, `GeometricCheckConfig.pinned_cross`).
        rescuable: refused for its free space under the keyframe model (1) alone,
            while the scans' model passes it and every other test holds
            (`GeometricCheckConfig.free_space_fallback`).
        rescuable_far: as `rescuable`, but the fit lies beyond the revisit radius
            (`NOT_A_REVISIT` would follow): the loop detector may find the query at a
            nearer keyframe from it.
        rescue, rescue_at: a check whose fit lies beyond the revisit radius and whose
            move to the keyframe `rescue_at` nearer where it fits (the loop detector's
            nearer-place check) passes only by the scans' model, that move's or its
            own, keeps its own verdict, and here the nearer check's verdict (None,
            -1: none).
    """

    accepted: bool
    reason: str
    relative: Array
    covariance: Array
    fitness: float
    inlier_ratio: float
    rms: float
    degeneracy: float
    margin: float
    hypotheses: int
    consistency: float = float("nan")
    conflict_ratio: float = float("nan")
    matched_length: float = float("nan")
    degenerate_axis: Array = field(default_factory=lambda: np.zeros(2))
    axis_length: float = float("nan")
    axis_hold: float = float("nan")
    pinned_length: float = float("nan")
    cross_hold: float = float("nan")
    rescuable: bool = False
    rescuable_far: bool = False
    rescue: LoopVerification | None = None
    rescue_at: int = -1


def slide_anisotropy(slid_hits: ArrayLike, cross_hits: ArrayLike) -> float:
    """How much better a fit's hits hold along its weak axis than across it.

    ``slid_hits``: the free-space test's hits (`loopclosure.free_space` (2)) with the
    fit slid one ambiguity distance either way along its degenerate axis;
    ``cross_hits``: the same slides along the perpendicular axis
    (`loopclosure.prior_free.axis_profile` with each axis).  The ratio of the better
    slide's hits:

        anisotropy = max(slid_hits) / max(cross_hits)

    Above 1 when the matched surface runs along the weak axis (a corridor keeps its
    walls' hits along it and loses them across); about 1 or below when the hits are
    lost whichever way the fit moves (isolated points).  Infinite when the cross
    slides keep no hit and the axis slide keeps some; NaN without both profiles or
    with no hit kept at all.
    """
    slid = np.asarray(slid_hits, dtype=float).reshape(-1)
    cross = np.asarray(cross_hits, dtype=float).reshape(-1)
    if len(slid) == 0 or len(cross) == 0:
        return float("nan")
    a, c = slid.max(), cross.max()
    if c <= 0:
        return float("inf") if a > 0 else float("nan")
    return float(a / c)


def held_by_pin(pinned: float, slid_hits: ArrayLike, cross_hits: ArrayLike,
                cfg: GeometricCheckConfig) -> bool:
    """Whether a correlative fit below a degeneracy bar is accepted by what pins it.

    With ``pinned_degenerate``: `pinned` [m] (`pinned_length`) reaches
    ``min_matched_length`` and, with ``pinned_cross``, the slide along the weak axis
    keeps more hits than the same slide across it (`slide_anisotropy` > 1).
    """
    if not (cfg.pinned_degenerate and pinned >= cfg.min_matched_length):
        return False
    return not cfg.pinned_cross or slide_anisotropy(slid_hits, cross_hits) > 1.0


def pinned_length(hits: int, slid_hits: ArrayLike, voxel: float) -> float:
    """Length of surface that pins a fit along its weakest direction [m].

    ``hits``: the free-space test's hits at the fit (points of either submap within
    the tolerance of the other, both directions, `loopclosure.free_space` (2));
    ``slid_hits``: the same with the fit slid one ambiguity distance either way along
    its degenerate axis (`loopclosure.prior_free.axis_profile`).  The hits the better
    slide loses, each a point standing for ``voxel`` [m] of surface, halved (both
    directions count each matched stretch once per submap):

        pinned = (hits - max(slid_hits)) * voxel / 2

    A plain corridor loses only its walls' ends (the slide per wall end); a corner,
    a door jamb or a gap between walls that the other pass saw at the same place
    loses all its hits.  NaN without slid hits.
    """
    slid = np.asarray(slid_hits, dtype=float).reshape(-1)
    if len(slid) == 0:
        return float("nan")
    return float((hits - slid.max()) * voxel / 2)


def axis_length(hessian: ArrayLike, voxel: float) -> float:
    """Length of matched surface facing the fit's weakest direction [m].

    ``hessian`` is ICP's ``3x3`` data Hessian ``sum_i w_i J_i^T J_i`` of its
    point-to-line rows (``J_i = [n_i^T, n_i^T R' p_i]``, unit normals, robust weights
    ``w_i``); the translational information with the rotation marginalised (its Schur
    complement) has smallest eigenvalue ``lambda = sum_i w_i (n_i . a)^2`` along the
    weakest direction ``a``: a weighted count of matched points whose surface faces
    ``a``.  Each point stands for ``voxel`` [m] of surface (the query is voxelised so),
    so ``lambda * voxel`` is that surface's length.  Unlike the degeneracy (``lambda``
    over the trace), it does not fall when more of the other direction's walls match.
    """
    h = np.asarray(hessian, dtype=float).reshape(3, 3)
    h_tt = h[:2, :2]
    if h[2, 2] > 1e-12:
        h_tt = h_tt - np.outer(h[:2, 2], h[2, :2]) / h[2, 2]
    return float(max(np.linalg.eigvalsh(0.5 * (h_tt + h_tt.T))[0], 0.0) * voxel)


def _offset_grid(step: float) -> Array:
    if step <= 0:
        return np.zeros((0, 2))
    g = np.array([[step, 0], [-step, 0], [0, step], [0, -step]], dtype=float)
    return g


def _floored(cov: Array, floor: tuple[float, float, float]) -> Array:
    sig = np.array([floor[0], floor[1], np.radians(floor[2])])
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    floored = vecs @ np.diag(np.maximum(vals, 0.0)) @ vecs.T
    return floored + np.diag(sig**2)


def _rejected_early(reason: str, relative: Array, cfg: GeometricCheckConfig
                    ) -> LoopVerification:
    """The verdict of a check rejected before any ICP ran: `relative` (the starting
    pose) with the failed variance as its covariance, every figure 0."""
    return LoopVerification(
        accepted=False, reason=reason, relative=relative,
        covariance=_floored(FAILED_VARIANCE * np.eye(3), cfg.covariance_floor),
        fitness=0.0, inlier_ratio=0.0, rms=0.0, degeneracy=0.0, margin=0.0, hypotheses=0)


def required_margin(fitness: float, cfg: GeometricCheckConfig) -> float:
    """The fitness margin a best fit of `fitness` needs over a runner-up at another
    pose: ``min(min_fitness_margin, min_relative_margin * fitness)``."""
    return min(cfg.min_fitness_margin, cfg.min_relative_margin * fitness)


def _different(a: Array, b: Array, cfg: GeometricCheckConfig) -> bool:
    d = se2.between(a, b)
    return bool(
        np.hypot(d[0], d[1]) > cfg.ambiguity_distance
        or abs(np.degrees(d[2])) > cfg.ambiguity_angle_deg
    )


def implausible_runner_up(runner_up: Consistency, best: Consistency,
                          cfg: GeometricCheckConfig) -> bool:
    """A runner-up the free space rules out as the other answer of an ambiguity: it
    fails the consistency bar on its own, and its conflict share exceeds the best's by
    more than clutter (people, doors) may cause, the bar's own allowance
    ``1 - min_consistency``."""
    return (runner_up.consistency < cfg.min_consistency
            and best.consistency - runner_up.consistency >= 1.0 - cfg.min_consistency)


def _verify_correlative(
    query_points: ArrayLike,
    candidate: RegistrationTarget,
    headings: ArrayLike | None,
    max_distance: float | None,
    cfg: GeometricCheckConfig,
) -> LoopVerification:
    """The prior-free check by correlative search (`loopclosure.prior_free`)."""
    scans = None
    if cfg.free_space_origins == "scans":
        q_free = getattr(query_points, "free_space", None)
        c_free = candidate.derived.get(SCAN_FREE_SPACE)
        if q_free is not None and c_free is not None:
            scans = (q_free, c_free)
    multi = match_prior_free(np.asarray(query_points, dtype=float), candidate,
                             headings=headings,
                             max_distance=max_distance, source_voxel=cfg.source_voxel,
                             icp=cfg.icp, config=cfg.search, compiled=cfg.compiled_icp,
                             profile_below=max(cfg.min_degeneracy, cfg.min_degeneracy_partial),
                             cross_profile=cfg.pinned_degenerate and cfg.pinned_cross,
                             scans=scans, confirm=cfg.free_space_confirm,
                             keyframe_too=cfg.free_space_either > 0)
    if not multi.results:
        return LoopVerification(
            accepted=False, reason="registration failed", relative=np.zeros(3),
            covariance=_floored(FAILED_VARIANCE * np.eye(3), cfg.covariance_floor),
            fitness=0.0, inlier_ratio=0.0, rms=0.0, degeneracy=0.0, margin=0.0,
            hypotheses=0, consistency=0.0, conflict_ratio=0.0)
    best = multi.results[0]
    free = multi.consistency[0]
    either = bool(multi.keyframe) and cfg.free_space_either > 0
    if cfg.free_space_either > 0 and not multi.keyframe:  # no scans: (1) at the either bar
        cfg = replace(cfg, min_consistency=cfg.free_space_either)
    judged, bar_cfg = ((multi.keyframe, replace(cfg, min_consistency=cfg.free_space_either))
                       if either else (multi.consistency, cfg))
    # With the fallback, a fit only the scans' model passes is judged by every other
    # test, then refused for its free space as (1) refuses it (`free_space_fallback`).
    held_back = (either and cfg.free_space_fallback
                 and multi.keyframe[0].consistency < cfg.free_space_either
                 and free.consistency >= cfg.min_consistency)
    others = [r.fitness for r, c in zip(multi.results[1:], judged[1:], strict=True)
              if r.ok and _different(r.pose, best.pose, cfg)
              and not (cfg.plausible_runner_up and implausible_runner_up(c, judged[0], bar_cfg))]
    margin = best.fitness - (max(others) if others else 0.0)
    reason = "accepted"
    partial = best.fitness < cfg.min_fitness or best.inlier_ratio < cfg.min_inlier_ratio
    matched = best.fitness * multi.source_points * cfg.source_voxel
    pinned = pinned_length(free.hits, multi.axis_hits,
                           0.5 * (cfg.source_voxel + cfg.search.submap_voxel))
    # A fit the slide along its weak axis un-matches as much surface as the check's
    # floor is pinned there, however large its other direction's information.
    held = held_by_pin(pinned, multi.axis_hits, multi.cross_hits, cfg)
    if not best.ok:
        reason = "registration failed"
    elif matched < cfg.min_matched_length:
        reason = (f"matched {matched:.1f} m of surface < {cfg.min_matched_length} m "
                  f"(fitness {best.fitness:.3f})")
    elif free.consistency < cfg.min_consistency and not (
            either and multi.keyframe[0].consistency >= cfg.free_space_either):
        reason = f"inconsistent free space ({free.consistency:.2f} < {cfg.min_consistency})"
    elif best.rms > cfg.max_rms:
        reason = f"rms {best.rms:.3f} m > {cfg.max_rms}"
    elif best.degeneracy < cfg.min_degeneracy and not held:
        reason = f"{DEGENERATE} (corridor-like, {best.degeneracy:.3f})"
    elif partial and best.degeneracy < cfg.min_degeneracy_partial and not held:
        reason = (f"{PARTIAL_DEGENERATE} {best.fitness:.2f} and degenerate "
                  f"(corridor-like, {best.degeneracy:.3f})")
    elif (cfg.pinned_required and best.degeneracy < cfg.min_degeneracy_partial
          and not pinned >= cfg.min_matched_length):
        reason = (f"{DEGENERATE} and not pinned (corridor-like, {best.degeneracy:.3f}, "
                  f"{pinned:.1f} m pinned)")
    elif margin < required_margin(best.fitness, cfg):
        reason = f"ambiguous (fitness margin {margin:.2f})"
    elif max_distance is not None and np.hypot(best.pose[0], best.pose[1]) > max_distance:
        reason = f"{NOT_A_REVISIT} ({np.hypot(best.pose[0], best.pose[1]):.1f} m apart)"
    rescuable = held_back and reason == "accepted"
    rescuable_far = held_back and reason.startswith(NOT_A_REVISIT)
    if held_back and not matched < cfg.min_matched_length and best.ok:
        reason = (f"inconsistent free space ({multi.keyframe[0].consistency:.2f} < "
                  f"{cfg.free_space_either})" + ("; rescuable" if rescuable else ""))
    return LoopVerification(
        accepted=reason == "accepted", reason=reason,
        relative=np.asarray(best.pose, dtype=float),
        covariance=_floored(np.asarray(best.covariance, dtype=float), cfg.covariance_floor),
        fitness=float(best.fitness), inlier_ratio=float(best.inlier_ratio),
        rms=float(best.rms), degeneracy=float(best.degeneracy), margin=float(margin),
        hypotheses=len(multi.results), consistency=float(free.consistency),
        conflict_ratio=float(free.conflict_ratio), matched_length=float(matched),
        degenerate_axis=np.asarray(best.degenerate_axis, dtype=float).copy(),
        axis_length=axis_length(best.hessian, cfg.source_voxel) if best.ok else float("nan"),
        axis_hold=(float(np.max(multi.axis_hits)) / free.hits
                   if len(multi.axis_hits) and free.hits else float("nan")),
        pinned_length=pinned,
        cross_hold=(float(np.max(multi.cross_hits)) / free.hits
                    if len(multi.cross_hits) and free.hits else float("nan")),
        rescuable=rescuable, rescuable_far=rescuable_far,
    )


def verify(
    query_points: ArrayLike,
    candidate: RegistrationTarget | None,
    *,
    prior: ArrayLike | None = None,
    prior_covariance: ArrayLike | None = None,
    headings: ArrayLike | None = None,
    translation: ArrayLike | None = None,
    offsets: float | None = None,
    max_distance: float | None = None,
    config: GeometricCheckConfig | None = None,
    grid: GridTarget | None = None,
) -> LoopVerification:
    """Check that the query submap (its frame) fits the candidate's submap (see module doc).

    Args:
        query_points: ``(N, 2)`` submap of the query keyframe, in its sensor frame [m].
        candidate: the candidate keyframe's submap as a registration target (None
            when `grid` is given).
        prior: ``(3,)`` predicted pose of the query in the candidate's frame (from the
            current estimates), or None for a purely appearance-based candidate.
        prior_covariance: ``3x3`` uncertainty of `prior`; enables the prior gate.
        headings: extra absolute headings [rad] of the query in the candidate's frame
            to try (`loopclosure.headings`, e.g. FFT cross-correlation).
        translation: ``(2,)`` translation used with the extra headings when there is
            no prior (e.g. from aligning the two places' centroids).
        offsets: translation offset of the extra guesses [m] (None: the config's;
            0: none, e.g. when the prior is already good to a few centimetres).
        max_distance: a verified relative pose longer than this is not a revisit
            [m] (None: no limit).
        grid: the candidate's submap as the compiled ICP's grid
            (`loopclosure.fast_icp.GridTarget`, e.g. a lazy one kept by the caller)
            instead of `candidate`: for a check from a prior with ``compiled_icp``.

    Raises:
        UserError: `grid` for a check that needs the `RegistrationTarget`, or
            neither given.
    """
    cfg = config or GeometricCheckConfig()
    if grid is not None and (prior is None or not cfg.compiled_icp):
        raise UserError("verify: a grid serves a check from a prior with compiled ICP only")
    if grid is None and candidate is None:
        raise UserError("verify needs the candidate's target or its grid")
    if prior is None and cfg.method == "correlative":
        assert candidate is not None
        return _verify_correlative(query_points, candidate, headings, max_distance, cfg)
    base = np.zeros(3) if prior is None else np.asarray(prior, dtype=float).reshape(3)
    if prior is None and translation is not None:
        base[:2] = np.asarray(translation, dtype=float).reshape(2)
    step = cfg.offsets if offsets is None else offsets
    guesses = initial_guesses(base, headings, _offset_grid(step))
    if prior is None and translation is not None and cfg.origin_guesses:
        at_origin = initial_guesses(np.zeros(3), headings, _offset_grid(step))
        guesses = np.vstack([guesses, at_origin])
    if cfg.compiled_icp:
        from loopclosure.fast_icp import voxel_downsample_fast as voxel  # numba on first use
    else:
        voxel = voxel_downsample
    source = voxel(np.asarray(query_points, dtype=float), cfg.source_voxel)
    gated = prior is not None and prior_covariance is not None
    min_fitness = cfg.min_fitness_gated if gated else cfg.min_fitness
    min_inliers = cfg.min_inlier_ratio_gated if gated else cfg.min_inlier_ratio
    gate = cfg.icp.max_correspondence_distance
    needed = max(min_fitness, min_inliers)
    overlap = bound = np.inf  # no screen
    if cfg.compiled_icp:
        from loopclosure import fast_icp
        from loopclosure.prior_screen import screen_passes

        # Both screens in one compiled pass on the grid ICP runs on, stopped once both
        # pass (`loopclosure.prior_screen`: the verdict is known then); the
        # candidate's KD-tree is needed only when ICP runs (its prescreen of the
        # guesses).
        if grid is None:
            assert candidate is not None
            grid = fast_icp.GridTarget.from_target(candidate, fast_icp.TARGET_GRID_CELL)
        if prior is not None and (cfg.min_prior_overlap > 0 or cfg.bound_reach > 0):
            passed, overlap, bound = screen_passes(
                source, grid, guesses, gate, cfg.bound_reach,
                max(cfg.min_prior_overlap, 0.0), needed if cfg.bound_reach > 0 else 0.0)
            if passed:
                overlap = bound = np.inf
    elif prior is not None and cfg.min_prior_overlap > 0:
        assert candidate is not None
        overlap = float(overlap_scores(source, candidate, guesses, gate).max(initial=0.0))
    if prior is not None and cfg.min_prior_overlap > 0 and overlap < cfg.min_prior_overlap:
        return _rejected_early(
            f"no overlap at the prior ({overlap:.3f} < {cfg.min_prior_overlap})", base, cfg)
    if prior is not None and cfg.bound_reach > 0 and bound < needed:
        return _rejected_early(
            f"no fit within reach (overlap bound {bound:.3f} < {needed})", base, cfg)
    multi = register_multi(source, candidate, guesses, config=cfg.icp, keep=cfg.keep,
                           compiled=cfg.compiled_icp, grid=grid)
    best: IcpResult = multi.best
    others = [r.fitness for r in multi.results if r.ok and _different(r.pose, best.pose, cfg)]
    margin = best.fitness - (max(others) if others else 0.0)
    reason = "accepted"
    if not best.ok:
        reason = "registration failed"
    elif best.fitness < min_fitness:
        reason = f"fitness {best.fitness:.2f} < {min_fitness}"
    elif best.inlier_ratio < min_inliers:
        reason = f"inlier ratio {best.inlier_ratio:.2f} < {min_inliers}"
    elif best.rms > cfg.max_rms:
        reason = f"rms {best.rms:.3f} m > {cfg.max_rms}"
    elif best.degeneracy < cfg.min_degeneracy:
        reason = f"degenerate (corridor-like, {best.degeneracy:.3f})"
    elif best.fitness < cfg.min_fitness and best.degeneracy < cfg.min_degeneracy_partial:
        reason = (f"partial overlap {best.fitness:.2f} and degenerate "
                  f"(corridor-like, {best.degeneracy:.3f})")
    elif margin < required_margin(best.fitness, cfg):
        reason = f"ambiguous (fitness margin {margin:.2f})"
    elif gated:
        d = se2.between(base, best.pose)
        cov = np.asarray(prior_covariance, dtype=float) + best.covariance
        m2 = float(d @ np.linalg.solve(cov + np.eye(3) * 1e-12, d))
        if np.sqrt(max(m2, 0.0)) > cfg.max_prior_mahalanobis:
            reason = f"far from the predicted pose ({np.sqrt(m2):.1f} sigma)"
    if reason == "accepted" and max_distance is not None:
        distance = float(np.hypot(best.pose[0], best.pose[1]))
        if distance > max_distance:
            reason = f"{NOT_A_REVISIT} ({distance:.1f} m apart)"
    return LoopVerification(
        accepted=reason == "accepted",
        reason=reason,
        relative=np.asarray(best.pose, dtype=float),
        covariance=_floored(np.asarray(best.covariance, dtype=float), cfg.covariance_floor),
        fitness=float(best.fitness),
        inlier_ratio=float(best.inlier_ratio),
        rms=float(best.rms),
        degeneracy=float(best.degeneracy),
        margin=float(margin),
        hypotheses=len(multi.results),
        degenerate_axis=np.asarray(best.degenerate_axis, dtype=float).copy(),
    )
