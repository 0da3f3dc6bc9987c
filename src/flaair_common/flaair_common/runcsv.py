"""Measured-run CSV (shared/measured-run-format.md): read with checks, write.

One file per bench run, one row per sample. Columns may come in any order; ground-truth
columns may be empty or NaN (video lost the wing); sensor columns never may. A file that
breaks the rules is refused with a message naming file, line and column.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

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


def read_run(path: str | Path, required: tuple[str, ...] = COLUMNS) -> MeasuredRun:
    """Read and check one measured-run CSV.

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
        Missing column, non-numeric or non-finite sensor cell, ragged row, time not
        increasing or not uniform; the message names file, line and column.
    """
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8") as handle:
            rows = list(csv.reader(handle))
    except OSError as exc:
        raise RunFileError(f"{path}: cannot read: {exc.strerror}") from exc
    except (UnicodeDecodeError, csv.Error) as exc:
        raise RunFileError(f"{path}: not a text CSV file: {exc}") from exc
    if not rows:
        raise RunFileError(f"{path}: empty file (expected a header line)")
    header = [name.strip() for name in rows[0]]
    missing = [name for name in required if name not in header]
    if missing:
        raise RunFileError(f"{path}: line 1: missing column(s) {', '.join(missing)} (header: {','.join(header)})")
    body = rows[1:]
    if not body:
        raise RunFileError(f"{path}: no data rows after the header")
    for line_no, row in enumerate(body, start=2):
        if len(row) != len(header):
            raise RunFileError(f"{path}: line {line_no}: {len(row)} cells, header has {len(header)}")
    columns: dict[str, np.ndarray] = {}
    for name in header:
        if name not in COLUMNS:
            continue
        index = header.index(name)
        cells = [row[index].strip() for row in body]
        is_truth = name in TRUTH_COLUMNS
        if is_truth:
            cells = [cell if cell else "nan" for cell in cells]
        try:
            values = np.array(cells, dtype=np.float64)
        except ValueError:
            for line_no, cell in enumerate(cells, start=2):
                try:
                    float(cell)
                except ValueError:
                    raise RunFileError(f"{path}: line {line_no}, column {name}: not a number: {cell!r}") from None
            raise
        if not is_truth:
            bad = ~np.isfinite(values)
            if bad.any():
                line_no = int(np.argmax(bad)) + 2
                raise RunFileError(f"{path}: line {line_no}, column {name}: {values[line_no - 2]} (sensor columns must be finite)")
        columns[name] = values
    sample_rate_hz = float("nan")
    if "time_s" in columns:
        time_s = columns["time_s"]
        if len(time_s) < 2:
            raise RunFileError(f"{path}: needs at least two samples")
        steps = np.diff(time_s)
        if (steps <= 0).any():
            line_no = int(np.argmax(steps <= 0)) + 3
            raise RunFileError(f"{path}: line {line_no}, column time_s: time not increasing ({time_s[line_no - 2]})")
        period_s = float(np.median(steps))
        if np.max(np.abs(steps - period_s)) > 1e-3 * period_s + 1e-9:
            line_no = int(np.argmax(np.abs(steps - period_s))) + 3
            raise RunFileError(f"{path}: line {line_no}, column time_s: sampling is not uniform")
        sample_rate_hz = 1.0 / period_s
    return MeasuredRun(name=path.stem, sample_rate_hz=sample_rate_hz, columns=columns)


def write_run(path: str | Path, columns: dict[str, np.ndarray]) -> None:
    """Write a measured-run CSV with the standard column order (missing columns left out)."""
    names = [name for name in COLUMNS if name in columns]
    table = np.column_stack([np.asarray(columns[name], dtype=np.float64) for name in names])
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", encoding="utf-8", newline="") as handle:
        handle.write(",".join(names) + "\n")
        np.savetxt(handle, table, delimiter=",", fmt="%.9g")
