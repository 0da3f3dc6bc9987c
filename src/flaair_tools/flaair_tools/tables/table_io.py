"""Tables from files, with the plant's range from config/ (the shell around `reader`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import yaml

from flaair_analysis.tables.reader import Table, TableInputError, TableLimits, read_table
from flaair_model import settings
from flaair_model.checked_files import CheckedFileError, read_text
from flaair_model.config import ConfigError
from flaair_model.validation import ModelError

__all__ = ["bad_input", "load_tables", "one_table", "table_limits", "write_table"]


def table_limits() -> TableLimits:
    """The frequency range (`tables` section) and the actuator's drive limit (`/**`)."""
    t = settings.tables()
    return TableLimits(t.min_frequency_hz, t.max_frequency_hz, settings.stream().drive_limit_v)


def load_tables(paths: Sequence[Path], limits: TableLimits | None = None) -> list[Table]:
    """Every robot's table in the CSV files `paths` (a robot in two files is refused).

    Each file is read through `checked_files` (a regular file of at most the `table` limit,
    UTF-8 with or without a byte-order mark): a FIFO, a device or a huge file is refused
    before it is read.
    """
    limits = limits or table_limits()
    out: list[Table] = []
    for path in paths:
        try:
            text = read_text(path, "table")
        except CheckedFileError as exc:
            raise TableInputError(str(exc)) from None
        for table in read_table(text, str(path), limits):
            if any(t.name == table.name for t in out):
                raise TableInputError(f"{path}: robot {table.name!r} is already in another table")
            out.append(table)
    return out


def one_table(paths: list[Path]) -> Table:
    """The one robot's table in `paths` (several robots are refused by name)."""
    tables = load_tables(paths)
    if len(tables) > 1:
        names = ", ".join(t.name for t in tables)
        raise TableInputError(f"{paths[0]}: several robots ({names}); give one robot's table")
    return tables[0]


def bad_input() -> tuple[type[Exception], ...]:
    """The errors a table command reports in one line with exit 2."""
    return (TableInputError, ConfigError, ModelError, OSError, yaml.YAMLError)


def write_table(table: Table, path: Path, comment: str = "") -> None:
    """`table` as a CSV in the lab's format (drive_amplitude_v; empty cells where not measured)."""
    cols = list(table.responses)
    lines = [f"# {comment}"] if comment else []
    lines.append(",".join(["drive_amplitude_v", "drive_bias_v", "frequency_hz", *cols]))
    for i in range(table.n_points):
        cells = [
            f"{table.drive_amplitude_v[i]:.6g}",
            f"{table.drive_bias_v[i]:.6g}",
            f"{table.frequency_hz[i]:.6g}",
        ]
        cells += [
            f"{v:.4f}" if np.isfinite(v) else "" for v in (table.responses[c][i] for c in cols)
        ]
        lines.append(",".join(cells))
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")
