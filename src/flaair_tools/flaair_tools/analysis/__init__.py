"""Analysis of recorded runs, from the bags: run recognition, per-run analyses, the report,
calibration, offline replay (the per-wingbeat summary and the headline table they use are
the pure `flaair_analysis.wingbeat` and `flaair_analysis.headline`).

Modules (import them by name; this package imports none of them eagerly):
- `analyze`: `bin/flaair analyze`: the paper's analysis and the HTML report
- `report`: figures and the HTML report (Jinja2)
- `per_run`: each run kind's analysis (sweeps, sines, free runs, collisions, the transition)
- `runkind`: what drive a run carries (pure)
- `replay`: a bag through the live nodes' cores
- `transition`: the sync -> async transition record, limit cycle and figure
- `calibrate`: `bin/flaair calibrate`: sensor gain and lag
- `diagnostic_events`: a run's health level changes, read from its bag's /diagnostics
- `health_cli`: `bin/flaair health`: the health monitor on bags (events, per-wingbeat series)
"""

__all__ = [
    "analyze",
    "calibrate",
    "diagnostic_events",
    "health_cli",
    "per_run",
    "replay",
    "report",
    "runkind",
    "transition",
]
