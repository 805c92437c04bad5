"""Read ROS bags as scans: ROS1 (v2.0 and the older V1.2) and ROS2 (sqlite3, MCAP).

`RosBag(path)` is a `data.sources.ScanSource`.  It yields one `Scan` per
``sensor_msgs/LaserScan`` message, or one `PointCloud` per ``sensor_msgs/PointCloud2``
message, of a single topic, streaming (one message decoded at a time), in bag order.

Units and frames:

- ``Scan.stamp`` / ``PointCloud.stamp`` [s] come from the message header,
  ``(sec * 10**9 + nanosec) / 10**9`` (one correctly rounded float64 division, no
  intermediate float product).
- ``Scan.ranges`` [m] are the raw float32 readings as float64; ``Scan.angles`` [rad]
  are ``angle_min + i * angle_increment`` in the sensor frame (``header.frame_id``),
  reversed together with the ranges when the increment is negative so that angles
  increase.  ``max_range = range_max``, ``min_range = range_min`` [m].
- ``PointCloud.points`` [m] are the finite x, y, z of the cloud in its header frame.
- ``odom`` is the pose of the *sensor* in the odometry frame at the scan stamp:
  ``(x, y, yaw)`` [m, m, rad] for scans, a ``4x4`` matrix for clouds, or None when
  the bag has no odometry.  It is ``T_odom_base(stamp) * T_base_sensor``, where
  ``T_odom_base`` comes from a ``nav_msgs/Odometry`` topic or from the ``odom ->
  base_link`` (or ``base_footprint``) transforms on ``/tf``, interpolated at the scan
  stamp (linear in translation, shortest arc / slerp in rotation; stamps outside the
  odometry span take the nearest end pose), and ``T_base_sensor`` is the chain of
  ``/tf_static`` (or other ``/tf``) transforms from the base frame to the sensor
  frame (identity when absent; with an Odometry topic, /tf is only consulted for
  this chain when the bag has no /tf_static).  Scans are buffered until an odometry
  sample at or after their stamp arrives (or the bag ends) and handed out in batches
  of up to 64, so the stream stays in bag order with bounded memory.

Reading paths: ROS2 bags go through ``rosbags.highlevel.AnyReader`` (a directory with
``metadata.yaml``, or a single ``.db3`` / ``.mcap`` file; a file with ``metadata.yaml``
beside it is read through its directory).  ROS1 v2.0 bags go through
``rosbags.rosbag1.Reader`` (the index); when the index cannot be used (inconsistent
index records, unindexed or truncated bag) the bag is read sequentially, record by
record (format spec: wiki.ros.org/Bags/Format/2.0), with one warning.  ROS bag V1.2
files (wiki.ros.org/Bags/Format/1.2), which rosbags refuses, are read sequentially
the same way.  ROS1 messages are decoded with ``Typestore.deserialize_ros1`` (types
from the bag's own message definitions, falling back to the ROS1 Noetic types), ROS2
messages with ``deserialize_cdr``.

Bad input (missing path, not a bag, truncated or empty bag, wrong topic) raises
`DataError` naming the file; no rosbags exception escapes.  Recoverable trouble
(index fallback, undecodable messages) warns once with counts; ``strict=True``
turns it into `DataError`.
"""

from __future__ import annotations

import bisect
import bz2
import functools
import math
import struct
import zlib
from collections import Counter, deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.typing import NDArray

from data import se2
from data.errors import DataError, warn
from data.types import PointCloud, Scan, SourceInfo

Array = NDArray[np.float64]

LASERSCAN = "sensor_msgs/msg/LaserScan"
POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
BASE_FRAMES = ("base_link", "base_footprint")

_ROS1_MAGIC = b"#ROSBAG V"
_ROS1_OLD_MAGIC = b"#ROSRECORD V"
_ROSLOG_MAGIC = b"#ROSLOG V"
_SQLITE_MAGIC = b"SQLite format 3\x00"
_MCAP_MAGIC = b"\x89MCAP0\r\n"

_U32 = struct.Struct("<I")
_MAX_HEADER = 1 << 24  # sanity bound on one record header [bytes]
_KEEP_ODOM_S = 1.0  # odometry history kept behind the last scan handed out [s]
_MAX_PENDING = 2000  # scans buffered at most while waiting for odometry
_BATCH = 64  # scans given their odometry pose together


class _BadMessage(Exception):
    """A message that decodes but cannot be turned into a scan (internal)."""


# --------------------------------------------------------------------------- sniffing


def is_rosbag(path: str | Path) -> bool:
    """Cheap sniff: a ROS1 bag (any version), a sqlite3 / MCAP file or a ROS2 bag folder.

    Never raises: an unreadable or missing path is simply not a bag.
    """
    path = Path(path)
    try:
        if path.is_dir():
            return (path / "metadata.yaml").is_file()
        with path.open("rb") as f:
            magic = f.read(16)
    except OSError:
        return False
    return magic.startswith((_ROS1_MAGIC, _ROS1_OLD_MAGIC, _ROSLOG_MAGIC, _SQLITE_MAGIC,
                             _MCAP_MAGIC))


# --------------------------------------------------------------------------- backends


@dataclass
class _Conn:
    """One ROS1 connection: topic, ROS2-style type name, definition text, md5."""

    topic: str
    msgtype: str
    msgdef: str = ""
    md5: str = ""


@functools.lru_cache(maxsize=256)
def _normalize_type(name: str) -> str:
    """``pkg/Type`` -> ``pkg/msg/Type`` (rosbags' ROS2-style names)."""
    from rosbags.typesys.msg import normalize_msgtype

    return normalize_msgtype(name)


def _ros1_typestore(conns: Iterable[_Conn]) -> Any:
    """ROS1 Noetic types plus the types the bag defines that Noetic lacks."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    extra: dict[str, Any] = {}
    for conn in conns:
        if conn.msgtype in store.fielddefs or not conn.msgdef:
            continue
        try:
            typs = get_types_from_msg(conn.msgdef, conn.msgtype)
        except Exception:  # a broken definition only makes that type undecodable
            continue
        extra.update({k: v for k, v in typs.items() if k not in store.fielddefs})
    if extra:
        try:
            store.register(extra)
        except Exception:  # same: those messages count as undecodable
            pass
    return store


class _Backend:
    """Topics of a bag and a raw message stream; `decode` turns bytes into messages."""

    format: str = "ros1"
    version: str = ""
    topics: dict[str, str]
    counts: dict[str, int]

    def messages(self, topics: set[str]) -> Iterator[tuple[str, str, bytes]]:
        """``(topic, msgtype, rawdata)`` of the given topics, in bag order."""
        raise NotImplementedError

    def decode(self, raw: bytes | memoryview, msgtype: str) -> Any:
        """Deserialised message (raises on failure)."""
        raise NotImplementedError


class _Ros2Backend(_Backend):
    """ROS2 bag (sqlite3 or MCAP) through ``rosbags.highlevel.AnyReader``."""

    def __init__(self, path: Path, shown: Path) -> None:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        self.path, self.shown = path, shown
        for db in [path] if path.is_file() else sorted(path.glob("*.db3")):
            if db.suffix == ".db3":
                _check_sqlite_complete(db, shown)
        self._default = get_typestore(Stores.ROS2_HUMBLE)
        # Opening costs rosbags a metadata parse and type compilation, so the reader
        # opened here is kept for the first pass over the messages.
        self._spare: Any = None
        reader = AnyReader([path], default_typestore=self._default)
        try:
            reader.open()
            self.typestore = reader.typestore
            self.topics = {name: info.msgtype or "" for name, info in reader.topics.items()}
            self.counts = {name: info.msgcount for name, info in reader.topics.items()}
            self.format = _ros2_format(reader)
        except Exception as exc:  # any rosbags failure is a bad bag
            _close_quietly(reader)
            raise DataError(shown, f"cannot read ROS2 bag: {_describe(exc)}") from None
        self._spare = reader
        self.version = "2"

    def messages(self, topics: set[str]) -> Iterator[tuple[str, str, bytes]]:
        from rosbags.highlevel import AnyReader

        reader, self._spare = self._spare, None
        try:
            if reader is None:
                reader = AnyReader([self.path], default_typestore=self._default)
                reader.open()
            conns = [c for c in reader.connections if c.topic in topics]
            if conns:
                for conn, _, raw in reader.messages(connections=conns):
                    yield conn.topic, conn.msgtype, raw
        except Exception as exc:
            raise DataError(self.shown, f"cannot read ROS2 bag: {_describe(exc)}") from None
        finally:
            _close_quietly(reader)

    def __del__(self) -> None:
        _close_quietly(getattr(self, "_spare", None))

    def decode(self, raw: bytes | memoryview, msgtype: str) -> Any:
        return self.typestore.deserialize_cdr(raw, msgtype)


def _check_sqlite_complete(db: Path, shown: Path) -> None:
    """Refuse a truncated sqlite3 file: sqlite reads its missing pages as zeros, which
    would pass silently altered messages on.

    The file header (sqlite.org/fileformat.html) holds the page size (offset 16, 2
    bytes big-endian, 1 meaning 65536) and the database size in pages (offset 28, 4
    bytes, valid when the change counter at 24 equals the version-valid-for number
    at 92); the file must be at least that long.
    """
    try:
        size = db.stat().st_size
        with db.open("rb") as f:
            header = f.read(100)
    except OSError as exc:
        raise DataError(shown, f"cannot open {db.name}: {exc.strerror or exc}") from None
    if len(header) < 100:
        raise DataError(shown, f"{db.name}: truncated sqlite3 database ({size} bytes)")
    page = int.from_bytes(header[16:18], "big")
    page = 65536 if page == 1 else page
    pages = int.from_bytes(header[28:32], "big")
    if header[24:28] == header[92:96] and size < page * pages:
        raise DataError(
            shown, f"{db.name}: truncated sqlite3 database ({size} of {page * pages} bytes)"
        )


def _close_quietly(reader: Any) -> None:
    """Close an AnyReader if it is open, ignoring errors (cleanup path)."""
    if reader is not None and getattr(reader, "stack", None) is not None:
        try:
            reader.close()
        except Exception:  # nothing useful to do while cleaning up
            pass


def _ros2_format(reader: Any) -> str:
    """``ros2-mcap`` or ``ros2-sqlite3`` from the storage plugin AnyReader opened."""
    from rosbags.rosbag2.storage_mcap import McapReader

    storage = reader.readers[0].storage
    parts = getattr(storage, "storages", None) or [storage]
    return "ros2-mcap" if isinstance(parts[0], McapReader) else "ros2-sqlite3"


class _Ros1IndexedBackend(_Backend):
    """ROS1 v2.0 bag read through its index (``rosbags.rosbag1.Reader``)."""

    def __init__(self, path: Path) -> None:
        from rosbags.rosbag1 import Reader

        self.path = path
        self.version = "2.0"
        with Reader(path) as reader:  # any exception: caller falls back to sequential reading
            conns = [_Conn(c.topic, c.msgtype, c.msgdef.data, c.digest) for c in reader.connections]
            self.topics = {name: info.msgtype or "" for name, info in reader.topics.items()}
            self.counts = {name: info.msgcount for name, info in reader.topics.items()}
        self.typestore = _ros1_typestore(conns)

    def messages(self, topics: set[str]) -> Iterator[tuple[str, str, bytes]]:
        from rosbags.rosbag1 import Reader

        try:
            with Reader(self.path) as reader:
                conns = [c for c in reader.connections if c.topic in topics]
                if not conns:
                    return
                for conn, _, raw in reader.messages(connections=conns):
                    yield conn.topic, conn.msgtype, raw
        except Exception as exc:
            raise DataError(self.path, f"cannot read ROS1 bag: {_describe(exc)}") from None

    def decode(self, raw: bytes | memoryview, msgtype: str) -> Any:
        return self.typestore.deserialize_ros1(raw, msgtype)


# ----------------------------------------------------- sequential ROS1 record reader


@dataclass
class _Damage:
    """What the sequential reader had to work around."""

    bad_lengths: int = 0  # index / chunk-info records whose data_len contradicts their count
    truncated_at: int | None = None  # byte offset of the record the file ends in
    malformed_at: int | None = None  # byte offset of an unparseable record
    bad_chunks: int = 0  # chunks that failed to decompress or hold a broken record
    orphans: int = 0  # messages of a connection never defined

    def describe(self) -> str:
        """Human summary, empty when nothing was wrong."""
        parts = []
        if self.bad_lengths:
            parts.append(f"{self.bad_lengths} index record(s) declare inconsistent lengths")
        if self.truncated_at is not None:
            parts.append(f"the file is truncated (it ends inside the record at byte "
                         f"{self.truncated_at})")
        if self.malformed_at is not None:
            parts.append(f"unreadable record at byte {self.malformed_at}; "
                         "nothing after it was read")
        if self.bad_chunks:
            parts.append(f"{self.bad_chunks} damaged chunk(s) read only in part")
        if self.orphans:
            parts.append(f"{self.orphans} message(s) of undefined connections skipped")
        return "; ".join(parts)


def _parse_fields(buf: bytes | memoryview) -> dict[str, bytes] | None:
    """``name=value`` fields, each prefixed by its uint32 length (None when malformed)."""
    fields: dict[str, bytes] = {}
    pos, size = 0, len(buf)
    while pos < size:
        if pos + 4 > size:
            return None
        (length,) = _U32.unpack_from(buf, pos)
        pos += 4
        if length > size - pos:
            return None
        name, sep, value = bytes(buf[pos : pos + length]).partition(b"=")
        if not sep:
            return None
        fields[name.decode("latin-1")] = value
        pos += length
    return fields


def _parse_header(buf: bytes | memoryview) -> dict[str, bytes] | None:
    """Fields of a record header, which must hold a one-byte ``op``."""
    fields = _parse_fields(buf)
    if fields is None or len(fields.get("op", b"")) != 1:
        return None
    return fields


def _u32(fields: dict[str, bytes], name: str) -> int | None:
    value = fields.get(name)
    return _U32.unpack(value)[0] if value is not None and len(value) == 4 else None


def _time_ns(value: bytes | None) -> int:
    if value is None or len(value) != 8:
        return 0
    sec, nsec = struct.unpack("<II", value)
    return sec * 10**9 + nsec


def _spec_length(op: int, fields: dict[str, bytes], version: str) -> int | None:
    """Data length the format spec implies for index-type records (None: no rule)."""
    count = _u32(fields, "count")
    if count is None:
        return None
    if version == "2.0" and op == 4 and _u32(fields, "ver") == 1:
        return 12 * count  # (time, offset) per message
    if version == "2.0" and op == 6 and _u32(fields, "ver") == 1:
        return 8 * count  # (conn, count) per connection
    if version == "1.2" and op == 4 and _u32(fields, "ver") == 0:
        return 16 * count  # (time, uint64 offset) per message
    return None


def _decompress_chunk(kind: bytes, data: bytes, complete: bool) -> bytes | None:
    """Chunk payload; a partial stream (truncated file) gives what can be decoded."""
    if kind in (b"none", b""):
        return data
    try:
        if kind == b"bz2":
            if complete:
                return bz2.decompress(data)
            return bz2.BZ2Decompressor().decompress(data)
        if kind == b"lz4":
            import lz4.frame  # installed with rosbags

            if complete:
                return lz4.frame.decompress(data)
            return lz4.frame.LZ4FrameDecompressor().decompress(data)
    except (OSError, ValueError, EOFError, RuntimeError, zlib.error):
        return None
    return None


def _inner_records(
    buf: bytes, damage: _Damage, complete: bool
) -> Iterator[tuple[int, dict[str, bytes], memoryview]]:
    """``(op, header, data)`` of the records inside a decompressed chunk."""
    view = memoryview(buf)
    pos, size = 0, len(buf)
    while pos < size:
        ok = pos + 4 <= size
        if ok:
            (hlen,) = _U32.unpack_from(buf, pos)
            ok = pos + 8 + hlen <= size
        if ok:
            fields = _parse_header(view[pos + 4 : pos + 4 + hlen])
            (dlen,) = _U32.unpack_from(buf, pos + 4 + hlen)
            ok = fields is not None and pos + 8 + hlen + dlen <= size
        if not ok:
            if complete:
                damage.bad_chunks += 1
            return
        start = pos + 8 + hlen
        yield fields["op"][0], fields, view[start : start + dlen]  # type: ignore[index]
        pos = start + dlen


def _walk_ros1(
    f: BinaryIO, file_size: int, version: str, damage: _Damage
) -> Iterator[tuple[str, Any, Any, Any]]:
    """Events of a ROS1 bag read record by record, from just after the version line.

    Yields ``("conn", key, _Conn, None)`` and ``("msg", key, time_ns, rawdata)``;
    `key` is the connection id (v2.0) or the topic (V1.2).  Index records are skipped
    using the length their ``count`` implies (the declared one may be wrong).
    """
    pos = f.tell()
    while pos < file_size:
        head = f.read(4)
        if len(head) < 4:
            damage.truncated_at = pos
            return
        (hlen,) = _U32.unpack(head)
        if hlen > _MAX_HEADER:
            damage.malformed_at = pos
            return
        if pos + 8 + hlen > file_size:
            damage.truncated_at = pos
            return
        fields = _parse_header(f.read(hlen))
        if fields is None:
            damage.malformed_at = pos
            return
        (dlen,) = _U32.unpack(f.read(4))
        op = fields["op"][0]
        start = pos + 8 + hlen
        expected = _spec_length(op, fields, version)
        if expected is not None and expected != dlen:
            damage.bad_lengths += 1
            if _record_at(f, start + expected, file_size) or not _record_at(
                    f, start + dlen, file_size):
                dlen = expected
            f.seek(start)
        complete = start + dlen <= file_size
        if not complete:
            damage.truncated_at = pos
            dlen = file_size - start  # read what there is, never more
        if version == "2.0" and op == 5:  # chunk
            data = _decompress_chunk(fields.get("compression", b"none"), f.read(dlen), complete)
            if data is None:
                damage.bad_chunks += 1
            else:
                yield from _chunk_events(data, damage, complete)
        elif version == "2.0" and op == 7 and complete:  # connection (index section)
            conn = _connection(fields, f.read(dlen))
            if conn is not None:
                yield "conn", conn[0], conn[1], None
        elif version == "2.0" and op == 2 and complete:  # message outside a chunk
            yield "msg", _u32(fields, "conn"), _time_ns(fields.get("time")), f.read(dlen)
        elif version == "1.2" and op in (1, 2) and complete:
            topic = fields.get("topic", b"").decode("latin-1")
            msgtype = _normalize_type(fields.get("type", b"").decode("latin-1"))
            if op == 1:
                _ = f.read(dlen)
                yield "conn", topic, _Conn(topic, msgtype, fields.get("def", b"").decode(
                    "utf-8", "replace"), fields.get("md5", b"").decode("latin-1")), None
            else:
                sec, nsec = _u32(fields, "sec") or 0, _u32(fields, "nsec") or 0
                yield "conn", topic, _Conn(topic, msgtype), None
                yield "msg", topic, sec * 10**9 + nsec, f.read(dlen)
        if not complete:
            return
        pos = start + dlen
        f.seek(pos)


def _record_at(f: BinaryIO, pos: int, file_size: int) -> bool:
    """Whether a well-formed record header starts at `pos` (or `pos` is the end of file)."""
    if pos == file_size:
        return True
    if pos + 8 > file_size:
        return False
    f.seek(pos)
    (hlen,) = _U32.unpack(f.read(4))
    return hlen <= _MAX_HEADER and pos + 8 + hlen <= file_size and \
        _parse_header(f.read(hlen)) is not None


def _connection(fields: dict[str, bytes], data: bytes | memoryview) -> tuple[int, _Conn] | None:
    """A v2.0 connection record: id, topic and (in its data) type and definition."""
    conn_id = _u32(fields, "conn")
    info = _parse_fields(data)
    if conn_id is None or info is None or "type" not in info:
        return None
    return conn_id, _Conn(
        fields.get("topic", info.get("topic", b"")).decode("latin-1"),
        _normalize_type(info["type"].decode("latin-1")),
        info.get("message_definition", b"").decode("utf-8", "replace"),
        info.get("md5sum", b"").decode("latin-1"),
    )


def _chunk_events(
    data: bytes, damage: _Damage, complete: bool
) -> Iterator[tuple[str, Any, Any, Any]]:
    for op, fields, body in _inner_records(data, damage, complete):
        if op == 7:
            conn = _connection(fields, body)
            if conn is not None:
                yield "conn", conn[0], conn[1], None
        elif op == 2:
            yield "msg", _u32(fields, "conn"), _time_ns(fields.get("time")), body


class _Ros1SequentialBackend(_Backend):
    """ROS1 bag (v2.0 without a usable index, or V1.2) read record by record."""

    def __init__(self, path: Path, version: str) -> None:
        self.path, self.version = path, version
        self.damage = _Damage()
        conns: dict[Any, _Conn] = {}
        counts: Counter[Any] = Counter()
        self.messages_read = 0
        for kind, key, value, _ in self._walk(self.damage):
            if kind == "conn":
                if key not in conns or (value.msgdef and not conns[key].msgdef):
                    conns[key] = value
            elif key in conns:
                counts[key] += 1
            else:
                self.damage.orphans += 1
        self.conns = conns
        self.topics = {c.topic: c.msgtype for c in conns.values()}
        self.counts = dict.fromkeys(self.topics, 0)
        for key, n in counts.items():
            self.counts[conns[key].topic] += n
        self.messages_read = sum(counts.values())
        self.typestore = _ros1_typestore(conns.values())

    def _walk(self, damage: _Damage) -> Iterator[tuple[str, Any, Any, Any]]:
        try:
            with self.path.open("rb") as f:
                f.seek(0, 2)
                size = f.tell()
                f.seek(0)
                f.readline()
                yield from _walk_ros1(f, size, self.version, damage)
        except OSError as exc:
            raise DataError(self.path, f"cannot read: {exc.strerror or exc}") from None

    def messages(self, topics: set[str]) -> Iterator[tuple[str, str, bytes]]:
        keys = {key: c for key, c in self.conns.items() if c.topic in topics}
        for kind, key, _, raw in self._walk(_Damage()):
            if kind == "msg" and key in keys:
                conn = keys[key]
                yield conn.topic, conn.msgtype, raw

    def decode(self, raw: bytes | memoryview, msgtype: str) -> Any:
        return self.typestore.deserialize_ros1(raw, msgtype)


# --------------------------------------------------------------------------- helpers


def _describe(exc: BaseException) -> str:
    """One line for an exception, even one without a message (AssertionError)."""
    text = " ".join(str(a) for a in exc.args if a) if exc.args else ""
    return text.strip().rstrip(".") or type(exc).__name__


def _listing(topics: dict[str, str]) -> str:
    """``/scan (sensor_msgs/msg/LaserScan), ...`` or a note that there are none."""
    if not topics:
        return "the bag has no topics"
    return "topics: " + ", ".join(f"{t} ({ty})" for t, ty in sorted(topics.items()))


def _frame(name: str) -> str:
    """tf frame name without the ROS1 leading slash."""
    return name.lstrip("/")


def _stamp(header: Any) -> float:
    """Header stamp [s] as float64, one correctly rounded division of integers."""
    return (int(header.stamp.sec) * 10**9 + int(header.stamp.nanosec)) / 10**9


def _vector(v: Any) -> tuple[float, float, float]:
    """Finite ``(x, y, z)`` of a Point / Vector3 message."""
    out = (float(v.x), float(v.y), float(v.z))
    if not all(math.isfinite(c) for c in out):
        raise _BadMessage("non-finite translation")
    return out


def _quaternion(q: Any) -> tuple[float, float, float, float]:
    """Unit ``(x, y, z, w)`` of a Quaternion message."""
    x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not math.isfinite(n) or n == 0.0:
        raise _BadMessage("quaternion of zero or non-finite norm")
    return x / n, y / n, z / n, w / n


def _yaw(q: tuple[float, float, float, float]) -> float:
    """Rotation about z [rad] of a unit quaternion (the planar part of its rotation)."""
    x, y, z, w = q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _matrix(t: tuple[float, float, float], q: tuple[float, float, float, float]) -> Array:
    """``4x4`` pose of translation `t` [m] and unit quaternion `q` (x, y, z, w)."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w), t[0]],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w), t[1]],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y), t[2]],
        [0.0, 0.0, 0.0, 1.0],
    ])


def _interpolate_se3(stamps: Array, mats: Array, query: Array) -> Array:
    """``(B, 4, 4)`` poses at `query`: linear translation, slerp rotation, clamped ends."""
    from scipy.spatial.transform import Rotation, Slerp

    query = np.clip(query, stamps[0], stamps[-1])
    if len(stamps) == 1 or stamps[-1] == stamps[0]:
        return np.repeat(mats[-1:], len(query), axis=0)
    # Slerp needs strictly increasing times: keep the last sample of equal stamps.
    keep = np.append(np.diff(stamps) > 0, True)
    stamps, mats = stamps[keep], mats[keep]
    out = np.repeat(np.eye(4)[None], len(query), axis=0)
    out[:, :3, :3] = Slerp(stamps, Rotation.from_matrix(mats[:, :3, :3]))(query).as_matrix()
    for k in range(3):
        out[:, k, 3] = np.interp(query, stamps, mats[:, k, 3])
    return out


# ------------------------------------------------------------ message conversion


def laserscan_to_scan(msg: Any, index: int = 0) -> Scan:
    """`Scan` of a ``sensor_msgs/LaserScan`` message (see the module docstring)."""
    ranges = np.asarray(msg.ranges, dtype=np.float64)
    n = len(ranges)
    if n == 0:
        raise _BadMessage("LaserScan with no ranges")
    a0, inc = float(msg.angle_min), float(msg.angle_increment)
    if not (np.isfinite(a0) and np.isfinite(inc)) or (n > 1 and inc == 0.0):
        raise _BadMessage(f"LaserScan with invalid angles (min {a0}, increment {inc})")
    angles = a0 + np.arange(n) * inc
    if inc < 0:
        angles, ranges = angles[::-1].copy(), ranges[::-1].copy()
    rmax, rmin = float(msg.range_max), float(msg.range_min)
    if not np.isfinite(rmax) or rmax <= 0.0:
        rmax = np.inf
    if not np.isfinite(rmin) or rmin < 0.0:
        rmin = 0.0
    return Scan(stamp=_stamp(msg.header), ranges=ranges, angles=angles, max_range=rmax,
                min_range=rmin, odom=None, index=index)


_POINTFIELD_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def pointcloud2_xyz(msg: Any) -> tuple[Array, int]:
    """``(N, 3)`` finite x, y, z [m] of a ``sensor_msgs/PointCloud2`` and the dropped count.

    Decoded in one go with a numpy structured dtype built from the x/y/z field
    offsets, ``point_step`` and the message endianness; rows are gathered with
    ``row_step`` strides when they are padded.  Non-finite points are dropped
    whatever ``is_dense`` claims.
    """
    fields = {f.name: f for f in msg.fields}
    missing = [a for a in "xyz" if a not in fields]
    if missing:
        raise _BadMessage(f"PointCloud2 without field(s) {', '.join(missing)}")
    order = ">" if msg.is_bigendian else "<"
    formats, offsets = [], []
    step = int(msg.point_step)
    for axis in "xyz":
        pf = fields[axis]
        if int(pf.datatype) not in (7, 8):
            raise _BadMessage(f"PointCloud2 field {axis} is not float32/float64")
        fmt = np.dtype(order + _POINTFIELD_DTYPES[int(pf.datatype)])
        if int(pf.offset) + fmt.itemsize > step:
            raise _BadMessage(f"PointCloud2 field {axis} lies outside point_step {step}")
        formats.append(fmt)
        offsets.append(int(pf.offset))
    width, height, row_step = int(msg.width), int(msg.height), int(msg.row_step)
    count = width * height
    if count == 0:
        return np.empty((0, 3)), 0
    data = np.asarray(msg.data, dtype=np.uint8)
    row_bytes = width * step
    if row_step < row_bytes or len(data) < (height - 1) * row_step + row_bytes:
        raise _BadMessage(f"PointCloud2 data of {len(data)} bytes is too short for "
                          f"{height}x{width} points")
    if row_step == row_bytes or height == 1:
        buf = data[: count * step]
    else:
        rows = np.lib.stride_tricks.as_strided(data, shape=(height, row_bytes),
                                               strides=(row_step, 1), writeable=False)
        buf = np.ascontiguousarray(rows).reshape(-1)
    dtype = np.dtype({"names": ["x", "y", "z"], "formats": formats, "offsets": offsets,
                      "itemsize": step})
    arr = np.frombuffer(buf.tobytes() if not buf.flags.c_contiguous else buf, dtype=dtype,
                        count=count)
    pts = np.column_stack([arr["x"], arr["y"], arr["z"]]).astype(np.float64)
    finite = np.isfinite(pts).all(axis=1)
    return pts[finite], int(count - np.count_nonzero(finite))


# ------------------------------------------------------------ odometry synchroniser


_Link = tuple[str, tuple[float, float, float], tuple[float, float, float, float]]


@dataclass
class _OdomSync:
    """Attach the sensor pose in the odom frame to scans, in stream order.

    Odometry samples are the base pose in the odom frame at header stamps, kept as
    ``(x, y, yaw)`` when `planar` (scans) and as ``4x4`` matrices otherwise (clouds).
    A scan waits in `pending` until a sample at or after its stamp exists (or the
    stream ends, or more than `_MAX_PENDING` scans wait).
    """

    mode: str | None  # None, "odom" (nav_msgs/Odometry) or "tf"
    planar: bool = True
    odom_frame: str = "odom"
    base_frame: str | None = None
    stamps: list[float] = field(default_factory=list)
    samples: list[Any] = field(default_factory=list)
    statics: dict[str, _Link] = field(default_factory=dict)
    links: dict[str, _Link] = field(default_factory=dict)
    pending: deque[tuple[Scan | PointCloud, str]] = field(default_factory=deque)
    outside: int = 0  # scans outside the odometry time span (nearest pose used)
    no_odom: int = 0  # scans handed out without any odometry sample
    missing_chain: set[str] = field(default_factory=set)
    _offsets: dict[str, Array] = field(default_factory=dict)  # sensor frame -> T_base_sensor
    _chain: set[str] = field(default_factory=set)  # frames the cached offsets depend on

    # -- inputs
    def add_odometry(self, msg: Any) -> None:
        """A ``nav_msgs/Odometry`` message: pose of child_frame_id in frame_id."""
        child = _frame(msg.child_frame_id)
        if self.base_frame is None:
            self.base_frame = child
            self.odom_frame = _frame(msg.header.frame_id)
        if child == self.base_frame:
            pose = msg.pose.pose
            self._add_sample(_stamp(msg.header), _vector(pose.position),
                             _quaternion(pose.orientation))

    def add_tf(self, msg: Any, static: bool) -> int:
        """A tf message; returns how many odom -> base samples it held."""
        added = 0
        for tr in msg.transforms:
            parent, child = _frame(tr.header.frame_id), _frame(tr.child_frame_id)
            try:
                t, q = _vector(tr.transform.translation), _quaternion(tr.transform.rotation)
            except _BadMessage:
                continue
            if not static and self.mode == "tf" and parent == self.odom_frame \
                    and self._is_base(child):
                self.base_frame = child
                self._add_sample(_stamp(tr.header), t, q)
                added += 1
                continue
            table = self.statics if static else self.links
            if child in self._chain and table.get(child) != (parent, t, q):
                self._offsets.clear()
                self._chain.clear()
            table[child] = (parent, t, q)
        return added

    def _is_base(self, child: str) -> bool:
        if self.base_frame is not None:
            return child == self.base_frame
        return child in BASE_FRAMES or child.endswith(tuple("/" + b for b in BASE_FRAMES))

    def _add_sample(self, stamp: float, t: tuple[float, float, float],
                    q: tuple[float, float, float, float]) -> None:
        sample = (t[0], t[1], _yaw(q)) if self.planar else _matrix(t, q)
        if not self.stamps or stamp >= self.stamps[-1]:
            i = len(self.stamps)
        else:
            i = bisect.bisect_right(self.stamps, stamp)
        self.stamps.insert(i, stamp)
        self.samples.insert(i, sample)

    # -- outputs
    def push(self, item: Scan | PointCloud, frame: str) -> list[Scan | PointCloud]:
        """Queue a scan; return the scans (in order) whose odometry is now known."""
        if self.mode is None:
            return [item]
        self.pending.append((item, _frame(frame)))
        return self.ready()

    def ready(self) -> list[Scan | PointCloud]:
        """Scans at the front of the queue covered by odometry, `_BATCH` at a time.

        Releasing in batches keeps the per-scan cost of the (vectorised) interpolation
        small; scans beyond `_MAX_PENDING` are forced out with the nearest pose.
        """
        n = 0
        if self.stamps:
            last = self.stamps[-1]
            while n < len(self.pending) and self.pending[n][0].stamp <= last:
                n += 1
        if n < _BATCH:
            n = 0
        return self._release(max(n, len(self.pending) - _MAX_PENDING))

    def finish(self) -> list[Scan | PointCloud]:
        """Everything still queued, with the nearest odometry pose (end of stream)."""
        return self._release(len(self.pending))

    def _release(self, n: int) -> list[Scan | PointCloud]:
        if n <= 0:
            return []
        batch = [self.pending.popleft() for _ in range(n)]
        items = [it for it, _ in batch]
        if not self.stamps:
            self.no_odom += n
            return items
        query = np.array([it.stamp for it in items])
        first, last = self.stamps[0], self.stamps[-1]
        self.outside += int(np.count_nonzero((query < first) | (query > last)))
        # Only the samples bracketing the batch take part in the interpolation.
        lo = max(0, bisect.bisect_right(self.stamps, float(query.min())) - 1)
        hi = max(bisect.bisect_left(self.stamps, float(query.max())) + 1, lo + 1)
        stamps = np.asarray(self.stamps[lo:hi])
        samples = np.asarray(self.samples[lo:hi])
        offsets = np.stack([self._offset(frame) for _, frame in batch])
        if self.planar:
            sensor = se2.compose(se2.interpolate(stamps, samples, query), offsets)
        else:
            sensor = _interpolate_se3(stamps, samples, query) @ offsets
        for it, pose in zip(items, sensor, strict=True):
            it.odom = pose
        self._prune(float(query.max()))
        return items

    def _offset(self, sensor: str) -> Array:
        """``T_base_sensor`` ((x, y, yaw) if planar) from the tf chain; identity if none.

        The chain follows /tf_static first, else the latest /tf transform of a frame.
        """
        cached = self._offsets.get(sensor)
        if cached is not None:
            return cached
        mat, frame, seen = np.eye(4), sensor, set()
        while frame and frame != self.base_frame:
            link = self.statics.get(frame) or self.links.get(frame)
            if link is None or frame in seen:
                self.missing_chain.add(sensor)
                mat = np.eye(4)
                break
            seen.add(frame)
            mat = _matrix(link[1], link[2]) @ mat
            frame = link[0]
        out = se2.from_matrix(mat) if self.planar else mat
        self._offsets[sensor] = out
        self._chain.update(seen)
        self._chain.add(sensor)
        return out

    def _prune(self, done: float) -> None:
        keep = max(0, bisect.bisect_right(self.stamps, done - _KEEP_ODOM_S) - 1)
        if keep > 0:
            del self.stamps[:keep], self.samples[:keep]


# --------------------------------------------------------------------------- the reader


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
        self.recovered = ""
        self._backend = self._open_backend()
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

    # -- opening
    def _open_backend(self) -> _Backend:
        path = self.path
        if not path.exists():
            raise DataError(path, "no such file or directory")
        if path.is_dir():
            if not (path / "metadata.yaml").is_file():
                raise DataError(path, "directory without metadata.yaml: not a ROS2 bag")
            return _Ros2Backend(path, path)
        try:
            with path.open("rb") as f:
                magic = f.read(32)
        except OSError as exc:
            raise DataError(path, f"cannot open: {exc.strerror or exc}") from None
        if not magic:
            raise DataError(path, "empty file, not a ROS bag")
        if magic.startswith((_SQLITE_MAGIC, _MCAP_MAGIC)):
            kind = ".db3" if magic.startswith(_SQLITE_MAGIC) else ".mcap"
            if (path.parent / "metadata.yaml").is_file():
                return _Ros2Backend(path.parent, path)
            if path.suffix != kind:
                raise DataError(path, f"a {kind[1:]} ROS2 bag file must end in {kind}")
            return _Ros2Backend(path, path)
        if magic.startswith((_ROS1_MAGIC, _ROS1_OLD_MAGIC, _ROSLOG_MAGIC)):
            version = magic.split(b"\n", 1)[0].rsplit(b"V", 1)[-1].decode("latin-1", "replace")
            if magic.startswith(_ROS1_MAGIC + b"2.0\n"):
                return self._open_ros1(path)
            if magic.startswith(_ROS1_OLD_MAGIC + b"1.2\n"):
                return self._sequential(path, "1.2")
            raise DataError(path, f"ROS bag format V{version} is not supported "
                                  "(readable: V1.2, V2.0 and ROS2 bags)")
        raise DataError(path, "not a ROS bag (no ROS1, sqlite3 or MCAP magic bytes)")

    def _open_ros1(self, path: Path) -> _Backend:
        try:
            return _Ros1IndexedBackend(path)
        except Exception as exc:  # any failure of the index: read sequentially
            reason = _describe(exc)
        backend = self._sequential(path, "2.0")
        damage = backend.damage.describe()
        msg = (f"{path}: the bag index is inconsistent or unusable ({damage or reason}); "
               f"read {backend.messages_read} messages sequentially, record by record")
        if self.strict:
            raise DataError(path, f"the bag index is inconsistent or unusable "
                                  f"({damage or reason}); strict mode refuses to read it "
                                  "sequentially")
        self.recovered = msg
        warn(msg)
        return backend

    def _sequential(self, path: Path, version: str) -> _Ros1SequentialBackend:
        backend = _Ros1SequentialBackend(path, version)
        damage = backend.damage
        if not backend.conns:
            what = damage.describe() or "no connection or message records"
            raise DataError(path, f"unreadable ROS bag V{version}: {what}")
        if version == "1.2" and damage.describe():
            text = (f"{path}: ROS bag V1.2 read in part ({damage.describe()}); "
                    f"{backend.messages_read} messages read")
            if self.strict:
                raise DataError(path, text.split(": ", 1)[1])
            warn(text)
        return backend

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
                                               f"{_describe(exc)}") from None
                problems[f"undecodable {msgtype} messages on {name}"] += 1
                msg = None
            yield name, msg

    def __iter__(self) -> Iterator[Scan | PointCloud]:
        """Scans (or clouds) of the chosen topic in bag order, odometry attached."""
        sync = _OdomSync(self._odom_mode, planar=self.msgtype == LASERSCAN)
        problems: Counter[str] = Counter()
        dropped = dense_lies = 0
        odom_msgs = self._odom_topics[0] if self._odom_mode == "odom" else None
        wanted = {self.topic, *self._odom_topics, *self._static_topics}
        index = -1
        for name, msg in self._decoded(wanted, problems):
            if name == self.topic:
                index += 1  # position of the message on its topic, undecodable ones included
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
                        item = PointCloud(stamp=_stamp(msg.header), points=pts, index=index)
                except (_BadMessage, AttributeError, ValueError, TypeError) as exc:
                    if self.strict:
                        raise DataError(self.path, f"message {index} on {name}: "
                                                   f"{_describe(exc)}") from None
                    problems[f"unusable messages on {name}"] += 1
                    continue
                yield from sync.push(item, msg.header.frame_id)
                continue
            if msg is None:
                continue
            try:
                if name == odom_msgs:
                    sync.add_odometry(msg)
                else:
                    sync.add_tf(msg, static=name in self._static_topics)
            except (_BadMessage, AttributeError) as exc:
                problems[f"unusable odometry messages on {name} ({_describe(exc)})"] += 1
            yield from sync.ready()
        yield from sync.finish()
        self._report(sync, problems, dropped, dense_lies)

    def _report(self, sync: _OdomSync, problems: Counter[str], dropped: int,
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
        sync = _OdomSync(self._odom_mode)
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
            return PointCloud(stamp=_stamp(msg.header), points=pointcloud2_xyz(msg)[0])
        except Exception:  # info leaves the sensor fields empty
            return None
