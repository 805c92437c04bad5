"""Tell a CARMEN log from other files by its first lines (`is_carmen`).

A file is taken for a CARMEN log when at least half of its first 50 message lines
(comments skipped) start with a message name CARMEN writes; at most about 256 KiB
of decompressed text are looked at.
"""

from __future__ import annotations

from pathlib import Path

from data.carmen.parsing import is_known_message
from data.compression import StreamBroken, decompressed, read_magic
from data.errors import DataError

_SNIFF_BYTES = 1 << 18
_SNIFF_LINES = 50


def sniff(path: Path) -> str | None:
    """None when `path` looks like a CARMEN log, else the reason it does not.

    Raises `DataError` for a missing file, a directory or an unreadable file.
    """
    read_magic(path)  # DataError for missing files, directories, unreadable files
    pieces: list[bytes] = []
    size = 0
    complete = False
    stream = decompressed(path)
    try:
        for piece in stream:
            pieces.append(piece)
            size += len(piece)
            if size >= _SNIFF_BYTES:
                break
        else:
            complete = True
    except StreamBroken as exc:
        if not pieces:
            return f"cannot decompress: {exc}"
    finally:
        stream.close()
    head = b"".join(pieces)
    if not head.strip():
        return "file is empty"
    lines = head.split(b"\n")
    if not complete and len(lines) > 1:
        lines.pop()  # the last line may be cut by the read limit or the damage
    considered = known = 0
    for raw in lines:
        tokens = raw.split(None, 1)
        if not tokens or tokens[0].startswith(b"#"):
            continue
        considered += 1
        if is_known_message(tokens[0].decode("latin-1")):
            known += 1
        if considered >= _SNIFF_LINES:
            break
    if considered == 0:
        return "no message lines, only comments"
    if known == 0 or 2 * known < considered:
        return f"{considered - known} of the first {considered} lines are not CARMEN messages"
    return None


def is_carmen(path: str | Path) -> bool:
    """Cheap sniff: do the first non-comment lines look like CARMEN messages?

    Reads at most about 256 KiB (decompressed).  False for missing files,
    directories, garbage and empty files; never raises.
    """
    try:
        return sniff(Path(path)) is None
    except DataError:
        return False
