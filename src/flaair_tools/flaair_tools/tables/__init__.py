"""Frequency-response tables (docs/TABLES.md): the commands, files and report around the pure
`flaair_analysis.tables`.

Modules (import them by name; this package imports none of them eagerly):
- `table_io`: table files and the tables section of the config
- `report`: discrepancy.json, figures and report.html of a table
- `import_cli`: `bin/flaair import-table`
- `identify_cli`: `bin/flaair identify TABLE.csv` (a table alone; `flaair identify` tells it
  from runs)
- `discrepancy_cli`: `bin/flaair discrepancy TABLE.csv` (a table alone)
"""

__all__ = ["discrepancy_cli", "identify_cli", "import_cli", "report", "table_io"]
