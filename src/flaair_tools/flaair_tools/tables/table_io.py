"""Tables from files, with the plant's range from config/ (the shell around `reader`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from flaair_model import settings

from .reader import Table, TableInputError, TableLimits, read_table

__all__ = ["load_tables", "table_limits"]


def table_limits() -> TableLimits:
    """The frequency range (`tables` section) and the actuator's drive limit (`/**`)."""
    t = settings.tables()
    return TableLimits(t.min_frequency_hz, t.max_frequency_hz, settings.stream().drive_limit_v)


def load_tables(paths: Sequence[Path], limits: TableLimits | None = None) -> list[Table]:
    """Every robot's table in the CSV files `paths` (a robot in two files is refused)."""
    limits = limits or table_limits()
    out: list[Table] = []
    for path in paths:
        try:
            text = Path(path).read_text(encoding="utf-8")
        except UnicodeDecodeError as exc:
            raise TableInputError(f"{path}: not a UTF-8 text table ({exc.reason})") from None
        for table in read_table(text, str(path), limits):
            if any(t.name == table.name for t in out):
                raise TableInputError(f"{path}: robot {table.name!r} is already in another table")
            out.append(table)
    return out
