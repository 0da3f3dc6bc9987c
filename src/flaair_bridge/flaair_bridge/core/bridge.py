"""The bridge's pure core: target sensor packets in,
FLAAIR blocks out; FLAAIR drive in, drive packets out.

``step(state, inputs, params) -> (state, outputs)`` with four kinds of input (numpy only, no
sockets, no ROS, time passed in):

- `SensorDatagram`: a datagram from the target. Malformed ones (protocol.ProtocolError, or a
  sample rate other than the bridge's) are counted and dropped. Sequence numbers are tracked
  modulo 2^32: a gap counts the packets lost and their samples are published as NaN (the front
  end marks non-finite samples invalid: loss is marked, never filled in); a duplicate or older
  sequence is stale and dropped. ``resync_packets`` stale packets in a row mean the target
  restarted: the bridge follows the new stream and keeps its own published index running.
  Samples are re-blocked to ``block_size`` (the lab's n = 10 passes straight through).
- `DriveBlock`: a block of FLAAIR's drive stream (its own sample count). The first block, or
  the first after a jump in the stream, is anchored as the protocol says: computed from samples
  up to k (the last sensor sample received), it is applied from k + 1 + ``lead_samples``; later
  blocks follow contiguously, so the drive the target applies is the stream with a constant
  delay, the one the controller compensates. The target's clock is extrapolated from the last
  packet's arrival (kernel timestamp). A block already behind it because the bridge fell behind
  (its packets waited unread) is dropped as late, and the stream keeps its place; a source that
  fell behind the data re-anchors ``lead_samples`` ahead of it (counted). Samples are clamped
  to +-drive_limit_v (non-finite ones become 0, counted) and sent in packets of at most 1000
  samples, never more than ``max_ahead_samples`` beyond clock + lead (the rest waits for the
  target's clock). A source that runs further ahead than that plus one packet drops its queue
  and re-anchors (counted).
- `Tick` (wall clock): the drive watchdog sends a stop packet when a non-zero drive stream falls
  silent for ``drive_timeout_s``; when the target falls silent for ``sensor_timeout_s`` the
  bridge sends a stop packet and publishes NaN (lost) blocks at the real-time rate, up to
  ``max_fill_samples``, so downstream nodes see the loss in signal time.
- `Stop`: a stop packet now (end of every run).

Latency: a drive packet whose first sample is k + 1 + lead answers the sensor packet that ended
at sample k; `Outputs.timing` pairs that packet's arrival with the drive packet's send time.
"""

from __future__ import annotations

import math
from typing import NamedTuple, Union

import numpy as np

from flaair_bridge.core import protocol
from flaair_bridge.core.bridge_params import BridgeParams
from flaair_model.notes import ERROR, WARNING, Note

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
    # arrival of the last packet (the target's clock is extrapolated from it)
    last_sensor_s: float | None = None
    # when the bridge last took a packet from its socket (silence)
    last_read_s: float | None = None
    silent: bool = False
    drive_expected: int | None = None  # next index of FLAAIR's drive stream
    drive_offset: int | None = None  # target index = drive-stream index + drive_offset
    queue: tuple = ()  # (target first index, drive_v) not yet sent
    drive_sequence: int = 0
    last_drive_s: float | None = None
    driving: bool = False  # non-zero drive sent since the last stop
    arrivals: np.ndarray = np.full((ARRIVAL_RING, 2), -1.0)  # (packet end index, arrival s)
    counters: Counters = Counters()


class SensorDatagram(NamedTuple):
    data: bytes
    now_s: float  # arrival (the kernel's receive time)
    read_s: float | None = None  # when the bridge took it from the socket (default: now_s)


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


Input = Union[SensorDatagram, DriveBlock, Tick, Stop]


class SensorBlock(NamedTuple):
    """One block to publish: published index, and float64 samples (NaN where lost)."""

    first_sample_index: int
    drive_v: np.ndarray
    stroke_sensor_v: np.ndarray
    pitch_sensor_v: np.ndarray


def _note(counter: str, text: str, error: bool = False) -> Note:
    """A warning (or an error) counted under `counter`, the name of its field in `Counters`."""
    return Note(ERROR if error else WARNING, text, counter)


class Outputs(NamedTuple):
    blocks: tuple = ()  # SensorBlock
    packets: tuple = ()  # bytes to send to the target
    timing: tuple = ()  # (target index of the drive packet, sensor arrival s, send s)
    notes: tuple = ()  # Note


def initial_state(params: BridgeParams) -> BridgeState:
    """State before the first datagram."""
    return BridgeState()


def step(state: BridgeState, inputs: Input, params: BridgeParams) -> tuple[BridgeState, Outputs]:
    """Advance the bridge by one input; see the module docstring."""
    if isinstance(inputs, SensorDatagram):
        return _on_sensor(state, inputs, params)
    if isinstance(inputs, DriveBlock):
        return _on_drive(state, inputs, params)
    if isinstance(inputs, Tick):
        return _on_tick(state, inputs, params)
    if isinstance(inputs, Stop):
        state, packet = _stop_packet(state)
        return state, Outputs(
            packets=(packet,), notes=(_note("stop_packets", f"stop packet sent: {inputs.reason}"),)
        )
    raise TypeError(f"unknown bridge input {type(inputs).__name__}")


def _count(counters: Counters, **increments: int) -> Counters:
    return counters._replace(
        **{name: getattr(counters, name) + value for name, value in increments.items()}
    )


# ---------------------------------------------------------------------------------- sensor side
def _on_sensor(
    state: BridgeState, inputs: SensorDatagram, params: BridgeParams
) -> tuple[BridgeState, Outputs]:
    try:
        packet = protocol.unpack_sensor(inputs.data)
        if not math.isclose(packet.sample_rate_hz, params.sample_rate_hz, rel_tol=1e-6):
            raise protocol.ProtocolError(
                f"sample_rate_hz {packet.sample_rate_hz:g}, the bridge "
                f"runs at {params.sample_rate_hz:g}"
            )
    except protocol.ProtocolError as exc:
        counters = _count(state.counters, malformed=1)
        return state._replace(counters=counters), Outputs(
            notes=(
                _note(
                    "malformed",
                    f"malformed datagram ({len(inputs.data)} bytes) dropped: {exc} "
                    f"[{counters.malformed} malformed so far]",
                ),
            )
        )
    if in_order(state, packet, params):
        return in_order_packet(state, packet, inputs.now_s, _read_s(inputs), params)
    return any_packet(state, packet, inputs, params)


def any_packet(
    state: BridgeState, packet: protocol.SensorPacket, inputs: SensorDatagram, params: BridgeParams
) -> tuple[BridgeState, Outputs]:
    """Any well-formed sensor packet: lost, stale, overlapping, partial blocks, a target restart."""
    notes: list[Note] = []
    counters = state.counters
    index_offset, stale_run = state.index_offset, 0
    if state.sequence is not None:
        delta = protocol.sequence_delta(packet.sequence, state.sequence)
        if delta < 0:
            stale_run = state.stale_run + 1
            if stale_run < params.resync_packets:
                counters = _count(counters, stale_packets=1)
                return (
                    state._replace(stale_run=stale_run, counters=counters),
                    Outputs(
                        notes=(
                            _note(
                                "stale_packets",
                                "stale sensor packet (sequence "
                                f"{packet.sequence}, expected "
                                f"{state.sequence}) dropped "
                                f"[{counters.stale_packets} stale so "
                                "far]",
                            ),
                        )
                    ),
                )
            # the target restarted: follow it, keep the published index running
            index_offset = _published_end(state) - packet.first_sample_index
            counters = _count(counters, resyncs=1)
            notes.append(
                _note(
                    "resyncs",
                    f"{stale_run} stale packets in a row: the target "
                    f"restarted (sequence {packet.sequence}, index "
                    f"{packet.first_sample_index}); following it",
                    True,
                )
            )
            state = state._replace(
                target_end=None,
                drive_offset=None,
                drive_expected=None,
                queue=(),
                arrivals=np.full((ARRIVAL_RING, 2), -1.0),
            )
        elif delta > 0:
            counters = _count(counters, lost_packets=delta)
            notes.append(
                _note(
                    "lost_packets",
                    f"{delta} sensor packet(s) lost before sequence "
                    f"{packet.sequence} [{counters.lost_packets} lost "
                    "so far]",
                )
            )
    samples = np.stack([packet.drive_v, packet.stroke_sensor_v, packet.pitch_sensor_v]).astype(
        np.float64
    )
    first = packet.first_sample_index + index_offset
    pending_first, pending = state.pending_first, state.pending
    expected = _published_end(state)
    blocks: list[SensorBlock] = []
    if expected is None:
        pending_first = first
    elif first < expected:
        skip = min(expected - first, samples.shape[1])
        samples, first = samples[:, skip:], first + skip
        counters = _count(counters, overlap_samples=skip)
    elif first > expected:
        gap = first - expected
        counters = _count(counters, lost_samples=gap)
        if gap <= params.max_fill_samples:
            pending = np.concatenate([pending, np.full((3, gap), np.nan)], axis=1)
        else:  # too long to fill: close the partial block with NaN, restart the blocks at `first`
            notes.append(
                _note(
                    "lost_samples",
                    f"{gap} samples lost before index {first}: the published stream jumps there",
                    True,
                )
            )
            pad = (-pending.shape[1]) % params.block_size
            blocks, _, _ = _blocks(
                pending_first,
                np.concatenate([pending, np.full((3, pad), np.nan)], axis=1),
                params.block_size,
            )
            pending, pending_first = pending[:, :0], first
    more, pending, pending_first = _blocks(
        pending_first, np.concatenate([pending, samples], axis=1), params.block_size
    )
    blocks += more
    counters = _count(counters, sensor_packets=1, published_blocks=len(blocks))
    if packet.target_watchdog_tripped:
        counters = _count(counters, target_watchdog_packets=1)
        notes.append(_target_watchdog_notice(packet, counters))
    if state.silent:
        notes.append(_note("silences", f"the target is sending again (sequence {packet.sequence})"))
    end = packet.first_sample_index + packet.n
    arrivals = state.arrivals.copy()
    arrivals[counters.sensor_packets % ARRIVAL_RING] = (end, inputs.now_s)
    state = state._replace(
        sequence=(packet.sequence + 1) % protocol.SEQUENCE_MODULUS,
        target_end=max(end, state.target_end or 0),
        index_offset=index_offset,
        pending_first=pending_first,
        pending=pending,
        stale_run=stale_run,
        last_sensor_s=inputs.now_s,
        last_read_s=_read_s(inputs),
        silent=False,
        arrivals=arrivals,
        counters=counters,
    )
    state, packets, timing = _release(state, params, inputs.now_s)
    return state, Outputs(tuple(blocks), packets, timing, tuple(notes))


def _read_s(inputs: SensorDatagram) -> float:
    return inputs.now_s if inputs.read_s is None else inputs.read_s


def _clock(state: BridgeState, now_s: float, params: BridgeParams) -> int:
    """The target's clock now: the last packet's end, moved on by the time since that packet arrived
    (if the bridge fell behind, it has moved on by more than a packet).
    """
    return state.target_end + max(
        0, int((now_s - state.last_sensor_s) * params.sample_rate_hz + 1e-6)
    )


def in_order(state: BridgeState, packet: protocol.SensorPacket, params: BridgeParams) -> bool:
    """The common case, 2000 times a second: the next packet in sequence and in samples, fitting in
    the block being filled, no flag but the target's watchdog, the target not silent before it.
    """
    return (
        packet.sequence == state.sequence
        and state.pending_first is not None
        and not state.silent
        and not packet.flags & ~protocol.FLAG_TARGET_WATCHDOG
        and packet.first_sample_index + state.index_offset
        == state.pending_first + state.pending.shape[1]
        and state.pending.shape[1] + packet.n <= params.block_size
    )


def in_order_packet(
    state: BridgeState,
    packet: protocol.SensorPacket,
    now_s: float,
    read_s: float,
    params: BridgeParams,
) -> tuple[BridgeState, Outputs]:
    """An `in_order` packet: same result as the general
    path (`any_packet`), a third of its cost.
    """
    end = packet.first_sample_index + packet.n
    held = state.pending.shape[1]
    # packets as long as blocks: passed on as they are
    if not held and packet.n == params.block_size:
        blocks: tuple[SensorBlock, ...] = (
            SensorBlock(
                state.pending_first, packet.drive_v, packet.stroke_sensor_v, packet.pitch_sensor_v
            ),
        )
        pending, pending_first = state.pending, state.pending_first + packet.n
    else:  # several packets to a block (a target's 0.5 ms packets, 1 ms control blocks)
        pending = np.concatenate(
            [state.pending, (packet.drive_v, packet.stroke_sensor_v, packet.pitch_sensor_v)], axis=1
        )
        pending_first = state.pending_first
        blocks = ()
        if pending.shape[1] == params.block_size:
            blocks = (SensorBlock(pending_first, pending[0], pending[1], pending[2]),)
            pending, pending_first = pending[:, :0], pending_first + params.block_size
    # while the loop catches up after a stall: as cheap as the rest
    tripped = packet.target_watchdog_tripped
    counters = state.counters._replace(
        sensor_packets=state.counters.sensor_packets + 1,
        published_blocks=state.counters.published_blocks + len(blocks),
        target_watchdog_packets=state.counters.target_watchdog_packets + tripped,
    )
    arrivals = state.arrivals.copy()
    arrivals[counters.sensor_packets % ARRIVAL_RING] = (end, now_s)
    state = state._replace(
        sequence=(packet.sequence + 1) % protocol.SEQUENCE_MODULUS,
        target_end=end,
        pending_first=pending_first,
        pending=pending,
        stale_run=0,
        last_sensor_s=now_s,
        last_read_s=read_s,
        arrivals=arrivals,
        counters=counters,
    )
    state, packets, timing = _release(state, params, now_s)
    return state, Outputs(
        blocks, packets, timing, (_target_watchdog_notice(packet, counters),) if tripped else ()
    )


def _target_watchdog_notice(packet: protocol.SensorPacket, counters: Counters) -> Note:
    return _note(
        "target_watchdog_packets",
        "the target's drive watchdog has tripped (packet "
        f"{packet.sequence}) "
        f"[{counters.target_watchdog_packets} such packets]",
    )


def _published_end(state: BridgeState) -> int | None:
    if state.pending_first is None:
        return None
    return state.pending_first + state.pending.shape[1]


def _blocks(
    first: int, samples: np.ndarray, block_size: int
) -> tuple[list[SensorBlock], np.ndarray, int]:
    """Cut whole blocks off the front of `samples`; return them, the rest and its first index."""
    n_blocks = samples.shape[1] // block_size
    blocks = []
    for b in range(n_blocks):
        chunk = samples[:, b * block_size : (b + 1) * block_size]
        blocks.append(SensorBlock(first + b * block_size, chunk[0], chunk[1], chunk[2]))
    used = n_blocks * block_size
    return blocks, samples[:, used:], first + used


# ---------------------------------------------------------------------------------- drive side
def _on_drive(
    state: BridgeState, inputs: DriveBlock, params: BridgeParams
) -> tuple[BridgeState, Outputs]:
    if (
        state.drive_offset is not None
        and inputs.first_sample_index == state.drive_expected
        and not state.queue
    ):
        fast = _in_order_drive(state, inputs, params)
        if fast is not None:
            return fast
    counters = _count(state.counters, drive_blocks=1)
    first, n = int(inputs.first_sample_index), len(inputs.drive_v)
    state = state._replace(last_drive_s=inputs.now_s)
    if state.target_end is None:
        counters = _count(counters, drive_unscheduled_blocks=1)
        return state._replace(counters=counters), Outputs(
            notes=(
                _note(
                    "drive_unscheduled_blocks",
                    f"drive block {first} dropped: no sensor packet from the "
                    f"target yet [{counters.drive_unscheduled_blocks} so far]",
                ),
            )
        )
    if state.drive_expected is not None and first < state.drive_expected:
        counters = _count(counters, drive_stale_blocks=1)
        return state._replace(counters=counters), Outputs(
            notes=(
                _note(
                    "drive_stale_blocks",
                    f"drive block {first} dropped: duplicate or out of order "
                    f"(expected {state.drive_expected}) "
                    f"[{counters.drive_stale_blocks} so far]",
                ),
            )
        )
    notes = []
    drive = np.array(inputs.drive_v, dtype=np.float64)
    bad = ~np.isfinite(drive)
    if bad.any():
        drive[bad] = 0.0
        counters = _count(counters, nonfinite_samples=int(bad.sum()))
        notes.append(
            _note(
                "nonfinite_samples",
                f"drive block {first}: {int(bad.sum())} non-finite sample(s) sent as 0",
            )
        )
    over = np.abs(drive) > params.drive_limit_v
    if over.any():
        drive = np.clip(drive, -params.drive_limit_v, params.drive_limit_v)
        counters = _count(counters, clamped_samples=int(over.sum()))
    clock = _clock(state, inputs.now_s, params)
    # the protocol: data up to k -> drive from k + 1 + lead
    anchor = state.target_end + params.lead_samples
    offset = state.drive_offset
    if offset is None or first != state.drive_expected:
        if offset is not None:
            counters = _count(counters, drive_reanchors=1)
            notes.append(
                _note(
                    "drive_reanchors",
                    f"drive stream jumped to {first} (expected "
                    f"{state.drive_expected}): re-anchored "
                    f"{params.lead_samples} samples ahead",
                )
            )
        offset = anchor - first
    elif first + offset + n <= clock and first + offset >= anchor:
        # The source keeps pace with the data, the bridge fell behind the target (its packets
        # waited unread): the block is late. Moving the stream ahead would change the loop's
        # delay for good, so it is dropped and the stream keeps its place.
        counters = _count(counters, drive_late_blocks=1)
        return state._replace(drive_expected=first + n, counters=counters), Outputs(
            notes=(
                _note(
                    "drive_late_blocks",
                    f"drive block {first} dropped: {clock - first - offset} samples "
                    "behind the target's clock (the bridge fell behind) "
                    f"[{counters.drive_late_blocks} so far]",
                ),
            )
        )
    # the source fell behind the data: it starts again lead_samples ahead
    elif first + offset < min(clock, anchor):
        counters = _count(counters, drive_reanchors=1)
        notes.append(
            _note(
                "drive_reanchors",
                f"drive block {first} is {clock - first - offset} "
                "samples behind the target's clock: re-anchored "
                f"{params.lead_samples} samples ahead "
                f"[{counters.drive_reanchors} re-anchors so far]",
            )
        )
        offset = anchor - first
    queue = state.queue
    queued = queue[-1][0] + len(queue[-1][1]) - queue[0][0] if queue else 0  # O(1): in order
    if queued + n > params.max_ahead_samples + protocol.MAX_SAMPLES:
        # A source faster than real time runs further ahead of the target than its buffer: the
        # queued samples are dropped, the stream goes on lead_samples ahead of the data.
        counters = _count(counters, drive_overflow_blocks=len(queue), drive_reanchors=1)
        notes.append(
            _note(
                "drive_overflow_blocks",
                f"drive block {first}: {queued} samples "
                "already wait for the target's clock: "
                f"dropped, re-anchored {params.lead_samples} "
                "samples ahead "
                f"[{counters.drive_overflow_blocks} blocks "
                "dropped so far]",
            )
        )
        queue, offset = (), anchor - first
    state = state._replace(
        drive_offset=offset,
        drive_expected=first + n,
        queue=(*queue, (first + offset, drive)),
        counters=counters,
    )
    state, packets, timing = _release(state, params, inputs.now_s)
    return state, Outputs(packets=packets, timing=timing, notes=tuple(notes))


def _in_order_drive(
    state: BridgeState, inputs: DriveBlock, params: BridgeParams
) -> tuple[BridgeState, Outputs] | None:
    """The common case, 2000 times a second: the stream's next block, finite, within the limit, in
    time and within the target's buffer, nothing queued: one packet. Same result as the general
    path (None when the block is not that case), a fraction of its cost.
    """
    drive = np.asarray(inputs.drive_v, dtype=np.float64)
    n = len(drive)
    # NaN fails too
    if not 0 < n <= protocol.MAX_SAMPLES or not np.abs(drive).max() <= params.drive_limit_v:
        return None
    index = inputs.first_sample_index + state.drive_offset
    clock = _clock(state, inputs.now_s, params)
    if (
        index < clock
        or index + n > max(state.target_end, clock) + params.lead_samples + params.max_ahead_samples
    ):
        return None
    packet = protocol.pack_drive(protocol.DrivePacket(state.drive_sequence, index, 0, drive))
    c = state.counters
    counters = c._replace(
        drive_blocks=c.drive_blocks + 1,
        drive_packets=c.drive_packets + 1,
        drive_samples=c.drive_samples + n,
    )
    cause = np.flatnonzero(state.arrivals[:, 0] == index - params.lead_samples)
    timing = ((index, float(state.arrivals[cause[-1], 1]), inputs.now_s),) if cause.size else ()
    state = state._replace(
        last_drive_s=inputs.now_s,
        drive_expected=inputs.first_sample_index + n,
        drive_sequence=(state.drive_sequence + 1) % protocol.SEQUENCE_MODULUS,
        driving=state.driving or bool(drive.any()),
        counters=counters,
    )
    return state, Outputs(packets=(packet,), timing=timing)


def _release(
    state: BridgeState, params: BridgeParams, now_s: float
) -> tuple[BridgeState, tuple, tuple]:
    """Send queued drive up to target clock + lead +
    max_ahead_samples, in packets of <= 1000 samples.
    """
    if not state.queue:
        return state, (), ()
    limit = (
        max(state.target_end, _clock(state, now_s, params))
        + params.lead_samples
        + params.max_ahead_samples
    )
    packets: list[bytes] = []
    timing: list = []
    queue: list = []
    sequence, counters, driving = state.drive_sequence, state.counters, state.driving
    for position, (target_first, drive) in enumerate(state.queue):
        count = max(0, min(len(drive), limit - target_first))
        # the queue is in index order: nothing after this can go either (O(1) when idle)
        if count == 0:
            queue.extend(state.queue[position:])
            break
        for start in range(0, count, protocol.MAX_SAMPLES):
            chunk = drive[start : min(count, start + protocol.MAX_SAMPLES)]
            index = target_first + start
            packets.append(protocol.pack_drive(protocol.DrivePacket(sequence, index, 0, chunk)))
            sequence = (sequence + 1) % protocol.SEQUENCE_MODULUS
            counters = _count(counters, drive_packets=1, drive_samples=len(chunk))
            driving = driving or bool(np.any(chunk != 0.0))
            cause = np.flatnonzero(state.arrivals[:, 0] == index - params.lead_samples)
            if cause.size:
                timing.append((index, float(state.arrivals[cause[-1], 1]), now_s))
        if count < len(drive):
            queue.append((target_first + count, drive[count:]))
    return (
        state._replace(
            queue=tuple(queue), drive_sequence=sequence, counters=counters, driving=driving
        ),
        tuple(packets),
        tuple(timing),
    )


def _stop_packet(state: BridgeState) -> tuple[BridgeState, bytes]:
    """A stop packet (zero now, hold zero) for the target's
    current clock; the drive stream re-anchors.
    """
    packet = protocol.pack_drive(
        protocol.DrivePacket(
            state.drive_sequence, state.target_end or 0, protocol.FLAG_STOP, np.zeros(1)
        )
    )
    return state._replace(
        drive_sequence=(state.drive_sequence + 1) % protocol.SEQUENCE_MODULUS,
        driving=False,
        drive_offset=None,
        drive_expected=None,
        queue=(),
        counters=_count(state.counters, stop_packets=1),
    ), packet


# ---------------------------------------------------------------------------------- wall clock
def _on_tick(state: BridgeState, inputs: Tick, params: BridgeParams) -> tuple[BridgeState, Outputs]:
    now = inputs.now_s
    packets: list[bytes] = []
    notes: list[Note] = []
    blocks: list[SensorBlock] = []
    if (
        state.driving
        and state.last_drive_s is not None
        and now - state.last_drive_s > params.drive_timeout_s
    ):
        silent_ms = 1e3 * (now - state.last_drive_s)
        state, packet = _stop_packet(state)
        state = state._replace(counters=_count(state.counters, watchdog_stops=1))
        packets.append(packet)
        notes.append(
            _note(
                "watchdog_stops",
                f"DRIVE WATCHDOG: no drive block for {silent_ms:.1f} "
                f"ms (> drive_timeout_s {params.drive_timeout_s:g} "
                "s): stop packet sent, the target zeroes the drive",
                True,
            )
        )
    if (
        state.last_read_s is not None
        and now - state.last_read_s > params.sensor_timeout_s
        and not inputs.backlog
    ):
        if not state.silent:
            state = state._replace(silent=True, counters=_count(state.counters, silences=1))
            notes.append(
                _note(
                    "silences",
                    "TARGET SILENT: no sensor packet for "
                    f"{1e3 * (now - state.last_read_s):.1f} ms (> "
                    f"sensor_timeout_s {params.sensor_timeout_s:g} s) after "
                    f"index {state.target_end}: samples published as lost"
                    + ("; stop packet sent" if state.driving else ""),
                    True,
                )
            )
            if state.driving:
                state, packet = _stop_packet(state)
                packets.append(packet)
        # NaN (lost) samples at the real-time rate, so downstream signal time goes on and shows
        # the loss
        behind_samples = int((now - state.last_read_s) * params.sample_rate_hz)
        due = state.target_end + state.index_offset + min(behind_samples, params.max_fill_samples)
        missing = due - _published_end(state)
        missing -= (missing + state.pending.shape[1]) % params.block_size  # whole blocks only
        if missing > 0:
            samples = np.concatenate([state.pending, np.full((3, missing), np.nan)], axis=1)
            blocks, pending, pending_first = _blocks(
                state.pending_first, samples, params.block_size
            )
            state = state._replace(
                pending=pending,
                pending_first=pending_first,
                counters=_count(
                    state.counters, silence_samples=missing, published_blocks=len(blocks)
                ),
            )
    return state, Outputs(tuple(blocks), tuple(packets), (), tuple(notes))
