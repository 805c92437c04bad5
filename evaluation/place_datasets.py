"""Place-recognition data sets of the benchmark: polygons grouped by place (class).

Every loader returns a `PlaceSet` ``(polygons, labels, description)``: a list of
`loopclosure.polygon.Polygon`, an ``(M,)`` array of class labels (str) in the same
order (grouped by class), and a JSON-ready dict describing what came out.  The
data-set spec of the CLI (`load_dataset`) is one of:

``box`` / ``surface``
    The simulator's Box and Surface worlds (`data.sim.place_dataset`): 11 places x
    21 scans of a 360-degree, 360-beam laser, positions drawn uniformly in a disc of
    0.3 m radius around each place centre, heading uniform in [-pi, pi) (the
    paper's Section III.A).  Polygons by `polygon_from_scan` (no-return beams at
    the laser's max range).  Units: metres, sensor frame.  Deterministic for a seed
    (same seed, same world as `simulate_run`).

``mpeg7:DIR``
    Every shape image in DIR (`data.mpeg7.load_silhouettes`: outer contour, Gaussian
    smoothing and Douglas-Peucker with 1 px): the 1,400 images of MPEG-7
    CE-Shape-1 Part B as well as the 200-image subset.  Label = file name without
    its ``-<index>`` suffix.  Units: pixels.  ``description["scale_invariant"]`` is
    True: as customary on MPEG-7 the matchers run scale invariant there.

``robot:DIR`` (or ``robot:FILE``)
    Real scans grouped by place from the GMapping-corrected CARMEN logs in DIR
    (every ``*-corrected.log.gz``; or one log file of any name).  The pose field
    of each ``FLASER`` scan is the SLAM-corrected laser pose ``(x, y, theta)`` in
    the log's map frame [m, rad]; it is the ground truth of "same place".  The
    rule, per log, with the defaults of `RobotPlacesConfig`:

    1. **Path and passes.**  ``s_i`` = path length travelled up to scan i (sum of
       the distances between consecutive scan positions) [m].  The *members* of a
       candidate centre c (the position of scan c) are the scans within
       ``radius`` = 0.5 m of it.  Members sorted by scan index form one *pass*
       while the path between consecutive members is at most ``pass_gap`` = 2 m
       (the robot did not leave the place); a longer path starts a new pass, i.e.
       the robot went away and came back.
    2. **Eligible centres.**  Scans with at least ``min_passes`` = 2 passes and
       ``min_scans`` = 5 members.
    3. **Greedy choice.**  Repeatedly the eligible candidate with the most passes
       (ties: most members, then smallest scan index) becomes a place centre when
       the headings of its members are varied (the largest angle between two
       member headings is at least ``min_heading_spread_deg`` = 45 degrees; the
       candidate is dropped otherwise); every candidate within
       ``min_separation`` = 4 m of a chosen centre stops being a candidate.  So
       centres are far apart, member discs never overlap, and each place holds
       scans of several visits.
    4. **Cap.**  A place keeps at most ``max_scans`` = 20 members: passes take
       turns (round robin, in pass order), each pass giving its scans in an order
       shuffled by the seed; the kept scans are listed in scan order.
    5. **360-degree polygons.**  A scan whose laser covers 360 degrees (`Scan.fov`)
       is used as it is.  A scan of a narrower laser (all six corrected logs: 180
       degrees) is replaced by a virtual scan
       (`loopclosure.virtual_scan.virtual_scan_from_scans`, ``beams`` = 360 over
       360 degrees, no return at ``max_range`` = 30 m) at its own corrected pose,
       ray-cast into its local map: the scans of the same log whose path position
       is within ``map_window`` = 10 m of ``s_i`` (behind and ahead on the
       robot's own path, as a SLAM front end's local map holds them).  Polygon by
       `polygon_from_scan`, in the scan's sensor frame (so heading varies); with
       ``range_cap`` (``bench places --range-cap M``) readings and open space
       farther than M are placed at M.

    Labels are ``<log>/place<k>`` (``<log>`` = file name without
    ``-corrected.log.gz``), places numbered in greedy order.  ``description["logs"]``
    reports, per log, its scans, laser field of view, places, members and passes
    per place and the heading spread.  Deterministic for a seed (only step 4 draws).

Degenerate polygons (fewer than 3 distinct vertices, zero area) are left out with
one warning that counts them; a set with fewer than two classes is a `UserError`.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from data.errors import DataError, UserError, warn
from data.types import Scan
from loopclosure.polygon import (
    DegeneratePolygonError,
    Polygon,
    PolygonConfig,
    polygon_from_scan,
)

Array = NDArray[np.float64]

DATASET_KINDS: tuple[str, ...] = ("box", "surface", "mpeg7", "robot")
"""Data-set kinds in the paper's column order."""

CORRECTED_SUFFIX = "-corrected.log.gz"


class PlaceSet(NamedTuple):
    """Polygons grouped by place: unpacks as ``polygons, labels, description``.

    Attributes:
        polygons: the shapes (sensor frame [m], or pixels for MPEG-7).
        labels: ``(M,)`` class label of each polygon (str).
        description: JSON-ready facts: ``name``, ``kind``, ``shapes``, ``classes``,
            ``class_sizes``, ``scale_invariant`` and loader-specific keys.
    """

    polygons: list[Polygon]
    labels: NDArray[np.str_]
    description: dict[str, Any]


def _finish(
    polygons: list[Polygon], labels: Sequence[str], description: dict[str, Any]
) -> PlaceSet:
    """Add the counts to `description`; fewer than two classes is a `UserError`."""
    lab = np.asarray(list(labels), dtype=str)
    counts = Counter(lab.tolist())
    if len(counts) < 2:
        raise UserError(
            f"data set {description['name']} has {len(counts)} class(es) of shapes: "
            "place recognition needs at least two"
        )
    description.update(
        shapes=len(polygons),
        classes=len(counts),
        class_sizes={k: counts[k] for k in dict.fromkeys(lab.tolist())},
    )
    return PlaceSet(polygons, lab, description)


def _polygons(items: Sequence[tuple[str, Any]], make: Any, what: str) -> tuple[list, list]:
    """``make(item)`` for each ``(label, item)``, leaving degenerate ones out (one warning)."""
    polys: list[Polygon] = []
    labels: list[str] = []
    bad: list[str] = []
    for label, item in items:
        try:
            polys.append(make(item))
        except DegeneratePolygonError as exc:
            bad.append(f"{label} ({exc})")
            continue
        labels.append(label)
    if bad:
        warn(f"{what}: left out {len(bad)} of {len(items)} degenerate shapes: "
             + ", ".join(bad[:5]) + (" ..." if len(bad) > 5 else ""))
    return polys, labels


# --------------------------------------------------------------------------- simulator


def sim_places(
    world: str, *, seed: int = 0, places: int = 11, scans_per_place: int = 21
) -> PlaceSet:
    """The simulator's Box or Surface place set (module docstring), `places` x `scans_per_place`."""
    from data.sim import place_dataset

    if seed < 0:
        raise UserError(f"seed must be >= 0, got {seed}")
    items = place_dataset(world, places=places, scans_per_place=scans_per_place, seed=seed)
    polys, labels = _polygons(items, polygon_from_scan, f"{world} (seed {seed})")
    scan = items[0][1]
    return _finish(polys, labels, {
        "name": world, "kind": world, "seed": seed, "scale_invariant": False,
        "units": "m", "beams": len(scan.ranges), "fov_deg": round(math.degrees(scan.fov), 3),
        "max_range_m": scan.max_range,
        "rule": "data.sim.place_dataset: scans in a 0.3 m disc around each place, "
                "heading uniform; polygon_from_scan",
    })


# --------------------------------------------------------------------------- MPEG-7


def mpeg7_places(folder: str | Path, *, smooth: float = 1.0) -> PlaceSet:
    """Every silhouette image of `folder` as a polygon [px], labelled by class."""
    from data.mpeg7 import load_silhouettes

    root = Path(folder)
    sils = load_silhouettes(root, smooth=smooth)
    polys, labels = _polygons([(s.label, s) for s in sils], lambda s: Polygon(s.contour),
                              str(root))
    return _finish(polys, labels, {
        "name": f"mpeg7:{root}", "kind": "mpeg7", "folder": str(root),
        "scale_invariant": True, "units": "px", "smooth_px": smooth,
        "rule": "data.mpeg7.load_silhouettes: outer contour, smoothed, Douglas-Peucker",
    })


# --------------------------------------------------------------------------- robot


@dataclass(frozen=True, slots=True)
class RobotPlacesConfig:
    """Parameters of the robot place rule (module docstring, steps 1-5).

    Attributes:
        radius: members lie within this distance of the place centre [m].
        pass_gap: path length between consecutive members that starts a new pass [m].
        min_passes: fewest passes (visits) of an accepted place.
        min_scans: fewest members of an accepted place.
        max_scans: most scans kept per place.
        min_separation: smallest distance between two place centres [m].
        min_heading_spread_deg: smallest largest-angle between member headings [deg].
        map_window: local map of a virtual scan: scans within this path length [m].
        beams: beams of a virtual scan over 360 degrees.
        max_range: no-return range of a virtual scan [m].
        link_dist: largest gap between neighbouring returns joined into a wall [m].
        range_cap: the polygon rule's range cap (`loopclosure.polygon.PolygonConfig`)
            [m]: every reading farther, and every beam without a return, is placed at
            this range, so a place is what lies within it of the sensor (None: the
            virtual scan's `max_range`, the whole local map).
    """

    radius: float = 0.5
    pass_gap: float = 2.0
    min_passes: int = 2
    min_scans: int = 5
    max_scans: int = 20
    min_separation: float = 4.0
    min_heading_spread_deg: float = 45.0
    map_window: float = 10.0
    beams: int = 360
    max_range: float = 30.0
    link_dist: float = 0.5
    range_cap: float | None = None

    def __post_init__(self) -> None:
        positive = ("radius", "pass_gap", "min_separation", "map_window", "max_range")
        positive += ("range_cap",) if self.range_cap is not None else ()
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise UserError(f"robot places: {name} must be a positive number, got {value}")
        if self.min_passes < 1 or self.min_scans < 1 or self.max_scans < self.min_scans:
            raise UserError(
                "robot places: need min_passes >= 1, min_scans >= 1 and max_scans >= min_scans"
            )
        if self.beams < 8:
            raise UserError(f"robot places: beams must be >= 8, got {self.beams}")


@dataclass(slots=True)
class RobotPlace:
    """One place of a log: its centre scan, kept member scans and counts.

    Attributes:
        centre: index (in the log's scan list) of the scan at the centre.
        members: indices of the kept scans, in scan order.
        passes: pass number (0-based) of each kept scan.
        n_members: members before the cap.
        n_passes: passes among all members.
        heading_spread_deg: largest angle between two member headings [deg].
    """

    centre: int
    members: NDArray[np.intp]
    passes: NDArray[np.intp]
    n_members: int
    n_passes: int
    heading_spread_deg: float


def path_length(poses: Array) -> Array:
    """``(N,)`` path length [m] travelled up to each pose (positions ``poses[:, :2]``).

    Steps from or to a pose with a non-finite position count as zero.
    """
    step = np.linalg.norm(np.diff(np.asarray(poses, dtype=float)[:, :2], axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(np.where(np.isfinite(step), step, 0.0))])


def _membership_counts(
    xy: Array, s: Array, radius: float, pass_gap: float, block: int = 512
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Members and passes of every candidate centre (step 1), in row blocks of the distances.

    Positions that are not finite are nobody's members (and have none).
    """
    finite = np.all(np.isfinite(xy), axis=1)
    n = len(xy)
    members = np.zeros(n, dtype=np.intp)
    passes = np.zeros(n, dtype=np.intp)
    cols = np.arange(n)
    for start in range(0, n, block):  # blocks keep memory at block x N
        rows = slice(start, min(start + block, n))
        with np.errstate(invalid="ignore"):
            inside = np.linalg.norm(xy[rows, None, :] - xy[None, :, :], axis=-1) <= radius
        inside &= finite[rows, None] & finite[None, :]
        idx = np.where(inside, cols[None, :], -1)
        last = np.maximum.accumulate(idx, axis=1)
        prev = np.concatenate([np.full((len(idx), 1), -1), last[:, :-1]], axis=1)
        gap = s[None, :] - s[np.maximum(prev, 0)]
        breaks = inside & (prev >= 0) & (gap > pass_gap)
        members[rows] = inside.sum(axis=1)
        passes[rows] = 1 + breaks.sum(axis=1)
    return members, passes


def _pass_ids(s: Array, pass_gap: float) -> NDArray[np.intp]:
    """Pass number of each member (members in scan order, path positions `s`)."""
    return np.concatenate([[0], np.cumsum(np.diff(s) > pass_gap)]).astype(np.intp)


def _heading_spread_deg(theta: Array) -> float:
    """Largest angle [deg] between two headings of `theta` [rad]."""
    d = np.angle(np.exp(1j * (theta[:, None] - theta[None, :])))
    return float(np.degrees(np.abs(d).max()))


def _capped(passes: NDArray[np.intp], cap: int, rng: np.random.Generator) -> NDArray[np.intp]:
    """Positions of at most `cap` members: passes take turns, shuffled order within a pass."""
    if len(passes) <= cap:
        return np.arange(len(passes))
    queues = [rng.permutation(np.flatnonzero(passes == p)) for p in np.unique(passes)]
    depth = max(len(q) for q in queues)
    order = [int(q[k]) for k in range(depth) for q in queues if k < len(q)]
    return np.sort(np.asarray(order[:cap], dtype=np.intp))


def choose_places(
    poses: Array, config: RobotPlacesConfig | None = None, *, seed: int = 0
) -> list[RobotPlace]:
    """Places of one log from its corrected scan poses ``(N, 3)`` (steps 1-4 of the rule).

    Poses with a non-finite component never become members or centres.
    """
    cfg = config or RobotPlacesConfig()
    p = np.asarray(poses, dtype=float).reshape(-1, 3)
    finite = np.all(np.isfinite(p), axis=1)
    xy = np.where(finite[:, None], p[:, :2], np.nan)
    s = path_length(xy)
    members, passes = _membership_counts(xy, s, cfg.radius, cfg.pass_gap)
    candidate = finite & (members >= cfg.min_scans) & (passes >= cfg.min_passes)
    rng = np.random.default_rng(seed)
    places: list[RobotPlace] = []
    order = np.lexsort((np.arange(len(p)), -members, -passes))  # best first
    order = order[candidate[order]]
    for c in order:  # one step per candidate tried; candidates are few after pruning
        if not candidate[c]:
            continue
        near = np.linalg.norm(xy - xy[c], axis=1)
        near[~finite] = np.inf
        idx = np.flatnonzero(near <= cfg.radius)
        spread = _heading_spread_deg(p[idx, 2])
        if spread < cfg.min_heading_spread_deg:
            candidate[c] = False
            continue
        pid = _pass_ids(s[idx], cfg.pass_gap)
        keep = _capped(pid, cfg.max_scans, rng)
        places.append(RobotPlace(int(c), idx[keep], pid[keep], len(idx), int(pid.max()) + 1,
                                 round(spread, 1)))
        candidate &= near > cfg.min_separation
    return places


def _polygon_360(
    scans: Sequence[Scan], poses: Array, s: Array, i: int, cfg: RobotPlacesConfig
) -> tuple[Polygon, bool]:
    """360-degree polygon of scan `i` (step 5); True when it is a virtual scan."""
    from loopclosure.virtual_scan import virtual_scan_from_scans

    scan = scans[i]
    rule = PolygonConfig() if cfg.range_cap is None else PolygonConfig(range_cap=cfg.range_cap)
    if scan.fov >= 2.0 * np.pi - 1e-6:
        return polygon_from_scan(scan, rule), False
    window = np.flatnonzero((np.abs(s - s[i]) <= cfg.map_window)
                            & np.all(np.isfinite(poses), axis=1))
    virtual = virtual_scan_from_scans(
        [scans[j] for j in window], poses[window], poses[i], beams=cfg.beams,
        max_range=cfg.max_range, link_dist=cfg.link_dist, stamp=scan.stamp, index=scan.index,
    )
    return polygon_from_scan(virtual, rule), True


def _log_name(path: Path) -> str:
    name = path.name
    return name[: -len(CORRECTED_SUFFIX)] if name.endswith(CORRECTED_SUFFIX) else path.stem


def robot_log_places(
    path: str | Path, config: RobotPlacesConfig | None = None, *, seed: int = 0
) -> tuple[list[Polygon], list[str], dict[str, Any]]:
    """Polygons, labels and per-log facts of one corrected CARMEN log (module docstring)."""
    from data.carmen import CarmenLog

    cfg = config or RobotPlacesConfig()
    path = Path(path)
    scans = list(CarmenLog(path))
    if not scans:
        raise DataError(path, "no laser scans")
    if any(sc.odom is None for sc in scans):
        raise DataError(path, "laser scans without a pose: not a corrected log")
    poses = np.array([sc.odom for sc in scans], dtype=float)
    s = path_length(poses)
    places = choose_places(poses, cfg, seed=seed)
    name = _log_name(path)
    polys: list[Polygon] = []
    labels: list[str] = []
    virtual = 0
    dropped = 0
    kept_sizes: list[int] = []
    for k, place in enumerate(places):  # one step per place; each polygon is vectorised
        label = f"{name}/place{k:02d}"
        before = len(polys)
        for i in place.members:
            try:
                poly, was_virtual = _polygon_360(scans, poses, s, int(i), cfg)
            except DegeneratePolygonError:
                dropped += 1
                continue
            polys.append(poly)
            labels.append(label)
            virtual += was_virtual
        kept_sizes.append(len(polys) - before)
    if dropped:
        warn(f"{path}: left out {dropped} degenerate place polygons")
    facts = {
        "file": str(path),
        "scans": len(scans),
        "beams": len(scans[0].ranges),
        "fov_deg": round(math.degrees(scans[0].fov), 3),
        "path_m": round(float(s[-1]), 1),
        "places": len(places),
        "shapes": len(polys),
        "virtual_scans": virtual,
        "scans_per_place": kept_sizes,
        "members_per_place": [pl.n_members for pl in places],
        "passes_per_place": [pl.n_passes for pl in places],
        "heading_spread_deg": [pl.heading_spread_deg for pl in places],
        "centres_xy_m": [[round(float(v), 3) for v in poses[pl.centre, :2]] for pl in places],
    }
    return polys, labels, facts


def robot_places(
    source: str | Path, config: RobotPlacesConfig | None = None, *, seed: int = 0
) -> PlaceSet:
    """Robot place set of every ``*-corrected.log.gz`` in a folder, or of one log file."""
    cfg = config or RobotPlacesConfig()
    root = Path(source)
    if not root.exists():
        raise DataError(root, "no such folder or file")
    if root.is_dir():
        logs = sorted(root.glob(f"*{CORRECTED_SUFFIX}"))
        if not logs:
            raise DataError(root, f"no corrected CARMEN logs (*{CORRECTED_SUFFIX}) in the folder")
    else:
        logs = [root]
    polys: list[Polygon] = []
    labels: list[str] = []
    facts: dict[str, Any] = {}
    for log in logs:  # one step per log file
        p, lab, f = robot_log_places(log, cfg, seed=seed)
        polys += p
        labels += lab
        facts[_log_name(log)] = f
    if not polys:
        raise DataError(root, "no place passed several times with enough scans "
                        f"(rule: {cfg.min_scans}+ scans within {cfg.radius} m, "
                        f"{cfg.min_passes}+ passes)")
    return _finish(polys, labels, {
        "name": f"robot:{root}", "kind": "robot", "source": str(root), "seed": seed,
        "scale_invariant": False, "units": "m", "config": asdict(cfg), "logs": facts,
        "rule": "evaluation.place_datasets (robot): greedy place centres over corrected "
                "poses, scans within radius from several passes, 360-degree virtual scans",
    })


# --------------------------------------------------------------------------- dispatch


def dataset_kind(spec: str) -> str:
    """The kind (``box``, ``surface``, ``mpeg7``, ``robot``) of a data-set spec."""
    kind = spec.split(":", 1)[0].strip().lower()
    if kind not in DATASET_KINDS:
        raise UserError(
            f"unknown data set {spec!r}: choose box, surface, mpeg7:DIR or robot:DIR"
        )
    return kind


def load_dataset(
    spec: str, *, seed: int = 0, robot: RobotPlacesConfig | None = None
) -> PlaceSet:
    """The data set named by a CLI spec: ``box``, ``surface``, ``mpeg7:DIR``, ``robot:DIR``."""
    kind = dataset_kind(spec)
    arg = spec.split(":", 1)[1].strip() if ":" in spec else ""
    if kind in ("box", "surface"):
        if arg:
            raise UserError(f"data set {kind} takes no folder, got {spec!r}")
        return sim_places(kind, seed=seed)
    if not arg:
        raise UserError(f"data set {kind} needs a folder: {kind}:DIR")
    if kind == "mpeg7":
        return mpeg7_places(arg)
    return robot_places(arg, robot, seed=seed)


__all__ = [
    "DATASET_KINDS",
    "PlaceSet",
    "RobotPlace",
    "RobotPlacesConfig",
    "choose_places",
    "dataset_kind",
    "load_dataset",
    "mpeg7_places",
    "path_length",
    "robot_log_places",
    "robot_places",
    "sim_places",
]
