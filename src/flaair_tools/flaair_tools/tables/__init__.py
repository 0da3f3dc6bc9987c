"""Frequency-response tables (docs/TABLES.md): the commands, files and report around the pure
`flaair_analysis.tables`.

Modules (import them by name; this package imports none of them eagerly):
- `table_io`: table files and the tables section of the config
- `report`: discrepancy.json, figures and report.html of a table
- `import_cli`: `bin/flaair import-table`
- `command`: the shell a table command shares (outputs checked, the table loaded, refusals)
- `discrepancy_cli`: `bin/flaair discrepancy TABLE.csv` (a table alone)
"""

__all__ = ["command", "discrepancy_cli", "import_cli", "report", "table_io"]
