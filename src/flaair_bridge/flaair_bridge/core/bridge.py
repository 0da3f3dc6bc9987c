"""The bridge's pure core: target sensor packets in,
FLAAIR blocks out; FLAAIR drive in, drive packets out.

``step(state, inputs, params) -> (state, outputs)`` with four kinds of input (numpy only, no
sockets, no ROS, time passed in):

- `SensorDatagram`: a datagram from the target. A valid sensor packet from another sender is
  foreign, counted and dropped: from a host other than the configured ``target_host``, or,
  while the stream's source (the sender of the first valid packet; the configured
  ``target_host:target_port`` itself whenever it sends) is not silent, from any other host and
  port. Malformed ones (protocol.ProtocolError, or a
  sample rate other than the bridge's) are counted and dropped. Sequence numbers are tracked
  modulo 2^32: a gap counts the packets lost and their samples are published as NaN (the front
  end marks non-finite samples invalid: loss is marked, never filled in); a duplicate or older
  sequence is stale and dropped. ``resync_packets`` stale packets in a row mean the target
  restarted: the bridge follows the new stream and keeps its own published index running. A
  packet that jumps further ahead (in sequence or in samples) than ``max_fill_samples`` is
  dropped and counted too, unless ``resync_packets`` such packets come in a row (a target
  back after a long outage): a stranger's far-ahead packets among the target's never move the
  stream.
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

The state, inputs and outputs are declared in `flaair_bridge.core.bridge_state` (import them
from there); the drive side is `flaair_bridge.core.bridge_drive`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from flaair_bridge.core import protocol
from flaair_bridge.core.bridge_drive import on_drive, release, stop_packet
from flaair_bridge.core.bridge_params import BridgeParams
from flaair_bridge.core.bridge_state import (
    ARRIVAL_RING,
    BridgeState,
    Counters,
    DriveBlock,
    Input,
    Outputs,
    SensorBlock,
    SensorDatagram,
    Stop,
    Tick,
    add_counts,
    counted_note,
)
from flaair_model.notes import Note

__all__ = ["foreign_sender", "in_order", "initial_state", "step"]


def initial_state(params: BridgeParams) -> BridgeState:
    """State before the first datagram."""
    return BridgeState()


def step(state: BridgeState, inputs: Input, params: BridgeParams) -> tuple[BridgeState, Outputs]:
    """Advance the bridge by one input; see the module docstring."""
    if isinstance(inputs, SensorDatagram):
        return _on_sensor(state, inputs, params)
    if isinstance(inputs, DriveBlock):
        return on_drive(state, inputs, params)
    if isinstance(inputs, Tick):
        return _on_tick(state, inputs, params)
    if isinstance(inputs, Stop):
        state, packet = stop_packet(state)
        return state, Outputs(
            packets=(packet,),
            notes=(counted_note("stop_packets", f"stop packet sent: {inputs.reason}"),),
        )
    raise TypeError(f"unknown bridge input {type(inputs).__name__}")


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
    except protocol.ProtocolError as exc:  # whoever sent it: counted as what it is
        counters = add_counts(state.counters, malformed=1)
        return state._replace(counters=counters), Outputs(
            notes=(
                counted_note(
                    "malformed",
                    f"malformed datagram ({len(inputs.data)} bytes) dropped: {exc} "
                    f"[{counters.malformed} malformed so far]",
                ),
            )
        )
    notes: tuple[Note, ...] = ()
    if inputs.sender is not None and inputs.sender != state.source:
        if foreign_sender(state, inputs.sender, params):
            return _foreign_packet(state, inputs, params)
        state, notes = _new_source(state, packet, inputs.sender)
    if in_order(state, packet, params):
        return in_order_packet(state, packet, inputs.now_s, _read_s(inputs), params)
    state, out = any_packet(state, packet, inputs, params)
    return state, out._replace(notes=notes + out.notes) if notes else out


def _new_source(
    state: BridgeState, packet: protocol.SensorPacket, sender: tuple[str, int]
) -> tuple[BridgeState, tuple[Note, ...]]:
    """The stream's source from now on: the first sender, or another one (the configured
    address, or a target back from a new port after a silence), whose stream is followed at
    once as a restarted target's, the published index running on.
    """
    if state.source is None:
        return state._replace(source=sender), ()
    end = _published_end(state)
    state = state._replace(
        source=sender,
        sequence=None,
        stale_run=0,
        jump_run=0,
        index_offset=state.index_offset if end is None else end - packet.first_sample_index,
        target_end=None,
        drive_offset=None,
        drive_expected=None,
        queue=(),
        arrivals=np.full((ARRIVAL_RING, 2), -1.0),
        counters=add_counts(state.counters, resyncs=1),
    )
    text = f"sensor packets now from {sender[0]}:{sender[1]}; following its stream"
    return state, (counted_note("resyncs", text, True),)


def foreign_sender(
    state: BridgeState, sender: tuple[str, int] | None, params: BridgeParams
) -> bool:
    """A datagram from anyone but the target: a host other than the configured one, or, while
    the stream's source is not silent, another sender than it (None: not known, not foreign).
    """
    if sender is None or sender == (params.target_host, params.target_port):
        return False
    if params.target_host and sender[0] != params.target_host:
        return True
    return state.source is not None and sender != state.source and not state.silent


def _foreign_packet(
    state: BridgeState, inputs: SensorDatagram, params: BridgeParams
) -> tuple[BridgeState, Outputs]:
    counters = add_counts(state.counters, foreign_packets=1)
    host, port = inputs.sender or ("?", 0)
    target = f"{state.source[0]}:{state.source[1]}" if state.source else params.target_host or "?"
    return state._replace(counters=counters, last_foreign_s=inputs.now_s), Outputs(
        notes=(
            counted_note(
                "foreign_packets",
                f"datagram from {host}:{port} dropped: not the target ({target}) "
                f"[{counters.foreign_packets} foreign so far]",
            ),
        )
    )


class _Sequenced(NamedTuple):
    """A packet's place in the target's sequence: the state and counts it leaves, or the
    outputs of a packet dropped there (`dropped`).
    """

    state: BridgeState
    counters: Counters
    index_offset: int
    stale_run: int
    notes: list[Note]
    dropped: Outputs | None


def _sequenced(
    state: BridgeState, packet: protocol.SensorPacket, params: BridgeParams
) -> _Sequenced:
    """The packet against the expected sequence: stale (dropped, or a target restart followed
    after `resync_packets` in a row), a jump beyond `max_fill_samples` (dropped unless repeated),
    packets lost before it.
    """
    notes: list[Note] = []
    counters = state.counters
    index_offset, stale_run = state.index_offset, 0
    if state.sequence is None:
        return _Sequenced(state, counters, index_offset, stale_run, notes, None)
    delta = protocol.sequence_delta(packet.sequence, state.sequence)
    if delta < 0:
        stale_run = state.stale_run + 1
        if stale_run < params.resync_packets:
            counters = add_counts(counters, stale_packets=1)
            note = counted_note(
                "stale_packets",
                f"stale sensor packet (sequence {packet.sequence}, expected {state.sequence}) "
                f"dropped [{counters.stale_packets} stale so far]",
            )
            kept = state._replace(stale_run=stale_run, counters=counters)
            return _Sequenced(
                kept, counters, index_offset, stale_run, notes, Outputs(notes=(note,))
            )
        # the target restarted: follow it, keep the published index running
        index_offset = _published_end(state) - packet.first_sample_index
        counters = add_counts(counters, resyncs=1)
        notes.append(
            counted_note(
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
    else:
        end = _published_end(state)
        index_gap = 0 if end is None else packet.first_sample_index + index_offset - end
        jump = max(delta * packet.n, index_gap)
        if jump > params.max_fill_samples and state.jump_run + 1 < params.resync_packets:
            counters = add_counts(counters, jump_packets=1)
            note = counted_note(
                "jump_packets",
                f"sensor packet {packet.sequence} (index "
                f"{packet.first_sample_index}) jumps {jump} samples ahead, beyond "
                f"max_fill_samples {params.max_fill_samples}: dropped unless "
                f"{params.resync_packets} such packets come in a row "
                f"[{counters.jump_packets} so far]",
            )
            kept = state._replace(jump_run=state.jump_run + 1, counters=counters)
            return _Sequenced(
                kept, counters, index_offset, stale_run, notes, Outputs(notes=(note,))
            )
    if delta > 0:
        counters = add_counts(counters, lost_packets=delta)
        notes.append(
            counted_note(
                "lost_packets",
                f"{delta} sensor packet(s) lost before sequence "
                f"{packet.sequence} [{counters.lost_packets} lost "
                "so far]",
            )
        )
    return _Sequenced(state, counters, index_offset, stale_run, notes, None)


def _placed(
    state: BridgeState,
    samples: np.ndarray,
    first: int,
    counters: Counters,
    params: BridgeParams,
    notes: list[Note],
) -> tuple[list[SensorBlock], np.ndarray, int, Counters]:
    """The samples placed after what was published: an overlap cut, a short gap filled with
    NaN, a long one closing the partial block and restarting the blocks at `first`; the whole
    blocks to publish, the partial one pending (and its first index), the counts.
    """
    pending_first, pending = state.pending_first, state.pending
    expected = _published_end(state)
    blocks: list[SensorBlock] = []
    if expected is None:
        pending_first = first
    elif first < expected:
        skip = min(expected - first, samples.shape[1])
        samples, first = samples[:, skip:], first + skip
        counters = add_counts(counters, overlap_samples=skip)
    elif first > expected:
        gap = first - expected
        counters = add_counts(counters, lost_samples=gap)
        if gap <= params.max_fill_samples:
            pending = np.concatenate([pending, np.full((3, gap), np.nan)], axis=1)
        else:  # too long to fill: close the partial block with NaN, restart the blocks at `first`
            notes.append(
                counted_note(
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
    return blocks + more, pending, pending_first, counters


def any_packet(
    state: BridgeState, packet: protocol.SensorPacket, inputs: SensorDatagram, params: BridgeParams
) -> tuple[BridgeState, Outputs]:
    """Any well-formed sensor packet: lost, stale, overlapping, partial blocks, a target restart."""
    seq = _sequenced(state, packet, params)
    if seq.dropped is not None:
        return seq.state, seq.dropped
    state, counters, notes = seq.state, seq.counters, seq.notes
    samples = np.stack([packet.drive_v, packet.stroke_sensor_v, packet.pitch_sensor_v]).astype(
        np.float64
    )
    first = packet.first_sample_index + seq.index_offset
    blocks, pending, pending_first, counters = _placed(
        state, samples, first, counters, params, notes
    )
    counters = add_counts(counters, sensor_packets=1, published_blocks=len(blocks))
    if packet.target_watchdog_tripped:
        counters = add_counts(counters, target_watchdog_packets=1)
        notes.append(_target_watchdog_notice(packet, counters))
    if state.silent:
        notes.append(
            counted_note("silences", f"the target is sending again (sequence {packet.sequence})")
        )
    end = packet.first_sample_index + packet.n
    arrivals = state.arrivals.copy()
    arrivals[counters.sensor_packets % ARRIVAL_RING] = (end, inputs.now_s)
    state = state._replace(
        sequence=(packet.sequence + 1) % protocol.SEQUENCE_MODULUS,
        target_end=max(end, state.target_end or 0),
        index_offset=seq.index_offset,
        pending_first=pending_first,
        pending=pending,
        stale_run=seq.stale_run,
        jump_run=0,
        last_sensor_s=inputs.now_s,
        last_read_s=_read_s(inputs),
        silent=False,
        arrivals=arrivals,
        counters=counters,
    )
    state, packets, timing = release(state, params, inputs.now_s)
    return state, Outputs(tuple(blocks), packets, timing, tuple(notes))


def _read_s(inputs: SensorDatagram) -> float:
    return inputs.now_s if inputs.read_s is None else inputs.read_s


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
        jump_run=0,
        last_sensor_s=now_s,
        last_read_s=read_s,
        arrivals=arrivals,
        counters=counters,
    )
    state, packets, timing = release(state, params, now_s)
    return state, Outputs(
        blocks, packets, timing, (_target_watchdog_notice(packet, counters),) if tripped else ()
    )


def _target_watchdog_notice(packet: protocol.SensorPacket, counters: Counters) -> Note:
    return counted_note(
        "target_watchdog_packets",
        "the target's drive watchdog has tripped (packet "
        f"{packet.sequence}) "
        f"[{counters.target_watchdog_packets} such packets]",
    )


def _published_end(state: BridgeState) -> int | None:
    if state.pending_first is None:
        return None
    return state.pending_first + int(state.pending.shape[1])


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
        state, packet = stop_packet(state)
        state = state._replace(counters=add_counts(state.counters, watchdog_stops=1))
        packets.append(packet)
        notes.append(
            counted_note(
                "watchdog_stops",
                f"DRIVE WATCHDOG: no drive block for {silent_ms:.1f} "
                f"ms (> drive_timeout_s {params.drive_timeout_s:g} "
                "s): stop packet sent, the target zeroes the drive",
                True,
            )
        )
    # Datagrams waiting unread mean a stalled bridge, not a silent target, unless the reader has
    # already taken another sender's datagram that arrived a timeout after the target's last one
    # (a new target flooding a bridge that is behind would otherwise never be heard).
    outlived = (
        state.last_foreign_s is not None
        and state.last_sensor_s is not None
        and state.last_foreign_s - state.last_sensor_s > params.sensor_timeout_s
    )
    if (
        state.last_read_s is not None
        and now - state.last_read_s > params.sensor_timeout_s
        and (not inputs.backlog or outlived)
    ):
        if not state.silent:
            state = state._replace(silent=True, counters=add_counts(state.counters, silences=1))
            notes.append(
                counted_note(
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
                state, packet = stop_packet(state)
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
                counters=add_counts(
                    state.counters, silence_samples=missing, published_blocks=len(blocks)
                ),
            )
    return state, Outputs(tuple(blocks), tuple(packets), (), tuple(notes))
