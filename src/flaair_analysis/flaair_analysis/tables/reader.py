"""A lab's frequency-response table (shared/sweep-tables.md): read, check, summarise. Pure.

One row per measured point (one drive level at one frequency), a header naming the columns in
any order, `#` comments. Refusals are `TableInputError`s whose message names the line and the
column; nothing is guessed.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "AMPLITUDE_COLUMNS",
    "PHASE_COLUMNS",
    "PLAUSIBLE_DEG",
    "RESPONSE_COLUMNS",
    "LevelSummary",
    "Table",
    "TableInputError",
    "TableLimits",
    "read_table",
    "summarise",
]

AMPLITUDE_COLUMNS: tuple[str, ...] = (
    "stroke_pp_deg",
    "stroke_amplitude_deg",
    "pitch_pp_deg",
    "pitch_amplitude_deg",
)
PHASE_COLUMNS: tuple[str, ...] = ("stroke_phase_deg", "pitch_phase_deg")
RESPONSE_COLUMNS: tuple[str, ...] = AMPLITUDE_COLUMNS + PHASE_COLUMNS
_DRIVE_COLUMNS = ("drive_amplitude_v", "drive_pp_v")
_KNOWN = ("frequency_hz", *_DRIVE_COLUMNS, "drive_bias_v", "robot", *RESPONSE_COLUMNS)
_LEVEL_DECIMALS = 9  # drive levels equal to 1 nV are one level
# the largest magnitude a cell may hold (deg): a wing angle past a full turn, a phase past two
# turns, is a typing or unit error (3081 for 30.81), as for a run's samples (signal_ranges)
PLAUSIBLE_DEG: dict[str, float] = {
    "stroke_pp_deg": 360.0,
    "stroke_amplitude_deg": 180.0,
    "pitch_pp_deg": 360.0,
    "pitch_amplitude_deg": 180.0,
    "stroke_phase_deg": 720.0,
    "pitch_phase_deg": 720.0,
}
_OTHER_SEPARATORS = {";": "semicolons (';')", "\t": "tabs", "|": "bars ('|')"}


class TableInputError(ValueError):
    """A table refused: the message names the file, the line and the column."""


@dataclass(frozen=True)
class TableLimits:
    """The plant's range a table's points must lie in.

    Attributes
    ----------
    min_frequency_hz, max_frequency_hz : drive frequencies the steady-state model covers.
    drive_limit_v : the actuator's safe range; |bias| + amplitude must not exceed it.
    """

    min_frequency_hz: float
    max_frequency_hz: float
    drive_limit_v: float


@dataclass(frozen=True)
class Table:
    """One robot's table, one entry per measured point (SI-named columns, NaN = not measured).

    Attributes
    ----------
    name : the robot's name (the `robot` column, else the file's stem).
    source : where it was read from.
    frequency_hz : (n,) drive frequency.
    drive_amplitude_v : (n,) sine amplitude at the actuator (half the peak to peak).
    drive_bias_v : (n,) constant bias the sine rides on.
    responses : column -> (n,) values, for each response column the table has.
    line : (n,) line number of each point in its file.
    """

    name: str
    source: str
    frequency_hz: np.ndarray
    drive_amplitude_v: np.ndarray
    drive_bias_v: np.ndarray
    responses: Mapping[str, np.ndarray]
    line: np.ndarray
    comments: tuple[str, ...] = field(default=())

    @property
    def n_points(self) -> int:
        """Number of measured points."""
        return int(self.frequency_hz.size)

    @property
    def levels_v(self) -> np.ndarray:
        """(L,) the distinct drive amplitudes, ascending."""
        return np.unique(np.round(self.drive_amplitude_v, _LEVEL_DECIMALS))

    @property
    def level_index(self) -> np.ndarray:
        """(n,) index into `levels_v` of each point."""
        return np.searchsorted(self.levels_v, np.round(self.drive_amplitude_v, _LEVEL_DECIMALS))

    def subset(self, mask: np.ndarray) -> Table:
        """The points where `mask` is true."""
        return Table(
            self.name,
            self.source,
            self.frequency_hz[mask],
            self.drive_amplitude_v[mask],
            self.drive_bias_v[mask],
            {k: v[mask] for k, v in self.responses.items()},
            self.line[mask],
            self.comments,
        )


@dataclass(frozen=True)
class LevelSummary:
    """One drive level of a table: its frequencies and the peak of its first amplitude column."""

    drive_amplitude_v: float
    n_points: int
    min_frequency_hz: float
    max_frequency_hz: float
    peak_column: str | None
    peak_frequency_hz: float | None
    peak_value: float | None


def _number(text: str, where: str, *, positive: bool = False) -> float:
    try:
        value = float(text)
    except ValueError:
        raise TableInputError(f"{where}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise TableInputError(f"{where}: {text!r} is not a finite number")
    if positive and value <= 0.0:
        raise TableInputError(f"{where}: must be a positive number, got {text}")
    return value


def _header(row: list[str], where: str) -> list[str]:
    names = [c.strip() for c in row]
    for name in names:
        sep = next((s for s in _OTHER_SEPARATORS if s in name), None)
        if name not in _KNOWN and sep is not None:
            raise TableInputError(
                f"{where}: the cells are separated by {_OTHER_SEPARATORS[sep]}; a table's "
                "cells are separated by commas (save it as comma-separated CSV)"
            )
        if name not in _KNOWN:
            hint = (
                " (a drive column is drive_amplitude_v or drive_pp_v, in volts)"
                if name.startswith("drive")
                else f" (known: {', '.join(_KNOWN)})"
            )
            raise TableInputError(f"{where}, column {name!r}: unknown column{hint}")
        if names.count(name) > 1:
            raise TableInputError(f"{where}, column {name!r}: given twice")
    if "frequency_hz" not in names:
        raise TableInputError(f"{where}: no frequency_hz column")
    drives = [d for d in _DRIVE_COLUMNS if d in names]
    if len(drives) != 1:
        raise TableInputError(
            f"{where}: give the drive level in exactly one of drive_amplitude_v, drive_pp_v"
            f" (found {', '.join(drives) or 'none'})"
        )
    if not any(c in names for c in RESPONSE_COLUMNS):
        raise TableInputError(f"{where}: no response column (one of {', '.join(RESPONSE_COLUMNS)})")
    return names


def _check_point(values: dict[str, float], where: str, col: str, limits: TableLimits) -> None:
    f = values["frequency_hz"]
    if not limits.min_frequency_hz <= f <= limits.max_frequency_hz:
        raise TableInputError(
            f"{where}, column 'frequency_hz': {f:g} Hz is outside the plant's range "
            f"{limits.min_frequency_hz:g}-{limits.max_frequency_hz:g} Hz"
        )
    peak = values["drive_amplitude_v"] + abs(values["drive_bias_v"])
    if peak > limits.drive_limit_v:
        raise TableInputError(
            f"{where}, column {col!r}: the drive reaches {peak:g} V, beyond the actuator's "
            f"{limits.drive_limit_v:g} V limit"
        )


def _row(
    names: list[str], row: list[str], where: str, limits: TableLimits
) -> tuple[str | None, dict[str, float]]:
    if len(row) != len(names):
        raise TableInputError(f"{where}: {len(row)} cells, the header names {len(names)}")
    cells = {n: c.strip() for n, c in zip(names, row, strict=True)}
    values: dict[str, float] = {}
    for name in ("frequency_hz", *_DRIVE_COLUMNS):
        if name in cells:
            if not cells[name]:
                raise TableInputError(f"{where}, column {name!r}: empty")
            values[name] = _number(cells[name], f"{where}, column {name!r}", positive=True)
    drive_col = "drive_pp_v" if "drive_pp_v" in values else "drive_amplitude_v"
    if drive_col == "drive_pp_v":
        values["drive_amplitude_v"] = values.pop("drive_pp_v") / 2.0
    bias = cells.get("drive_bias_v", "")
    values["drive_bias_v"] = _number(bias, f"{where}, column 'drive_bias_v'") if bias else 0.0
    for name in RESPONSE_COLUMNS:
        text = cells.get(name, "")
        if text:
            v = _number(text, f"{where}, column {name!r}")
            if name in AMPLITUDE_COLUMNS and v < 0.0:
                raise TableInputError(f"{where}, column {name!r}: an amplitude cannot be {v:g}")
            if abs(v) > PLAUSIBLE_DEG[name]:
                raise TableInputError(
                    f"{where}, column {name!r}: {text} deg is beyond the plausible "
                    f"+-{PLAUSIBLE_DEG[name]:g} deg: check the cell's decimal point and unit"
                )
            values[name] = v
    if not any(n in values for n in RESPONSE_COLUMNS):
        raise TableInputError(f"{where}: no response measured (every response cell is empty)")
    _check_point(values, where, drive_col, limits)
    return cells.get("robot") or None, values


def read_table(text: str, source: str, limits: TableLimits) -> list[Table]:
    """The tables in one CSV text (one per robot named in a `robot` column).

    Parameters
    ----------
    text
        The file's contents.
    source
        Its name in messages (a path); the stem names a table without a `robot` column.
    limits
        The plant's frequency and drive range.

    Returns
    -------
    list of Table
        In the order each robot first appears.

    Raises
    ------
    TableInputError
        Naming the line and the column of the first problem.
    """
    names: list[str] | None = None
    comments: list[str] = []
    rows: dict[str | None, list[tuple[int, dict[str, float]]]] = {}
    seen: dict[tuple[str | None, float, float, float], int] = {}
    for lineno, raw in enumerate(text.removeprefix("\ufeff").splitlines(), start=1):
        stripped = raw.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            comments.append(stripped.lstrip("#").strip())
            continue
        where = f"{source} line {lineno}"
        row = next(csv.reader(io.StringIO(raw)))
        if names is None:
            names = _header(row, where)
            continue
        robot, values = _row(names, row, where, limits)
        key = (
            robot,
            round(values["drive_amplitude_v"], _LEVEL_DECIMALS),
            values["drive_bias_v"],
            values["frequency_hz"],
        )
        if key in seen:
            raise TableInputError(
                f"{where}, column 'frequency_hz': this drive level and frequency are already "
                f"on line {seen[key]}"
            )
        seen[key] = lineno
        rows.setdefault(robot, []).append((lineno, values))
    if names is None or not rows:
        raise TableInputError(f"{source}: no {'header' if names is None else 'data'} rows")
    stem = source.rsplit("/", 1)[-1].rsplit(".", 1)[0]
    present = [c for c in RESPONSE_COLUMNS if c in names]
    out = []
    for robot, points in rows.items():
        col = {
            k: np.array([v.get(k, np.nan) for _, v in points])
            for k in ("frequency_hz", "drive_amplitude_v", "drive_bias_v", *present)
        }
        order = np.lexsort((col["frequency_hz"], col["drive_amplitude_v"]))
        out.append(
            Table(
                robot or stem,
                source,
                col["frequency_hz"][order],
                col["drive_amplitude_v"][order],
                col["drive_bias_v"][order],
                {c: col[c][order] for c in present if np.isfinite(col[c]).any()},
                np.array([ln for ln, _ in points])[order],
                tuple(comments),
            )
        )
    return out


def summarise(table: Table) -> list[LevelSummary]:
    """Per drive level: its points, frequency range and the peak of its first amplitude column."""
    peak_col = next((c for c in AMPLITUDE_COLUMNS if c in table.responses), None)
    out = []
    idx = table.level_index
    for i, level in enumerate(table.levels_v):
        sel = idx == i
        f = table.frequency_hz[sel]
        pf = pv = None
        if peak_col is not None:
            y = table.responses[peak_col][sel]
            if np.isfinite(y).any():
                k = int(np.nanargmax(y))
                pf, pv = float(f[k]), float(y[k])
        out.append(
            LevelSummary(
                float(level),
                int(sel.sum()),
                float(f.min()),
                float(f.max()),
                peak_col if pf is not None else None,
                pf,
                pv,
            )
        )
    return out
