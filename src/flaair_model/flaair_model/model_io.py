"""YAML I/O for `flaair_model.model.Model` (the layout of config/model.yaml).

`model_to_dict` and `model_from_dict` round-trip exactly; unknown sections or keys are refused
with a `ModelError` that names them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from pathlib import Path
from typing import Any

import yaml

from flaair_model.checked_files import CheckedFileError, read_yaml
from flaair_model.config import CONFIG_DIR_ENV, ConfigError, config_dir
from flaair_model.pvdf import PvdfMaterial, SensorBeam
from flaair_model.term_entry import term_from_dict, term_to_dict
from flaair_model.validation import coerce_number

from .effects import EFFECT_TYPES
from .model import Model, NoiseParams, PlantParams, SensorParams, effect_from_params, effect_params
from .validation import ModelError

__all__ = ["default_model_path", "load_model", "model_from_dict", "model_to_dict", "save_model"]

_MODEL_FILE = "model.yaml"
_SECTIONS = ("plant", "sensors", "noise", "effects", "discovered")
_SENSOR_KEYS = ("reference_voltage_v", "pvdf", "stroke", "pitch")


def default_model_path() -> Path:
    """config/model.yaml in the one config directory (`flaair_model.config.config_dir`).

    Raises
    ------
    FileNotFoundError
        If that directory has no model.yaml.
    """
    try:
        path = config_dir() / _MODEL_FILE
    except ConfigError as exc:
        raise FileNotFoundError(str(exc)) from exc
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no {_MODEL_FILE} there; set {CONFIG_DIR_ENV}")
    return path


def _mapping(where: str, value: Any) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise ModelError(f"{where} must be a mapping, got {type(value).__name__}")
    return value


def _build(kind: type, where: str, raw: Any) -> Any:
    raw = _mapping(where, raw)
    names = [f.name for f in fields(kind)]
    unknown = sorted(set(raw) - set(names))
    if unknown:
        raise ModelError(f"{where}: unknown key(s) {', '.join(map(str, unknown))}")
    missing = [n for n in names if n not in raw]
    if missing:
        raise ModelError(f"{where}: missing key(s) {', '.join(missing)}")
    return kind(**{n: coerce_number(raw[n]) for n in names})


def model_from_dict(d: Mapping[str, Any]) -> Model:
    """Model from the nested dict layout of config/model.yaml.

    Raises
    ------
    ModelError
        Missing or unknown section/key, or an invalid value (the message names it).
    """
    d = _mapping("model", d)
    unknown = sorted(set(d) - set(_SECTIONS))
    if unknown:
        raise ModelError(f"model: unknown section(s) {', '.join(map(str, unknown))}")
    missing = [s for s in ("plant", "sensors", "noise") if s not in d]
    if missing:
        raise ModelError(f"model: missing section(s) {', '.join(missing)}")
    plant = _build(PlantParams, "plant", d["plant"])
    sensors_raw = _mapping("sensors", d["sensors"])
    unknown = sorted(set(sensors_raw) - set(_SENSOR_KEYS))
    if unknown:
        raise ModelError(f"sensors: unknown key(s) {', '.join(map(str, unknown))}")
    missing = [k for k in _SENSOR_KEYS if k not in sensors_raw]
    if missing:
        raise ModelError(f"sensors: missing key(s) {', '.join(missing)}")
    sensors = SensorParams(
        reference_voltage_v=coerce_number(sensors_raw["reference_voltage_v"]),
        pvdf=_build(PvdfMaterial, "sensors.pvdf", sensors_raw["pvdf"]),
        stroke=_build(SensorBeam, "sensors.stroke", sensors_raw["stroke"]),
        pitch=_build(SensorBeam, "sensors.pitch", sensors_raw["pitch"]),
    )
    noise = _build(NoiseParams, "noise", d["noise"])
    effects_raw = d.get("effects") or {}
    effects_raw = _mapping("effects", effects_raw)
    effects = []
    for name, params in effects_raw.items():
        if name in EFFECT_TYPES:
            params = {
                k: (
                    {kk: coerce_number(vv) for kk, vv in v.items()}
                    if isinstance(v, Mapping)
                    else coerce_number(v)
                )
                for k, v in _mapping(f"effects.{name}", params or {}).items()
            }
        effects.append((name, effect_from_params(name, params)))
    terms_raw = d.get("discovered") or []
    if not isinstance(terms_raw, list):
        raise ModelError(f"discovered must be a list of terms, got {type(terms_raw).__name__}")
    terms = tuple(term_from_dict(t, f"discovered[{i}]") for i, t in enumerate(terms_raw))
    return Model(
        plant=plant, sensors=sensors, noise=noise, effects=tuple(effects), discovered=terms
    )


def _as_dict(obj: Any) -> dict[str, Any]:
    return {f.name: getattr(obj, f.name) for f in fields(obj)}


def model_to_dict(m: Model) -> dict[str, Any]:
    """Nested dict in the layout of config/model.yaml; effects as {name: {param: value}} (a sensor
    effect with its own value per chain: {name: {stroke: {param: value}, pitch: {param: value}}}).
    """
    return {
        "plant": _as_dict(m.plant),
        "sensors": {
            "reference_voltage_v": m.sensors.reference_voltage_v,
            "pvdf": _as_dict(m.sensors.pvdf),
            "stroke": _as_dict(m.sensors.stroke),
            "pitch": _as_dict(m.sensors.pitch),
        },
        "noise": _as_dict(m.noise),
        "effects": {name: effect_params(effect) for name, effect in m.effects},
        **({"discovered": [term_to_dict(t) for t in m.discovered]} if m.discovered else {}),
    }


def load_model(path: str | Path | None = None) -> Model:
    """Read a model YAML file (None: the default config, see `default_model_path`).

    Raises
    ------
    ModelError
        Malformed YAML (file, line, column), or a missing/unknown/invalid key (file and key).
    OSError
        The file cannot be opened.
    """
    path = default_model_path() if path is None else Path(path)
    try:
        data = read_yaml(path, "model")
    except CheckedFileError as exc:
        raise ModelError(str(exc)) from None
    if data is None:
        raise ModelError(f"{path}: empty model file")
    try:
        return model_from_dict(data)
    except (ValueError, TypeError) as exc:  # ModelError included: name the file too
        raise ModelError(f"{path}: {exc}") from None


def save_model(m: Model, path: str | Path) -> None:
    """Write a model in the config/model.yaml layout (loads back equal)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = yaml.safe_dump(model_to_dict(m), sort_keys=False, default_flow_style=False)
    path.write_text(
        "# FLAAIR plant and sensor model (flaair_model.model_io.save_model)\n" + text,
        encoding="utf-8",
    )
