"""Simulation studies on Dask: wing damage, the dSA map, the stroke-controller experiments.

Modules (import them by name; this package imports none of them eagerly):
- `sweep`: the engine: grids, chunks, cluster or in process
- `sweep_report`: run, write, draw, read
(the compiled closed-loop batch they run is `flaair_analysis.closed_loop`)
- `stroke_experiments`: the stroke controller's
  experiments, closed loop in process, recorded as bags
- `sweep_cli`: `bin/flaair sweep`
"""

__all__ = ["stroke_experiments", "sweep", "sweep_cli", "sweep_report"]
