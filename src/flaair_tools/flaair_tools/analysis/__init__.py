"""Analysis of recorded runs, from the bags: run recognition,
per-wingbeat summaries, the report, calibration, offline replay.

Modules (import them by name; this package imports none of them eagerly):
- `analyze`: `bin/flaair analyze`: the paper's analysis and the HTML report
- `report`: figures and the HTML report (Jinja2)
- `runkind`: what drive a run carries (pure)
- `wingbeat`: per-wingbeat summary (pure)
- `replay`: a bag through the live nodes' cores
- `transition`: the sync -> async transition record, limit cycle and figure
- `calibrate`: `bin/flaair calibrate`: sensor gain and lag
- `health_cli`: `bin/flaair health`: the health monitor on bags (events, per-wingbeat series)
"""

__all__ = [
    "analyze",
    "calibrate",
    "health_cli",
    "replay",
    "report",
    "runkind",
    "transition",
    "wingbeat",
]
