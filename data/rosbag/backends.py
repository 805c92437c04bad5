"""Storage backends of a bag: topics, counts and a raw message stream for each kind.

- ROS2 (sqlite3 or MCAP, a bag folder or a single ``.db3`` / ``.mcap`` file):
  ``rosbags.highlevel.AnyReader``, messages decoded with ``deserialize_cdr``.
- ROS1 v2.0 with a usable index: ``rosbags.rosbag1.Reader``.
- ROS1 v2.0 without a usable index, and V1.2: the sequential record reader
  (`data.rosbag.ros1_records`).  ROS1 messages are decoded with
  ``deserialize_ros1``, types from the bag's own definitions over ROS1 Noetic's.

`open_backend` picks the backend by the file's magic bytes.  Every failure is a
`DataError` naming the bag; no rosbags exception escapes.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from data.errors import DataError, warn
from data.rosbag.ros1_records import Conn, Damage, walk_ros1

_ROS1_MAGIC = b"#ROSBAG V"
_ROS1_OLD_MAGIC = b"#ROSRECORD V"
_ROSLOG_MAGIC = b"#ROSLOG V"
_SQLITE_MAGIC = b"SQLite format 3\x00"
_MCAP_MAGIC = b"\x89MCAP0\r\n"


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


def describe(exc: BaseException) -> str:
    """One line for an exception, even one without a message (AssertionError)."""
    text = " ".join(str(a) for a in exc.args if a) if exc.args else ""
    return text.strip().rstrip(".") or type(exc).__name__


def _ros1_typestore(conns: Iterable[Conn]) -> Any:
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


class Backend:
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


class _Ros2Backend(Backend):
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
            raise DataError(shown, f"cannot read ROS2 bag: {describe(exc)}") from None
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
            raise DataError(self.shown, f"cannot read ROS2 bag: {describe(exc)}") from None
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


class _Ros1IndexedBackend(Backend):
    """ROS1 v2.0 bag read through its index (``rosbags.rosbag1.Reader``)."""

    def __init__(self, path: Path) -> None:
        from rosbags.rosbag1 import Reader

        self.path = path
        self.version = "2.0"
        with Reader(path) as reader:  # any exception: caller falls back to sequential reading
            conns = [Conn(c.topic, c.msgtype, c.msgdef.data, c.digest) for c in reader.connections]
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
            raise DataError(self.path, f"cannot read ROS1 bag: {describe(exc)}") from None

    def decode(self, raw: bytes | memoryview, msgtype: str) -> Any:
        return self.typestore.deserialize_ros1(raw, msgtype)


class _Ros1SequentialBackend(Backend):
    """ROS1 bag (v2.0 without a usable index, or V1.2) read record by record."""

    def __init__(self, path: Path, version: str) -> None:
        self.path, self.version = path, version
        self.damage = Damage()
        conns: dict[Any, Conn] = {}
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

    def _walk(self, damage: Damage) -> Iterator[tuple[str, Any, Any, Any]]:
        try:
            with self.path.open("rb") as f:
                f.seek(0, 2)
                size = f.tell()
                f.seek(0)
                f.readline()
                yield from walk_ros1(f, size, self.version, damage)
        except OSError as exc:
            raise DataError(self.path, f"cannot read: {exc.strerror or exc}") from None

    def messages(self, topics: set[str]) -> Iterator[tuple[str, str, bytes]]:
        keys = {key: c for key, c in self.conns.items() if c.topic in topics}
        for kind, key, _, raw in self._walk(Damage()):
            if kind == "msg" and key in keys:
                conn = keys[key]
                yield conn.topic, conn.msgtype, raw

    def decode(self, raw: bytes | memoryview, msgtype: str) -> Any:
        return self.typestore.deserialize_ros1(raw, msgtype)


# --------------------------------------------------------------------------- opening


def open_backend(path: Path, strict: bool) -> tuple[Backend, str]:
    """The backend for the bag at `path`, and the recovery note ("" when none was needed).

    A ROS1 v2.0 bag whose index cannot be used is read sequentially with one warning
    (the note); `strict` refuses that, and a V1.2 bag read only in part, instead.

    Raises:
        DataError: missing path, not a bag, unsupported version, unreadable bag.
    """
    if not path.exists():
        raise DataError(path, "no such file or directory")
    if path.is_dir():
        if not (path / "metadata.yaml").is_file():
            raise DataError(path, "directory without metadata.yaml: not a ROS2 bag")
        return _Ros2Backend(path, path), ""
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
            return _Ros2Backend(path.parent, path), ""
        if path.suffix != kind:
            raise DataError(path, f"a {kind[1:]} ROS2 bag file must end in {kind}")
        return _Ros2Backend(path, path), ""
    if magic.startswith((_ROS1_MAGIC, _ROS1_OLD_MAGIC, _ROSLOG_MAGIC)):
        version = magic.split(b"\n", 1)[0].rsplit(b"V", 1)[-1].decode("latin-1", "replace")
        if magic.startswith(_ROS1_MAGIC + b"2.0\n"):
            return _open_ros1(path, strict)
        if magic.startswith(_ROS1_OLD_MAGIC + b"1.2\n"):
            return _sequential(path, "1.2", strict), ""
        raise DataError(path, f"ROS bag format V{version} is not supported "
                              "(readable: V1.2, V2.0 and ROS2 bags)")
    raise DataError(path, "not a ROS bag (no ROS1, sqlite3 or MCAP magic bytes)")


def _open_ros1(path: Path, strict: bool) -> tuple[Backend, str]:
    try:
        return _Ros1IndexedBackend(path), ""
    except Exception as exc:  # any failure of the index: read sequentially
        reason = describe(exc)
    backend = _sequential(path, "2.0", strict)
    damage = backend.damage.describe()
    msg = (f"{path}: the bag index is inconsistent or unusable ({damage or reason}); "
           f"read {backend.messages_read} messages sequentially, record by record")
    if strict:
        raise DataError(path, f"the bag index is inconsistent or unusable "
                              f"({damage or reason}); strict mode refuses to read it "
                              "sequentially")
    warn(msg)
    return backend, msg


def _sequential(path: Path, version: str, strict: bool) -> _Ros1SequentialBackend:
    backend = _Ros1SequentialBackend(path, version)
    damage = backend.damage
    if not backend.conns:
        what = damage.describe() or "no connection or message records"
        raise DataError(path, f"unreadable ROS bag V{version}: {what}")
    if version == "1.2" and damage.describe():
        text = (f"{path}: ROS bag V1.2 read in part ({damage.describe()}); "
                f"{backend.messages_read} messages read")
        if strict:
            raise DataError(path, text.split(": ", 1)[1])
        warn(text)
    return backend
