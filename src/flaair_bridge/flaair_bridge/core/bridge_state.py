"""The bridge core's vocabulary: its counters, state, inputs and outputs, and the helpers both
of its sides use (`add_counts`, `counted_note`, `target_clock`).

`flaair_bridge.core.bridge` (the sensor side, the wall clock and `step`) steps over these;
`flaair_bridge.core.bridge_drive` is the drive side. Their one address is this module.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from flaair_bridge.core.bridge_params import BridgeParams
from flaair_model.notes import ERROR, WARNING, Note

__all__ = [
    "ARRIVAL_RING",
    "BridgeState",
    "Counters",
    "DriveBlock",
    "Input",
    "Outputs",
    "SensorBlock",
    "SensorDatagram",
    "Stop",
    "Tick",
    "add_counts",
    "counted_note",
    "target_clock",
]

ARRIVAL_RING = 256  # recent sensor packets remembered for the latency pairing


class Counters(NamedTuple):
    """What the bridge has seen and done since it started."""

    sensor_packets: int = 0  # valid, in-order (or after a gap) packets accepted
    lost_packets: int = 0  # sequence gaps
    lost_samples: int = 0  # samples missing in the index sequence (published as NaN)
    stale_packets: int = 0  # duplicate or older sequence: dropped
    # samples already published (as NaN, while the target was silent): dropped
    overlap_samples: int = 0
    malformed: int = 0  # not a valid sensor packet (or the wrong sample rate): dropped
    foreign_packets: int = 0  # from another sender than the target's: dropped
    jump_packets: int = 0  # a sequence or index jump beyond max_fill_samples: dropped until
    # resync_packets such packets come in a row
    resyncs: int = 0  # target restarts followed
    target_watchdog_packets: int = 0  # packets with the target's watchdog flag set
    silences: int = 0  # times the target fell silent
    silence_samples: int = 0  # NaN samples published while the target was silent
    published_blocks: int = 0
    drive_blocks: int = 0  # drive blocks received from FLAAIR
    drive_stale_blocks: int = 0  # older than the drive stream: dropped
    drive_unscheduled_blocks: int = 0  # arrived before any sensor packet: dropped
    # stream re-anchored lead_samples ahead (jump, or the source fell behind)
    drive_reanchors: int = 0
    # behind the target's clock because the bridge fell behind: dropped
    drive_late_blocks: int = 0
    # queued too far ahead of the target's clock: dropped (the stream re-anchors)
    drive_overflow_blocks: int = 0
    drive_packets: int = 0
    drive_samples: int = 0
    clamped_samples: int = 0
    nonfinite_samples: int = 0
    watchdog_stops: int = 0  # stop packets because the drive stream fell silent
    stop_packets: int = 0  # every stop packet sent


class BridgeState(NamedTuple):
    """Everything the bridge remembers between inputs (arrays are never written in place).

    A NamedTuple rather than a frozen dataclass: `_replace` is several times cheaper than
    dataclasses.replace, and the core runs twice per 0.5 ms packet.
    """

    sequence: int | None = None  # next expected sensor sequence
    # target clock: index after the last sensor sample received
    target_end: int | None = None
    # published index = target index + index_offset (after a resync)
    index_offset: int = 0
    pending_first: int | None = None  # published index of pending[:, 0]
    pending: np.ndarray = np.empty((3, 0))  # drive, stroke, pitch samples not yet in a full block
    stale_run: int = 0
    jump_run: int = 0  # far-ahead packets in a row
    source: tuple[str, int] | None = None  # the sender the sensor stream comes from
    # arrival of the last packet (the target's clock is extrapolated from it)
    last_sensor_s: float | None = None
    # when the bridge last took a packet from its socket (silence)
    last_read_s: float | None = None
    # arrival of the last datagram read from another sender (proves the reader is not stalled)
    last_foreign_s: float | None = None
    silent: bool = False
    drive_expected: int | None = None  # next index of FLAAIR's drive stream
    drive_offset: int | None = None  # target index = drive-stream index + drive_offset
    queue: tuple[tuple[int, np.ndarray], ...] = ()  # (target first index, drive_v) not yet sent
    drive_sequence: int = 0
    last_drive_s: float | None = None
    driving: bool = False  # non-zero drive sent since the last stop
    arrivals: np.ndarray = np.full((ARRIVAL_RING, 2), -1.0)  # (packet end index, arrival s)
    counters: Counters = Counters()


class SensorDatagram(NamedTuple):
    data: bytes
    now_s: float  # arrival (the kernel's receive time)
    read_s: float | None = None  # when the bridge took it from the socket (default: now_s)
    sender: tuple[str, int] | None = None  # its source address (None: not known, not checked)


class DriveBlock(NamedTuple):
    first_sample_index: int
    drive_v: np.ndarray
    now_s: float


class Tick(NamedTuple):
    now_s: float
    backlog: bool = False  # datagrams wait unread: the bridge stalled, the target is not silent


class Stop(NamedTuple):
    now_s: float
    reason: str


Input = SensorDatagram | DriveBlock | Tick | Stop


class SensorBlock(NamedTuple):
    """One block to publish: published index, and float64 samples (NaN where lost)."""

    first_sample_index: int
    drive_v: np.ndarray
    stroke_sensor_v: np.ndarray
    pitch_sensor_v: np.ndarray


def counted_note(counter: str, text: str, error: bool = False) -> Note:
    """A warning (or an error) counted under `counter`, the name of its field in `Counters`."""
    return Note(ERROR if error else WARNING, text, counter)


class Outputs(NamedTuple):
    blocks: tuple[SensorBlock, ...] = ()
    packets: tuple[bytes, ...] = ()  # to send to the target
    # (target index of the drive packet, sensor arrival s, send s)
    timing: tuple[tuple[int, float, float], ...] = ()
    notes: tuple[Note, ...] = ()


def add_counts(counters: Counters, **increments: int) -> Counters:
    """`counters` with each named field increased by its increment."""
    return counters._replace(
        **{name: getattr(counters, name) + value for name, value in increments.items()}
    )


def target_clock(state: BridgeState, now_s: float, params: BridgeParams) -> int:
    """The target's clock now: the last packet's end, moved on by the time since that packet arrived
    (if the bridge fell behind, it has moved on by more than a packet).
    """
    return state.target_end + max(
        0, int((now_s - state.last_sensor_s) * params.sample_rate_hz + 1e-6)
    )
