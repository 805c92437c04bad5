"""A library of known objects as stripe descriptors, and recognition against it.

Building (`ObjectLibrary.build`): every known object is scanned by the same push-broom
laser as the robot's (`sensor`), in controlled straight passes: the robot drives along
+x at the world speed and scan rate while the object rests beside its path at a known
pose: `yaws` (object yaw relative to the direction of travel) times `offsets` (lateral
distance, left and right).  Each pass goes through the mapper's own segmentation
(`segmentation.segment`), so library stripes are made exactly as the stripes seen in
the world; the largest accepted cluster of the pass is the entry.  An entry keeps the
stripe descriptor (`loopclosure.stripes.describe_stripes`), and the offset from the
centroid of the seen points to the object's true footprint centre, in the travel
frame (x along travel, y left): the seen points are only the sides facing the laser,
so their centroid is biased towards the robot; the offset removes that bias when the
object is recognised (`Recognition.centre_offset`).

Recognition (`ObjectLibrary.recognise`), retrieval by stripes then verification:

1. The cluster's descriptor is compared with every entry by the vectorised
   `StripeDatabase` (Eq. 4-6, lambda = 0.6, 0.3, 0.1); per object the distance is that
   of its nearest entry.
2. With ``d1`` the nearest object's distance and ``d2`` the nearest *other* object's,
   the stripes accept the match when

       d1 <= max_distance   and   d1 <= max_ratio * d2

   (an absolute test against objects in no library entry, and Lowe's ratio test
   against look-alikes).
3. Size verification (an addition to the paper, whose descriptor is blind to absolute
   size: ``l`` is normalised per object and trimming equalises stripe counts): the
   cluster's height (98th percentile of its point heights; yaw-independent for an
   object resting on the floor) must be within `max_height_diff` of the matched
   entry's, and its stripe count (the object's length along the direction of travel)
   within a factor `min_count_ratio` of that entry's.  A match that fails is rejected,
   never re-assigned: the stripes decide *which* object, the size only vetoes.

The defaults were chosen on library passes and distractor objects of seeds not used
for the reported figures (see the benchmark's report).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np
from numpy.typing import NDArray

from data.errors import DataError, UserError
from data.stripe_scanner.meshes import Mesh
from loopclosure.stripes import StripeDatabase, StripeDescriptor, describe_stripes
from slam.landmarks.segmentation import (
    ObjectCluster,
    SegmentationConfig,
    cluster_stripes,
    segment,
)
from slam.landmarks.sensor import PushBroomLaser, candidate_scans, cast, place_object

Array = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class RecognitionConfig:
    """Acceptance test of a recognition (module docstring).

    Attributes:
        max_distance: largest Eq. 5 distance to the nearest object.
        max_ratio: largest ratio of the nearest to the second nearest other object.
        max_height_diff: size verification: largest height difference [m].
        min_count_ratio: size verification: smallest ratio of stripe counts
            (smaller / larger).
    """

    max_distance: float = 0.05
    max_ratio: float = 0.7
    max_height_diff: float = 0.005
    min_count_ratio: float = 0.7

    def to_json(self) -> dict[str, float]:
        """Plain dict of the parameters."""
        return asdict(self)


@dataclass(frozen=True, slots=True)
class LibraryConfig:
    """How the library passes are made.

    Attributes:
        yaws_deg: object yaws relative to the direction of travel [deg].
        offsets: lateral distances of the object from the robot's path [m] (both sides).
        speed: robot speed during the pass [m/s] (the world's speed: same stripe spacing).
    """

    yaws_deg: tuple[float, ...] = (0.0, 45.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0)
    offsets: tuple[float, ...] = (0.33,)
    speed: float = 0.5

    def to_json(self) -> dict[str, object]:
        """Plain dict of the parameters."""
        return asdict(self)


@dataclass(slots=True)
class LibraryEntry:
    """One library pass: object, its pose relative to the pass, descriptor, centre offset,
    and the size-verification figures (height [m], stripe count)."""

    identity: int
    yaw: float
    lateral: float
    descriptor: StripeDescriptor
    centre_offset: Array
    height: float
    stripes: int


@dataclass(slots=True)
class Recognition:
    """Outcome of matching one cluster against the library.

    Attributes:
        identity: nearest library object (index), whether accepted or not.
        name, label: its name and class.
        distance: Eq. 5 distance to its nearest entry (``d1``).
        second: distance to the nearest entry of another object (``d2``; inf if none).
        accepted: the acceptance test passed.
        entry: index of the nearest entry.
        centre_offset: that entry's centroid-to-centre offset (travel frame) [m].
        size_verified: the size verification's verdict (None: not checked).
    """

    identity: int
    name: str
    label: str
    distance: float
    second: float
    accepted: bool
    entry: int
    centre_offset: Array
    size_verified: bool | None = None

    @property
    def ratio(self) -> float:
        """``d1 / d2`` (0 when d2 is infinite)."""
        return float(self.distance / self.second) if np.isfinite(self.second) else 0.0


def pass_poses(laser: PushBroomLaser, speed: float, length: float) -> Array:
    """``(S, 3)`` robot poses of a straight pass along +x from ``-length`` to ``+0.3`` m."""
    spacing = speed / laser.rate_hz
    xs = np.arange(-length, 0.3, spacing)
    return np.column_stack([xs, np.zeros_like(xs), np.zeros_like(xs)])


def scan_pass(
    laser: PushBroomLaser,
    mesh: Mesh,
    yaw: float,
    lateral: float,
    speed: float,
    seg: SegmentationConfig,
    rng: np.random.Generator,
) -> tuple[ObjectCluster, Array]:
    """Scan `mesh` at ``(0, lateral, yaw)`` from a straight pass; its cluster and the
    offset (travel frame) from the cluster's centroid to the object's centre.

    Raises:
        DataError: the pass gives no accepted object cluster.
    """
    obj = place_object(mesh, (0.0, lateral, yaw))
    poses = pass_poses(laser, speed, laser.reach + obj.radius + 0.1)
    keep = np.flatnonzero(candidate_scans(laser, poses, [obj])[:, 0])
    if len(keep) == 0:
        raise DataError(mesh.name, "never under the laser's fan in a library pass")
    ranges, _ = cast(laser, poses[keep], [obj], rng)
    clusters = [c for c in segment(laser, keep, ranges, poses[keep], seg) if not c.rejected]
    if not clusters:
        raise DataError(mesh.name, f"no object cluster in the library pass at yaw "
                        f"{np.degrees(yaw):.0f} deg, lateral {lateral:+.2f} m")
    best = max(clusters, key=lambda c: len(c.scans))
    return best, obj.pose[:2] - best.centroid


@dataclass(slots=True)
class ObjectLibrary:
    """Known objects and their stripe descriptors from library passes (module docstring)."""

    names: list[str]
    labels: list[str]
    entries: list[LibraryEntry]
    recognition: RecognitionConfig = field(default_factory=RecognitionConfig)
    resolution: float = 0.002
    database: StripeDatabase = field(init=False)
    _owner: NDArray[np.intp] = field(init=False)

    def __post_init__(self) -> None:
        if not self.entries:
            raise UserError("the object library has no entry")
        self.database = StripeDatabase([e.descriptor for e in self.entries])
        self._owner = np.array([e.identity for e in self.entries], dtype=np.intp)

    @classmethod
    def build(
        cls,
        meshes: Sequence[Mesh],
        labels: Sequence[str],
        laser: PushBroomLaser,
        config: LibraryConfig | None = None,
        segmentation: SegmentationConfig | None = None,
        recognition: RecognitionConfig | None = None,
        seed: int = 0,
        progress: Callable[[str, int, int], None] | None = None,
    ) -> ObjectLibrary:
        """Scan every mesh at every library yaw and offset (both sides) and describe it."""
        cfg = config or LibraryConfig()
        seg = segmentation or SegmentationConfig()
        rng = np.random.default_rng(seed)
        entries: list[LibraryEntry] = []
        poses = [(np.deg2rad(y), side * off) for y in cfg.yaws_deg for off in cfg.offsets
                 for side in (1.0, -1.0)]
        total = len(meshes) * len(poses)
        for i, mesh in enumerate(meshes):
            for j, (yaw, lateral) in enumerate(poses):
                cluster, offset = scan_pass(laser, mesh, yaw, lateral, cfg.speed, seg, rng)
                desc = describe_stripes(cluster_stripes(cluster, seg.resolution),
                                        name=f"{mesh.name}@{np.degrees(yaw):.0f}")
                entries.append(LibraryEntry(i, float(yaw), float(lateral), desc, offset,
                                            cluster_height(cluster), len(cluster.scans)))
                if progress is not None:
                    progress("library", i * len(poses) + j + 1, total)
        return cls([m.name for m in meshes], list(labels), entries,
                   recognition or RecognitionConfig(), seg.resolution)

    def __len__(self) -> int:
        return len(self.names)

    def size_ok(self, entry: int, height: float, stripes: int) -> bool:
        """Step 3: does a cluster of this height [m] and stripe count fit `entry`'s size?"""
        rc = self.recognition
        e = self.entries[entry]
        ratio = min(e.stripes, stripes) / max(e.stripes, stripes, 1)
        return abs(e.height - height) <= rc.max_height_diff and ratio >= rc.min_count_ratio

    def object_distances(self, descriptor: StripeDescriptor) -> tuple[Array, NDArray[np.intp]]:
        """Per library object: distance of its nearest entry, and that entry's index."""
        d = self.database.distances(descriptor)
        best = np.full(len(self.names), np.inf)
        np.minimum.at(best, self._owner, d)
        order = np.lexsort((d, self._owner))  # by object, then distance
        first = np.r_[True, self._owner[order][1:] != self._owner[order][:-1]]
        entry = np.full(len(self.names), -1, dtype=np.intp)
        entry[self._owner[order][first]] = order[first]
        return best, entry

    def recognise_descriptor(
        self, descriptor: StripeDescriptor, height: float | None = None,
        stripes: int | None = None,
    ) -> Recognition:
        """Steps 1-3 of the module docstring (step 3 skipped when height / stripes are None)."""
        best, entry = self.object_distances(descriptor)
        o1 = int(np.argmin(best))
        d1 = float(best[o1])
        others = np.delete(best, o1)
        d2 = float(others.min()) if len(others) else float("inf")
        rc = self.recognition
        e = int(entry[o1])
        accepted = d1 <= rc.max_distance and (not np.isfinite(d2) or d1 <= rc.max_ratio * d2)
        verified = None
        if height is not None and stripes is not None:
            verified = self.size_ok(e, height, stripes)
            accepted = accepted and verified
        return Recognition(o1, self.names[o1], self.labels[o1], d1, d2, bool(accepted), e,
                           self.entries[e].centre_offset.copy(), verified)

    def recognise(self, cluster: ObjectCluster) -> Recognition:
        """Recognise an object cluster (stripes retrieval, acceptance tests, size check)."""
        return self.recognise_descriptor(self.describe(cluster), cluster_height(cluster),
                                         len(cluster.scans))

    def describe(self, cluster: ObjectCluster) -> StripeDescriptor:
        """Stripe descriptor of a cluster, made as the library's own."""
        return describe_stripes(cluster_stripes(cluster, self.resolution))


def cluster_height(cluster: ObjectCluster) -> float:
    """Height of a cluster [m]: 98th percentile of its point heights (robust to noise)."""
    return float(np.percentile(cluster.points_odom[:, 2], 98.0))
