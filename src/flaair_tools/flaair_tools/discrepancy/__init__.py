"""`bin/flaair discrepancy` and `bin/flaair identify`: command lines and reports around the pure
workflow in `flaair_analysis.discrepancy`.

Modules:
- `cli`: `bin/flaair discrepancy` (any mix of runs, bags, tables and multisine sets; the
  workflow, the report)
- `identify`: `bin/flaair identify` (the grey-box plant fit alone, on any mix)
- `evidence_inputs`: a command's evidence read and recognised by content, and the one way both
  commands check outputs, load, compute and refuse bad input
- `run_inputs`: the inputs told apart by content (runs, tables, and each kind of evidence file
  in its `EVIDENCE_FILES` table), runs from CSV files and bags, the errors reported in one line
- `report`: the report's JSON, Markdown and HTML pages and the validation table
- `report_figures`: the report's figures (matplotlib, no pyplot)
- `validation_file`: a `--validation` file read and checked before the analysis
"""

from __future__ import annotations

from .cli import main

__all__ = ["main"]
