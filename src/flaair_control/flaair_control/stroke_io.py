"""The stroke controller node's mapping: its parameters
to the cores' and its messages to their inputs.

No rclpy: `stroke_controller_node` calls these, and an offline tool may too.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from flaair_control.core import safety, stroke, stroke_loop
from flaair_control.core.dsa import loop_delay_s
from flaair_model.model_io import load_model
from flaair_model.schema import ParameterError
from flaair_sensors.frontend_io import velocity_delay_s

__all__ = [
    "StrokeSetup",
    "complete_text",
    "empty_input",
    "ready_text",
    "retargeted",
    "setup_from_values",
    "state_fields",
    "timing_params",
    "wing_fields",
    "wing_input",
]


class StrokeSetup(NamedTuple):
    """What the node runs: the design plant, the controller's and the guard's parameters."""

    plant: stroke.StrokePlant
    params: stroke.StrokeParams
    guard: safety.SafetyParams


def setup_from_values(p: Mapping[str, Any]) -> StrokeSetup:
    """The cores' parameters from the node's values
    (loop delay: blocks in flight + front-end lag).
    """
    fs, n = p["sample_rate_hz"], p["block_size"]
    plant = stroke.StrokePlant.from_model(load_model(p["model_file"] or None))
    velocity = (
        p["velocity_delay_s"]
        if p["velocity_delay_s"] >= 0
        else velocity_delay_s(p["compensation_frequency_hz"])
    )
    try:
        params = stroke.params_from_values(
            dict(p), plant, fs, loop_delay_s(n * p["blocks_in_flight"], fs, velocity * fs)
        )
    except ValueError as exc:  # the design cannot reach the setpoint, or the limits contradict it
        raise ParameterError(f"parameter 'setpoint_deg' / command limits: {exc}") from exc
    guard = safety.SafetyParams(
        p["drive_limit_v"], p["slew_limit_v_per_s"], p["invalid_timeout_s"], p["ramp_down_s"], fs
    )
    return StrokeSetup(plant, params, guard)


def ready_text(params: stroke.StrokeParams) -> str:
    """The node's start-up log line: mode, setpoint, feed-forward, slope and gain."""
    return (
        f"stroke control ({params.mode}): {params.setpoint_deg:g} deg, feed-forward "
        f"{params.command_nominal:.4g}, slope {params.elasticity:.3f}, gain "
        f"{params.gain:.3f}/wingbeat"
    )


def retargeted(
    setup: StrokeSetup, params: stroke.StrokeParams, p: Mapping[str, Any], setpoint_deg: float
) -> stroke.StrokeParams:
    """`params` held at a new setpoint (feed-forward redesigned, learnt correction kept); ValueError
    if the design cannot reach it.
    """
    u_ff, slope = stroke.design(
        setup.plant,
        params.mode,
        setpoint_deg,
        sync_frequency_hz=p["sync_frequency_hz"],
        r3_rad_s=p["r3_rad_s"],
        kappa=p["kappa"],
    )
    return stroke.retarget(params, setpoint_deg, u_ff, slope)


def wing_input(
    fields: Mapping[str, Any], n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """(stroke rad, stroke velocity rad/s, valid, whole
    block valid) of a WingStateBlock's fields.
    """
    stroke_rad = np.radians(np.asarray(fields["stroke_deg"], dtype=float))
    valid = np.asarray(fields["stroke_valid"], dtype=bool)
    if valid.size != stroke_rad.size:
        valid = np.zeros(stroke_rad.size, bool)
    ok = bool(valid.all() and np.isfinite(stroke_rad).all() and stroke_rad.size == n)
    return (
        stroke_rad,
        np.radians(np.asarray(fields["stroke_velocity_deg_s"], dtype=float)),
        valid,
        ok,
    )


def empty_input(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, None]:
    """No estimate (start, retry, ramp-down blocks): NaN samples, none valid, validity unknown."""
    return np.full(n, np.nan), np.full(n, np.nan), np.zeros(n, bool), None


def state_fields(
    params: stroke.StrokeParams, state: stroke.StrokeState, drive_v: np.ndarray, clamped: bool
) -> dict[str, Any]:
    """A ControllerState's fields for a block (amplitude_scale = command / feed-forward)."""
    return {
        "k_r": 1.0 if params.mode == "sync" else 0.0,
        "drive_v": float(drive_v[-1]),
        "drive_clamped": clamped,
        "amplitude_scale": stroke.command(state, params) / params.command_nominal,
    }


def complete_text(state: stroke.StrokeState) -> str:
    """The log line at the end of a run of run_time_s."""
    return (
        f"run complete after {stroke.wingbeats(state)} wingbeats, "
        f"last amplitude {stroke.last_amplitude_deg(state):.2f} deg"
    )


def timing_params(p: Mapping[str, Any]) -> stroke_loop.TimingParams:
    """The loop timing's wall-clock settings from stroke_controller_node values."""
    return stroke_loop.TimingParams(p["start_delay_s"], p["start_retry_s"], p["watchdog_timeout_s"])


def wing_fields(msg: Any) -> dict[str, Any]:
    """The WingStateBlock fields `wing_input` reads."""
    return {
        "stroke_deg": msg.stroke_deg,
        "stroke_valid": msg.stroke_valid,
        "stroke_velocity_deg_s": msg.stroke_velocity_deg_s,
    }
