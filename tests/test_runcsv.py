"""Measured-run CSV reader (issue 15 item 8): counted lines, rows parsed straight into their
arrays a block at a time, every check and line number the same across block boundaries.
"""

from __future__ import annotations

import csv
import os
import threading
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from flaair_common import runcsv
from flaair_common.runcsv import COLUMNS, RunFileError, count_lines, read_run

FS_HZ = 20000.0


def _columns(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    time_s = np.arange(n) / FS_HZ
    columns = {
        "time_s": time_s,
        "drive_v": 100.0 * np.sin(2 * np.pi * 120.0 * time_s),
        "stroke_sensor_v": 1.25 + rng.normal(0.0, 0.1, n),
        "pitch_sensor_v": 1.25 + rng.normal(0.0, 0.05, n),
        "stroke_deg": 30.0 * rng.standard_normal(n),
        "pitch_deg": 20.0 * rng.standard_normal(n),
    }
    columns["stroke_deg"][::7] = np.nan  # video lost the wing
    return columns


def _write(
    path: Path,
    columns: dict[str, np.ndarray],
    newline: str = "\n",
    bom: bool = False,
    last_newline: bool = True,
) -> list[list[str]]:
    """Write with repr() floats (exact float64 round trip); return the cell table as written."""
    table = [list(COLUMNS)] + [
        ["" if np.isnan(columns[name][k]) else repr(float(columns[name][k])) for name in COLUMNS]
        for k in range(len(columns["time_s"]))
    ]
    text = newline.join(",".join(row) for row in table) + (newline if last_newline else "")
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + text.encode())
    return table


@pytest.mark.parametrize("newline", ["\n", "\r\n", "\r"])
@pytest.mark.parametrize("last_newline", [True, False])
def test_values_are_exact_float64_across_block_boundaries(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, newline: str, last_newline: bool
) -> None:
    monkeypatch.setattr(runcsv, "CHUNK_LINES", 7)  # 1000 rows cross ~140 block boundaries
    monkeypatch.setattr(runcsv, "_COUNT_BYTES", 13)  # and \r\n pairs split between counted blocks
    columns = _columns(1000)
    path = tmp_path / "run.csv"
    _write(path, columns, newline=newline, bom=True, last_newline=last_newline)
    run = read_run(path)
    # an independent reader: csv, whole file
    with open(path, newline="", encoding="utf-8-sig") as handle:
        rows = list(csv.reader(handle))
    for index, name in enumerate(rows[0]):
        expected = np.array([float(row[index]) if row[index] else np.nan for row in rows[1:]])
        assert run[name].dtype == np.float64 and run[name].shape == (1000,)
        # bit-exact, NaN where the cell was empty
        np.testing.assert_array_equal(run[name], expected)
        np.testing.assert_array_equal(run[name], columns[name])
    assert run.sample_rate_hz == pytest.approx(FS_HZ, rel=1e-9)


@pytest.mark.parametrize(
    "text, lines",
    [
        ("", 0),
        ("a", 1),
        ("a\n", 1),
        ("a\nb", 2),
        ("a\r\nb\r\n", 2),
        ("a\rb\r", 2),
        ("a\r\rb", 3),
        ("a\n\nb\n", 3),
        ("\r\n\r\n\n", 3),
    ],
)
@pytest.mark.parametrize("block_bytes", [1, 2, 3, 1 << 20])
def test_count_lines_splits_as_text_mode_does(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, text: str, lines: int, block_bytes: int
) -> None:
    monkeypatch.setattr(runcsv, "_COUNT_BYTES", block_bytes)
    path = tmp_path / "lines.txt"
    path.write_bytes(text.encode())
    with open(path, newline="") as handle:
        assert len(handle.readlines()) == lines
    assert count_lines(path) == lines


@pytest.mark.parametrize(
    "line, column, cell, message",
    [
        (2, "drive_v", "abc", "line 2, column drive_v: not a number: 'abc'"),
        (9, "pitch_sensor_v", "x1", "line 9, column pitch_sensor_v: not a number: 'x1'"),
        (16, "time_s", "", "line 16, column time_s: not a number: ''"),
        (
            17,
            "stroke_sensor_v",
            "inf",
            "line 17, column stroke_sensor_v: inf (sensor columns must be finite)",
        ),
        (30, "stroke_deg", "deg", "line 30, column stroke_deg: not a number: 'deg'"),
    ],
)
def test_a_bad_cell_is_named_by_its_line_in_any_block(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, line: int, column: str, cell: str, message: str
) -> None:
    monkeypatch.setattr(runcsv, "CHUNK_LINES", 7)  # blocks start at lines 2, 9, 16, 23, 30, ...
    path = tmp_path / "bad.csv"
    table = _write(path, _columns(40))
    table[line - 1][COLUMNS.index(column)] = cell
    path.write_text("\n".join(",".join(row) for row in table) + "\n")
    with pytest.raises(RunFileError) as info:
        read_run(path)
    assert str(info.value) == f"{path}: {message}"


def test_ragged_row_and_empty_body_keep_their_messages(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(runcsv, "CHUNK_LINES", 7)
    path = tmp_path / "ragged.csv"
    table = _write(path, _columns(40))
    table[24] = table[24][:-1]
    path.write_text("\n".join(",".join(row) for row in table) + "\n")
    with pytest.raises(RunFileError, match=rf"^{path}: line 25: 5 cells, header has 6$"):
        read_run(path)
    path.write_text(",".join(COLUMNS) + "\n")
    with pytest.raises(RunFileError, match=rf"^{path}: no data rows after the header$"):
        read_run(path)
    path.write_text("")
    with pytest.raises(RunFileError, match=rf"^{path}: empty file \(expected a header line\)$"):
        read_run(path)


@pytest.mark.slow  # reads a large run file under a memory probe
def test_reading_holds_no_second_copy_of_the_columns(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Peak allocation while reading stays within the result, one column of time steps (the
    sample-rate check) and one block's strings: the rows go straight into their arrays
    (per-block parts concatenated held the result and a column of parts at once, and the
    rate check three more columns).
    """
    monkeypatch.setattr(runcsv, "CHUNK_LINES", 1000)
    path = tmp_path / "run.csv"
    _write(path, _columns(60_000))
    read_run(path)  # first call: imports and caches out of the measurement
    tracemalloc.start()
    try:
        run = read_run(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    result_bytes = sum(values.nbytes for values in run.columns.values())
    assert result_bytes == 6 * 8 * 60_000
    time_steps_bytes = 8 * 60_000
    # one block of lines, rows and cells as Python strings (about 600 B a row)
    block_strings_bytes = 1000 * 600
    assert peak < result_bytes + time_steps_bytes + block_strings_bytes, (peak, result_bytes)


def test_a_pipe_is_read_once_and_gives_the_same_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`bin/flaair import <(unzip -p runs.zip run.csv)`: no line count first (it would consume the
    pipe); the arrays grow as blocks arrive and end at the row count.
    """
    monkeypatch.setattr(runcsv, "CHUNK_LINES", 7)
    columns = _columns(1000)
    path = tmp_path / "run.csv"
    _write(path, columns)
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    writer = threading.Thread(target=lambda: fifo.write_bytes(path.read_bytes()))
    writer.start()
    try:
        run = read_run(fifo)
    finally:
        writer.join(timeout=30)
    for name in COLUMNS:
        assert run[name].shape == (1000,)
        np.testing.assert_array_equal(run[name], columns[name])
