"""Plain, gzip and bzip2 files, told apart by content rather than by name.

Every decompression in `data` goes through here, and so does streamed compressed
output (whole texts are compressed by `data.atomic_write.write_text_atomic`):

- `open_binary` / `open_text`: a reader that decompresses transparently.
- `decompressed` / `iter_lines`: a streaming reader that recovers what it can from a
  damaged stream (it feeds the decompressor 1 KiB at a time, so a stream that
  breaks off gives nearly every byte before the damage, then `StreamBroken`);
  `iter_lines` decompresses in a background thread.
- `decompress_buffer`: one bzip2 or LZ4-frame block held in memory (the chunks of
  a ROS1 bag), or what can be decoded of one cut short.
- `compressing_text_writer`: a text stream onto an open binary file, gzip or bzip2
  compressed by the suffix of the file's name.

Magic bytes: gzip ``1f 8b``, bzip2 ``BZh``; anything else is read as plain bytes.
"""

from __future__ import annotations

import bz2
import contextlib
import gzip
import io
import queue
import threading
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import IO, TypeVar

from data.errors import DataError
from data.progress import ReadProgress

__all__ = [
    "StreamBroken",
    "compressing_text_writer",
    "compression_of",
    "decompress_buffer",
    "decompressed",
    "in_thread",
    "iter_lines",
    "open_binary",
    "open_text",
    "read_magic",
]

_GZIP_MAGIC = b"\x1f\x8b"
_BZIP2_MAGIC = b"BZh"

_READ = 1 << 15  # bytes read from the file at a time
_FEED = 1 << 10  # compressed bytes per decompressor call: a failing call loses its output
_QUEUE = 16  # pieces the decompressing thread may run ahead (bzip2: up to 900 kB each)
_STREAM_ERRORS = (OSError, EOFError, zlib.error)
_T = TypeVar("_T")


def read_magic(path: str | Path, size: int = 16) -> bytes:
    """First `size` bytes of the file (raises `DataError` when it cannot be opened)."""
    path = Path(path)
    if not path.exists():
        raise DataError(path, "no such file or directory")
    if path.is_dir():
        raise DataError(path, "is a directory, expected a file")
    try:
        with path.open("rb") as f:
            return f.read(size)
    except OSError as exc:
        raise DataError(path, f"cannot open: {exc.strerror or exc}") from exc


def compression_of(path: str | Path) -> str:
    """``"gzip"``, ``"bzip2"`` or ``"none"`` from the file's magic bytes."""
    magic = read_magic(path, 3)
    if magic.startswith(_GZIP_MAGIC):
        return "gzip"
    if magic.startswith(_BZIP2_MAGIC):
        return "bzip2"
    return "none"


def open_binary(path: str | Path) -> IO[bytes]:
    """Decompressing binary reader for a plain, ``.gz`` or ``.bz2`` file."""
    kind = compression_of(path)
    if kind == "gzip":
        return gzip.open(path, "rb")
    if kind == "bzip2":
        return bz2.open(path, "rb")
    return open(path, "rb")


def open_text(path: str | Path, encoding: str = "latin-1") -> IO[str]:
    """Decompressing text reader (latin-1 by default: never fails on stray bytes)."""
    return io.TextIOWrapper(open_binary(path), encoding=encoding, newline=None)


# --------------------------------------------------------------------------- streaming


def _short(exc: BaseException) -> str:
    text = str(exc)
    return text if len(text) <= 60 else text[:57] + "..."


class StreamBroken(Exception):
    """The decompressor failed after some data; carries the original error."""

    def __init__(self, cause: BaseException) -> None:
        super().__init__(_short(cause) or type(cause).__name__)
        self.cause = cause


def decompressed(path: str | Path) -> Iterator[bytes]:
    """The file's bytes, decompressed (gzip or bzip2 by magic bytes), piece by piece.

    Feeds the decompressor 1 KiB at a time and yields each output at once, so a
    damaged stream gives (nearly) every byte before the damage (bzip2: every block
    before the damaged one) before `StreamBroken`.  Concatenated streams are read on.
    Raises `DataError` when the file cannot be opened.
    """
    pieces = _pieces_at(path)
    try:
        for piece, _ in pieces:
            yield piece
    finally:
        pieces.close()


def _pieces_at(path: str | Path) -> Iterator[tuple[bytes, int]]:
    """`decompressed`, each piece with the bytes of the stored file consumed once it
    was produced (the offset just past the compressed input that released it)."""
    kind = compression_of(path)
    try:
        f = open(path, "rb")  # closed in the finally below
    except OSError as exc:
        raise DataError(path, f"cannot open: {exc.strerror or exc}") from None
    try:
        read = 0  # bytes of the file read before the current `data`
        if kind == "none":
            while piece := f.read(_READ):
                read += len(piece)
                yield piece, read
            return
        make = bz2.BZ2Decompressor if kind == "bzip2" else lambda: zlib.decompressobj(31)
        decompressor = make()
        fresh = True  # nothing fed to the current decompressor yet
        while True:
            data = f.read(_READ)
            if not data:
                if not (decompressor.eof or fresh):
                    raise StreamBroken(EOFError("compressed data ends before its end marker"))
                return
            for at in range(0, len(data), _FEED):
                data_left = data[at : at + _FEED]
                fed = read + min(at + _FEED, len(data))
                while data_left:
                    try:
                        out = decompressor.decompress(data_left)
                    except _STREAM_ERRORS as exc:
                        raise StreamBroken(exc) from exc
                    fresh = False
                    if out:
                        yield out, fed
                    if not decompressor.eof:
                        break
                    data_left = decompressor.unused_data  # a concatenated stream follows
                    decompressor, fresh = make(), True
            read += len(data)
    finally:
        f.close()


def in_thread(pieces: Iterator[_T]) -> Iterator[_T]:
    """`pieces` produced by a background thread (zlib and bzip2 release the GIL).

    At most `_QUEUE` pieces wait in memory; closing the generator stops the thread.
    Exceptions of the producer are raised in the consumer.
    """
    pipe: queue.Queue[_T | BaseException | None] = queue.Queue(maxsize=_QUEUE)
    stop = threading.Event()

    def put(item: _T | BaseException | None) -> None:
        while not stop.is_set():
            try:
                pipe.put(item, timeout=0.05)
                return
            except queue.Full:
                continue

    def produce() -> None:
        try:
            for piece in pieces:
                if stop.is_set():
                    return
                put(piece)
        except BaseException as exc:  # handed to the consumer, raised there
            put(exc)
            return
        finally:
            pieces.close()  # type: ignore[attr-defined]
        put(None)

    worker = threading.Thread(target=produce, name="decompress", daemon=True)
    worker.start()
    try:
        while True:
            item = pipe.get()
            if item is None:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        worker.join(timeout=5.0)


def iter_lines(path: str | Path, progress: ReadProgress | None = None) -> Iterator[bytes]:
    """Lines of the (decompressed) file without their ``\\n``, in file order.

    Compressed files are decompressed by a background thread.  Raises
    `StreamBroken` when decompression fails; the partial line before the failure
    is dropped.  `progress` (unit bytes), when given, follows the bytes of the
    stored file behind the lines yielded: within a decompressed piece the
    compressed bytes that released it are shared out in proportion to the
    decompressed bytes of its lines.
    """
    pieces: Iterator[tuple[bytes, int]] = _pieces_at(path)
    if compression_of(path) != "none":
        pieces = in_thread(pieces)
    tail = b""
    before = 0  # stored bytes consumed before the current piece
    for piece, after in pieces:
        parts = (tail + piece).split(b"\n")
        if progress is None:
            tail = parts.pop()
            yield from parts
            continue
        # Every line but the last of `parts` ends inside `piece`: 0 < used <= size.
        size, used, span, cell = len(piece), -len(tail), after - before, progress.cell
        tail = parts.pop()
        for line in parts:
            used += len(line) + 1
            cell.value = before + span * used // size
            yield line
        before = after
    if progress is not None:
        progress.done = before
    if tail:
        yield tail


def decompress_buffer(data: bytes, kind: str, complete: bool = True) -> bytes | None:
    """`data` decompressed; `kind` is ``"bzip2"``, ``"lz4"`` (an LZ4 frame) or ``"none"``.

    With `complete` False (a stream cut short) it gives what can be decoded.  None
    when the data does not decompress or `kind` is none of these.
    """
    if kind == "none":
        return data
    try:
        if kind == "bzip2":
            if complete:
                return bz2.decompress(data)
            return bz2.BZ2Decompressor().decompress(data)
        if kind == "lz4":
            import lz4.frame  # installed with rosbags

            if complete:
                return lz4.frame.decompress(data)
            return lz4.frame.LZ4FrameDecompressor().decompress(data)
    except (OSError, ValueError, EOFError, RuntimeError, zlib.error):
        return None
    return None


# --------------------------------------------------------------------------- writing


@contextlib.contextmanager
def compressing_text_writer(
    raw: IO[bytes], name: str | Path, encoding: str = "ascii"
) -> Iterator[IO[str]]:
    """Text stream (``\\n`` line ends) onto `raw`, compressed by the suffix of `name`.

    ``.gz``: gzip, level 6, the file name without ``.gz`` in the gzip header;
    ``.bz2``: bzip2; anything else: plain.  The compressed stream is finished when
    the ``with`` block ends; `raw` itself stays open (its owner closes it).
    """
    name = Path(name)
    suffix = name.suffix.lower()
    with contextlib.ExitStack() as stack:
        if suffix == ".gz":
            raw = stack.enter_context(
                gzip.GzipFile(filename=name.stem, mode="wb", compresslevel=6, fileobj=raw)
            )
        elif suffix == ".bz2":
            raw = stack.enter_context(bz2.BZ2File(raw, "wb"))
        text = io.TextIOWrapper(raw, encoding=encoding, newline="\n")
        try:
            yield text
        finally:
            text.detach()  # flushes; leaves `raw` open for the gzip / bzip2 trailer
