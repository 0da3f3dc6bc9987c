"""The simulated actuator driver: which drive block the plant steps next, and when (pure).

``step(state, inputs, params) -> (state, outputs)`` takes a command block or a wall-clock tick
and returns the drive blocks the plant must simulate now, in order, with log notes.

Modes:
  lockstep  one block per accepted command block, so a closed loop is deterministic whatever
            the wall speed (signal time = samples / sample_rate_hz);
  realtime  the wall clock sets the pace: a tick releases the next due block (call again until
            none is due), the oldest queued command, or zero drive when none is queued.

A command with NaN/inf samples, the wrong length or rate is stepped as zero drive (counted,
logged); a duplicate or out-of-order one is ignored; a gap is accepted.

Drive watchdog (lockstep): the plant stands in for the actuator and its driver, which must not
hold a voltage when the command source dies. Once commands have flowed for arm_s of signal
time, if none arrives for command_timeout_s of wall-clock time while the last applied block was
not all zeros (a source that stops cleanly sends a zero block first), the drive is zeroed and
the wing rings down with zero drive at the real-time rate for ring_down_s of signal time; a
command that continues the sample count re-arms it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from flaair_common.stream import check_block
from flaair_model.notes import ERROR, INFO, WARNING, Note

__all__ = [
    "MAX_PENDING",
    "ActuatorParams",
    "ActuatorState",
    "Command",
    "Outputs",
    "Tick",
    "blocks_per_tick",
    "clamp_drive",
    "initial_state",
    "step",
    "tick_period_s",
]

MAX_PENDING = 1000  # realtime: queued command blocks kept (0.5 s at 20 kHz in 10-sample blocks)


@dataclass(frozen=True)
class ActuatorParams:
    """Pacing and watchdog settings (config/flaair.yaml `plant_node`)."""

    sample_rate_hz: float
    block_size: int
    mode: str  # lockstep | realtime
    command_timeout_s: float  # 0: no watchdog
    ring_down_s: float
    arm_s: float


class Command(NamedTuple):
    """A /flaair/drive block as it arrived."""

    t_wall: float
    first_sample_index: int
    sample_rate_hz: float
    drive_v: np.ndarray


class Tick(NamedTuple):
    """The wall-clock timer."""

    t_wall: float


class Outputs(NamedTuple):
    """Drive blocks to step now (in order) and what to log."""

    drive_blocks: tuple[np.ndarray, ...] = ()
    notes: tuple[Note, ...] = ()


class ActuatorState(NamedTuple):
    """Pacing state (a NamedTuple: ``_replace`` is ~1 us, a frozen dataclass's ``replace`` ~10 us,
    and a command block takes several).
    """

    next_index: int  # first sample index of the next stepped block
    expected_command_index: int | None
    last_command_wall: float
    driven: bool  # last applied block not all zeros
    commanded_samples: int
    ring_down: tuple[float, int, int] | None  # (wall start, first index, end index)
    pending: tuple[np.ndarray, ...]  # realtime: queued commands
    wall_start_s: float  # realtime: wall time of sample 0
    rejected: int


def initial_state(params: ActuatorParams, *, t_wall: float) -> ActuatorState:
    """Nothing commanded yet; the watchdog's clock starts at `t_wall`."""
    return ActuatorState(0, None, t_wall, False, 0, None, (), t_wall, 0)


def step(
    state: ActuatorState, inputs: Command | Tick, p: ActuatorParams
) -> tuple[ActuatorState, Outputs]:
    """Advance the driver by one command block or one wall-clock tick."""
    if isinstance(inputs, Command):
        return _on_command(state, inputs, p)
    return _on_tick(state, inputs, p)


_SMALL_BLOCK = 64  # samples: up to this many, Python's min and max beat two numpy ufuncs


def clamp_drive(drive_v: np.ndarray, limit_v: float) -> np.ndarray:
    """The drive the actuator takes: clamped to +-`limit_v` (the driver's safe range).

    A block already inside the range comes back as it is (clamping it is the identity).
    """
    if drive_v.size <= _SMALL_BLOCK:  # a block's few samples: Python's min and max, no ufuncs
        values = drive_v.tolist()
        if values and -limit_v <= min(values) and max(values) <= limit_v:
            return drive_v
    clamped: np.ndarray = np.minimum(np.maximum(drive_v, -limit_v), limit_v)  # np.clip's third
    return clamped


def tick_period_s(params: ActuatorParams) -> float | None:
    """The wall-clock tick's period: 5 ms in realtime, a quarter of the drive watchdog's timeout
    (at most 10 ms) in lockstep with the watchdog on; None: no tick needed.
    """
    if params.mode == "realtime":
        return 0.005
    if params.command_timeout_s > 0:
        return min(0.01, params.command_timeout_s / 4)
    return None


def blocks_per_tick(params: ActuatorParams) -> int:
    """Realtime: at most this many due blocks (20 ms) are stepped per tick, so a plant behind
    the wall clock does not starve its executor (timers, shutdown).
    """
    return int(0.02 * params.sample_rate_hz / params.block_size)


def _emit(state: ActuatorState, blocks: list[np.ndarray], drive_v: np.ndarray) -> ActuatorState:
    blocks.append(drive_v)
    return state._replace(next_index=state.next_index + drive_v.size)


def _on_command(
    state: ActuatorState, c: Command, p: ActuatorParams
) -> tuple[ActuatorState, Outputs]:
    first = int(c.first_sample_index)
    drive_v = np.array(c.drive_v, dtype=np.float64)
    values = drive_v.tolist()  # a block's few samples: Python's sum and any, no numpy reduction
    notes: list[Note] = []
    # Fast path (every block of a healthy stream; a finite sum proves every sample finite, an
    # overflowing one goes the slow way); check_block names what is wrong otherwise.
    if not (
        first == state.expected_command_index
        and drive_v.size == p.block_size
        and c.sample_rate_hz == p.sample_rate_hz
        and math.isfinite(sum(values))
    ):
        check = check_block(
            {"drive_v": drive_v},
            c.sample_rate_hz,
            p.sample_rate_hz,
            first,
            state.expected_command_index,
            p.block_size,
        )
        if not check.ok:
            state = state._replace(rejected=state.rejected + 1)
            action = {
                "stale": "ignored",
                "gap": "accepted after the gap",
                "content": "holding zero drive",
            }[check.kind]
            notes.append(
                Note(
                    WARNING,
                    f"rejected command block {first} ({check.reason}); {action} "
                    f"[{state.rejected} rejected so far]",
                    "rejected",
                )
            )
            if check.kind == "stale":
                # a duplicate must not advance the plant again
                return state, Outputs((), tuple(notes))
            if check.kind == "content":
                drive_v = np.zeros(p.block_size)
                values = drive_v.tolist()
    if p.mode != "lockstep":
        return (
            state._replace(
                expected_command_index=first + p.block_size,
                last_command_wall=c.t_wall,
                pending=((*state.pending, drive_v))[-MAX_PENDING:],
            ),
            Outputs((), tuple(notes)),
        )
    if state.ring_down is not None:
        notes.append(
            Note(INFO, f"drive commands resumed at block {first}; drive watchdog re-armed")
        )
    # the block is stepped at once: one _replace (a healthy loop's every block comes here)
    state = state._replace(
        expected_command_index=first + p.block_size,
        last_command_wall=c.t_wall,
        ring_down=None,
        driven=any(values),
        commanded_samples=state.commanded_samples + drive_v.size,
        next_index=state.next_index + drive_v.size,
    )
    return state, Outputs((drive_v,), tuple(notes))


def _on_tick(state: ActuatorState, tick: Tick, p: ActuatorParams) -> tuple[ActuatorState, Outputs]:
    now = tick.t_wall
    blocks: list[np.ndarray] = []
    zero = np.zeros(p.block_size)
    if p.mode == "realtime":
        # One due block per call: the caller steps it and calls again, so a command the step
        # itself caused (an in-process loop answers at once) is used by the very next block.
        if int((now - state.wall_start_s) * p.sample_rate_hz) - state.next_index >= p.block_size:
            if state.pending:
                drive_v, state = state.pending[0], state._replace(pending=state.pending[1:])
            else:
                drive_v = zero
            state = _emit(state, blocks, drive_v)
        return state, Outputs(tuple(blocks))
    if p.command_timeout_s <= 0:
        return state, Outputs()
    notes: list[Note] = []
    if state.ring_down is None:
        silent_s = now - state.last_command_wall
        # Armed once commands have flowed for arm_s of signal time: a controller's start-up
        # (first blocks unanswered until its retry) is not a dead source.
        armed = state.commanded_samples >= p.arm_s * p.sample_rate_hz
        if not (armed and state.driven and silent_s > p.command_timeout_s):
            return state, Outputs()
        n_ring = round(p.ring_down_s * p.sample_rate_hz / p.block_size) * p.block_size
        state = state._replace(
            ring_down=(now, state.next_index, state.next_index + n_ring), driven=False
        )
        notes.append(
            Note(
                ERROR,
                f"DRIVE WATCHDOG: no command block for {1e3 * silent_s:.1f} ms (> "
                f"command_timeout_s {p.command_timeout_s:g} s) after block "
                f"{state.next_index - p.block_size}, last drive not zero: drive "
                f"zeroed, ringing down for {p.ring_down_s:g} s",
            )
        )
    assert state.ring_down is not None  # set just above when the watchdog trips
    wall_start, first, end = state.ring_down
    due = min(end, first + int((now - wall_start) * p.sample_rate_hz))
    while state.next_index + p.block_size <= due:
        state = _emit(state, blocks, zero)
    if blocks and state.next_index == end:
        notes.append(
            Note(
                INFO, f"ring-down done at sample {end}: zero drive held until a command block comes"
            )
        )
    # the stream continues from here: a command for the next block is in order
    return (
        state._replace(expected_command_index=state.next_index),
        Outputs(tuple(blocks), tuple(notes)),
    )
