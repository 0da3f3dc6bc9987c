"""`flaair import-table TABLE.csv...`: check a lab's frequency-response table and summarise it.

The format is docs/TABLES.md (steady sines over a grid of frequencies at a few drive levels,
amplitudes read from video). Prints, per robot, the drive levels, the frequencies, the response
columns (and how many points each has) and the peak of each level. A table that would be refused
by `identify` or `discrepancy` is refused here, by line and column.

Exit status: 0 when every table reads, 2 on bad input (one line naming the line and column).

Examples
--------
  bin/flaair import-table lab/robot3_sweep.csv
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from flaair_analysis.tables.reader import Table, TableInputError, summarise
from flaair_common.cli_help import HelpFormatter
from flaair_model.config import ConfigError

from .table_io import load_tables

PROG = "flaair import-table"


def describe(table: Table) -> list[str]:
    """The summary lines of one table."""
    lines = [
        f"{table.name}: {table.n_points} points, {table.levels_v.size} drive level(s), "
        f"{table.frequency_hz.min():g}-{table.frequency_hz.max():g} Hz"
    ]
    counts = ", ".join(f"{c} ({int(np.isfinite(v).sum())})" for c, v in table.responses.items())
    lines.append(f"  responses: {counts}")
    for s in summarise(table):
        peak = (
            f"peak {s.peak_value:g} ({s.peak_column}) at {s.peak_frequency_hz:g} Hz"
            if s.peak_value is not None
            else "no amplitude measured"
        )
        lines.append(
            f"  drive {s.drive_amplitude_v:g} V amplitude: {s.n_points} points, "
            f"{s.min_frequency_hz:g}-{s.max_frequency_hz:g} Hz, {peak}"
        )
    if table.levels_v.size < 2:
        lines.append(
            "  one drive level: the plant can be fitted, the effects search needs two or more"
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    """`flaair import-table TABLE...`; returns the exit status."""
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__, formatter_class=HelpFormatter)
    parser.add_argument("tables", nargs="+", type=Path, help="frequency-response CSV tables")
    args = parser.parse_args(argv)
    try:
        tables = load_tables(args.tables)
    except (TableInputError, ConfigError, OSError) as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        return 2
    for table in tables:
        print("\n".join(describe(table)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
