"""`bin/flaair discrepancy` and `bin/flaair identify`: command lines and reports around the pure
workflow in `flaair_analysis.discrepancy`.

Modules:
- `cli`: `bin/flaair discrepancy` (runs from CSV files or bags, the workflow, the report)
- `identify`: `bin/flaair identify` (the grey-box plant fit alone)
- `joint_cli`: `identify` and `discrepancy` on runs and a table of the same robot together
- `run_inputs`: runs from CSV files and bags, and the errors reported in one line
- `report`: the report's JSON, Markdown and HTML pages and the validation table
- `report_figures`: the report's figures (matplotlib, no pyplot)
- `validation_file`: a `--validation` file read and checked before the analysis
"""

from __future__ import annotations

from .cli import main

__all__ = ["main"]
