"""The stroke controller's loop timing (pure): when it starts, retries its start and trips.

WAITING until the drive has a subscriber and the wing state a publisher for start_delay_s
(wall clock), then LOOP: `blocks_in_flight` empty blocks start it, and one more goes out every
start_retry_s until a wing-state block answers (a lost first block). In LOOP, no wing-state
block for watchdog_timeout_s of wall-clock time trips the watchdog (TRIPPED: the node ramps the
drive down through the safety core). A wing-state block that finds the drive subscribed starts
the loop at once.
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = [
    "DONE",
    "LOOP",
    "NOTHING",
    "RETRY",
    "START",
    "TRIP",
    "TRIPPED",
    "WAITING",
    "LoopTiming",
    "TimingParams",
    "initial_state",
    "on_timer",
    "on_wing_state",
]

WAITING, LOOP, TRIPPED, DONE = "waiting", "loop", "tripped", "done"
# what a timer tick asks of the node
NOTHING, START, RETRY, TRIP = "nothing", "start", "retry", "trip"


class TimingParams(NamedTuple):
    """Wall-clock settings (config/flaair.yaml `stroke_controller_node`)."""

    start_delay_s: float
    start_retry_s: float
    watchdog_timeout_s: float


class LoopTiming(NamedTuple):
    """The mode and the wall-clock times the decisions read."""

    mode: str
    last_wall: float  # the last wing-state block (or start, or retry)
    peers_wall: float | None  # since when the peers are up (None: not up)
    answered: bool  # a wing-state block has answered the start


def initial_state(params: TimingParams, *, t_wall: float) -> LoopTiming:
    """Waiting for the peers, at wall-clock time `t_wall`."""
    return LoopTiming(WAITING, t_wall, None, False)


def on_wing_state(
    state: LoopTiming, t_wall: float, drive_subscribed: bool
) -> tuple[LoopTiming, bool]:
    """A wing-state block arrived at `t_wall`: (state, whether the loop answers it)."""
    if state.mode == WAITING and drive_subscribed:
        state = state._replace(mode=LOOP)
    if state.mode != LOOP:
        return state, False
    return state._replace(last_wall=t_wall, answered=True), True


def on_timer(
    state: LoopTiming, t_wall: float, peers_up: bool, params: TimingParams
) -> tuple[LoopTiming, str]:
    """A timer tick at `t_wall` (`peers_up`: drive subscribed and wing state published):
    (state, what the node must do: NOTHING, START, RETRY or TRIP).
    """
    if state.mode == WAITING:
        peers_wall = (state.peers_wall or t_wall) if peers_up else None
        if peers_wall is not None and t_wall - peers_wall >= params.start_delay_s:
            return state._replace(mode=LOOP, last_wall=t_wall, peers_wall=peers_wall), START
        return state._replace(peers_wall=peers_wall), NOTHING
    if (
        state.mode == LOOP
        and not state.answered
        and t_wall - state.last_wall > params.start_retry_s
    ):
        return state._replace(last_wall=t_wall), RETRY
    if state.mode == LOOP and t_wall - state.last_wall > params.watchdog_timeout_s:
        return state._replace(mode=TRIPPED), TRIP
    return state, NOTHING
