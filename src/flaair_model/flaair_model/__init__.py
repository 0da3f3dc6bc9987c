"""FLAAIR's bottom package: the nominal plant and sensor model, its effects, and its files.

Pure Python (numpy, scipy, numba, PyYAML). Everything else (sim, sensors, control, analysis,
tools) depends on it; it depends on nothing of FLAAIR's.

- `effects`: the effect table (`EFFECTS`): each effect's parameters, kernel terms, channels,
  fit and draw ranges, declared once.
- `model`: the frozen parameter dataclasses of a model (plant, sensors, noise, its effects and
  discovered terms).
- `model_io`: config/model.yaml <-> `Model`.
- `term_forms`: dynamics term forms composed from primitives (parsed, canonical, generated).
- `terms`: the term library the discrepancy workflow discovers missing physics from, and a
  model's discovered terms (`DiscoveredTerm`).
- `term_entry`: a discovered term as a model-file or discrepancy.json entry (one shape).
- `validation`: the checks of model numbers and channels (`ModelError`).
- `pvdf`: the composite-beam PVDF charge model (paper eqs. charge, strain, chargeamp).
- `checked_files`: the one way a given file is opened (regular, bounded, YAML aliases bounded).
- `config`: the one locator of config/ and the ROS parameter-file reader.
- `schema`: `ParamSpec`, each node parameter declared once, and `declared_values`.
- `settings`: typed accessors of the config sections a tool reads that are not its own.
- `lfilter`: scipy.signal.lfilter as numba kernels for the per-block cores.
- `notes`: `Note`, the one type of a core's log lines.
- `last_call`: `remember_last`, a function's last result found again by its first argument's
  identity (a per-block lookup of frozen parameters).
"""

__all__ = [
    "checked_files",
    "config",
    "effects",
    "last_call",
    "lfilter",
    "model",
    "model_io",
    "notes",
    "pvdf",
    "schema",
    "settings",
    "term_entry",
    "term_forms",
    "terms",
    "validation",
]
