"""The drive node's parameters: their one declaration, and config values -> pacing params.

`DRIVE_NODE_PARAMS` declares each parameter once (type, unit in the name and description,
range); the values live in config/flaair.yaml `drive_node`. `pacing_params_from_config`
builds the pure pacing core's parameters from those values, for the node and offline alike.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from flaair_model.schema import ParameterError, ParamSpec
from flaair_model.settings import node_section
from flaair_sim.core import drive
from flaair_sim.core.drive_pacing import PACINGS, PacingParams

__all__ = [
    "CONFIG_FILE",
    "DRIVE_NODE_PARAMS",
    "NODE_NAME",
    "pacing_params_from_config",
]


CONFIG_FILE = "flaair.yaml"
NODE_NAME = "drive_node"

DRIVE_NODE_PARAMS = [
    ParamSpec(
        "sample_rate_hz", float, "Sample rate of the drive [Hz]", 1000.0, 1.0e6, read_only=True
    ),
    ParamSpec("block_size", int, "Samples per command block", 1, 100000, read_only=True),
    ParamSpec(
        "drive_limit_v", float, "Actuator safe range: drive clamped to +-this [V]", 0.0, 300.0
    ),
    ParamSpec("waveform", str, "Drive waveform", choices=drive.DRIVE_KINDS, read_only=True),
    ParamSpec(
        "amplitude_v", float, "Waveform amplitude (half of Vpp) [V]", 0.0, 300.0, read_only=True
    ),
    ParamSpec("bias_v", float, "Offset added to the waveform [V]", -300.0, 300.0, read_only=True),
    ParamSpec(
        "frequency_hz",
        float,
        "Sine frequency; multisine: its base frequency f0 = fs / N [Hz]",
        0.0,
        5000.0,
        read_only=True,
    ),
    ParamSpec(
        "multisine_lines",
        list,
        "Multisine: its excited lines k, each at k x frequency_hz (whole numbers)",
        read_only=True,
    ),
    ParamSpec(
        "multisine_phases_rad",
        list,
        "Multisine: the phase of each excited line (amplitude_v is each line's) [rad]",
        read_only=True,
    ),
    ParamSpec(
        "start_hz",
        float,
        "Chirp start / first stepped-sine frequency [Hz]",
        0.0,
        5000.0,
        read_only=True,
    ),
    ParamSpec(
        "stop_hz",
        float,
        "Chirp stop / last stepped-sine frequency [Hz]",
        0.0,
        5000.0,
        read_only=True,
    ),
    ParamSpec("duration_s", float, "Chirp sweep duration [s]", 1e-3, 3600.0, read_only=True),
    ParamSpec("step_hz", float, "Stepped-sine frequency step [Hz]", 1e-3, 5000.0, read_only=True),
    ParamSpec(
        "dwell_s", float, "Stepped-sine time at each frequency [s]", 1e-3, 3600.0, read_only=True
    ),
    ParamSpec(
        "lead_in_s",
        float,
        "Zero drive for this long before the waveform starts (a rest) [s]",
        0.0,
        3600.0,
        read_only=True,
    ),
    ParamSpec(
        "run_time_s",
        float,
        "Stop after this much signal time, lead-in included (0: never) [s]",
        0.0,
        1e6,
        read_only=True,
    ),
    ParamSpec(
        "pacing",
        str,
        "realtime or lockstep (paced by the plant's sensor blocks)",
        choices=PACINGS,
        read_only=True,
    ),
    ParamSpec(
        "lockstep_window_blocks",
        int,
        "lockstep: command blocks allowed ahead of the plant",
        1,
        10000,
        read_only=True,
    ),
    ParamSpec(
        "ack_retry_s",
        float,
        "lockstep: no acknowledgement for this long: one more block (< "
        "the plant's command_timeout_s) [s]",
        1e-3,
        60.0,
        read_only=True,
    ),
    ParamSpec(
        "pace_on_wing_state",
        bool,
        "lockstep: pace on the front end's /flaair/wing_state "
        "(the whole chain) instead of the plant's sensor blocks",
        read_only=True,
    ),
    ParamSpec(
        "min_subscribers",
        int,
        "Start only once this many subscribers listen (e.g. plant + recorder)",
        1,
        100,
        read_only=True,
    ),
    ParamSpec(
        "first_sample_index",
        int,
        "Index of the first command sample (continue a plant's count)",
        0,
        2**62,
        read_only=True,
    ),
]


def pacing_params_from_config(values: Mapping[str, Any] | None = None) -> PacingParams:
    """The pacing core's parameters from drive_node values (default: config/flaair.yaml)."""
    values = node_section(DRIVE_NODE_PARAMS, NODE_NAME, CONFIG_FILE) if values is None else values
    missing = [s.name for s in DRIVE_NODE_PARAMS if s.name not in values]
    if missing:
        raise ParameterError(f"missing parameter(s): {', '.join(missing)}")
    try:
        waveform = drive.DriveParams(
            kind=values["waveform"],
            amplitude_v=values["amplitude_v"],
            bias_v=values["bias_v"],
            frequency_hz=values["frequency_hz"],
            start_hz=values["start_hz"],
            stop_hz=values["stop_hz"],
            duration_s=values["duration_s"],
            step_hz=values["step_hz"],
            dwell_s=values["dwell_s"],
            lead_in_s=values["lead_in_s"],
            lines=tuple(values["multisine_lines"]),
            phases_rad=tuple(values["multisine_phases_rad"]),
        )
        return PacingParams(
            sample_rate_hz=values["sample_rate_hz"],
            block_size=values["block_size"],
            pacing=values["pacing"],
            lockstep_window_blocks=values["lockstep_window_blocks"],
            min_subscribers=values["min_subscribers"],
            first_sample_index=values["first_sample_index"],
            run_time_s=values["run_time_s"],
            ack_retry_s=values["ack_retry_s"],
            drive=waveform,
        )
    except drive.DriveError as exc:
        raise ParameterError(str(exc)) from exc
