"""The place database's key index (`loopclosure.place_rows.KeyIndex`)."""

from __future__ import annotations

import numpy as np
import pytest

from data.errors import UserError
from loopclosure.place_rows import KeyIndex


def test_increasing_int_keys_past_the_first_growth() -> None:
    index = KeyIndex()
    keys = [3 * i + 1 for i in range(150)]  # more than the first capacity (64)
    for k in keys[:70]:
        index.add(k)
    np.testing.assert_array_equal(index.rows(np.array([1, 208, 4])), [0, 69, 1])
    for k in keys[70:]:
        index.add(np.int64(k))
    np.testing.assert_array_equal(index.rows(np.array(keys[::-7])), np.arange(150)[::-7])
    assert index.rows([]).shape == (0,)
    with pytest.raises(UserError, match="not in the place database"):
        index.rows(np.array([1, 2]))  # 2 lies between two stored keys
    with pytest.raises(UserError, match="not in the place database"):
        index.rows(np.array([10_000]))  # beyond the last key


def test_keys_out_of_order_or_not_ints_are_looked_up_one_by_one() -> None:
    index = KeyIndex()
    for k in (5, 9, 7, 2**70):  # 7 breaks the increasing order; 2**70 is no int64
        index.add(k)
    np.testing.assert_array_equal(index.rows(np.array([7, 5, 9])), [2, 0, 1])
    assert index.row(2**70) == 3
    named = KeyIndex()
    for k in ("a", "b"):
        named.add(k)
    np.testing.assert_array_equal(named.rows(["b", "a"]), [1, 0])
    with pytest.raises(UserError, match="already"):
        named.add("a")
    huge = KeyIndex()
    huge.add(2**64)  # an int key beyond int64: looked up by the dictionary
    huge.add(2**65)
    np.testing.assert_array_equal(huge.rows([2**65]), [1])
