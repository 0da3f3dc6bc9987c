"""FLAAIR's bottom package: the nominal plant and sensor model, its effects, and its files.

Pure Python (numpy, PyYAML). Everything else (sim, sensors, control, tools) depends on it;
it depends on nothing of FLAAIR's.

- `pvdf`: the composite-beam PVDF charge model (paper eqs. charge, strain, chargeamp).
- `model`: frozen parameter dataclasses and the effect registry (`EFFECT_TYPES`).
- `model_io`: config/model.yaml <-> `Model`.
- `terms`: the term library the discrepancy workflow discovers missing physics from.
- `checked_files`: the one way a given file is opened (regular, bounded, YAML aliases bounded).
- `config`: the one locator of config/ and the ROS parameter-file reader.
- `schema`: `ParamSpec`, each node parameter declared once.
- `lfilter`: scipy.signal.lfilter as numba kernels for the per-block cores.
- `notes`: `Note`, the one type of a core's log lines.
- `settings`: typed accessors of the config sections a tool reads that are not its own.
"""

__all__ = [
    "checked_files",
    "config",
    "lfilter",
    "model",
    "model_io",
    "notes",
    "pvdf",
    "schema",
    "settings",
    "terms",
]
