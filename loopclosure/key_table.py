"""Per-keyframe columns of the loop detector as numpy arrays that grow in place.

`LoopClosureDetector` asks, at every keyframe, which older keyframes are eligible
(their stamps, sessions, frames and whether they were described): with Python lists
each question converted all of them to arrays again, O(n) per keyframe and O(n^2)
over a log (seconds at 10,000 keyframes).  `KeyTable` keeps the columns as arrays
whose capacity doubles when full (amortised O(1) append), and hands out views of
the filled part: reading a column costs nothing.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

_COLUMNS = {"stamps": np.float64, "sessions": np.int64, "frames": np.int64,
            "described": np.bool_}


class KeyTable:
    """Columns ``stamps`` [s], ``sessions``, ``frames`` and ``described`` of keys
    ``0..len-1``; each a view (writable: `frames` changes when sessions are joined)."""

    def __init__(self) -> None:
        self._n = 0
        self._data = {name: np.zeros(16, dtype) for name, dtype in _COLUMNS.items()}

    def __len__(self) -> int:
        return self._n

    def append(self, stamp: float, session: int, described: bool) -> None:
        """Add the next key: its stamp, its session (also its frame) and whether it
        was described."""
        if self._n == len(self._data["stamps"]):
            self._data = {name: np.concatenate([a, np.zeros_like(a)])
                          for name, a in self._data.items()}
        n = self._n
        self._data["stamps"][n] = stamp
        self._data["sessions"][n] = session
        self._data["frames"][n] = session
        self._data["described"][n] = described
        self._n += 1

    @property
    def stamps(self) -> NDArray[np.float64]:
        return self._data["stamps"][: self._n]

    @property
    def sessions(self) -> NDArray[np.int64]:
        return self._data["sessions"][: self._n]

    @property
    def frames(self) -> NDArray[np.int64]:
        return self._data["frames"][: self._n]

    @property
    def described(self) -> NDArray[np.bool_]:
        return self._data["described"][: self._n]


__all__ = ["KeyTable"]
