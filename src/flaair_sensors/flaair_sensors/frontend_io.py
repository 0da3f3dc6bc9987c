"""The front end's parameters: their one declaration and the mapping from config values.

`FRONTEND_PARAMS` declares the frontend_node parameters (type, unit, range); values come from
config/flaair.yaml. `frontend_params_from_config` turns those values into the core's
`FrontendParams`, for the node and for offline tools (a controller learning the velocity
delay, analysis of a bag) alike; the rest maps the core's estimate and figures to the node's
message fields and log lines.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from flaair_model.config import ConfigError, load_yaml
from flaair_model.model_io import load_model
from flaair_model.schema import STREAM_PARAMS, ParameterError, ParamSpec
from flaair_model.settings import node_section
from flaair_model.validation import ModelError
from flaair_sensors.core import frontend, frontend_params

__all__ = [
    "CONFIG_FILE",
    "FRONTEND_PARAMS",
    "NODE_NAME",
    "frontend_params_from_config",
    "frontend_tuning_from_config",
    "frontend_values",
    "latency_text",
    "ready_text",
    "velocity_delay_s",
    "wing_state_fields",
]


NODE_NAME = "frontend_node"
CONFIG_FILE = "flaair.yaml"
FRONTEND_PARAMS = [
    *STREAM_PARAMS,
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
_TUNING = frontend_params.TUNING_FIELDS


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


def frontend_params_from_config(values: Mapping, fs_hz: float) -> frontend_params.FrontendParams:
    """FrontendParams from the node's parameter values (model or calibration gains)."""
    tuning = frontend_tuning_from_config(values)
    try:
        if values["gains_from"] == "calibration":
            if not values["calibration_file"]:
                raise ParameterError(
                    "parameter 'calibration_file' is empty but gains_from is 'calibration'"
                )
            calibration = load_yaml(values["calibration_file"])
            return frontend_params.params_from_calibration(calibration, fs_hz, **tuning)
        return frontend_params.params_from_model(
            load_model(values["model_file"] or None), fs_hz, **tuning
        )
    except (ConfigError, ModelError, OSError) as exc:
        source = "calibration_file" if values["gains_from"] == "calibration" else "model_file"
        raise ParameterError(f"parameter '{source}': {exc}") from exc
    except frontend_params.FrontendError as exc:
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


def ready_text(gains_from: str, params: frontend_params.FrontendParams) -> str:
    """The front end's start-up line: gains, velocity phase lag and remaining delay at 140 Hz."""
    delay = frontend.estimate_delay_s(params)
    return (
        f"front end ready: gains from {gains_from}, stroke "
        f"{abs(np.degrees(1 / params.stroke_volts_per_rad)):.2f} deg/V, pitch "
        f"{abs(np.degrees(1 / params.pitch_volts_per_rad)):.2f} deg/V, velocity phase lag "
        f"at 140 Hz {frontend.velocity_phase_lag_deg(params):.1f} deg, remaining delay at "
        "140 Hz "
        + ", ".join(
            f"{name[:-2].replace('_', ' ')} {1e6 * delay_s:.1f} us"
            for name, delay_s in delay.items()
        )
    )


def wing_state_fields(
    first: int, rate_hz: float, source: int, estimate: frontend.WingEstimate
) -> dict[str, Any]:
    """A WingStateBlock's fields for the front end's estimate of a block from sample `first`."""
    return {
        "sample_rate_hz": rate_hz,
        "first_sample_index": first,
        "source": source,
        "stroke_deg": np.degrees(estimate.stroke_rad),
        "pitch_deg": np.degrees(estimate.pitch_rad),
        "stroke_velocity_deg_s": np.degrees(estimate.stroke_velocity_rad_s),
        "stroke_valid": estimate.stroke_valid,
        "pitch_valid": estimate.pitch_valid,
    }


def latency_text(latencies_s: np.ndarray) -> str:
    """The block processing time's median and 99th percentile over `latencies_s`."""
    p50, p99 = 1e3 * np.percentile(latencies_s, [50, 99])
    return (
        f"block processing over the last {latencies_s.size} blocks: "
        f"p50 {p50:.3f} ms, p99 {p99:.3f} ms"
    )
