"""The dSA loop supervisor's vocabulary: its modes, parameters, state, events and outputs.

`flaair_control.core.supervisor` is the state machine over these (import them from here);
`timer_period_s` is the rule for its wall-clock tick, `summary` its one-line account.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from flaair_control.core import dsa, safety
from flaair_control.core.transition import CrossingParams, CrossingState
from flaair_model.notes import Note

__all__ = [
    "DONE",
    "LOOP",
    "TRIPPED",
    "WAITING",
    "Close",
    "Collision",
    "Counts",
    "DriveOut",
    "Input",
    "Outputs",
    "ResetWatchdog",
    "SetRamp",
    "SupervisorParams",
    "SupervisorState",
    "Tick",
    "WingBlock",
    "summary",
    "timer_period_s",
]

WAITING = "waiting"
LOOP = "loop"
TRIPPED = "tripped"
DONE = "done"


@dataclass(frozen=True)
class SupervisorParams:
    """Loop supervision settings (config/flaair.yaml `dsa_controller_node`; units in names)."""

    sample_rate_hz: float
    block_size: int
    blocks_in_flight: int
    drive_limit_v: float
    watchdog_timeout_s: float  # wall clock without any wing-state block
    ramp_down_s: float
    zero_hold_s: float
    keepalive_period_s: float
    wait_for_peers: bool
    min_drive_subscribers: int
    start_delay_s: float
    start_retry_s: float
    run_time_s: float  # 0: never
    collision_response: str  # none | stop | reduce_amplitude
    collision_reduction_factor: float
    collision_restore_on_clearance: bool
    # onsets during a K_r ramp and this long after it are not acted on
    collision_ramp_guard_s: float
    # ControllerState with every n-th drive block (and every watchdog/fault change)
    state_every_blocks: int
    timer_period_s: float  # the wall-clock tick (`timer_period_s` below)
    dsa: dsa.DsaParams
    safety: safety.SafetyParams
    frequency: CrossingParams  # stroke-frequency estimate for ControllerState (deg)


class Counts(NamedTuple):
    """Wing-state blocks seen, by outcome."""

    blocks: int = 0
    invalid: int = 0
    rejected: int = 0
    stale: int = 0
    gaps: int = 0
    kicks: int = 0
    trips: int = 0  # watchdog trips (each latched until a reset)
    clamped: int = 0  # drive blocks the limiter clamped


class SupervisorState(NamedTuple):
    """Everything the controller remembers between events (a NamedTuple: ``_replace`` costs
    ~1 us against ~10 us for a frozen dataclass's ``replace``, and it runs several times a block).
    """

    mode: str
    fault: str
    amplitude_scale: float
    next_index: int  # first sample index of the next drive block
    expected_index: int | None  # first sample index of the next wing-state block
    dsa_params: dsa.DsaParams  # current (a K_r ramp request replaces the schedule)
    ctrl: dsa.DsaState
    safety: safety.SafetyState
    frequency: CrossingState
    counts: Counts
    peers_seen_wall: float | None
    last_arrival_wall: float
    first_arrival_wall: float | None
    first_arrival_index: int
    last_sent_wall: float
    trip_pace_wall: float
    trip_pace_index: int
    start_blocks: tuple[DriveOut, ...]  # the loop's first blocks, retransmitted until answered
    blocks_since_state: int = 0  # drive blocks sent since the last one with a ControllerState
    clamped_since_state: bool = False  # one of them was clamped (the next state says so)
    state_key: tuple[bool, str] = (False, "")  # (tripped, fault) of the last ControllerState


# --------------------------------------------------------------------------- inputs


class WingBlock(NamedTuple):
    """A /flaair/wing_state block as it arrived (fields as in the message)."""

    t_wall: float
    first_sample_index: int
    sample_rate_hz: float
    stroke_velocity_deg_s: np.ndarray
    stroke_deg: np.ndarray
    stroke_valid: np.ndarray
    drive_subscribers: int


class Tick(NamedTuple):
    """The wall-clock timer, with the graph's peers as the node sees them (read while WAITING
    only: a shell may pass 0 once the loop has started).
    """

    t_wall: float
    drive_subscribers: int
    sensor_publishers: int
    wing_state_publishers: int


class Collision(NamedTuple):
    """A /flaair/collision/events message, and when it arrived."""

    t_wall: float
    onset: bool
    wingbeat_index: int
    spectrum_rmse_deg: float


class SetRamp(NamedTuple):
    """A new K_r ramp from the current K_r to kr_target over kr_ramp_duration_s."""

    kr_target: float
    kr_ramp_duration_s: float


class ResetWatchdog(NamedTuple):
    """Re-arm a tripped watchdog (restarts the loop)."""

    t_wall: float


class Close(NamedTuple):
    """Shutdown: one zero block so the actuator does not hold the last command."""


Input = WingBlock | Tick | Collision | SetRamp | ResetWatchdog | Close


# --------------------------------------------------------------------------- outputs


class DriveOut(NamedTuple):
    """One drive block and the ControllerState that goes with it."""

    first_sample_index: int
    drive_v: np.ndarray
    k_r: float
    async_drive_v: float
    sync_drive_v: float
    drive_clamped: bool
    tripped: bool
    fault: str
    amplitude_scale: float
    stroke_frequency_hz: float
    answers_wing_block: bool  # True: the reply to a wing-state block (loop timing)
    # False: a bare zero block (run end, shutdown), no ControllerState
    with_state: bool


class Outputs(NamedTuple):
    """What one event produced."""

    blocks: tuple[DriveOut, ...] = ()
    notes: tuple[Note, ...] = ()
    refused: str = ""  # SetRamp refused: why


def timer_period_s(watchdog_timeout_s: float) -> float:
    """The wall-clock tick: a quarter of the watchdog's timeout, at most 10 ms (every wake-up
    costs a spin of the executor: no faster than needed).
    """
    return min(0.01, watchdog_timeout_s / 4)


def summary(state: SupervisorState, p: SupervisorParams, what: str) -> str:
    """One line: blocks by outcome, signal vs wall time, watchdog."""
    wall = (state.last_arrival_wall - state.first_arrival_wall) if state.first_arrival_wall else 0.0
    sim = (
        (state.expected_index - state.first_arrival_index) / p.sample_rate_hz
        if state.expected_index
        else 0.0
    )
    rtf = f"{sim / wall:.3f}" if wall > 0 else "n/a"
    c = state.counts
    return (
        f"{what}: {c.blocks} wing-state blocks ({c.invalid} invalid, {c.rejected} rejected, "
        f"{c.stale} stale, {c.gaps} gaps), {sim:.4f} s signal in {wall:.3f} s wall (RTF "
        f"{rtf}), watchdog "
        f"{'TRIPPED: ' + state.fault if state.safety.status == safety.TRIPPED else 'ok'}"
    )
