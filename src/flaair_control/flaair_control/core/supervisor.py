"""Loop supervisor: the dSA controller's start / loop / trip / keepalive state machine, pure.

``step(state, inputs, params) -> (state, outputs)`` takes one event of the controller node:
a wing-state block, a wall-clock tick, a collision event, a K_r ramp request, a watchdog reset
or the close at shutdown, and returns the drive blocks to publish (each with its
ControllerState fields) and the log lines. The node maps messages to these inputs and the
outputs back to messages; offline, a recorded bag replays through the same function.

Modes: WAITING (not started: peers and start delay), LOOP (one command block per wing-state
block; velocity block k drives block k + blocks_in_flight), TRIPPED (the wall-clock tick paces
the ramp-down and zero_hold_s of zeros at the real-time rate, then one zero block per
keepalive_period_s), DONE (run_time_s reached: a zero block, then idle).

Watchdogs (latched until `ResetWatchdog`):
  * no wing-state block for watchdog_timeout_s of *wall-clock* time (in lockstep, signal time
    stops with the loop, so only the wall clock can see a dead loop);
  * no fully valid block for invalid_timeout_s of *signal* time (`flaair_control.core.safety`);
  * a collision onset with collision_response stop.
Every block passes the safety core (non-finite -> 0, slew limit, clamp to +-drive_limit_v).

Its parameters, state, events and outputs are declared in `flaair_control.core.loop_state`
(import them from there).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
from numba import njit

from flaair_common.stream import check_block
from flaair_control.core import dsa, safety
from flaair_control.core.loop_state import (
    DONE,
    LOOP,
    TRIPPED,
    WAITING,
    Close,
    Collision,
    Counts,
    DriveOut,
    Input,
    Outputs,
    ResetWatchdog,
    SetRamp,
    SupervisorParams,
    SupervisorState,
    Tick,
    WingBlock,
    summary,
)
from flaair_control.core.transition import (
    CROSSING_START,
    crossing_frequency_hz,
    crossing_step,
)
from flaair_model.notes import ERROR, INFO, WARNING, Note

__all__ = ["drive_block", "initial_state", "step", "warm_up"]


def initial_state(params: SupervisorParams) -> SupervisorState:
    """Not started; nothing seen."""
    return SupervisorState(
        WAITING,
        "",
        1.0,
        0,
        None,
        params.dsa,
        dsa.initial_state(params.dsa),
        safety.initial_state(params.safety),
        CROSSING_START,
        Counts(),
        None,
        0.0,
        None,
        0,
        0.0,
        0.0,
        0,
        (),
    )


def warm_up(params: SupervisorParams) -> None:
    """Load the dSA and safety cores' compiled kernels now (a throwaway loop start), not on the
    first live block, when the target's packets would queue up behind it.
    """
    params = replace(params, min_drive_subscribers=1)
    state = initial_state(params)
    for t_wall in (0.0, 1e3):
        state, _ = step(state, Tick(t_wall, 1, 1, 1), params)


def step(
    state: SupervisorState, inputs: Input, params: SupervisorParams
) -> tuple[SupervisorState, Outputs]:
    """Advance the supervisor by one event (see the module docstring)."""
    handler = _HANDLERS[type(inputs)]
    return handler(state, inputs, params)


# --------------------------------------------------------------------------- handlers


# The dSA signals a drive block reports.
_KR, _ASYNC, _SYNC, _UNCLIPPED, _DRIVE = (
    dsa.SIGNAL_ROWS.index(name)
    for name in ("kr", "async_v", "sync_v", "drive_unclipped_v", "drive_v")
)


@njit(cache=True)
def drive_block(
    velocity_rad_s: np.ndarray,
    t_start_s: float,
    zi_adv: np.ndarray,
    zi_raw: np.ndarray,
    coefficients: np.ndarray,
    scalars: np.ndarray,
    amplitude_scale: float,
    drive_limit_v: float,
    guard_args: tuple[float, float, bool, float, float, float, float, float],
) -> tuple[np.ndarray, np.ndarray, float, float, float, bool]:
    """A velocity block through the dSA filter, the amplitude scale and the drive guard in one
    compiled call (the cores' own kernels): the guarded drive, the filter state, K_r, the
    asynchronous and synchronous drive at the block's last sample, and whether the limit
    clamped it (max |u| x scale > limit, as numpy's max says it: a NaN sample is not clamped).
    """
    out, z = dsa.filter_block(velocity_rad_s, t_start_s, zi_adv, zi_raw, coefficients, scalars)
    guarded, _ = safety.guard_block(out[_DRIVE] * amplitude_scale, *guard_args)  # x 1.0 exact
    peak, any_nan = 0.0, False
    for u in out[_UNCLIPPED]:
        any_nan = any_nan or math.isnan(u)
        peak = max(peak, abs(u))
    clamped = not any_nan and peak * amplitude_scale > drive_limit_v
    last = out.shape[1] - 1
    return guarded[0], z, out[_KR, last], out[_ASYNC, last], out[_SYNC, last], clamped


def _send(
    state: SupervisorState,
    velocity_rad_s: np.ndarray,
    answers: bool,
    t_wall: float,
    p: SupervisorParams,
    frequency_hz: float | None = None,
    arrival: dict[str, Any] | None = None,
) -> tuple[SupervisorState, list[DriveOut], list[Note]]:
    """Run the dSA and safety cores on one velocity block: the next drive block (`frequency_hz`:
    the stroke frequency its block reports, if the caller has just estimated it; `arrival`: the
    state's fields a healthy wing block changed, set in the drive block's one ``_replace``).
    """
    arrival = arrival or {}
    index = state.next_index
    t_start = index / p.sample_rate_hz
    guard, guard_args = safety.guard_arguments(
        arrival.get("safety", state.safety), t_start, p.block_size, p.safety
    )
    drive_v, z, kr, async_v, sync_v, clamped = drive_block(
        velocity_rad_s,  # float64 and contiguous on every path (np.radians, np.full, np.where)
        t_start,
        state.ctrl.zi_advanced,
        state.ctrl.zi_raw,
        *state.dsa_params.kernel_args,
        float(state.amplitude_scale),  # one compiled signature, whatever the config's types
        float(p.drive_limit_v),
        guard_args,
    )
    ctrl = dsa.DsaState(z[0], z[1])
    guard = guard._replace(last_drive_v=float(drive_v[-1]))
    tripped = guard.status == safety.TRIPPED
    if clamped:
        state, arrival = _count(state._replace(**arrival), "clamped"), {}
    # the safety core tripped: trip at this block
    if tripped and state.mode == LOOP:
        state, notes = _check_core_trip(
            state._replace(**{**arrival, "ctrl": ctrl, "safety": guard, "last_sent_wall": t_wall}),
            t_wall,
            p,
        )
        due, with_state, clamped = _state_due(state, clamped, tripped, p)
        state = state._replace(next_index=index + p.block_size, **due)
    else:  # every block of a healthy loop: one _replace
        due, with_state, clamped = _state_due(state, clamped, tripped, p)
        state, notes = (
            state._replace(
                **{
                    **arrival,
                    "ctrl": ctrl,
                    "safety": guard,
                    "last_sent_wall": t_wall,
                    "next_index": index + p.block_size,
                    **due,
                }
            ),
            [],
        )
    block = DriveOut(
        index,
        drive_v,
        kr,
        async_v,
        sync_v,
        clamped,
        tripped,
        state.fault,
        state.amplitude_scale,
        _frequency_hz(state, p) if frequency_hz is None else frequency_hz,
        answers,
        with_state,
    )
    blocks = [block]
    end_index = round(p.run_time_s * p.sample_rate_hz)
    if end_index and state.next_index >= end_index and state.mode != DONE:
        state = state._replace(mode=DONE)
        state, zero = _zero_block(state, p)
        blocks.append(zero)
        notes.append(Note(INFO, summary(state, p, "run complete")))
    return state, blocks, notes


def _state_due(
    state: SupervisorState, clamped: bool, tripped: bool, p: SupervisorParams
) -> tuple[dict[str, Any], bool, bool]:
    """Does this drive block carry a ControllerState (every state_every_blocks-th, and at once when
    the watchdog or the fault changes)? Returns the state's fields that say so (for the caller's
    one ``_replace``), that, and whether any block since the last ControllerState was clamped.
    """
    clamped = clamped or state.clamped_since_state
    key = (tripped, state.fault)
    if state.blocks_since_state + 1 >= p.state_every_blocks or key != state.state_key:
        return (
            {"blocks_since_state": 0, "clamped_since_state": False, "state_key": key},
            True,
            clamped,
        )
    return (
        {"blocks_since_state": state.blocks_since_state + 1, "clamped_since_state": clamped},
        False,
        clamped,
    )


def _frequency_hz(state: SupervisorState, p: SupervisorParams) -> float:
    return crossing_frequency_hz(state.frequency, p.frequency)


def _zero_block(state: SupervisorState, p: SupervisorParams) -> tuple[SupervisorState, DriveOut]:
    block = DriveOut(
        state.next_index,
        np.zeros(p.block_size),
        math.nan,
        math.nan,
        math.nan,
        False,
        state.mode == TRIPPED,
        state.fault,
        state.amplitude_scale,
        _frequency_hz(state, p),
        False,
        False,
    )
    return state._replace(next_index=state.next_index + p.block_size), block


def _check_core_trip(
    state: SupervisorState, t_wall: float, p: SupervisorParams
) -> tuple[SupervisorState, list[Note]]:
    """The safety core tripped by itself (signal-time timeout without a valid block)."""
    if state.safety.status == safety.TRIPPED and state.mode == LOOP:
        fault = (
            f"no valid wing-state block after t = {state.safety.last_valid_time_s:.4f} s for "
            f"more than invalid_timeout_s = {p.safety.invalid_timeout_s:g} s of signal time"
        )
        return _enter_tripped(state._replace(fault=fault), t_wall, p)
    return state, []


def _enter_tripped(
    state: SupervisorState, t_wall: float, p: SupervisorParams
) -> tuple[SupervisorState, list[Note]]:
    state = _count(state, "trips")._replace(
        mode=TRIPPED, trip_pace_wall=t_wall, trip_pace_index=state.next_index
    )
    return state, [
        Note(
            ERROR,
            f"WATCHDOG TRIPPED at t = {state.safety.trip_time_s:.4f} s: "
            f"{state.fault}; ramping the drive to zero over {p.ramp_down_s:g} "
            "s",
        )
    ]


def _trip(
    state: SupervisorState, fault: str, t_wall: float, p: SupervisorParams
) -> tuple[SupervisorState, list[Note]]:
    """Trip now (at the next unpublished sample) with a fault text."""
    if state.mode in (TRIPPED, DONE):
        return state, []
    t_now = state.next_index / p.sample_rate_hz
    # The safety core trips an invalid block at its time: the ramp starts at the next sample.
    guard = safety.note_sensor_block(state.safety, t_now, False, p.safety)
    return _enter_tripped(state._replace(safety=guard, fault=fault), t_wall, p)


def _count(state: SupervisorState, name: str) -> SupervisorState:
    counts = state.counts
    return state._replace(counts=counts._replace(**{name: getattr(counts, name) + 1}))


# A block off the fast path: its kind -> (the count it adds to, and the note's key; the note).
_BLOCK_FAULTS = {
    "stale": ("stale", "wing-state block {first} ignored: {reason} [{count} stale so far]"),
    "gap": ("gaps", "wing-state block {first}: {reason} [{count} gaps so far]"),
    "content": (
        "rejected",
        "wing-state block {first} rejected: {reason}; its samples drive the filter as 0 "
        "[{count} rejected so far]",
    ),
}


def _checked(
    state: SupervisorState, block: WingBlock, size: int, p: SupervisorParams, notes: list[Note]
) -> tuple[str, Counts]:
    """A block off the fast path checked (`check_block`): its kind (stale, gap, content, ok)
    and the counts with it.
    """
    first = int(block.first_sample_index)
    counts = state.counts
    check = check_block(
        {"stroke_velocity_deg_s": np.zeros(size)},
        block.sample_rate_hz,
        p.sample_rate_hz,
        first,
        state.expected_index,
        p.block_size,
    )
    if check.kind in _BLOCK_FAULTS:
        field, text = _BLOCK_FAULTS[check.kind]
        counts = counts._replace(**{field: getattr(counts, field) + 1})
        said = text.format(first=first, reason=check.reason, count=getattr(counts, field))
        notes.append(Note(WARNING, said, field))
    return check.kind, counts


def _velocity(
    block: WingBlock, field: np.ndarray, n: int, counts: Counts, notes: list[Note]
) -> tuple[np.ndarray, bool, Counts]:
    """The block's stroke velocity [rad/s] (invalid samples NaN), whether all of it is valid,
    and the counts.
    """
    velocity_rad_s = np.radians(field)
    flags = np.asarray(block.stroke_valid, dtype=bool)
    # a finite sum proves every sample finite (the fast path);
    # an overflowing one is checked sample by sample. A block's few samples are reduced in
    # Python: a numpy reduction costs ~2 us of fixed overhead.
    valid = (
        flags.size == n
        and all(flags.tolist())
        and (math.isfinite(sum(velocity_rad_s.tolist())) or bool(np.isfinite(velocity_rad_s).all()))
    )
    if not valid:
        counts = counts._replace(invalid=counts.invalid + 1)
        notes.append(
            Note(
                WARNING,
                f"wing-state block {int(block.first_sample_index)} invalid (stroke_valid false "
                "or non-finite velocity); its invalid samples drive the "
                f"filter as 0 [{counts.invalid} invalid so far]",
                "invalid",
            )
        )
        if flags.size == n:
            velocity_rad_s = np.where(flags, velocity_rad_s, np.nan)
    return velocity_rad_s, bool(valid), counts


def _on_wing(
    state: SupervisorState, block: WingBlock, p: SupervisorParams
) -> tuple[SupervisorState, Outputs]:
    if state.mode == DONE:
        return state, Outputs()
    notes: list[Note] = []
    first = int(block.first_sample_index)
    if state.mode == WAITING:
        # Blocks already flow (a realtime plant, a target): join the loop by answering them, no
        # extra start blocks - once the drive's listeners are there (a recorder included).
        if block.drive_subscribers < (p.min_drive_subscribers if p.wait_for_peers else 1):
            return state, Outputs()
        state = state._replace(mode=LOOP)
        notes.append(Note(INFO, f"wing-state block {first} before the start: joining the loop"))
    if state.first_arrival_wall is None:
        # The drive counts from 0 at the controller's start; a loop that was already flowing (a
        # target, a real-time plant) counts its samples from its own start. The safety watchdog
        # runs on the drive's timeline: wing block `first` maps to time (first - this index) / fs.
        state = state._replace(
            first_arrival_wall=block.t_wall,
            first_arrival_index=first,
            safety=safety.initial_state(p.safety),
        )
        notes.append(Note(INFO, f"loop closed: first wing-state block {first}"))
    n = p.block_size
    field = np.asarray(block.stroke_velocity_deg_s, dtype=float)
    kind = "ok"
    counts = state.counts  # the block's updates are gathered and applied in one _replace below
    # Fast path (every block in a healthy loop): in order, right length and rate.
    if not (
        first == state.expected_index
        and field.size == n
        and block.sample_rate_hz == p.sample_rate_hz
    ):
        kind, counts = _checked(state, block, field.size, p, notes)
        if kind == "stale":
            state = state._replace(last_arrival_wall=block.t_wall, counts=counts)
            return state, Outputs((), tuple(notes))
    counts = counts._replace(blocks=counts.blocks + 1)
    frequency, guard, frequency_hz = state.frequency, state.safety, None
    if kind == "content":
        velocity_rad_s, valid = np.full(n, np.nan), False
    else:
        velocity_rad_s, valid, counts = _velocity(block, field, n, counts, notes)
        stroke_deg = np.asarray(block.stroke_deg, dtype=float)
        frequency, frequency_hz = crossing_step(
            frequency, stroke_deg if stroke_deg.size == n else np.full(n, np.nan), p.frequency
        )
    if valid:
        guard = safety.note_sensor_block(
            guard, (first + n - state.first_arrival_index) / p.sample_rate_hz, True, p.safety
        )
    arrival: dict[str, Any] = {
        "last_arrival_wall": block.t_wall,
        "expected_index": first + n,
        "counts": counts,
        "frequency": frequency,
        "safety": guard,
    }
    if state.mode == LOOP and guard.status != safety.TRIPPED:
        # a healthy loop's block: no trip to check, its fields go into the drive block's _replace
        state, blocks, more = _send(
            state, velocity_rad_s, True, block.t_wall, p, frequency_hz, arrival
        )
        return state, Outputs(tuple(blocks), tuple(notes + more))
    state = state._replace(**arrival)
    if valid:
        state, more = _check_core_trip(state, block.t_wall, p)
        notes.extend(more)
    if state.mode != LOOP:
        return state, Outputs((), tuple(notes))
    state, blocks, more = _send(state, velocity_rad_s, True, block.t_wall, p, frequency_hz)
    return state, Outputs(tuple(blocks), tuple(notes + more))


def _on_tick(
    state: SupervisorState, tick: Tick, p: SupervisorParams
) -> tuple[SupervisorState, Outputs]:
    now = tick.t_wall
    nan_block = np.full(p.block_size, np.nan)
    blocks: list[DriveOut] = []
    notes: list[Note] = []
    if state.mode == WAITING:
        # A /flaair/drive subscriber alone may be a monitor or a recorder: also wait for the
        # sensor stream's source (the plant, or the DAQ) and the wing-state source (front end).
        if p.wait_for_peers and (
            tick.drive_subscribers < p.min_drive_subscribers
            or tick.sensor_publishers == 0
            or tick.wing_state_publishers == 0
        ):
            return state, Outputs()
        seen_wall = state.peers_seen_wall
        if seen_wall is None:
            seen_wall = now
            state = state._replace(peers_seen_wall=now)
        if now - seen_wall < p.start_delay_s:
            return state, Outputs()
        state = state._replace(mode=LOOP)
        notes.append(Note(INFO, f"starting the loop: {p.blocks_in_flight} block(s) in flight"))
        for _ in range(p.blocks_in_flight):
            state, sent, more = _send(state, nan_block, False, now, p)
            blocks += sent
            notes += more
        state = state._replace(start_blocks=tuple(blocks))
    elif state.mode == LOOP:
        if state.first_arrival_wall is None:
            if now - state.last_sent_wall > p.start_retry_s:
                # A retransmission of the same blocks, not new ones: when
                # the first answer is only late, new blocks would stay in
                # the loop as extra delay (the plant ignores duplicates).
                state = _count(state, "kicks")._replace(last_sent_wall=now)
                notes.append(
                    Note(
                        WARNING,
                        f"no wing-state block {p.start_retry_s:g} s after "
                        "starting; sending the first block(s) again "
                        f"({state.counts.kicks}) - is the front end running?",
                    )
                )
                blocks += [b._replace(with_state=False) for b in state.start_blocks]
        elif now - state.last_arrival_wall > p.watchdog_timeout_s:
            last = (state.expected_index or p.block_size) - p.block_size
            state, more = _trip(
                state,
                "no wing-state block for "
                f"{1e3 * (now - state.last_arrival_wall):.0f} ms of "
                "wall-clock time (> watchdog_timeout_s "
                f"{p.watchdog_timeout_s:g} s) after block {last}",
                now,
                p,
            )
            notes += more
    elif state.mode == TRIPPED:
        t_quiet = state.safety.trip_time_s + p.ramp_down_s + p.zero_hold_s
        if state.next_index / p.sample_rate_hz < t_quiet:
            due = state.trip_pace_index + int((now - state.trip_pace_wall) * p.sample_rate_hz)
            budget = max(1, int(4 * p.timer_period_s * p.sample_rate_hz / p.block_size))
            while state.next_index + p.block_size <= due and budget > 0:
                state, sent, more = _send(state, nan_block, False, now, p)
                blocks += sent
                notes += more
                budget -= 1
        elif now - state.last_sent_wall >= p.keepalive_period_s:
            state, sent, more = _send(state, nan_block, False, now, p)
            blocks += sent
            notes += more
    return state, Outputs(tuple(blocks), tuple(notes))


def _on_collision(
    state: SupervisorState, event: Collision, p: SupervisorParams
) -> tuple[SupervisorState, Outputs]:
    response = p.collision_response
    notes: list[Note] = []
    if event.onset:
        text = (
            f"collision onset at wingbeat {event.wingbeat_index} "
            f"(spectrum RMSE {event.spectrum_rmse_deg:.2f} deg)"
        )
        if response != "none" and _in_ramp_guard(state, p):
            # the stroke turns from the sync sine into the self-excited one by design:
            # a per-wingbeat distortion score reads that change as a collision
            guard = f"collision_ramp_guard_s = {p.collision_ramp_guard_s:g} s"
            ignored = f"{text} during the K_r ramp (or within {guard} of its end): not acted on"
            return state, Outputs((), (Note(INFO, ignored),))
        if response == "stop":
            state, notes = _trip(state, f"{text}: stop", event.t_wall, p)
        elif response == "reduce_amplitude":
            state = state._replace(amplitude_scale=p.collision_reduction_factor)
            notes.append(Note(WARNING, f"{text}: drive scaled by {p.collision_reduction_factor:g}"))
        else:
            notes.append(Note(WARNING, f"{text}: no response configured"))
    elif (
        response == "reduce_amplitude"
        and p.collision_restore_on_clearance
        and state.amplitude_scale != 1.0
    ):
        state = state._replace(amplitude_scale=1.0)
        notes.append(
            Note(INFO, f"collision cleared at wingbeat {event.wingbeat_index}: full drive again")
        )
    else:
        notes.append(Note(INFO, f"collision cleared at wingbeat {event.wingbeat_index}"))
    return state, Outputs((), tuple(notes))


def _in_ramp_guard(state: SupervisorState, p: SupervisorParams) -> bool:
    """K_r is ramping now (signal time), or stopped ramping less than collision_ramp_guard_s ago."""
    kr = state.dsa_params.kr_schedule
    t_s = state.next_index / p.sample_rate_hz
    return (
        kr.start_value != kr.end_value
        and kr.start_time_s <= t_s < kr.start_time_s + kr.duration_s + p.collision_ramp_guard_s
    )


def _on_set_ramp(
    state: SupervisorState, request: SetRamp, p: SupervisorParams
) -> tuple[SupervisorState, Outputs]:
    t_now = state.next_index / p.sample_rate_hz
    current = float(state.dsa_params.kr_schedule.value(np.array([t_now]))[0])
    try:
        schedule = dsa.KrSchedule(
            current, float(request.kr_target), t_now, float(request.kr_ramp_duration_s)
        )
        params = replace(state.dsa_params, kr_schedule=schedule)
    except dsa.DsaParameterError as exc:
        return state, Outputs(refused=str(exc))
    return state._replace(dsa_params=params), Outputs(
        (),
        (
            Note(
                INFO,
                f"K_r ramp {current:.3f} -> {request.kr_target:g} over "
                f"{request.kr_ramp_duration_s:g} s from t = {t_now:.4f} s",
            ),
        ),
    )


def _on_reset(
    state: SupervisorState, request: ResetWatchdog, p: SupervisorParams
) -> tuple[SupervisorState, Outputs]:
    if state.mode != TRIPPED:
        return state, Outputs(
            (), (Note(INFO, "reset_watchdog: watchdog not tripped, nothing to do"),)
        )
    t_now = state.next_index / p.sample_rate_hz
    state = state._replace(
        safety=safety.reset(state.safety, t_now),
        fault="",
        mode=LOOP,
        last_arrival_wall=request.t_wall,
    )
    notes = [Note(WARNING, "watchdog reset by request; restarting the loop")]
    blocks: list[DriveOut] = []
    for _ in range(p.blocks_in_flight):
        state, sent, more = _send(state, np.full(p.block_size, np.nan), False, request.t_wall, p)
        blocks += sent
        notes += more
    return state, Outputs(tuple(blocks), tuple(notes))


def _on_close(
    state: SupervisorState, request: Close, p: SupervisorParams
) -> tuple[SupervisorState, Outputs]:
    state, zero = _zero_block(state, p)
    return state, Outputs(
        (zero,), (Note(INFO, summary(state, p, "shutting down, zero drive sent")),)
    )


_HANDLERS: dict[type, Callable[..., tuple[SupervisorState, Outputs]]] = {
    WingBlock: _on_wing,
    Tick: _on_tick,
    Collision: _on_collision,
    SetRamp: _on_set_ramp,
    ResetWatchdog: _on_reset,
    Close: _on_close,
}
