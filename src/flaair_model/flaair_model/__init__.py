"""FLAAIR's bottom package: the nominal plant and sensor model, its effects, and its files.

Pure Python (numpy, scipy, numba, PyYAML). Everything else (sim, sensors, control, analysis,
tools) depends on it; it depends on nothing of FLAAIR's.

- `pvdf`: the composite-beam PVDF charge model (paper eqs. charge, strain, chargeamp).
- `validation`: the checks every model dataclass runs on construction (numbers, rules, channels).
- `effects`: the effect table (`EFFECTS`, `EFFECT_TYPES`): each effect's parameters, kernel
  terms, channels, fit and draw ranges, declared once.
- `model`: the frozen parameter dataclasses (`PlantParams`, `SensorParams`, `NoiseParams`) and
  `Model`, which combines them with effects and discovered terms.
- `model_io`: config/model.yaml <-> `Model`.
- `term_forms`: dynamics term forms composed from primitives (parsed, canonical, generated).
- `terms`: the term library the discrepancy workflow discovers missing physics from, and a
  model's discovered terms.
- `config`: the one locator of config/ and the ROS parameter-file reader.
- `schema`: `ParamSpec`, each node parameter declared once.
- `lfilter`: scipy.signal.lfilter as numba kernels for the per-block cores.
- `notes`: `Note`, the one type of a core's log lines.
- `settings`: typed accessors of the config sections a tool reads that are not its own.
"""

__all__ = [
    "config",
    "effects",
    "lfilter",
    "model",
    "model_io",
    "notes",
    "pvdf",
    "schema",
    "settings",
    "term_forms",
    "terms",
    "validation",
]
