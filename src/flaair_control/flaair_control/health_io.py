"""The health monitor's parameters (ParamSpec list, config section) and its core's params."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from flaair_control.core.health import HealthParams
from flaair_model.model import Model
from flaair_model.model_io import load_model
from flaair_model.schema import ParamSpec
from flaair_model.settings import node_section

CONFIG_FILE = "flaair.yaml"
NODE_NAME = "health_node"

HEALTH_PARAMS = [
    ParamSpec(
        "sample_rate_hz",
        float,
        "Sample rate of the film blocks [Hz]",
        1000.0,
        1.0e6,
        read_only=True,
    ),
    ParamSpec(
        "model_file",
        str,
        "Model the estimates are relative to ('' = config/model.yaml)",
        read_only=True,
    ),
    ParamSpec(
        "hysteresis_rad",
        float,
        "Wingbeat trigger: Schmitt band on the stroke [rad]",
        0.0,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "min_frequency_hz", float, "Slowest wingbeat estimated [Hz]", 1.0, 1000.0, read_only=True
    ),
    ParamSpec(
        "max_frequency_hz", float, "Fastest wingbeat estimated [Hz]", 1.0, 5000.0, read_only=True
    ),
    ParamSpec(
        "min_drive_v",
        float,
        "Quieter drive (fundamental amplitude) gives no estimate [V]",
        0.0,
        1000.0,
        read_only=True,
    ),
    ParamSpec(
        "min_stroke_rad",
        float,
        "Smaller stroke (fundamental) gives no estimate [rad]",
        0.0,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "average_wingbeats",
        int,
        "Published estimate: mean of this many wingbeats",
        1,
        1000,
        read_only=True,
    ),
    ParamSpec(
        "warmup_wingbeats",
        int,
        "Wingbeats skipped before (and after each event) the baseline is learned",
        0,
        100000,
        read_only=True,
    ),
    ParamSpec(
        "baseline_wingbeats",
        int,
        "Wingbeats the baseline is learned over",
        2,
        100000,
        read_only=True,
    ),
    ParamSpec("cusum_drift", float, "CUSUM drift k [baseline sigmas]", 0.0, 100.0, read_only=True),
    ParamSpec(
        "cusum_threshold", float, "CUSUM threshold h [baseline sigmas]", 0.1, 1000.0, read_only=True
    ),
    ParamSpec(
        "sigma_floor", float, "Least relative scatter a baseline is given", 0.0, 1.0, read_only=True
    ),
    ParamSpec(
        "confirm_wingbeats",
        int,
        "Estimates after the change point an event averages",
        1,
        1000,
        read_only=True,
    ),
    ParamSpec(
        "max_amplitude_change",
        float,
        "Wingbeat whose stroke or drive amplitude moved "
        "more than this fraction: transient, no estimate",
        0.0,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "agree_tolerance",
        float,
        "Both films moved by ratios this close: actuator gain",
        0.0,
        1.0,
        read_only=True,
    ),
]


def health_values() -> dict[str, Any]:
    """health_node's values in config/flaair.yaml, checked against its schema."""
    return node_section(HEALTH_PARAMS, NODE_NAME, CONFIG_FILE)


def health_params_from_config(
    values: Mapping[str, Any] | None = None, model: Model | None = None
) -> HealthParams:
    """The health core's parameters: tunables from health_node values (default: config),
    plant and film constants from `model` (default: the values' model_file).
    """
    values = health_values() if values is None else values
    if model is None:
        model = load_model(values["model_file"] or None)
    p = model.plant
    damping = model.effect("structural_damping")
    zeta = float(getattr(damping, "damping_ratio", 0.0) or 0.0)
    k = p.stroke_stiffness_nm_per_rad
    return HealthParams(
        sample_rate_hz=values["sample_rate_hz"],
        stroke_inertia_kg_m2=p.stroke_inertia_kg_m2,
        stroke_stiffness_nm_per_rad=k,
        aero_damping_nm_s2=p.aero_damping_nm_s2,
        structural_damping_nm_s_per_rad=2.0 * zeta * (k * p.stroke_inertia_kg_m2) ** 0.5,
        actuator_gain_nm_per_v=p.actuator_gain_nm_per_v,
        pitch_inertia_kg_m2=p.pitch_inertia_kg_m2,
        hinge_stiffness_nm_per_rad=p.hinge_stiffness_nm_per_rad,
        hinge_damping_nm_s_per_rad=p.hinge_damping_nm_s_per_rad,
        inertial_coupling_kg_m2=p.inertial_coupling_kg_m2,
        aero_coupling_nm_s2=p.aero_coupling_nm_s2,
        stroke_volts_per_rad=model.stroke_volts_per_rad,
        pitch_volts_per_rad=model.pitch_volts_per_rad,
        reference_voltage_v=model.sensors.reference_voltage_v,
        **{
            name: values[name]
            for name in (
                "hysteresis_rad",
                "min_frequency_hz",
                "max_frequency_hz",
                "min_drive_v",
                "min_stroke_rad",
                "average_wingbeats",
                "warmup_wingbeats",
                "baseline_wingbeats",
                "cusum_drift",
                "cusum_threshold",
                "sigma_floor",
                "confirm_wingbeats",
                "agree_tolerance",
                "max_amplitude_change",
            )
        },
    )
