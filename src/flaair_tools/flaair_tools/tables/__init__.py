"""Frequency-response tables (docs/TABLES.md): the commands, files and report around the pure
`flaair_analysis.tables`.

Modules (import them by name; this package imports none of them eagerly):
- `table_io`: table files (one robot's table, the errors refused in one line) and the tables
  section of the config
- `report`: discrepancy.json, figures and report.html of a table
- `import_cli`: `bin/flaair import-table`
"""

__all__ = ["import_cli", "report", "table_io"]
