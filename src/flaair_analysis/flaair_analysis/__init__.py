"""FLAAIR science, pure: no rclpy, no ROS messages, no matplotlib, no Jinja2, no file I/O (but the
nominal model the off-nominal generator reads).

It sits above the domain packages (model, sim, sensors, control) and below `flaair_tools`,
which keeps the command lines, reports, bags and orchestration around it.

Modules (import them by name; this package imports none of them eagerly):
- `evidence`: the `Evidence` protocol every measured data set meets (residuals in units of its
  own noise, its nuisance parameters, the sites it sees) and the one least-squares fit over any
  list of evidence (`fit_evidence`);
- `exact_score`: the one rule that says whether a discrepancy outcome is right (status, named
  effects and discovered terms all the truth's), used by the benchmarks, tests and case scoring;
- `discrepancy`: the model-vs-measurement workflow (diagnosis, the effect search, grey-box
  identification, term discovery, hidden-effect datasets and their scoring);
- `wingbeat`: per-wingbeat summary of a stroke and pitch record (numba);
- `headline`: the paper's headline figures beside the measured ones (`flaair analyze`'s table);
- `closed_loop`: the compiled closed-loop batch engine the sweeps run (many robots, each under
  its own sync or dSA drive, on the plant's own kernels);
- `multisine`: odd random-phase multisines: the design, the best linear approximation with its
  noise and odd and even nonlinear distortion per channel, the model's distortion beside it;
- `tables`: a lab's frequency-response tables: reading, the model's steady state per point,
  the plant fitted to a table, the discrepancy workflow on held-out drive levels.
"""

__all__ = [
    "closed_loop",
    "discrepancy",
    "evidence",
    "exact_score",
    "headline",
    "multisine",
    "tables",
    "wingbeat",
]
