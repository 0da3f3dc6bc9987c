"""Frequency-response tables (docs/TABLES.md): a lab's steady-sine sweeps, read from video.

Modules: `reader` (the CSV format, checked by line and column), `steady_state` (the plant's
steady-state response at each drive level and frequency, batched through the simulator's own
core), `table_evidence` (a table as evidence for the one fit: each cell in units of its reading
noise), `fit` (the plant fitted to a table, started from the data), `workflow` (the discrepancy
workflow on a table, held-out drive levels), `datasets` (tables the simulated robot makes),
`joint` (the plant fitted to runs and a table of the same robot at once, each set's agreement)
and `joint_workflow` (the discrepancy workflow on both: the runs' search from the joint plant,
its findings checked on the table's held-out levels). The
files, the report and the commands are in `flaair_tools.tables`.
"""

from __future__ import annotations

from .reader import (
    AMPLITUDE_COLUMNS,
    PHASE_COLUMNS,
    PLAUSIBLE_DEG,
    RESPONSE_COLUMNS,
    LevelSummary,
    Table,
    TableInputError,
    TableLimits,
    read_table,
    summarise,
)
from .table_evidence import TableEvidence

__all__ = [
    "AMPLITUDE_COLUMNS",
    "PHASE_COLUMNS",
    "PLAUSIBLE_DEG",
    "RESPONSE_COLUMNS",
    "LevelSummary",
    "Table",
    "TableEvidence",
    "TableInputError",
    "TableLimits",
    "read_table",
    "summarise",
]
