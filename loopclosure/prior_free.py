"""The search of the prior-free geometric check: correlative matching, then ICP from its peaks.

A place-database candidate has no pose prior, only heading hypotheses
(`loopclosure.headings`' convention: the heading of the query in the candidate's
frame).  `match_prior_free` finds the pose of the query submap (its sensor frame)
in the candidate's submap (the candidate's sensor frame) in three steps:

1. **Coarse lattice** (`loopclosure.correlative`): the query, voxelised to
   `coarse_voxel` [m], scored (mean likelihood, `loopclosure.correlative` (1), on
   the candidate's grid of width `coarse_sigma` [m]) at every pose of a lattice:
   translations every ``coarse_step_cells * grid_resolution`` [m] within `radius` of
   0 (a revisit's sensor is within the loop detector's ``max_distance`` of the
   candidate's: the caller passes ``max_distance``, the square's half side is that
   plus `radius_margin`), headings every `coarse_angle_step_deg` within
   `angle_window_deg` of each hypothesis and, with `opposite_headings`, of each
   hypothesis plus pi (a corridor or a room seen in the other direction correlates
   at both; the whole circle without hypotheses).
   Its `coarse_peaks` best distinct poses (more than `peak_separation` [m] or
   `peak_separation_deg` apart, `loopclosure.correlative.peaks`) seed
2. **a fine lattice** about each: the query voxelised to `fine_voxel`, on the grid
   of width `grid_sigma`, translations every grid cell within one coarse step,
   headings every `angle_step_deg` within one coarse heading step.  The best fine
   pose of each seed, distinct ones only, best first: at most `refine` of them,
   those after the first only when they score at least `refine_ratio` of it.
   The likelihood grids (one Euclidean distance transform) are built once per
   registration target and cached on it (`RegistrationTarget.derived`); the
   query's voxelised points and free-space submap are kept for the next candidate
   of the same query (`_QueryProducts`: the loop detector checks several in a row).
3. **ICP** (`loopclosure.registration.register`, point to line, initial gate
   `icp_gate`, at most `icp_iterations`) of the query voxelised to the check's
   ``source_voxel`` from each of those poses; and the free-space
   consistency of the two submaps at each ICP pose (`loopclosure.free_space` (2):
   free space about each submap's sensor origin (1) or, given ``scans``, about each
   of their scans' own origins (1')).

The caller (`loopclosure.geometric_check`) applies the acceptance rule to the
runs; they are returned best first by ICP fitness (ties: lower rms; failed runs
last), as `loopclosure.multi_start` ranks them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data import se2
from loopclosure.free_space import Consistency, ScanFreeSpace, Submap, consistency
from loopclosure.registration import (
    IcpConfig,
    IcpResult,
    RegistrationTarget,
    as_points,
    register,
    voxel_downsample,
)

Array = NDArray[np.float64]


@dataclass(slots=True)
class PriorFreeConfig:
    """Parameters of the prior-free search (module docstring).

    Attributes:
        angle_window_deg: headings searched within this of each hypothesis [deg].
        coarse_angle_step_deg: heading step of the coarse lattice [deg].
        opposite_headings: also search about each hypothesis plus pi.
        angle_step_deg: heading step of the fine lattice [deg].
        radius: half side of the translation square without a ``max_distance`` [m].
        radius_margin: the square's half side is ``max_distance`` plus this [m].
        grid_resolution: cell of the likelihood grids [m].
        coarse_sigma: width of the coarse grid's truncated quadratic [m].
        grid_sigma: width of the fine grid's truncated quadratic [m].
        coarse_step_cells: translation step of the coarse lattice, in grid cells.
        coarse_voxel: voxel of the query points on the coarse lattice [m].
        coarse_peaks: coarse poses that seed a fine lattice.
        fine_voxel: voxel of the query points on the fine lattice [m].
        refine: fine poses at most refined by ICP ...
        refine_ratio: ... the best one, and the others scoring at least this fraction
            of its fine score (a runner-up far below cannot make it ambiguous).
        icp_gate: initial correspondence gate of the ICP from a fine pose [m].
        icp_iterations: ICP iterations at most.
        peak_separation: poses closer than this are one [m] ...
        peak_separation_deg: ... and closer than this in heading [deg].
        consistency_tolerance: a point this close to the other submap is a hit [m].
        free_margin: free space ends this far before an observed range [m].
        free_bins: bearing sectors of the free-space model.
        submap_voxel: voxel of the candidate's points in the consistency test [m].
        axis_shift: slide of the best run along its degenerate axis in `axis_profile`
            [m]: the check's ``ambiguity_distance``, beyond which a pose is another
            answer.
    """

    angle_window_deg: float = 10.0
    coarse_angle_step_deg: float = 3.0
    opposite_headings: bool = True
    angle_step_deg: float = 1.0
    radius: float = 2.4
    radius_margin: float = 0.4
    grid_resolution: float = 0.1
    coarse_sigma: float = 0.6
    grid_sigma: float = 0.3
    coarse_step_cells: int = 4
    coarse_voxel: float = 0.4
    coarse_peaks: int = 4
    fine_voxel: float = 0.2
    refine: int = 2
    refine_ratio: float = 0.8
    icp_gate: float = 0.3
    icp_iterations: int = 15
    peak_separation: float = 0.5
    peak_separation_deg: float = 10.0
    consistency_tolerance: float = 0.1
    free_margin: float = 0.3
    free_bins: int = 720
    submap_voxel: float = 0.1
    axis_shift: float = 0.5


@dataclass(slots=True)
class PriorFreeMatch:
    """The runs of `match_prior_free`, best first.

    Attributes:
        results: ICP from each lattice peak (pose of the query in the candidate frame).
        consistency: free-space consistency at each run's pose.
        peak_scores: ``(k,)`` fine lattice score of each run's start.
        source_points: points of the query given to ICP (voxelised to the check's
            ``source_voxel``): a run's fitness times this is its matched point count.
        axis_hits: ``(2,)`` hits of (2) (`loopclosure.free_space`) with the best run's
            pose moved by ``-axis_shift`` and ``+axis_shift`` [m] along its degenerate
            axis (`axis_profile`; empty when the best run failed); at the pose itself
            they are ``consistency[0].hits``.
        cross_hits: ``(2,)`` the same with the pose moved across that axis (along its
            perpendicular, the best-constrained direction; `axis_profile`); empty
            unless asked (``cross_profile``).
        keyframe: with ``keyframe_too``, each run's consistency with the free space
            about each submap's origin (1), in the order of `consistency` (empty
            otherwise).
    """

    results: list[IcpResult] = field(default_factory=list)
    consistency: list[Consistency] = field(default_factory=list)
    peak_scores: Array = field(default_factory=lambda: np.zeros(0))
    source_points: int = 0
    axis_hits: NDArray[np.intp] = field(default_factory=lambda: np.zeros(0, np.intp))
    cross_hits: NDArray[np.intp] = field(default_factory=lambda: np.zeros(0, np.intp))
    keyframe: list[Consistency] = field(default_factory=list)


def axis_profile(query: Submap, candidate: Submap, pose: ArrayLike, axis: ArrayLike,
                 shift: float, tolerance: float, margin: float) -> NDArray[np.intp]:
    """``(2,)`` hits of the fit slid along its weakest direction.

    The hits of `loopclosure.free_space` (2) (points within `tolerance` [m] of the
    other submap, both directions) at `pose` (query in the candidate's frame) moved by
    ``-shift`` and ``+shift`` [m] along the unit `axis` (candidate frame).  Against
    the hits at `pose` itself: about as many where the submaps match as well one slide
    away (nothing pins the position along the axis; a plain corridor loses only its
    walls' ends), fewer by the surface that crosses the axis (a corner, a door jamb,
    an end wall, a gap between walls) and holds the fit where it is.
    """
    t = np.asarray(pose, dtype=float).reshape(3)
    a = np.asarray(axis, dtype=float).reshape(2)
    moved = np.repeat(t[None], 2, axis=0)
    moved[:, :2] += np.outer([-shift, shift], a)
    return np.array([consistency(query, candidate, m, tolerance, margin).hits
                     for m in moved], dtype=np.intp)


def _cached(target: RegistrationTarget, key: tuple, make):
    if key not in target.derived:
        target.derived[key] = make()
    return target.derived[key]


class _QueryProducts:
    """What `match_prior_free` derives from the query alone (its voxelised points,
    its free-space submap), kept for the last query seen: the loop detector checks
    one query against several candidates in a row.  Each product is a deterministic
    function of the query's coordinates and the product's parameters, so a product
    made for an equal query is the one a fresh call would make."""

    def __init__(self) -> None:
        self._last: tuple[Array, dict] = (np.zeros((0, 2)), {})

    def products(self, query: Array) -> dict:
        """The products' dict of `query` (``(N, 2)`` [m]): the last one when its
        coordinates are equal, else a new empty one."""
        points, products = self._last  # one read: another thread may replace it
        if points.shape == query.shape and np.array_equal(points, query):
            return products
        products = {}
        # A copy: a caller may change its array in place before the next call.
        self._last = (query.copy(), products)
        return products

    def get(self, query: Array, key: tuple, make):
        """The product `key` of `query`, made by ``make()`` when not yet made."""
        products = self.products(query)
        if key not in products:
            products[key] = make()
        return products[key]


_QUERY = _QueryProducts()


def _two_level(query: Array, candidate: RegistrationTarget, angles: Array, radius: float,
               cfg: PriorFreeConfig) -> tuple[Array, Array]:
    """Lattice peaks ``(k, 3)`` and their fine scores ``(k,)``, best first: the coarse
    lattice over the whole window, then a fine lattice about each coarse peak."""
    from loopclosure import correlative

    coarse_grid, fine_grid = _cached(
        candidate, ("likelihood", cfg.grid_resolution, cfg.coarse_sigma, cfg.grid_sigma),
        lambda: correlative.LikelihoodGrid.widths(candidate.points, cfg.grid_resolution,
                                                  (cfg.coarse_sigma, cfg.grid_sigma)))
    coarse = correlative.search(
        _QUERY.get(query, ("voxel", cfg.coarse_voxel),
                   lambda: voxel_downsample(query, cfg.coarse_voxel)),
        coarse_grid, angles, radius, cfg.coarse_step_cells)
    seeds, _ = correlative.peaks(coarse, cfg.coarse_peaks, cfg.peak_separation,
                                 np.radians(cfg.peak_separation_deg))
    fine_points = _QUERY.get(query, ("voxel", cfg.fine_voxel),
                             lambda: voxel_downsample(query, cfg.fine_voxel))
    coarse_step = cfg.coarse_step_cells * cfg.grid_resolution
    poses, scores = [], []
    for seed in seeds:  # a few seeds: one compiled call each
        fine_angles = correlative.search_angles(
            [seed[2]], np.radians(cfg.coarse_angle_step_deg), np.radians(cfg.angle_step_deg))
        fine = correlative.search(fine_points, fine_grid, fine_angles, coarse_step, 1,
                                  centre=seed[:2])
        flat = int(np.argmax(fine.scores))  # the best pose: `peaks` with count 1
        poses.append(fine.pose(flat))
        scores.append(float(fine.scores.ravel()[flat]))
    if not poses:
        return np.zeros((0, 3)), np.zeros(0)
    order = np.argsort(-np.asarray(scores), kind="stable")
    out_p: list[Array] = []
    out_s: list[float] = []
    for i in order:  # distinct fine peaks, best first
        p = poses[i]
        if all(np.hypot(*(p[:2] - q[:2])) > cfg.peak_separation
               or abs(se2.wrap_angle(p[2] - q[2])) > np.radians(cfg.peak_separation_deg)
               for q in out_p):
            out_p.append(p)
            out_s.append(scores[i])
    return np.array(out_p)[: cfg.refine], np.array(out_s)[: cfg.refine]


def _rank(r: IcpResult) -> tuple:
    return (not r.ok, -round(r.fitness, 9), r.rms)


def match_prior_free(
    query_points: ArrayLike,
    candidate: RegistrationTarget,
    *,
    headings: ArrayLike | None,
    max_distance: float | None,
    source_voxel: float,
    icp: IcpConfig,
    config: PriorFreeConfig | None = None,
    compiled: bool = False,
    profile_below: float = 1.0,
    cross_profile: bool = False,
    scans: tuple[ScanFreeSpace, ScanFreeSpace] | None = None,
    confirm: bool = False,
    keyframe_too: bool = False,
) -> PriorFreeMatch:
    """Search, peaks, ICP and consistency (module docstring).

    Args:
        query_points: ``(N, 2)`` query submap [m], query sensor frame.
        candidate: the candidate's submap as a registration target (candidate frame).
        headings: ``(H,)`` heading hypotheses [rad], or None (the whole circle).
        max_distance: the loop detector's revisit radius [m] (None: `radius`).
        source_voxel: voxel of the query points given to ICP [m].
        icp: ICP parameters.
        config: the search's parameters (default `PriorFreeConfig()`).
        compiled: ICP by `loopclosure.fast_icp.register_target` (the same maths,
            numba) instead of `loopclosure.registration.register`.
        profile_below: the best run's `axis_profile` only when its degeneracy is
            below this (the default: always; the check asks below its bars only).
        cross_profile: with the axis profile, the same slides across the axis
            (`PriorFreeMatch.cross_hits`).
        scans: the free space of the query's and the candidate's scans, each about
            its own sensor (`loopclosure.free_space` (1'); their submaps' frames),
            instead of (1) about the submaps' origins.
        confirm: with `scans`, a point is free only where (1) about the submap's
            origin calls it free as well (`loopclosure.free_space` (5)).
        keyframe_too: with `scans`, also each run's consistency under (1)
            (`PriorFreeMatch.keyframe`).

    Returns:
        The runs, best first; none when either submap is empty or nothing scores.
    """
    from loopclosure import correlative  # compiled kernel: numba loads on first use

    cfg = config or PriorFreeConfig()
    query = as_points(query_points, "query points")
    # Nothing ICP can match (`RegistrationTarget.tree` is None exactly then), asked
    # without building the KD-tree: the compiled ICP and the free-space test use none.
    if len(query) == 0 or len(candidate) == 0:
        return PriorFreeMatch()
    if headings is None or len(np.atleast_1d(headings)) == 0:
        angles = correlative.search_angles([0.0], np.pi, np.radians(cfg.coarse_angle_step_deg))
    else:
        if cfg.opposite_headings:
            h = np.atleast_1d(np.asarray(headings, dtype=float))
            headings = np.concatenate([h, h + np.pi])
        angles = correlative.search_angles(headings, np.radians(cfg.angle_window_deg),
                                           np.radians(cfg.coarse_angle_step_deg))
    radius = cfg.radius if max_distance is None else max_distance + cfg.radius_margin
    starts, scores = _two_level(query, candidate, angles, radius, cfg)
    keep = (scores > 0) & (scores >= cfg.refine_ratio * scores[:1].max(initial=0.0))
    starts, scores = starts[keep], scores[keep]
    if len(starts) == 0:
        return PriorFreeMatch()
    source = _QUERY.get(query, ("voxel", source_voxel),
                        lambda: voxel_downsample(query, source_voxel))
    icp = dataclasses.replace(icp, max_correspondence_distance=cfg.icp_gate,
                              max_iterations=cfg.icp_iterations)
    if compiled:
        from loopclosure import fast_icp  # numba, as the correlative kernel

        results = fast_icp.register_target(source, candidate, starts, config=icp)
    else:
        results = [register(source, candidate, s, config=icp) for s in starts]
    order = sorted(range(len(results)), key=lambda i: _rank(results[i]))
    q_scans, c_scans = (None, None) if scans is None else scans
    confirm = confirm and c_scans is not None
    key = (("free", cfg.submap_voxel, cfg.free_bins) + (() if c_scans is None else ("scans",))
           + (("confirm",) if confirm else ()))
    cand_submap = _cached(
        candidate, key,
        lambda: Submap.of(voxel_downsample(candidate.points, cfg.submap_voxel), cfg.free_bins,
                          scans=c_scans, confirm=confirm))
    query_submap = _QUERY.get(query, ("free", source_voxel, cfg.free_bins, q_scans, confirm),
                              lambda: Submap.of(source, cfg.free_bins, scans=q_scans,
                                                confirm=confirm))
    figures = [consistency(query_submap, cand_submap, results[i].pose,
                           cfg.consistency_tolerance, cfg.free_margin) for i in order]
    best = results[order[0]]
    profiled = best.ok and best.degeneracy < profile_below
    axis = np.asarray(best.degenerate_axis, dtype=float).reshape(2)
    hits, cross = (
        axis_profile(query_submap, cand_submap, best.pose, a, cfg.axis_shift,
                     cfg.consistency_tolerance, cfg.free_margin)
        if profiled and ask else np.zeros(0, np.intp)
        for a, ask in ((axis, True), (np.array([-axis[1], axis[0]]), cross_profile)))
    keyframe = []
    if keyframe_too and c_scans is not None:
        plain_c = _cached(candidate, ("free", cfg.submap_voxel, cfg.free_bins),
                          lambda: Submap.of(voxel_downsample(candidate.points, cfg.submap_voxel),
                                            cfg.free_bins))
        plain_q = _QUERY.get(query, ("free", source_voxel, cfg.free_bins, None, False),
                             lambda: Submap.of(source, cfg.free_bins))
        keyframe = [consistency(plain_q, plain_c, results[i].pose, cfg.consistency_tolerance,
                                cfg.free_margin) for i in order]
    return PriorFreeMatch([results[i] for i in order], figures, scores[order], len(source),
                          hits, cross, keyframe)
