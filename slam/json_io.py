"""JSON text of the project's results, and writing it to a file atomically.

`to_json_text` converts numpy scalars and arrays to plain numbers and lists, paths to
strings and non-finite floats to ``null``; `write_json` writes that text through
`data.atomic_write`, so an output file is either the old one or the complete new one.
No CLI import here: the library (`slam.results`) and the commands both use it.
"""

from __future__ import annotations

import json
import math
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from data.atomic_write import write_bytes_atomic

__all__ = ["to_json_text", "write_json"]


def _plain(obj: Any) -> Any:
    """JSON-serialisable copy of `obj` (numpy scalars/arrays, paths, NaN -> null)."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.generic):
        return _plain(obj.item())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def to_json_text(obj: Any, indent: int | None = 2) -> str:
    """`obj` as JSON text; numpy values converted, non-finite floats become null."""
    return json.dumps(_plain(obj), indent=indent)


def write_json(path: str | PathLike[str], obj: Any) -> Path:
    """Write `obj` as UTF-8 JSON (and a final newline) to `path` atomically; returns the path.

    Raises:
        DataError: the folder is missing or the file cannot be written.
    """
    return write_bytes_atomic(path, (to_json_text(obj) + "\n").encode("utf-8"))
