"""The front end's parameters: their one declaration and the mapping from config values.

`FRONTEND_PARAMS` declares the frontend_node parameters (type, unit, range); values come from
config/flaair.yaml. `frontend_params_from_config` turns those values into the core's
`FrontendParams`, for the node and for offline tools (a controller learning the velocity
delay, analysis of a bag) alike.
"""

from __future__ import annotations

from collections.abc import Mapping

from flaair_model.config import ConfigError, load_yaml
from flaair_model.model import ModelError
from flaair_model.model_io import load_model
from flaair_model.schema import ParameterError, ParamSpec
from flaair_model.settings import node_section
from flaair_sensors.core import frontend

NODE_NAME = "frontend_node"
CONFIG_FILE = "flaair.yaml"
FRONTEND_PARAMS = [
    ParamSpec(
        "sample_rate_hz",
        float,
        "Sample rate of the sensor blocks [Hz]",
        1000.0,
        1.0e6,
        read_only=True,
    ),
    ParamSpec("block_size", int, "Samples per block", 1, 100000, read_only=True),
    ParamSpec(
        "gains_from",
        str,
        "Where the sensor gains come from",
        choices=("model", "calibration"),
        read_only=True,
    ),
    ParamSpec("model_file", str, "Model YAML (empty: config/model.yaml)", read_only=True),
    ParamSpec(
        "calibration_file", str, "calibration.yaml from `bin/flaair calibrate`", read_only=True
    ),
    ParamSpec(
        "drift_corner_hz", float, "Drift-tracking corner (0: off) [Hz]", 0.0, 20.0, read_only=True
    ),
    ParamSpec(
        "compensate_lag", bool, "Phase-lead compensation of the calibrated lag", read_only=True
    ),
    ParamSpec(
        "lead_rolloff_hz", float, "Lead compensator roll-off [Hz]", 1.0, 9000.0, read_only=True
    ),
    ParamSpec("rail_low_v", float, "Charge-amplifier low rail [V]", -100.0, 100.0, read_only=True),
    ParamSpec(
        "rail_high_v", float, "Charge-amplifier high rail [V]", -100.0, 100.0, read_only=True
    ),
    ParamSpec(
        "rail_margin_v",
        float,
        "Distance from a rail that counts as saturated [V]",
        0.0,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "holdoff_s", float, "Time invalid after an unusable sample [s]", 0.0, 1.0, read_only=True
    ),
    ParamSpec(
        "velocity_cutoff_hz",
        float,
        "Stroke-velocity differentiator cutoff [Hz]",
        10.0,
        9000.0,
        read_only=True,
    ),
]
_TUNING = frontend.TUNING_FIELDS


def frontend_values() -> dict:
    """frontend_node's values in config/flaair.yaml, checked against its schema."""
    return node_section(FRONTEND_PARAMS, NODE_NAME, CONFIG_FILE)


def frontend_tuning_from_config(values: Mapping | None = None) -> dict:
    """The front end's tuning fields (filters, rails, hold-off) from frontend_node values
    (default: config/flaair.yaml), for offline tools that build their own FrontendParams.
    """
    values = frontend_values() if values is None else values
    missing = [name for name in _TUNING if name not in values]
    if missing:
        raise ParameterError(f"config/{CONFIG_FILE} {NODE_NAME}: missing {', '.join(missing)}")
    return {name: values[name] for name in _TUNING}


def frontend_params_from_config(values: Mapping, fs_hz: float) -> frontend.FrontendParams:
    """FrontendParams from the node's parameter values (model or calibration gains)."""
    tuning = frontend_tuning_from_config(values)
    try:
        if values["gains_from"] == "calibration":
            if not values["calibration_file"]:
                raise ParameterError(
                    "parameter 'calibration_file' is empty but gains_from is 'calibration'"
                )
            calibration = load_yaml(values["calibration_file"])
            return frontend.params_from_calibration(calibration, fs_hz, **tuning)
        return frontend.params_from_model(load_model(values["model_file"] or None), fs_hz, **tuning)
    except (ConfigError, ModelError, OSError) as exc:
        source = "calibration_file" if values["gains_from"] == "calibration" else "model_file"
        raise ParameterError(f"parameter '{source}': {exc}") from exc
    except frontend.FrontendError as exc:
        raise ParameterError(str(exc)) from exc


def velocity_delay_s(frequency_hz: float, values: Mapping | None = None) -> float:
    """Group delay (s) of the front end's stroke velocity at ``frequency_hz``.

    ``values``: the frontend_node parameter values (default: its config/flaair.yaml section).
    """
    try:
        values = frontend_values() if values is None else values
    except ParameterError as exc:
        raise ParameterError(
            f"the frontend_node config is needed for its velocity delay: {exc}"
        ) from exc
    params = frontend_params_from_config(values, values["sample_rate_hz"])
    return float(frontend.estimate_delay_s(params, frequency_hz)["stroke_velocity_s"])
