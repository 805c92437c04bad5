"""Row storage of the place database: growing float32 rows and the key -> row index.

Every stored keyframe is one row, numbered in insertion order.  Two structures keep
that bookkeeping out of `loopclosure.place_database.PlaceDatabase`:

- `FloatRows`: a float32 ``(M, D)`` array grown by amortised doubling (appending never
  re-stacks the stored rows), e.g. the range functions behind the heading hypotheses
  (another dtype on request: the bit-packed dilated polar grids are uint8 rows).
  The prefilter vectors use `loopclosure.matchers.vector_search.VectorStore`, the same
  growth with squared norms for the distance arithmetic.
- `KeyIndex`: the keys (any hashable values, e.g. keyframe ids) in insertion order and
  their row numbers.  Integer keys added in increasing order are looked up in bulk
  with ``np.searchsorted``; any other key sequence falls back to a dict.

An unknown or repeated key is the caller's mistake: `UserError` naming the key.
"""

from __future__ import annotations

from collections.abc import Hashable, Iterable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data.errors import UserError


class FloatRows:
    """A float32 (or `dtype`) ``(M, D)`` array grown by amortised doubling."""

    def __init__(self, dim: int, capacity: int = 64, dtype: type = np.float32) -> None:
        self._data = np.zeros((capacity, dim), dtype)
        self._size = 0

    def append(self, row: ArrayLike) -> None:
        """Store one ``(D,)`` row (cast to the rows' dtype)."""
        if self._size == len(self._data):
            grown = np.zeros((2 * len(self._data), self._data.shape[1]), self._data.dtype)
            grown[: self._size] = self._data
            self._data = grown
        self._data[self._size] = row
        self._size += 1

    @property
    def data(self) -> NDArray[np.float32]:
        """``(M, D)`` view of the stored rows."""
        return self._data[: self._size]


class KeyIndex:
    """Keys in insertion order and the row number of each (module docstring)."""

    def __init__(self) -> None:
        self._keys: list[Hashable] = []
        self._index: dict[Hashable, int] = {}
        # The keys while every one is an int larger than the last (None after one is
        # not), grown by amortised doubling: `rows` searches them without a copy.
        self._int_keys: FloatRows | None = FloatRows(1, dtype=np.int64)

    def __len__(self) -> int:
        return len(self._keys)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._index

    @property
    def keys(self) -> list[Hashable]:
        """Stored keys in insertion order (a copy)."""
        return list(self._keys)

    def key(self, row: int) -> Hashable:
        """The key stored at `row`."""
        return self._keys[row]

    def check_new(self, key: Hashable) -> None:
        """Raise `UserError` if `key` is already stored."""
        if key in self._index:
            raise UserError(f"key {key!r} is already in the place database")

    def add(self, key: Hashable) -> int:
        """Store a new `key` (see `check_new`); returns its row."""
        self.check_new(key)
        row = len(self._keys)
        self._keys.append(key)
        self._index[key] = row
        if self._int_keys is not None:
            last = self._int_keys.data[-1:, 0]
            if (isinstance(key, int | np.integer) and -(2**63) <= int(key) < 2**63
                    and (not len(last) or int(key) > last[0])):
                self._int_keys.append([int(key)])
            else:
                self._int_keys = None
        return row

    def row(self, key: Hashable) -> int:
        """The row of `key` (`UserError` if it is not stored)."""
        try:
            return self._index[key]
        except KeyError:
            raise UserError(f"key {key!r} is not in the place database") from None

    def rows(self, keys: Iterable[Hashable]) -> NDArray[np.intp]:
        """Rows of `keys` (an unknown key raises `UserError`)."""
        arr = np.asarray(keys if not isinstance(keys, set | frozenset) else list(keys))
        if arr.size == 0:
            return np.zeros(0, np.intp)
        if self._int_keys is not None and np.issubdtype(arr.dtype, np.integer):
            table = self._int_keys.data[:, 0]
            idx = np.searchsorted(table, arr.ravel())
            ok = idx < len(table)
            ok[ok] = table[idx[ok]] == arr.ravel()[ok]
            if not ok.all():
                raise UserError(f"key {arr.ravel()[~ok][0]!r} is not in the place database")
            return idx.astype(np.intp)
        return np.fromiter((self.row(k) for k in arr.ravel().tolist()), np.intp)


__all__ = ["FloatRows", "KeyIndex"]
