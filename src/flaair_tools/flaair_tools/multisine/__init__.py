"""Odd random-phase multisines (docs/MULTISINE.md): the commands, files and report around the
pure `flaair_analysis.multisine`.

Modules (import them by name; this package imports none of them eagerly):
- `cli`: `bin/flaair multisine design|analyze`
- `design_cli`: `flaair multisine design`
- `analyze_cli`: `flaair multisine analyze`
- `design_file`: multisine.yaml written and read back
- `drives`: a design's realizations as drive_node runs (`flaair experiment multisine`)
- `report`: the figures and report.html of an analysis
"""

__all__ = ["analyze_cli", "cli", "design_cli", "design_file", "drives", "report"]
