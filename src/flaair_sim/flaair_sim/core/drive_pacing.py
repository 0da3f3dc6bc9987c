"""Drive pacing: when the open-loop drive generator sends which block, pure.

``step(state, inputs, params) -> (state, outputs)`` takes one event of the drive node: a
wall-clock tick (`Tick`, with the graph's peers as the node sees them), an acknowledgement
from the plant or the front end (`Ack`) or the shutdown (`Close`), and returns the drive
blocks to publish and the log lines. The node maps timers and messages to these inputs and
the blocks to messages; nothing here reads a clock or touches ROS.

Pacing:
  realtime  blocks leave at the wall-clock rate of the signal, from the first tick at which
            `min_subscribers` listen.
  lockstep  at most `lockstep_window_blocks` blocks ahead of the last acknowledged sample,
            once the command subscribers and the acknowledging publisher are matched. No
            acknowledgement for `ack_retry_s` of wall time: one more block (the first
            acknowledgements may be lost while discovery completes; a merely slow plant is
            not harmed by one extra block).

Ending: after `run_time_s` of signal (lead-in included), and at `Close` if the last block was
not zero, one block of zero drive follows, so the actuator is never left holding a voltage.
Every block is clamped to +-drive_limit_v (an input: the node's parameter may change live).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from flaair_model.notes import INFO, WARNING, Note
from flaair_sim.core.drive import DriveError, DriveParams, DriveState, drive_step

__all__ = [
    "LOCKSTEP",
    "PACINGS",
    "REALTIME",
    "Ack",
    "Block",
    "Close",
    "Inputs",
    "Outputs",
    "PacingParams",
    "PacingState",
    "Tick",
    "finished",
    "initial_state",
    "step",
]


REALTIME = "realtime"
LOCKSTEP = "lockstep"
PACINGS = (REALTIME, LOCKSTEP)


@dataclass(frozen=True)
class PacingParams:
    """Drive node settings (config/flaair.yaml `drive_node`; units in names)."""

    sample_rate_hz: float
    block_size: int
    pacing: str  # realtime | lockstep
    lockstep_window_blocks: int
    min_subscribers: int
    first_sample_index: int
    run_time_s: float  # signal time, lead-in included (0: never)
    # lockstep: wall time without acknowledgement before one more block
    ack_retry_s: float
    drive: DriveParams

    def __post_init__(self) -> None:
        if self.pacing not in PACINGS:
            raise DriveError(f"pacing must be one of {', '.join(PACINGS)}, got {self.pacing!r}")
        if not (
            self.sample_rate_hz > 0 and self.block_size >= 1 and self.lockstep_window_blocks >= 1
        ):
            raise DriveError(
                "sample_rate_hz must be > 0, block_size and lockstep_window_blocks >= 1"
            )
        if not self.ack_retry_s > 0:
            raise DriveError(f"ack_retry_s must be > 0, got {self.ack_retry_s:g}")

    @property
    def total_samples(self) -> int | None:
        """Index one past the last sample of the run (None: runs until closed)."""
        run_samples = round(self.run_time_s * self.sample_rate_hz)
        return self.first_sample_index + run_samples if run_samples else None


@dataclass(frozen=True)
class PacingState:
    """Everything the drive node remembers between events."""

    drive: DriveState
    next_index: int  # first sample index of the next block
    acknowledged_index: int  # one past the last sample the plant (or front end) answered
    last_ack_index: int
    last_ack_wall: float
    retries: int
    last_block_zero: bool
    wall_start: float | None  # realtime: wall time of the stream's sample 0


class Tick(NamedTuple):
    """The wall-clock timer, with the peers as the node sees them."""

    t_wall: float
    drive_subscribers: int
    ack_publishers: int  # lockstep: publishers of the acknowledging stream
    drive_limit_v: float


class Ack(NamedTuple):
    """A sensor (or wing-state) block arrived: samples up to `end_index` are answered."""

    t_wall: float
    end_index: int
    drive_subscribers: int
    ack_publishers: int
    drive_limit_v: float


class Close(NamedTuple):
    """Shutdown."""

    drive_limit_v: float


Inputs = Tick | Ack | Close


class Block(NamedTuple):
    """One drive block to publish."""

    first_sample_index: int
    drive_v: np.ndarray


class Outputs(NamedTuple):
    """Blocks to publish, in order, and log lines."""

    blocks: tuple[Block, ...] = ()
    notes: tuple[Note, ...] = ()


def initial_state(params: PacingParams, *, t_wall: float) -> PacingState:
    """Nothing sent, nothing acknowledged; the acknowledgement clock starts at `t_wall`."""
    first = params.first_sample_index
    return PacingState(
        drive=DriveState(),
        next_index=first,
        acknowledged_index=first,
        last_ack_index=-1,
        last_ack_wall=t_wall,
        retries=0,
        last_block_zero=True,
        wall_start=None,
    )


def finished(state: PacingState, params: PacingParams) -> bool:
    """Whether the run's last sample has been sent."""
    total = params.total_samples
    return total is not None and state.next_index >= total


def _send(
    state: PacingState,
    params: PacingParams,
    limit_v: float,
    blocks: list[Block],
    logs: list[Note],
    zero: bool = False,
) -> PacingState:
    """One block (the waveform's next, or zeros); the end-of-run zero block follows it."""
    drive_state = state.drive
    if zero:
        drive_v = np.zeros(params.block_size)
    else:
        drive_state, drive_v = drive_step(
            state.drive, params.block_size, params.sample_rate_hz, params.drive
        )
    blocks.append(Block(state.next_index, np.clip(drive_v, -limit_v, limit_v)))
    state = replace(
        state,
        drive=drive_state,
        next_index=state.next_index + params.block_size,
        last_block_zero=not np.any(drive_v),
    )
    if finished(state, params) and not state.last_block_zero:
        state = _send(state, params, limit_v, blocks, logs, zero=True)
        logs.append(
            Note(
                INFO,
                f"run complete at sample {state.next_index - params.block_size}; zero drive sent",
            )
        )
    return state


def _realtime(
    state: PacingState, tick: Tick, params: PacingParams, blocks: list[Block], logs: list[Note]
) -> PacingState:
    wall_start = state.wall_start
    if wall_start is None:
        if tick.drive_subscribers < params.min_subscribers:
            return state
        wall_start = tick.t_wall
        state = replace(state, wall_start=wall_start)
    due = int((tick.t_wall - wall_start) * params.sample_rate_hz)
    while not finished(state, params) and state.next_index + params.block_size <= due:
        state = _send(state, params, tick.drive_limit_v, blocks, logs)
    return state


def _lockstep(
    state: PacingState,
    event: Tick | Ack,
    params: PacingParams,
    blocks: list[Block],
    logs: list[Note],
) -> PacingState:
    # Both ends matched before the first window: the command subscribers, and the
    # acknowledgement stream (missed acknowledgements would stall the run forever).
    if event.drive_subscribers < params.min_subscribers or event.ack_publishers == 0:
        return state
    if state.acknowledged_index != state.last_ack_index:
        state = replace(state, last_ack_index=state.acknowledged_index, last_ack_wall=event.t_wall)
    window = params.lockstep_window_blocks * params.block_size
    while not finished(state, params) and state.next_index < state.acknowledged_index + window:
        state = _send(state, params, event.drive_limit_v, blocks, logs)
    if not finished(state, params) and event.t_wall - state.last_ack_wall > params.ack_retry_s:
        state = replace(state, retries=state.retries + 1, last_ack_wall=event.t_wall)
        logs.append(
            Note(
                WARNING,
                f"no acknowledgement for {params.ack_retry_s:g} s at block "
                f"{state.next_index}; sending one more block ({state.retries})",
            )
        )
        state = _send(state, params, event.drive_limit_v, blocks, logs)
    return state


def step(state: PacingState, inputs: Inputs, params: PacingParams) -> tuple[PacingState, Outputs]:
    """Advance the pacing by one event; return the new state and what to publish and log."""
    blocks: list[Block] = []
    logs: list[Note] = []
    if isinstance(inputs, Close):
        if state.next_index > params.first_sample_index and not state.last_block_zero:
            state = _send(state, params, inputs.drive_limit_v, blocks, logs, zero=True)
    elif isinstance(inputs, Ack):
        state = replace(state, acknowledged_index=inputs.end_index)
        if params.pacing == LOCKSTEP:
            state = _lockstep(state, inputs, params, blocks, logs)
    elif params.pacing == LOCKSTEP:
        state = _lockstep(state, inputs, params, blocks, logs)
    else:
        state = _realtime(state, inputs, params, blocks, logs)
    return state, Outputs(tuple(blocks), tuple(logs))
