"""The collision monitor node's parameters: their one declaration, config values -> core params,
and its messages <-> the monitor core's inputs and /diagnostics.

`COLLISION_MONITOR_PARAMS` declares each parameter once (type, unit in the name and
description, range); the values live in config/flaair.yaml. The `*_from_config` functions build
the pure core's parameters (`flaair_control.core.monitor`) from those values, for the node and
for offline tools (bag replay, analysis) alike.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from flaair_common.diagnostics import OK, WARN, Health, health
from flaair_control.core import collision as col
from flaair_control.core import monitor, spectral
from flaair_control.core.monitor import CollisionMonitorParams, metric_params, window_params
from flaair_model.schema import STREAM_PARAMS, ParameterError, ParamSpec, declared_values
from flaair_model.settings import node_section

__all__ = [
    "COLLISION_MONITOR_PARAMS",
    "CONFIG_FILE",
    "collision_monitor_params_from_config",
    "collision_monitor_values",
    "describe_monitor",
    "dropped_text",
    "event_fields",
    "monitor_drive_input",
    "monitor_health",
    "monitor_windows_from_config",
    "monitor_wing_input",
    "spectral_metric_params_from_config",
    "status_fields",
    "verdict_text",
]

CONFIG_FILE = "flaair.yaml"

COLLISION_MONITOR_PARAMS = [
    *STREAM_PARAMS,
    ParamSpec(
        "window_source",
        str,
        "Wingbeat windows locked to the drive or to the measured stroke",
        choices=("drive", "stroke"),
        read_only=True,
    ),
    ParamSpec(
        "drive_frequency_hz",
        float,
        "drive windows: drive frequency (0: estimate from /flaair/drive) [Hz]",
        0.0,
        2500.0,
        read_only=True,
    ),
    ParamSpec(
        "drive_phase_rad",
        float,
        "drive windows with a known frequency: window starts where 2 pi f t + phase = 2 pi k [rad]",
        -10.0,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "drive_hysteresis_v",
        float,
        "Drive-frequency estimate: Schmitt hysteresis on the drive [V]",
        0.0,
        100.0,
        read_only=True,
    ),
    ParamSpec(
        "frequency_average_wingbeats",
        int,
        "Drive-frequency estimate: wingbeats averaged",
        1,
        1000,
        read_only=True,
    ),
    ParamSpec(
        "relock_tolerance",
        float,
        "Re-lock the drive windows when the estimate moves by this fraction [-]",
        1e-6,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "decision",
        str,
        "Which metric decides onset/clearance",
        choices=("paper", "distortion"),
        read_only=True,
    ),
    ParamSpec(
        "threshold_deg", float, "paper: spectral RMSE threshold [deg]", 1e-6, 90.0, read_only=True
    ),
    ParamSpec(
        "metric_wingbeats", int, "paper: wingbeats in the FFT record", 1, 1000, read_only=True
    ),
    ParamSpec("metric_band_hz", float, "paper: RMSE over 0..this [Hz]", 1.0, 1e5, read_only=True),
    ParamSpec(
        "stroke_threshold",
        float,
        "distortion: stroke distortion ratio scored 1 [-]",
        1e-6,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "pitch_threshold",
        float,
        "distortion: pitch distortion ratio scored 1 [-]",
        1e-6,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "off_level",
        float,
        "Clearance level as a fraction of the onset threshold [-]",
        1e-6,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "n_on",
        int,
        "Consecutive wingbeats above the threshold for an onset",
        1,
        1000,
        read_only=True,
    ),
    ParamSpec(
        "n_off",
        int,
        "Consecutive wingbeats below off_level for a clearance",
        1,
        1000,
        read_only=True,
    ),
    ParamSpec(
        "arm_wingbeats",
        int,
        "Wingbeats ignored after start or re-lock (start-up transient)",
        0,
        100000,
        read_only=True,
    ),
    ParamSpec(
        "min_amplitude_deg",
        float,
        "Stroke amplitude below which a wingbeat is IDLE (not flapping) [deg]",
        0.0,
        90.0,
        read_only=True,
    ),
    ParamSpec(
        "crossing_hysteresis_deg",
        float,
        "stroke windows: Schmitt hysteresis [deg]",
        0.0,
        90.0,
        read_only=True,
    ),
    ParamSpec(
        "min_wingbeat_hz",
        float,
        "Slowest wingbeat (longer windows are IDLE) [Hz]",
        1.0,
        1000.0,
        read_only=True,
    ),
    ParamSpec(
        "max_wingbeat_hz",
        float,
        "Fastest accepted wingbeat (stroke windows) [Hz]",
        1.0,
        5000.0,
        read_only=True,
    ),
    ParamSpec(
        "stroke_noise_rms_deg",
        float,
        "distortion: stroke sensor noise removed in quadrature [deg]",
        0.0,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "pitch_noise_rms_deg",
        float,
        "distortion: pitch sensor noise removed in quadrature [deg]",
        0.0,
        10.0,
        read_only=True,
    ),
]


def collision_monitor_values() -> dict[str, Any]:
    """collision_monitor_node's values in config/flaair.yaml, checked against its schema."""
    return node_section(COLLISION_MONITOR_PARAMS, "collision_monitor_node", CONFIG_FILE)


def collision_monitor_params_from_config(
    values: Mapping[str, Any] | None = None,
) -> CollisionMonitorParams:
    """The monitor core's parameters from collision_monitor_node
    values (default: config/flaair.yaml).
    """
    values = collision_monitor_values() if values is None else values
    try:
        return CollisionMonitorParams(**declared_values(values, COLLISION_MONITOR_PARAMS))
    except spectral.CollisionParameterError as exc:
        raise ParameterError(str(exc)) from exc


def monitor_windows_from_config(
    frequency_hz: float | None, phase_rad: float = 0.0, values: Mapping[str, Any] | None = None
) -> col.MonitorParams:
    """The per-wingbeat window monitor as configured,
    at a drive frequency (None: stroke windows).
    """
    p = collision_monitor_params_from_config(values)
    if frequency_hz is None:
        p = replace(p, window_source="stroke")
    return window_params(p, frequency_hz, phase_rad)


def spectral_metric_params_from_config(
    values: Mapping[str, Any] | None = None,
) -> spectral.SpectralMetricParams:
    """The paper collision metric as configured (threshold, band, wingbeats)."""
    return metric_params(collision_monitor_params_from_config(values))


def monitor_drive_input(fields: Mapping[str, Any]) -> monitor.DriveBlock:
    """A /flaair/drive block's fields as the collision monitor's input."""
    return monitor.DriveBlock(
        int(fields["first_sample_index"]), np.asarray(fields["drive_v"], dtype=np.float64)
    )


def monitor_wing_input(fields: Mapping[str, Any]) -> monitor.WingBlock:
    """A /flaair/wing_state block's fields as the
    collision monitor's input (rad, NaN where invalid).
    """
    return monitor.wing_block(
        fields["first_sample_index"],
        fields["stroke_deg"],
        fields["pitch_deg"],
        fields["stroke_valid"],
        fields["pitch_valid"],
    )


def monitor_health(
    now: tuple[monitor.CollisionMonitorState, int, int],
    before: tuple[monitor.CollisionMonitorState, int, int] | None,
) -> Health:
    """/diagnostics of the collision monitor: collision state, wingbeats, dropped blocks."""
    state, rejected, undecodable = now
    dropped = rejected + undecodable - (before[1] + before[2] if before is not None else 0)
    problems = [
        (WARN, "COLLISION: the pitch spectrum left the free-flapping one")
        if state.colliding
        else (OK, "")
    ]
    if dropped:
        problems.append((WARN, f"{dropped} wing-state block(s) dropped"))
    frequency_hz = state.lock.locked_hz or (
        state.windows.drive_frequency_hz or 0.0 if state.windows else 0.0
    )
    return health(
        "collision monitor",
        problems,
        "no collision" if state.wingbeats else "waiting for the first wingbeat",
        {
            "colliding": state.colliding,
            "wingbeats": state.wingbeats,
            "wingbeat_frequency_hz": float(frequency_hz),
            "rejected_blocks": rejected,
            "undecodable_blocks": undecodable,
        },
    )


def describe_monitor(p: Mapping[str, Any], estimates_frequency: bool) -> str:
    """The collision monitor's ready line: its windows and its decision."""
    where = (
        "stroke windows"
        if p["window_source"] == "stroke"
        else "drive windows, frequency estimated from /flaair/drive"
        if estimates_frequency
        else f"drive windows at {p['drive_frequency_hz']:g} Hz"
    )
    how = (
        f"pitch FFT RMSE over {p['metric_wingbeats']} wingbeats, 0-{p['metric_band_hz']:g} "
        f"Hz, threshold {p['threshold_deg']:g} deg"
        if p["decision"] == "paper"
        else f"per-wingbeat distortion: stroke {p['stroke_threshold']:g}, pitch "
        f"{p['pitch_threshold']:g}"
    )
    return (
        f"collision monitor ready: {where}; decision {p['decision']} ({how}); onset after "
        f"{p['n_on']}, clearance after {p['n_off']} wingbeats"
    )


def dropped_text(exc: Exception, count: int) -> str:
    """The warning for an undecodable block (`count` so far)."""
    return f"block dropped: {exc} [{count} undecodable so far]"


def verdict_text(v: monitor.Verdict, fs_hz: float, threshold_deg: float) -> str:
    """The log line of a collision onset or clearance (`fs_hz`: the wing state's rate)."""
    return (
        f"collision {'ONSET' if v.colliding else 'CLEARANCE'} at wingbeat {v.wingbeat_index} "
        f"(t = {v.end_index / fs_hz:.4f} s, {v.frequency_hz:.1f} Hz): pitch spectrum "
        f"RMSE {v.spectrum_rmse_deg:.3f} deg (threshold {threshold_deg:g} deg), distortion "
        f"score {v.score:.2f}"
    )


def event_fields(v: monitor.Verdict) -> dict[str, Any]:
    """A CollisionEvent's fields but its kind (the message's constant)."""
    return {"wingbeat_index": v.wingbeat_index, "spectrum_rmse_deg": v.spectrum_rmse_deg}


def status_fields(v: monitor.Verdict, threshold_deg: float) -> dict[str, Any]:
    """A CollisionStatus's fields for verdict `v`."""
    return {
        "wingbeat_index": v.wingbeat_index,
        "wingbeat_frequency_hz": v.frequency_hz,
        "colliding": v.colliding,
        "spectrum_rmse_deg": v.spectrum_rmse_deg,
        "time_rmse_deg": v.time_rmse_deg,
        "threshold_deg": threshold_deg,
    }
