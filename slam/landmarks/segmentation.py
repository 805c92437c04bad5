"""Object clusters from push-broom scans: points above the floor, runs, tracks, stripes.

The mapper's segmentation, run on what the robot knows: ranges, the sensor mount
(`sensor.PushBroomLaser`) and the odometry pose of every scan.

1. Points above the floor (`scan_runs`): every return is put in the robot frame; a
   point more than `min_height` above the floor plane ``z = 0`` is an object point
   (the floor is flat and the mount is fixed, so no plane fit is needed).
2. Runs inside a scan: consecutive object points along the beam order, split where
   more than `max_beam_gap` beams are missing or where two neighbours are more than
   `max_jump` apart in 3D (vectorised over all scans at once).
3. Tracks across scans (`segment`): each run's centroid is put in the odometry frame;
   a run joins the open track whose last centroid is nearest, if within
   `link_distance` (several runs of one scan joining one track form one stripe); other
   runs open new tracks; a track closes when `max_scan_gap` scans pass without a run.
   The loop is over scans (inner work vectorised), as the scanner's loop over laser
   positions.
4. A closed track is an object cluster if it has at least `min_stripes` stripes, a
   footprint no wider than `max_extent`, is no taller than `max_height` (walls,
   furniture and people are not objects), and never touches the fan's first or last
   beam (an object cut by the edge of the fan is only partly seen).
5. Its stripes (`cluster_stripes`): one per scan, in scan order; each stripe is the
   profile of the object in that scan, ``u`` = lateral position along the scan line
   (robot y) and ``v`` = height, quantised to `resolution` by
   `loopclosure.stripes.stripes_from_points` (scan rank as the slice coordinate, so
   each scan is exactly one slice).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np
from numpy.typing import NDArray

from loopclosure.stripes import stripes_from_points
from slam.landmarks.sensor import PushBroomLaser

Array = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class SegmentationConfig:
    """Parameters of the segmentation (module docstring), metres unless stated.

    Attributes:
        min_height: object points are this far above the floor.
        max_beam_gap: missing beams allowed inside a run.
        max_jump: largest 3D step between neighbouring points of a run.
        link_distance: largest odometry-frame distance between the centroids of a track's
            last run and a new run.
        max_scan_gap: scans without a run before a track closes.
        min_stripes: fewest stripes of an object cluster.
        max_extent: largest footprint diagonal of an object cluster.
        max_height: tallest object cluster.
        resolution: stripe unit (the descriptor's "pixel").
    """

    min_height: float = 0.008
    max_beam_gap: int = 3
    max_jump: float = 0.03
    link_distance: float = 0.06
    max_scan_gap: int = 4
    min_stripes: int = 8
    max_extent: float = 0.40
    max_height: float = 0.40
    resolution: float = 0.002

    def to_json(self) -> dict[str, float | int]:
        """Plain dict of the parameters."""
        return asdict(self)


@dataclass(slots=True)
class Runs:
    """Runs of object points of many scans (flat arrays, run-major).

    Attributes:
        scan: ``(R,)`` position (into the scans given) of each run's scan.
        start: ``(R + 1,)`` offsets of each run's points in the point arrays.
        beam: ``(P,)`` beam index of each point.
        local: ``(P, 3)`` robot-frame point [m].
    """

    scan: NDArray[np.intp]
    start: NDArray[np.intp]
    beam: NDArray[np.intp]
    local: Array

    def __len__(self) -> int:
        return len(self.scan)


def scan_runs(laser: PushBroomLaser, ranges: Array, config: SegmentationConfig) -> Runs:
    """Runs of points above the floor in every scan of ``ranges`` ``(S, B)`` (steps 1-2)."""
    pts, ok = laser.points(np.asarray(ranges, dtype=float).reshape(-1, laser.beams))
    above = ok & (pts[..., 2] > config.min_height)
    si, bi = np.nonzero(above)  # scan-major, beams increasing
    p = pts[si, bi]
    if len(si) == 0:
        e = np.zeros(0, dtype=np.intp)
        return Runs(e, np.zeros(1, dtype=np.intp), e, np.zeros((0, 3)))
    new = np.ones(len(si), dtype=bool)
    new[1:] = (
        (si[1:] != si[:-1])
        | (bi[1:] - bi[:-1] > config.max_beam_gap + 1)
        | (np.linalg.norm(p[1:] - p[:-1], axis=1) > config.max_jump)
    )
    starts = np.flatnonzero(new)
    return Runs(si[starts], np.append(starts, len(si)).astype(np.intp), bi, p)


@dataclass(slots=True)
class ObjectCluster:
    """One object seen in one pass of the fan.

    Attributes:
        scans: ``(N,)`` indices (into the scans given to `segment`) of its stripes' scans.
        stripe_points: per stripe, ``(H, 3)`` robot-frame points [m] of that scan.
        stripe_beams: per stripe, ``(H,)`` beam indices of the points.
        points_odom: ``(P, 3)`` all points, xy in the odometry frame, z height [m].
        rejected: why the track is not an object cluster ("" when it is).
    """

    scans: NDArray[np.intp]
    stripe_points: list[Array]
    stripe_beams: list[NDArray[np.intp]]
    points_odom: Array
    rejected: str = ""
    extra: dict[str, float] = field(default_factory=dict)

    @property
    def centroid(self) -> Array:
        """``(2,)`` mean xy of its points in the odometry frame [m]."""
        return self.points_odom[:, :2].mean(axis=0)

    @property
    def middle_scan(self) -> int:
        """Index of the scan in the middle of the pass."""
        return int(self.scans[len(self.scans) // 2])


def _to_odom(poses: Array, local: Array) -> Array:
    """Robot-frame points ``(P, 3)`` with per-point poses ``(P, 3)`` -> odometry xy + z."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    x = poses[:, 0] + c * local[:, 0] - s * local[:, 1]
    y = poses[:, 1] + s * local[:, 0] + c * local[:, 1]
    return np.column_stack([x, y, local[:, 2]])


def segment(
    laser: PushBroomLaser,
    scan_ids: NDArray[np.integer],
    ranges: Array,
    odom: Array,
    config: SegmentationConfig | None = None,
) -> list[ObjectCluster]:
    """Object clusters (and rejected tracks, flagged) of a sequence of scans.

    Args:
        laser: the sensor and its mount.
        scan_ids: ``(S,)`` increasing global scan numbers (gaps: scans not given,
            which saw only the floor).
        ranges: ``(S, B)`` ranges [m] (0 = no return).
        odom: ``(S, 3)`` odometry pose of the robot at each scan.
        config: parameters.

    Returns every closed track in the order it closed; object clusters have
    ``rejected == ""``.
    """
    cfg = config or SegmentationConfig()
    ids = np.asarray(scan_ids, dtype=np.int64)
    odom = np.asarray(odom, dtype=float).reshape(-1, 3)
    runs = scan_runs(laser, ranges, cfg)
    if len(runs) == 0:
        return []
    counts = np.diff(runs.start)
    owner_scan = np.repeat(runs.scan, counts)
    world = _to_odom(odom[owner_scan], runs.local)
    cent = np.add.reduceat(world[:, :2], runs.start[:-1], axis=0) / counts[:, None]
    run_bounds = np.flatnonzero(np.diff(runs.scan)) + 1
    groups = np.split(np.arange(len(runs)), run_bounds)
    open_tracks: list[dict] = []
    closed: list[dict] = []
    for g in groups:  # one group = the runs of one scan
        s = int(runs.scan[g[0]])
        sid = int(ids[s])
        still = []
        for tr in open_tracks:
            (still if sid - tr["last_id"] <= cfg.max_scan_gap else closed).append(tr)
        open_tracks = still
        joined: dict[int, list[int]] = {}
        if open_tracks:
            last = np.array([tr["last_centroid"] for tr in open_tracks])
            d = np.linalg.norm(cent[g][:, None, :] - last[None, :, :], axis=2)
            best = np.argmin(d, axis=1)
            for r, (b, db) in enumerate(zip(best, d[np.arange(len(g)), best], strict=True)):
                if db <= cfg.link_distance:
                    joined.setdefault(int(b), []).append(int(g[r]))
                else:
                    open_tracks.append({"runs": [[int(g[r])]], "scans": [s], "last_id": sid,
                                        "last_centroid": cent[g[r]]})
        else:
            for r in g:
                open_tracks.append({"runs": [[int(r)]], "scans": [s], "last_id": sid,
                                    "last_centroid": cent[r]})
        for b, rs in joined.items():
            tr = open_tracks[b]
            tr["runs"].append(rs)
            tr["scans"].append(s)
            tr["last_id"] = sid
            tr["last_centroid"] = cent[rs].mean(axis=0)
    closed.extend(open_tracks)
    return [_cluster(tr, runs, world, laser, cfg) for tr in closed]


def _cluster(
    track: dict, runs: Runs, world: Array, laser: PushBroomLaser, cfg: SegmentationConfig
) -> ObjectCluster:
    """The `ObjectCluster` of a closed track, with the acceptance tests of step 4."""
    pts, beams, odo = [], [], []
    for rs in track["runs"]:
        idx = np.concatenate([np.arange(runs.start[r], runs.start[r + 1]) for r in rs])
        idx = idx[np.argsort(runs.beam[idx], kind="stable")]
        pts.append(runs.local[idx])
        beams.append(runs.beam[idx])
        odo.append(world[idx])
    points_odom = np.concatenate(odo)
    cluster = ObjectCluster(np.array(track["scans"], dtype=np.intp), pts, beams, points_odom)
    span = points_odom[:, :2].max(axis=0) - points_odom[:, :2].min(axis=0)
    extent = float(np.hypot(*span))
    height = float(points_odom[:, 2].max())
    cluster.extra = {"extent_m": extent, "height_m": height}
    all_beams = np.concatenate(beams)
    if len(pts) < cfg.min_stripes:
        cluster.rejected = f"{len(pts)} stripes (< {cfg.min_stripes})"
    elif extent > cfg.max_extent:
        cluster.rejected = f"footprint {extent:.2f} m (> {cfg.max_extent})"
    elif height > cfg.max_height:
        cluster.rejected = f"height {height:.2f} m (> {cfg.max_height})"
    elif all_beams.min() == 0 or all_beams.max() == laser.beams - 1:
        cluster.rejected = "cut by the edge of the fan"
    return cluster


def cluster_stripes(cluster: ObjectCluster, resolution: float = 0.002) -> list[Array]:
    """The cluster's ordered stripes ``(H, 2)`` = (lateral, -height) in `resolution` units."""
    pseudo = np.concatenate([
        np.column_stack([np.full(len(p), k + 0.5), p[:, 1], p[:, 2]])
        for k, p in enumerate(cluster.stripe_points)
    ])
    return stripes_from_points(pseudo, spacing=1.0, normal=(1.0, 0.0, 0.0), up=(0.0, 0.0, 1.0),
                               resolution=resolution)

