"""Graphs brought up and run: the paper experiments, `live`, the demo, the transition figure.

Modules (import them by name; this package imports none of them eagerly):
- `experiment`: `bin/flaair experiment`: one paper experiment on the simulated robot, recorded
- `live`: `bin/flaair live`: the live graph around a target (or --sim)
- `demo`: `bin/flaair demo`: every experiment, then the report
- `transition_figure`: the sync -> async transition figure
"""

__all__ = ["demo", "experiment", "live", "transition_figure"]
