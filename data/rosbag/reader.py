"""`RosBag`: a ROS1 / ROS2 bag as a stream of scans or point clouds, odometry attached.

Chooses the scan and odometry topics, decodes the messages of one pass over the
storage backend (`data.rosbag.backends`), converts them (`data.rosbag.messages`),
attaches odometry (`data.rosbag.odom_sync`) and reports recoverable trouble as one
warning.  The rules are in the `data.rosbag` docstring.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from data.errors import DataError, warn
from data.progress import ReadProgress
from data.rosbag.backends import describe, open_backend
from data.rosbag.messages import (
    LASERSCAN,
    ODOMETRY,
    POINTCLOUD2,
    TF_TYPES,
    BadMessage,
    laserscan_to_scan,
    pointcloud2_xyz,
    stamp_of,
)
from data.rosbag.odom_sync import OdomSync
from data.types import PointCloud, Scan, SourceInfo


def _listing(topics: dict[str, str]) -> str:
    """``/scan (sensor_msgs/msg/LaserScan), ...`` or a note that there are none."""
    if not topics:
        return "the bag has no topics"
    return "topics: " + ", ".join(f"{t} ({ty})" for t, ty in sorted(topics.items()))


class RosBag:
    """A ROS1 / ROS2 bag as a stream of `Scan` (LaserScan) or `PointCloud` (PointCloud2).

    Args:
        path: ROS1 ``.bag`` file, ROS2 bag directory (with ``metadata.yaml``), or a
            ``.db3`` / ``.mcap`` file.
        topic: scan topic; by default the only LaserScan topic (else the only
            PointCloud2 topic).
        odom_topic: ``nav_msgs/Odometry`` (or tf) topic for the scan poses; by default
            the only Odometry topic, else the ``odom -> base_link`` transforms on /tf.
        strict: turn recoverable problems (unusable index, undecodable messages) into
            `DataError`.

    Attributes:
        path: the path given.
        format: ``"ros1"``, ``"ros2-sqlite3"`` or ``"ros2-mcap"``.
        topic: the scan topic read; `msgtype` its type (``sensor_msgs/msg/...``).
        topics: ``{topic: msgtype}`` of the whole bag.
    """

    def __init__(self, path: str | Path, *, topic: str | None = None,
                 odom_topic: str | None = None, strict: bool = False) -> None:
        self.path = Path(path)
        self.strict = strict
        self._backend, self.recovered = open_backend(self.path, strict)
        self.format = self._backend.format
        self.topics = dict(self._backend.topics)
        try:
            self.topic = self._choose_topic(topic)
            self.msgtype = self.topics[self.topic]
            if self._backend.counts.get(self.topic, 0) == 0:
                raise DataError(self.path, f"topic {self.topic} has no messages (empty bag)")
        except DataError as exc:
            damage = getattr(self._backend, "damage", None)
            if damage is not None and damage.describe():  # say why topics may be missing
                raise DataError(self.path, f"{exc.message} (note: {damage.describe()})") from None
            raise
        self._odom_mode, self._odom_topics, self._static_topics = self._choose_odometry(
            odom_topic)
        self._progress = ReadProgress(self._backend.counts.get(self.topic, 0), "scans")

    def progress(self) -> ReadProgress:
        """How far the latest iteration has read: messages of the scan topic, of the
        count in the bag's index (nothing is read to know the total), and the scans
        yielded."""
        return self._progress

    # -- topic choice
    def _choose_topic(self, topic: str | None) -> str:
        topics = self.topics
        if topic is not None:
            if topic not in topics:
                alt = [t for t in topics if t.lstrip("/") == topic.lstrip("/")]
                if len(alt) != 1:
                    raise DataError(self.path, f"topic {topic} not found; {_listing(topics)}")
                topic = alt[0]
            if topics[topic] not in (LASERSCAN, POINTCLOUD2):
                raise DataError(self.path, f"topic {topic} has type {topics[topic]}, expected "
                                           f"{LASERSCAN} or {POINTCLOUD2}")
            return topic
        lasers = sorted(t for t, ty in topics.items() if ty == LASERSCAN)
        clouds = sorted(t for t, ty in topics.items() if ty == POINTCLOUD2)
        candidates = lasers or clouds
        if not candidates:
            raise DataError(self.path, f"no {LASERSCAN} or {POINTCLOUD2} topic; "
                                       f"{_listing(topics)}")
        if len(candidates) > 1:
            kind = LASERSCAN if lasers else POINTCLOUD2
            raise DataError(self.path, f"several {kind} topics ({', '.join(candidates)}); "
                                       "choose one with --topic")
        return candidates[0]

    def _choose_odometry(self, odom_topic: str | None) -> tuple[str | None, list[str], list[str]]:
        topics = self.topics
        static = sorted(t for t, ty in topics.items() if ty in TF_TYPES
                        and t.rstrip("/").endswith("tf_static"))
        tf = sorted(t for t, ty in topics.items() if ty in TF_TYPES and t not in static)
        odoms = sorted(t for t, ty in topics.items()
                       if ty == ODOMETRY and self._backend.counts.get(t, 0) > 0)
        if odom_topic is not None:
            if odom_topic not in topics:
                raise DataError(self.path, f"odometry topic {odom_topic} not found; "
                                           f"{_listing(topics)}")
            kind = topics[odom_topic]
            if kind == ODOMETRY:
                return "odom", [odom_topic, *([] if static else tf)], static
            if kind in TF_TYPES:
                return "tf", [odom_topic], static
            raise DataError(self.path, f"odometry topic {odom_topic} has type {kind}, expected "
                                       f"{ODOMETRY} or {TF_TYPES[0]}")
        if len(odoms) == 1:
            return "odom", [odoms[0], *([] if static else tf)], static
        if len(odoms) > 1:
            warn(f"{self.path}: several {ODOMETRY} topics ({', '.join(odoms)}); pass an "
                 f"odometry topic to use one; {'using /tf' if tf else 'scans get no odometry'}")
        if tf:
            return "tf", tf, static
        return None, [], []

    # -- reading
    def _decoded(self, topics: set[str], problems: Counter[str]) -> Iterator[tuple[str, Any]]:
        """``(topic, message)``; message None when it could not be decoded (counted)."""
        backend = self._backend
        for name, msgtype, raw in backend.messages(topics):
            try:
                msg = backend.decode(raw, msgtype)
            except Exception as exc:  # rosbags raises several kinds
                if self.strict:
                    raise DataError(self.path, f"undecodable {msgtype} message on {name}: "
                                               f"{describe(exc)}") from None
                problems[f"undecodable {msgtype} messages on {name}"] += 1
                msg = None
            yield name, msg

    def __iter__(self) -> Iterator[Scan | PointCloud]:
        """Scans (or clouds) of the chosen topic in bag order, odometry attached."""
        sync = OdomSync(self._odom_mode, planar=self.msgtype == LASERSCAN)
        problems: Counter[str] = Counter()
        dropped = dense_lies = 0
        odom_msgs = self._odom_topics[0] if self._odom_mode == "odom" else None
        wanted = {self.topic, *self._odom_topics, *self._static_topics}
        index = -1
        progress = self._progress
        progress.start()
        for name, msg in self._decoded(wanted, problems):
            if name == self.topic:
                index += 1  # position of the message on its topic, undecodable ones included
                progress.done = index + 1
                if msg is None:
                    continue
                try:
                    if self.msgtype == LASERSCAN:
                        item: Scan | PointCloud = laserscan_to_scan(msg, index)
                    else:
                        pts, bad = pointcloud2_xyz(msg)
                        if bad and msg.is_dense:
                            dense_lies += 1
                            dropped += bad
                        item = PointCloud(stamp=stamp_of(msg.header), points=pts, index=index)
                except (BadMessage, AttributeError, ValueError, TypeError) as exc:
                    if self.strict:
                        raise DataError(self.path, f"message {index} on {name}: "
                                                   f"{describe(exc)}") from None
                    problems[f"unusable messages on {name}"] += 1
                    continue
                for ready in sync.push(item, msg.header.frame_id):
                    progress.scans += 1
                    yield ready
                continue
            if msg is None:
                continue
            try:
                if name == odom_msgs:
                    sync.add_odometry(msg)
                else:
                    sync.add_tf(msg, static=name in self._static_topics)
            except (BadMessage, AttributeError) as exc:
                problems[f"unusable odometry messages on {name} ({describe(exc)})"] += 1
            for ready in sync.ready():
                progress.scans += 1
                yield ready
        for ready in sync.finish():
            progress.scans += 1
            yield ready
        progress.finish()
        self._report(sync, problems, dropped, dense_lies)

    def _report(self, sync: OdomSync, problems: Counter[str], dropped: int,
                dense_lies: int) -> None:
        notes = [f"{n} {what}" for what, n in problems.items()]
        if sync.no_odom:
            notes.append(f"{sync.no_odom} scans got no odometry (no odom -> base sample found)")
        if sync.outside:
            notes.append(f"{sync.outside} scans lie outside the odometry time span and took "
                         "the nearest odometry pose")
        if sync.missing_chain:
            notes.append(f"no transform from {sync.base_frame} to sensor frame(s) "
                         f"{', '.join(sorted(sync.missing_chain))}: the base pose is used")
        if dense_lies:  # non-finite points in clouds not marked dense are expected
            notes.append(f"{dense_lies} clouds marked is_dense held non-finite points "
                         f"({dropped} dropped)")
        if notes:
            warn(f"{self.path}: " + "; ".join(notes))

    def info(self) -> SourceInfo:
        """Counts and sensor description; reads the scan topic (and tf) once.

        `scans` counts the messages of the scan topic; `beams`, `fov_deg` and
        `max_range` describe its first message; `duration_s` is the span of the header
        stamps of its first and last messages; `odometry` counts Odometry messages (or
        ``odom -> base`` transforms on /tf); `topics` lists the whole bag.
        """
        first = last = None
        count = odometry = 0
        tf_topics = set(self._odom_topics) if self._odom_mode == "tf" else set()
        sync = OdomSync(self._odom_mode)
        backend = self._backend
        for name, msgtype, raw in backend.messages({self.topic} | tf_topics):
            if name == self.topic:
                count += 1
                if first is None:
                    first = (raw, msgtype)
                last = (raw, msgtype)
                continue
            try:
                odometry += sync.add_tf(backend.decode(raw, msgtype), static=False)
            except Exception:  # info counts what it can decode; iterating reports the rest
                continue
        if self._odom_mode == "odom":
            odometry = self._backend.counts.get(self._odom_topics[0], 0)
        info = SourceInfo(format=self.format, path=str(self.path), scans=count,
                          odometry=odometry, topics=dict(sorted(self.topics.items())))
        info.extra.update({
            "scan_topic": self.topic,
            "scan_type": self.msgtype,
            "odometry_source": self._odom_topics[0] if self._odom_mode else None,
            "ros_version": self._backend.version,
        })
        if self.recovered:
            info.extra["recovered"] = self.recovered
        items = [self._convert_quietly(x) for x in (first, last) if x is not None]
        if items and items[0] is not None:
            head = items[0]
            if isinstance(head, Scan):
                info.beams = len(head.ranges)
                info.fov_deg = float(np.degrees(head.fov))
                info.max_range = float(head.max_range)
            else:
                info.extra["points"] = len(head.points)
            if items[-1] is not None:
                info.duration_s = float(items[-1].stamp - head.stamp)
        return info

    def _convert_quietly(self, item: tuple[bytes, str]) -> Scan | PointCloud | None:
        try:
            msg = self._backend.decode(item[0], item[1])
            if self.msgtype == LASERSCAN:
                return laserscan_to_scan(msg)
            return PointCloud(stamp=stamp_of(msg.header), points=pointcloud2_xyz(msg)[0])
        except Exception:  # info leaves the sensor fields empty
            return None
