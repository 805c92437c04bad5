"""`loopclosure.key_table.KeyTable`: columns that grow in place, views that write through."""

import numpy as np

from loopclosure.key_table import KeyTable


def test_columns_hold_every_appended_key_past_growth() -> None:
    table = KeyTable()
    for k in range(40):  # past the initial capacity of 16, twice
        table.append(0.5 * k, k // 20, k % 3 != 0)
    assert len(table) == 40
    np.testing.assert_array_equal(table.stamps, 0.5 * np.arange(40))
    np.testing.assert_array_equal(table.sessions, np.arange(40) // 20)
    np.testing.assert_array_equal(table.frames, table.sessions)
    np.testing.assert_array_equal(table.described, np.arange(40) % 3 != 0)


def test_frames_view_writes_through() -> None:
    table = KeyTable()
    for k in range(5):
        table.append(float(k), int(k >= 3), True)
    frames = table.frames
    frames[table.sessions == 1] = 0
    np.testing.assert_array_equal(table.frames, np.zeros(5))
    np.testing.assert_array_equal(table.sessions, [0, 0, 0, 1, 1])
