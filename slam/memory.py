"""The process's memory: its peak, and handing freed heap back to the system.

glibc's malloc keeps memory that numpy frees in its heap (the threshold above
which it maps large blocks on their own grows with the blocks a run frees), so
a run's resident size only climbs: the transient arrays of one phase (the final
optimisation, one occupancy grid) stay resident under the next.
`release_free_memory` calls ``malloc_trim(0)``, which returns every free page of
the heap to the system; the pipeline calls it between such phases.  Elsewhere
than glibc it does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import resource
from collections.abc import Callable
from pathlib import Path

__all__ = ["peak_rss_mb", "peak_rss_since_reset_mb", "release_free_memory", "reset_peak_rss"]


def peak_rss_mb() -> float:
    """Peak resident memory of this process [MB] (Linux: ru_maxrss is in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def reset_peak_rss() -> bool:
    """Reset this process's peak resident memory (Linux ``clear_refs``); False where
    that cannot be done."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def peak_rss_since_reset_mb(reset: bool) -> float:
    """Peak resident memory [MB] since `reset_peak_rss` (VmHWM) when `reset` (its
    result), else of the whole process (`peak_rss_mb`)."""
    if reset:
        try:
            for line in Path("/proc/self/status").read_text().splitlines():
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
        except (OSError, ValueError, IndexError):
            pass
    return peak_rss_mb()


@functools.cache
def _malloc_trim() -> Callable[[int], int] | None:
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim = libc.malloc_trim
    except (OSError, AttributeError):  # not glibc (macOS, musl)
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


def release_free_memory() -> bool:
    """Return the heap's free pages to the system (glibc ``malloc_trim(0)``); True when
    the C library has it."""
    trim = _malloc_trim()
    if trim is None:
        return False
    trim(0)
    return True
