"""Measured-run CSV (docs/LAB_CSV_FORMAT.md): read with checks, write.

One file per bench run, one row per sample. Columns may come in any order; ground-truth
columns may be empty or NaN (video lost the wing); sensor columns never may. A file that
breaks the rules is refused with a message naming file, line and column.
"""

from __future__ import annotations

import csv
import itertools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from flaair_model.checked_files import CheckedFileError, check_file, printable

SENSOR_COLUMNS = ("time_s", "drive_v", "stroke_sensor_v", "pitch_sensor_v")
TRUTH_COLUMNS = ("stroke_deg", "pitch_deg")
COLUMNS = SENSOR_COLUMNS + TRUTH_COLUMNS


class RunFileError(ValueError):
    """A measured-run file breaks the format; the message names file, line and column."""


@dataclass(frozen=True)
class MeasuredRun:
    """One bench run: uniformly sampled columns (NaN where ground truth is missing)."""

    name: str
    sample_rate_hz: float
    columns: dict[str, np.ndarray]

    def __getitem__(self, column: str) -> np.ndarray:
        return self.columns[column]


# rows parsed at a time: their Python strings are the only memory beside the result
CHUNK_LINES = 1 << 13
_COUNT_BYTES = 1 << 20  # bytes read at a time while counting lines


def _floats(cells: list[str], path: Path, first_line: int, name: str) -> np.ndarray:
    """Cells as float64; a cell that is not a number is named by line and column."""
    try:
        return np.array(cells, dtype=np.float64)
    except (ValueError, OverflowError):
        for offset, cell in enumerate(cells):
            try:
                np.array([cell], dtype=np.float64)
            except (ValueError, OverflowError):
                raise RunFileError(
                    f"{path}: line {first_line + offset}, column {name}: not a number: {cell!r}"
                ) from None
        raise RunFileError(
            f"{path}: lines {first_line}-{first_line + len(cells) - 1}, column {name}: not numbers"
        ) from None


def _header(path: Path, line: str, required: tuple[str, ...]) -> list[str]:
    """Column names of the header line; a missing or duplicated column is refused by name."""
    header = [name.strip() for name in next(csv.reader([line]), [])]
    if not any(header):
        raise RunFileError(f"{path}: line 1: empty header line (expected column names)")
    seen: dict[str, int] = {}
    for number, name in enumerate(header, start=1):
        if name in seen:
            raise RunFileError(
                f"{path}: line 1, column {number}: duplicate column {name!r} "
                f"(also column {seen[name]}); keep one"
            )
        seen[name] = number
    missing = [name for name in required if name not in header]
    if missing:
        raise RunFileError(
            f"{path}: line 1: missing column(s) {', '.join(missing)} (header: {','.join(header)})"
        )
    return header


def count_lines(path: str | Path) -> int:
    r"""Lines in a text file as `open(path, newline="")` splits them (at \n, \r and \r\n).

    A last line without a terminator counts. Reads the bytes a block at a time (no decoding).
    """
    lines = 0
    previous_cr = False
    last = b""
    with open(path, "rb") as handle:
        while block := handle.read(_COUNT_BYTES):
            lines += block.count(b"\n") + block.count(b"\r") - block.count(b"\r\n")
            if previous_cr and block.startswith(b"\n"):  # a \r\n split between two blocks
                lines -= 1
            previous_cr = block.endswith(b"\r")
            last = block[-1:]
    return lines + (1 if last not in (b"", b"\n", b"\r") else 0)


def read_run(path: str | Path, required: tuple[str, ...] = COLUMNS) -> MeasuredRun:
    """Read and check one measured-run CSV, a block of rows at a time.

    A UTF-8 byte-order mark (Excel's "CSV UTF-8") is accepted. Memory stays near the size
    of the returned arrays: the lines are counted first, then rows are parsed `CHUNK_LINES`
    at a time straight into float64 arrays of that length (nothing is concatenated).

    Parameters
    ----------
    path
        The CSV file.
    required
        Columns that must be present (`bin/flaair simulate` needs only time_s and drive_v).

    Returns
    -------
    MeasuredRun
        Columns as float64 arrays; empty ground-truth cells are NaN.

    Raises
    ------
    RunFileError
        Missing or duplicated column, non-numeric or non-finite sensor cell, ragged row, time
        not increasing or not uniform; the message names file, line and column.
    """
    path = Path(path)
    columns: dict[str, np.ndarray] = {}
    rows = 0
    try:
        check_file(path, "csv", pipe=True)  # no directory, no device (/dev/zero), bounded
        # a pipe (`<(...)`) is read once: its arrays grow as rows come instead
        capacity = max(count_lines(path) - 1, 0) if path.is_file() else 0
        with open(path, newline="", encoding="utf-8-sig") as handle:
            first = handle.readline()
            if not first:
                raise RunFileError(f"{path}: empty file (expected a header line)")
            header = _header(path, first, required)
            wanted = [(index, name) for index, name in enumerate(header) if name in COLUMNS]
            columns = {name: np.empty(capacity, dtype=np.float64) for _, name in wanted}
            while True:
                lines = list(itertools.islice(handle, CHUNK_LINES))
                if not lines:
                    break
                if rows + len(lines) > capacity:  # a pipe, or a file that grew after it was counted
                    capacity = max(rows + len(lines), 2 * capacity)
                    columns = {name: _grown(values, capacity) for name, values in columns.items()}
                _parse_rows(path, lines, rows + 2, len(header), wanted, columns, rows)
                rows += len(lines)
    except OSError as exc:
        raise RunFileError(f"{path}: cannot read: {exc.strerror}") from exc
    except CheckedFileError as exc:
        raise RunFileError(str(exc)) from None
    except UnicodeDecodeError as exc:
        raise RunFileError(
            f"{path}: not a UTF-8 text CSV file: {exc.reason} at byte {exc.start}"
        ) from exc
    if not columns or rows == 0:
        raise RunFileError(f"{path}: no data rows after the header")
    # fewer rows than room for them (a pipe, a file that shrank): keep only the rows read
    if rows < capacity:
        columns = {name: values[:rows].copy() for name, values in columns.items()}
    return MeasuredRun(
        name=printable(path.stem), sample_rate_hz=_sample_rate_hz(path, columns), columns=columns
    )


def _grown(values: np.ndarray, length: int) -> np.ndarray:
    """`values` in a longer array (its first len(values) entries kept)."""
    grown = np.empty(length, dtype=values.dtype)
    grown[: len(values)] = values
    return grown


def _parse_rows(
    path: Path,
    lines: list[str],
    first_line: int,
    width: int,
    wanted: list[tuple[int, str]],
    columns: dict[str, np.ndarray],
    start: int,
) -> None:
    """Parse one block of lines into `columns[name][start:start
    + len(lines)]` (checks as `read_run`).
    """
    try:
        rows = list(csv.reader(lines))
    except csv.Error as exc:
        last_line = first_line + len(lines) - 1
        raise RunFileError(
            f"{path}: lines {first_line}-{last_line}: not a CSV file: {exc}"
        ) from None
    if len(rows) != len(lines):  # a quoted cell spanning lines: the line numbers below would drift
        raise RunFileError(
            f"{path}: lines {first_line}-{first_line + len(lines) - 1}: a quoted cell spans lines"
        )
    for offset, row in enumerate(rows):
        if len(row) != width:
            raise RunFileError(
                f"{path}: line {first_line + offset}: {len(row)} cells, header has {width}"
            )
    for index, name in wanted:
        is_truth = name in TRUTH_COLUMNS
        cells = [row[index].strip() or ("nan" if is_truth else "") for row in rows]
        values = _floats(cells, path, first_line, name)
        if not is_truth:
            bad = ~np.isfinite(values)
            if bad.any():
                offset = int(np.argmax(bad))
                raise RunFileError(
                    f"{path}: line {first_line + offset}, column {name}: "
                    f"{values[offset]} (sensor columns must be finite)"
                )
        columns[name][start : start + len(values)] = values


def _sample_rate_hz(path: Path, columns: dict[str, np.ndarray]) -> float:
    """Sample rate from time_s (NaN if there is none); time must increase uniformly.

    Holds one array of time steps beside the columns (the median partitions it in place).
    """
    if "time_s" not in columns:
        return float("nan")
    time_s = columns["time_s"]
    if len(time_s) < 2:
        raise RunFileError(f"{path}: needs at least two samples")
    steps = np.diff(time_s)
    if steps.min() <= 0:
        line_no = int(np.argmax(steps <= 0)) + 3
        raise RunFileError(
            f"{path}: line {line_no}, column time_s: time not increasing ({time_s[line_no - 2]})"
        )
    shortest, longest = steps.min(), steps.max()
    period_s = float(np.median(steps, overwrite_input=True))
    # max |step - period|
    if max(longest - period_s, period_s - shortest) > 1e-3 * period_s + 1e-9:
        steps = np.diff(time_s)  # unpartitioned again, to name the line
        line_no = int(np.argmax(np.abs(steps - period_s))) + 3
        raise RunFileError(f"{path}: line {line_no}, column time_s: sampling is not uniform")
    return 1.0 / period_s


def write_run(path: str | Path, columns: dict[str, np.ndarray]) -> None:
    """Write a measured-run CSV with the standard column order (missing columns left out)."""
    names = [name for name in COLUMNS if name in columns]
    table = np.column_stack([np.asarray(columns[name], dtype=np.float64) for name in names])
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", encoding="utf-8", newline="") as handle:
        handle.write(",".join(names) + "\n")
        np.savetxt(handle, table, delimiter=",", fmt="%.9g")
