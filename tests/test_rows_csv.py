"""The benchmarks' CSV writer: header from the first row's keys, nothing for no rows."""

from benchmarks.rows_csv import write_rows


def test_rows_are_written_under_the_first_rows_keys(tmp_path):
    path = tmp_path / "rows.csv"
    write_rows(path, [{"query": 3, "score": 0.5}, {"query": 7, "score": 0.25}])
    assert path.read_text().splitlines() == ["query,score", "3,0.5", "7,0.25"]


def test_no_rows_writes_no_file(tmp_path):
    path = tmp_path / "none.csv"
    write_rows(path, [])
    assert not path.exists()
