"""The dSA controller node's parameters: their one declaration, config values -> core params,
and its messages <-> the loop supervisor's inputs and outputs.

`DSA_CONTROLLER_PARAMS` declares each parameter once (type, unit in the name and description,
range); the values live in config/flaair.yaml. `supervisor_params_from_config` builds the pure
core's parameters from those values, for the node and for offline tools (bag replay, analysis)
alike; `stroke_controller_values` reads the stroke controller's section. The collision
monitor's counterpart is `flaair_control.monitor_io`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

from flaair_common.diagnostics import ERROR, WARN, Health, health
from flaair_control.core import dsa, loop_state, safety, stroke
from flaair_control.core.loop_state import SupervisorParams
from flaair_control.core.transition import TransitionError, crossing_params
from flaair_model.model import Model
from flaair_model.model_io import load_model
from flaair_model.schema import STREAM_PARAMS, ParameterError, ParamSpec, declared_values
from flaair_model.settings import node_section
from flaair_model.validation import ModelError
from flaair_sensors.frontend_io import velocity_delay_s as frontend_velocity_delay_s

__all__ = [
    "CONFIG_FILE",
    "DSA_CONTROLLER_PARAMS",
    "controller_health",
    "controller_state_fields",
    "describe_loop",
    "drive_fields",
    "dropped_text",
    "dsa_controller_values",
    "kr_schedule",
    "loop_delay_s",
    "ramp_request",
    "reset_reply",
    "stroke_controller_values",
    "supervisor_params_from_config",
    "supervisor_params_from_values",
    "supervisor_wing_input",
]


CONFIG_FILE = "flaair.yaml"

DSA_CONTROLLER_PARAMS = [
    *STREAM_PARAMS,
    ParamSpec(
        "drive_limit_v",
        float,
        "Actuator safe range: drive clamped to +-this [V]",
        0.0,
        300.0,
        read_only=True,
    ),
    ParamSpec(
        "model_file",
        str,
        "Model YAML for the actuator gain G_a (empty: config/model.yaml)",
        read_only=True,
    ),
    ParamSpec(
        "r3_rad_s", float, "dSA coefficient r3 (force delay) [rad/s]", 1e-3, 1e6, read_only=True
    ),
    ParamSpec("kappa", float, "dSA coefficient kappa (force decay) [-]", 1e-6, 1e3, read_only=True),
    ParamSpec(
        "mu_nm_s_per_rad",
        float,
        "dSA gain mu (DC: tau = -mu phi') [N m s/rad]",
        0.0,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "sync_amplitude_v", float, "Synchronous sine amplitude [V]", 0.0, 300.0, read_only=True
    ),
    ParamSpec(
        "sync_frequency_hz", float, "Synchronous sine frequency [Hz]", 0.0, 5000.0, read_only=True
    ),
    ParamSpec(
        "sync_phase_rad",
        float,
        "Synchronous sine phase at t = 0 [rad]",
        -10.0,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "kr_initial",
        float,
        "K_r before the ramp (1 synchronous, 0 asynchronous) [-]",
        0.0,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "kr_target",
        float,
        "K_r after the ramp; set while running: new ramp from the current K_r [-]",
        0.0,
        1.0,
    ),
    ParamSpec(
        "kr_ramp_start_s",
        float,
        "Signal time at which the first K_r ramp starts [s]",
        0.0,
        1e6,
        read_only=True,
    ),
    ParamSpec(
        "kr_ramp_duration_s", float, "K_r ramp duration; set while running: new ramp [s]", 0.0, 1e6
    ),
    ParamSpec(
        "compensate_delay",
        bool,
        "Phase-advance compensation of the loop delay (dsa core)",
        read_only=True,
    ),
    ParamSpec(
        "compensation_frequency_hz",
        float,
        "Frequency w_c/2pi at which the delay is cancelled exactly [Hz]",
        1.0,
        5000.0,
        read_only=True,
    ),
    ParamSpec(
        "velocity_delay_s",
        float,
        "Front-end velocity delay to compensate (< 0: from the front end's config) [s]",
        -1.0,
        0.1,
        read_only=True,
    ),
    ParamSpec(
        "blocks_in_flight",
        int,
        "Command blocks kept in the lockstep loop (loop delay = this many blocks)",
        1,
        64,
        read_only=True,
    ),
    ParamSpec(
        "slew_limit_v_per_s",
        float,
        "Drive slew-rate limit (0: off) [V/s]",
        0.0,
        1e9,
        read_only=True,
    ),
    ParamSpec(
        "watchdog_timeout_s",
        float,
        "Trip when no wing-state block arrives for this long (wall-clock time) [s]",
        1e-3,
        60.0,
        read_only=True,
    ),
    ParamSpec(
        "invalid_timeout_s",
        float,
        "Trip when no valid wing-state block arrives for this long (signal time) [s]",
        1e-4,
        60.0,
        read_only=True,
    ),
    ParamSpec(
        "ramp_down_s",
        float,
        "Drive ramp to zero after a trip (signal time) [s]",
        0.0,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "zero_hold_s",
        float,
        "Zero drive published at the real-time rate after the ramp [s]",
        0.0,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "keepalive_period_s",
        float,
        "Tripped and ramped down: one zero block per this period (wall clock) [s]",
        1e-3,
        60.0,
        read_only=True,
    ),
    ParamSpec(
        "collision_response",
        str,
        "Reaction to a collision onset",
        choices=("none", "stop", "reduce_amplitude"),
        read_only=True,
    ),
    ParamSpec(
        "collision_reduction_factor",
        float,
        "reduce_amplitude: drive scale while colliding [-]",
        0.0,
        1.0,
        read_only=True,
    ),
    ParamSpec(
        "collision_restore_on_clearance",
        bool,
        "reduce_amplitude: back to full drive at the clearance",
        read_only=True,
    ),
    ParamSpec(
        "state_every_blocks",
        int,
        "ControllerState with every n-th drive block (and at every watchdog or fault change)",
        1,
        100000,
        read_only=True,
    ),
    ParamSpec(
        "collision_ramp_guard_s",
        float,
        "Collision onsets during a K_r ramp and this long after it are not acted on [s]",
        0.0,
        10.0,
        read_only=True,
    ),
    ParamSpec(
        "min_stream_listeners",
        int,
        "Composed: start once every batched block stream has "
        "this many DDS subscribers (live: the recorder)",
        0,
        100,
        read_only=True,
    ),
    ParamSpec(
        "min_state_subscribers",
        int,
        "Start once /flaair/controller/state has this many "
        "subscribers (a listener that must see the whole run)",
        0,
        100,
        read_only=True,
    ),
    ParamSpec(
        "min_drive_subscribers",
        int,
        "Start once /flaair/drive has this many subscribers (plant, + recorder, + monitor)",
        1,
        100,
        read_only=True,
    ),
    ParamSpec(
        "wait_for_peers",
        bool,
        "Start only once /flaair/drive has a subscriber and "
        "/flaair/sensor_v and /flaair/wing_state publishers",
        read_only=True,
    ),
    ParamSpec(
        "start_delay_s",
        float,
        "Wall time between seeing the peers and sending the first blocks [s]",
        0.0,
        60.0,
        read_only=True,
    ),
    ParamSpec(
        "start_retry_s",
        float,
        "No answer to the first blocks for this long: send one more (wall clock) [s]",
        0.01,
        60.0,
        read_only=True,
    ),
    ParamSpec(
        "run_time_s",
        float,
        "Stop after this much signal time: zero block, then idle (0: never) [s]",
        0.0,
        1e6,
        read_only=True,
    ),
    ParamSpec(
        "frequency_hysteresis_deg",
        float,
        "Stroke-frequency estimate: Schmitt hysteresis about 0 [deg]",
        0.0,
        90.0,
        read_only=True,
    ),
    ParamSpec(
        "timing_file",
        str,
        "Write per-block receive/publish monotonic times here at exit (.npz; empty: off)",
        read_only=True,
    ),
]


def dsa_controller_values() -> dict[str, Any]:
    """dsa_controller_node's values in config/flaair.yaml, checked against its schema."""
    return node_section(DSA_CONTROLLER_PARAMS, "dsa_controller_node", CONFIG_FILE)


def stroke_controller_values() -> dict[str, Any]:
    """stroke_controller_node's values in config/flaair.yaml, checked against its schema."""
    return node_section(stroke.NODE_PARAMS, "stroke_controller_node", CONFIG_FILE)


def loop_delay_s(values: Mapping[str, Any]) -> tuple[float, float]:
    """(loop delay, front-end velocity delay) in s: blocks in flight + ZOH + velocity filter.

    Velocity block k is complete only at the end of block k, so its drive is applied in block
    k + blocks_in_flight: T = (blocks_in_flight N + 0.5) / fs plus the front end's velocity
    group delay (0.22 ms for the 1 kHz differentiator): 0.75 ms at 20 kHz with 10-sample
    blocks, 38 deg at 140 Hz. Uncompensated, that lag turns part of the dSA negative damping
    into negative stiffness and the loop self-excites below the resonance (135 Hz, 25 deg);
    the dsa core's phase advance at compensation_frequency_hz cancels it, and the loop
    settles where the delay-free Hopf theory puts it (144.2 Hz, 20.5 deg).
    """
    fs = values["sample_rate_hz"]
    velocity = (
        values["velocity_delay_s"]
        if values["velocity_delay_s"] >= 0
        else frontend_velocity_delay_s(values["compensation_frequency_hz"])
    )
    return (
        dsa.loop_delay_s(values["block_size"] * values["blocks_in_flight"], fs, velocity * fs),
        velocity,
    )


def kr_schedule(values: Mapping[str, Any]) -> dsa.KrSchedule:
    """The configured K_r schedule (also what `flaair live` runs)."""
    return dsa.KrSchedule(
        values["kr_initial"],
        values["kr_target"],
        values["kr_ramp_start_s"],
        values["kr_ramp_duration_s"],
    )


def supervisor_params_from_config(values: Mapping[str, Any], model: Model) -> SupervisorParams:
    """The dSA loop's parameters from dsa_controller_node values and the model (for G_a)."""
    v = declared_values(values, DSA_CONTROLLER_PARAMS, skip=("model_file", "timing_file"))
    fs = v["sample_rate_hz"]
    try:
        delay, _ = loop_delay_s(v)
        dsa_params = dsa.dsa_params(
            v,
            actuator_gain_nm_per_v=model.plant.actuator_gain_nm_per_v,
            sample_rate_hz=fs,
            loop_delay_s=delay,
            kr_schedule=kr_schedule(v),
        )
        safety_params = safety.SafetyParams(
            drive_limit_v=v["drive_limit_v"],
            slew_limit_v_per_s=v["slew_limit_v_per_s"] if v["slew_limit_v_per_s"] > 0 else math.inf,
            invalid_timeout_s=v["invalid_timeout_s"],
            ramp_down_s=v["ramp_down_s"],
            sample_rate_hz=fs,
        )
        frequency = crossing_params(fs, v["frequency_hysteresis_deg"])
    except (dsa.DsaParameterError, safety.SafetyParameterError, TransitionError) as exc:
        raise ParameterError(str(exc)) from exc
    return SupervisorParams(
        sample_rate_hz=fs,
        block_size=v["block_size"],
        blocks_in_flight=v["blocks_in_flight"],
        drive_limit_v=v["drive_limit_v"],
        watchdog_timeout_s=v["watchdog_timeout_s"],
        ramp_down_s=v["ramp_down_s"],
        zero_hold_s=v["zero_hold_s"],
        keepalive_period_s=v["keepalive_period_s"],
        wait_for_peers=v["wait_for_peers"],
        min_drive_subscribers=v["min_drive_subscribers"],
        start_delay_s=v["start_delay_s"],
        start_retry_s=v["start_retry_s"],
        run_time_s=v["run_time_s"],
        collision_response=v["collision_response"],
        collision_reduction_factor=v["collision_reduction_factor"],
        collision_restore_on_clearance=v["collision_restore_on_clearance"],
        collision_ramp_guard_s=v["collision_ramp_guard_s"],
        state_every_blocks=v["state_every_blocks"],
        timer_period_s=loop_state.timer_period_s(v["watchdog_timeout_s"]),
        dsa=dsa_params,
        safety=safety_params,
        frequency=frequency,
    )


def describe_loop(params: SupervisorParams, values: Mapping[str, Any]) -> str:
    """One line on the configured loop, for the controller's start-up log."""
    d = params.dsa
    f_c = values["compensation_frequency_hz"]
    return (
        f"r3 {d.r3_rad_s:g} rad/s, kappa {d.kappa:g}, mu {d.mu_nm_s_per_rad:g} N m s/rad, G_a "
        f"{d.actuator_gain_nm_per_v:g} N m/V; sync {d.sync_amplitude_v:g} V at "
        f"{d.sync_frequency_hz:g} Hz; K_r {values['kr_initial']:g} -> {values['kr_target']:g} "
        f"from {values['kr_ramp_start_s']:g} s over {values['kr_ramp_duration_s']:g} s; loop "
        f"delay {1e3 * loop_delay_s(values)[0]:.3f} ms = "
        f"{360 * f_c * loop_delay_s(values)[0]:.1f} deg at {f_c:g} Hz "
        f"{'compensated' if values['compensate_delay'] else '(NOT compensated)'}; limit "
        f"+-{d.drive_limit_v:g} V; collision response {values['collision_response']}"
    )


# One adapter between the block messages (their fields, as the nodes and `replay` decode them)
# and the cores' inputs: the live nodes and the offline replay feed the cores the same values.


def supervisor_wing_input(
    fields: Mapping[str, Any], t_wall: float, drive_subscribers: int
) -> loop_state.WingBlock:
    """A /flaair/wing_state block's fields as the dSA
    loop supervisor's input, received at `t_wall`.
    """
    return loop_state.WingBlock(
        t_wall,
        int(fields["first_sample_index"]),
        float(fields["sample_rate_hz"]),
        fields["stroke_velocity_deg_s"],
        fields["stroke_deg"],
        fields["stroke_valid"],
        drive_subscribers,
    )


def supervisor_params_from_values(values: Mapping[str, Any]) -> SupervisorParams:
    """The dSA controller node's supervisor parameters,
    its model file loaded (ParameterError names it).
    """
    try:
        model = load_model(values["model_file"] or None)
    except (ModelError, OSError) as exc:
        raise ParameterError(f"parameter 'model_file': {exc}") from exc
    return supervisor_params_from_config(values, model)


def drive_fields(block: loop_state.DriveOut, sample_rate_hz: float) -> dict[str, Any]:
    """A DriveCommandBlock's fields (for `intra.BlockPublisher.publish`)."""
    return {
        "sample_rate_hz": sample_rate_hz,
        "first_sample_index": block.first_sample_index,
        "drive_v": block.drive_v,
    }


def controller_state_fields(block: loop_state.DriveOut, watchdog_code: int) -> dict[str, Any]:
    """A ControllerState's fields for the drive block
    `block` (`watchdog_code`: the message's constant).
    """
    return {
        "k_r": block.k_r,
        "async_drive_v": block.async_drive_v,
        "sync_drive_v": block.sync_drive_v,
        "drive_v": block.drive_v[-1],
        "drive_clamped": block.drive_clamped,
        "watchdog": watchdog_code,
        "fault": block.fault,
        "amplitude_scale": block.amplitude_scale,
        "stroke_frequency_hz": block.stroke_frequency_hz,
    }


_MODE_TEXT = {
    loop_state.WAITING: "waiting for the loop to start",
    loop_state.LOOP: "closing the loop",
    loop_state.DONE: "run complete",
}


def controller_health(
    now: loop_state.SupervisorState, before: loop_state.SupervisorState | None
) -> Health:
    """/diagnostics of the dSA controller: watchdog, trips, clamping, bad wing-state blocks
    (clamping and bad blocks: in the period since `before`).
    """
    c, b = now.counts, (before.counts if before is not None else loop_state.Counts())
    problems = []
    if now.mode == loop_state.TRIPPED:
        problems.append((ERROR, f"watchdog tripped: {now.fault} (re-arm: ~/reset_watchdog)"))
    if c.clamped > b.clamped:
        problems.append((WARN, f"drive clamped at the limit in {c.clamped - b.clamped} block(s)"))
    bad = c.invalid + c.rejected + c.stale - b.invalid - b.rejected - b.stale
    if bad:
        problems.append((WARN, f"{bad} wing-state block(s) invalid, rejected or stale"))
    return health(
        "dSA controller",
        problems,
        _MODE_TEXT.get(now.mode, now.mode),
        {
            "mode": now.mode,
            "watchdog": "tripped" if now.mode == loop_state.TRIPPED else "ok",
            "fault": now.fault,
            "trips": c.trips,
            "clamped_blocks": c.clamped,
            "wing_state_blocks": c.blocks,
            "invalid_blocks": c.invalid,
            "rejected_blocks": c.rejected,
            "stale_blocks": c.stale,
            "gaps": c.gaps,
            "amplitude_scale": now.amplitude_scale,
        },
    )


def reset_reply(notes: tuple, mode: str) -> tuple[bool, str]:
    """std_srvs/Trigger's answer to ~/reset_watchdog: success once the loop runs again."""
    return mode == loop_state.LOOP, "; ".join(note.text for note in notes) or mode


def dropped_text(exc: Exception, count: int) -> str:
    """The warning for an undecodable wing-state block (`count` so far)."""
    return f"wing-state block dropped: {exc} [{count} so far]"


def ramp_request(
    changes: Mapping[str, Any], current: Callable[[str], Any]
) -> loop_state.SetRamp | None:
    """The K_r ramp a parameter change asks for: kr_target or kr_ramp_duration_s changed (the
    other at its `current` value); None: no ramp asked for.
    """
    if "kr_target" not in changes and "kr_ramp_duration_s" not in changes:
        return None
    return loop_state.SetRamp(
        changes.get("kr_target", current("kr_target")),
        changes.get("kr_ramp_duration_s", current("kr_ramp_duration_s")),
    )
