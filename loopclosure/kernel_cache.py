"""numba's on-disk cache (``cache=True``) of kernels that call kernels of other modules.

numba keys a cached kernel on its own source file only (modification time and size),
yet compiles the kernels it calls from other modules into it: after an edit of a
callee's file, the caller's cache still loads the old callee's machine code (a
limitation numba documents).  The compiled ICP's kernels call across modules
(`loopclosure.icp_kernel` and `loopclosure.grid_overlap` into
`loopclosure.grid_nearest`, all of them into `loopclosure.grid_target`), so each
calling module runs `drop_stale` when imported: a kernel whose cached machine code is
older than a callee's source file is compiled again on its next call.  Nothing changes
while the sources do not; a fresh install has no cache to drop.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence


def cached_files(kernel: object) -> list[str] | None:
    """Paths of the machine-code files that numba's cache index of `kernel` (a
    dispatcher) refers to now (none when the index is missing or stale for the
    kernel's own file); None without an on-disk cache (or a numba that keeps it
    otherwise)."""
    try:
        files = kernel._cache._cache_file  # type: ignore[attr-defined]
        return [files._data_path(name) for name in files._load_index().values()]
    except AttributeError:
        return None


def drop_stale(module: str, callees: Sequence[str]) -> list[str]:
    """Empty numba's cache index of every kernel defined in `module` (an imported
    module's name) whose cached machine code was written before the last change of the
    source file of one of `callees` (the imported modules whose kernels `module`'s
    kernels call, directly or through each other), so that its next call compiles it
    again.  Returns the names of the kernels dropped, in definition order."""
    newest = max(os.stat(sys.modules[name].__file__).st_mtime for name in callees)
    dropped = []
    for name, kernel in vars(sys.modules[module]).items():
        py_func = getattr(kernel, "py_func", None)
        if getattr(py_func, "__module__", None) != module:
            continue  # not a kernel, or one imported from elsewhere
        paths = cached_files(kernel)
        if paths and any(os.path.exists(p) and os.stat(p).st_mtime < newest for p in paths):
            try:
                kernel._cache.flush()  # type: ignore[attr-defined]
            except OSError:
                continue  # a read-only cache (an installed copy, whose sources stay put)
            dropped.append(name)
    return dropped


def kernels_cold(kernels: Sequence[object]) -> bool:
    """True when a kernel of `kernels` (dispatchers with ``cache=True``) has no usable
    machine code on disk: its index missing, stale for its own file, emptied by
    `drop_stale`, or naming a file that is gone; False as well for a numba that keeps
    its cache otherwise (no way to tell)."""
    files = [cached_files(k) for k in kernels]
    if any(f is None for f in files):
        return False
    return not all(f and all(os.path.exists(p) for p in f) for f in files)


__all__ = ["cached_files", "drop_stale", "kernels_cold"]
