"""The ROS1 bag record format, read sequentially: records, chunks, connections, messages.

For bags whose index cannot be used (inconsistent index records, unindexed or
truncated bags) and for ROS bag V1.2, which rosbags does not read.  A record is a
uint32 header length, the header (``name=value`` fields, each prefixed by its
uint32 length, with a one-byte ``op``), a uint32 data length and the data; the
specs are wiki.ros.org/Bags/Format/2.0 and wiki.ros.org/Bags/Format/1.2.
`walk_ros1` yields connection and message events and records in a `Damage` what it
had to work around; it never raises on bad bytes.
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, BinaryIO

from data.compression import decompress_buffer

_U32 = struct.Struct("<I")
_MAX_HEADER = 1 << 24  # sanity bound on one record header [bytes]


@dataclass
class Conn:
    """One ROS1 connection: topic, ROS2-style type name, definition text, md5."""

    topic: str
    msgtype: str
    msgdef: str = ""
    md5: str = ""


@functools.lru_cache(maxsize=256)
def normalize_type(name: str) -> str:
    """``pkg/Type`` -> ``pkg/msg/Type`` (rosbags' ROS2-style names)."""
    from rosbags.typesys.msg import normalize_msgtype

    return normalize_msgtype(name)


@dataclass
class Damage:
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


_CHUNK_COMPRESSION = {b"none": "none", b"": "none", b"bz2": "bzip2", b"lz4": "lz4"}


def _decompress_chunk(kind: bytes, data: bytes, complete: bool) -> bytes | None:
    """Chunk payload; a partial stream (truncated file) gives what can be decoded.

    None when it does not decompress or its ``compression`` field is unknown.
    """
    return decompress_buffer(data, _CHUNK_COMPRESSION.get(kind, "unknown"), complete)


def _inner_records(
    buf: bytes, damage: Damage, complete: bool
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


def walk_ros1(
    f: BinaryIO, file_size: int, version: str, damage: Damage
) -> Iterator[tuple[str, Any, Any, Any]]:
    """Events of a ROS1 bag read record by record, from just after the version line.

    Yields ``("conn", key, Conn, None)`` and ``("msg", key, time_ns, rawdata)``;
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
            msgtype = normalize_type(fields.get("type", b"").decode("latin-1"))
            if op == 1:
                _ = f.read(dlen)
                yield "conn", topic, Conn(topic, msgtype, fields.get("def", b"").decode(
                    "utf-8", "replace"), fields.get("md5", b"").decode("latin-1")), None
            else:
                sec, nsec = _u32(fields, "sec") or 0, _u32(fields, "nsec") or 0
                yield "conn", topic, Conn(topic, msgtype), None
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


def _connection(fields: dict[str, bytes], data: bytes | memoryview) -> tuple[int, Conn] | None:
    """A v2.0 connection record: id, topic and (in its data) type and definition."""
    conn_id = _u32(fields, "conn")
    info = _parse_fields(data)
    if conn_id is None or info is None or "type" not in info:
        return None
    return conn_id, Conn(
        fields.get("topic", info.get("topic", b"")).decode("latin-1"),
        normalize_type(info["type"].decode("latin-1")),
        info.get("message_definition", b"").decode("utf-8", "replace"),
        info.get("md5sum", b"").decode("latin-1"),
    )


def _chunk_events(
    data: bytes, damage: Damage, complete: bool
) -> Iterator[tuple[str, Any, Any, Any]]:
    for op, fields, body in _inner_records(data, damage, complete):
        if op == 7:
            conn = _connection(fields, body)
            if conn is not None:
                yield "conn", conn[0], conn[1], None
        elif op == 2:
            yield "msg", _u32(fields, "conn"), _time_ns(fields.get("time")), body
