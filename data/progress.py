"""`ReadProgress`: how far the current pass of a reader has got through its input.

A progress display needs a total before the pass starts; counting the scans of a
log would mean reading it twice.  A reader states instead what it knows without
reading: the size of the stored (possibly compressed) file in bytes, or the scan
count of a bag's index, and advances `done` and `scans` as it reads.  Both live in
shared memory, so a pass iterated in a forked worker process is seen from the
parent.

A consumer that lags the reader (a worker reading ahead) compares its own count
with `scan_total`: the scans the whole input holds, exact for a scan-counted
input or a finished pass, else extrapolated from the scans per byte read so far,
``scans * total / done``.
"""

from __future__ import annotations

import multiprocessing as mp


class ReadProgress:
    """`done` of `total` `unit`s of one pass, and the `scans` it has read.

    `unit` is ``"bytes"``: bytes of the stored file consumed (compressed bytes for
    a compressed file, interpolated within each decompressed piece), or
    ``"scans"``: scans read.  `total` is None when unknown.  `scans` counts scans
    as their data is read, so `scans` / `done` is the input's density even when
    the reader holds scans back before releasing them; at the end of the pass it
    is the count released.  Written by one reader, read by anyone.
    """

    def __init__(self, total: int | None, unit: str) -> None:
        if unit not in ("bytes", "scans"):
            raise ValueError(f"unit must be 'bytes' or 'scans', got {unit!r}")
        self.total = total
        self.unit = unit
        self.cell = mp.RawValue("q", 0)
        """`done` in anonymous shared memory (survives a fork); a hot loop sets
        ``cell.value`` directly."""
        self.scan_cell = mp.RawValue("q", 0)
        """`scans` in shared memory."""
        self.finished = mp.RawValue("b", 0)

    @property
    def done(self) -> int:
        """Units consumed so far by the current pass."""
        return int(self.cell.value)

    @done.setter
    def done(self, value: int) -> None:
        self.cell.value = value

    @property
    def scans(self) -> int:
        """Scans read so far by the current pass (released or held back)."""
        return int(self.scan_cell.value)

    @scans.setter
    def scans(self, value: int) -> None:
        self.scan_cell.value = value

    def start(self) -> None:
        """A new pass: nothing read yet."""
        self.done = self.scans = 0
        self.finished.value = 0

    def finish(self) -> None:
        """The pass has read the whole input: `scans` is the input's scan count."""
        if self.unit == "bytes" and self.total is not None:
            self.done = self.total
        self.finished.value = 1

    def scan_total(self) -> tuple[int | None, bool]:
        """``(scans of the whole input, exact)``: exact once the pass has finished or
        when the unit is scans; else ``scans * total / done`` rounded (at least
        `scans`), or None before anything is read."""
        if self.finished.value:
            return self.scans, True
        if self.unit == "scans":
            return self.total, self.total is not None
        done, scans = self.done, self.scans
        if not self.total or done <= 0 or scans <= 0:
            return None, False
        return max(scans, round(scans * self.total / done)), False

    def __getstate__(self) -> tuple[int | None, str, int, int, int]:
        """Pickled as plain numbers: a copy in another process starts its own count."""
        return self.total, self.unit, self.done, self.scans, int(self.finished.value)

    def __setstate__(self, state: tuple[int | None, str, int, int, int]) -> None:
        self.__init__(state[0], state[1])  # type: ignore[misc]
        self.done, self.scans, self.finished.value = state[2], state[3], state[4]

    def fraction(self) -> float | None:
        """`done` / `total` clipped to [0, 1]; None when the total is unknown or zero."""
        if not self.total:
            return None
        return min(max(self.done / self.total, 0.0), 1.0)
