"""Tables from files, with the plant's range from config/ (the shell around `reader`)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from flaair_analysis.tables.reader import Table, TableInputError, TableLimits, read_table
from flaair_model import settings

__all__ = ["load_tables", "table_limits", "write_table"]


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
