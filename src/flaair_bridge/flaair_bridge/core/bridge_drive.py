"""The bridge core's drive side: FLAAIR's drive blocks in, drive packets out (pure).

Anchoring, clamping, late and overflowing blocks, release in packets within the target's buffer,
and the stop packet: see `flaair_bridge.core.bridge`'s docstring (`DriveBlock`, `Stop`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from flaair_bridge.core import protocol
from flaair_bridge.core.bridge_params import BridgeParams
from flaair_bridge.core.bridge_state import (
    BridgeState,
    Counters,
    DriveBlock,
    Outputs,
    add_counts,
    counted_note,
    target_clock,
)
from flaair_model.notes import Note

__all__ = ["on_drive", "release", "stop_packet"]


def on_drive(
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
    counters = add_counts(state.counters, drive_blocks=1)
    first, n = int(inputs.first_sample_index), len(inputs.drive_v)
    state = state._replace(last_drive_s=inputs.now_s)
    refused = _refused(state, first, counters)
    if refused is not None:
        return refused
    notes: list[Note] = []
    drive, counters = _guarded_drive(inputs.drive_v, first, counters, params, notes)
    clock = target_clock(state, inputs.now_s, params)
    # the protocol: data up to k -> drive from k + 1 + lead
    anchor = state.target_end + params.lead_samples
    offset, counters, late = _drive_offset(state, first, n, clock, anchor, counters, params, notes)
    if late is not None:
        return late
    queue = state.queue
    queued = queue[-1][0] + len(queue[-1][1]) - queue[0][0] if queue else 0  # O(1): in order
    if queued + n > params.max_ahead_samples + protocol.MAX_SAMPLES:
        # A source faster than real time runs further ahead of the target than its buffer: the
        # queued samples are dropped, the stream goes on lead_samples ahead of the data.
        counters = add_counts(counters, drive_overflow_blocks=len(queue), drive_reanchors=1)
        notes.append(
            counted_note(
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
    state, packets, timing = release(state, params, inputs.now_s)
    return state, Outputs(packets=packets, timing=timing, notes=tuple(notes))


def _refused(
    state: BridgeState, first: int, counters: Counters
) -> tuple[BridgeState, Outputs] | None:
    """A block with nowhere to go: before the target's first sensor packet, or a duplicate or
    out-of-order one (None: it is taken).
    """
    if state.target_end is None:
        counters = add_counts(counters, drive_unscheduled_blocks=1)
        return state._replace(counters=counters), Outputs(
            notes=(
                counted_note(
                    "drive_unscheduled_blocks",
                    f"drive block {first} dropped: no sensor packet from the "
                    f"target yet [{counters.drive_unscheduled_blocks} so far]",
                ),
            )
        )
    if state.drive_expected is not None and first < state.drive_expected:
        counters = add_counts(counters, drive_stale_blocks=1)
        return state._replace(counters=counters), Outputs(
            notes=(
                counted_note(
                    "drive_stale_blocks",
                    f"drive block {first} dropped: duplicate or out of order "
                    f"(expected {state.drive_expected}) "
                    f"[{counters.drive_stale_blocks} so far]",
                ),
            )
        )
    return None


def _guarded_drive(
    drive_v: Any, first: int, counters: Counters, params: BridgeParams, notes: list[Note]
) -> tuple[np.ndarray, Counters]:
    """The block as the piezo may take it: a non-finite sample sent as 0, every sample within
    +-drive_limit_v.
    """
    drive = np.array(drive_v, dtype=np.float64)
    bad = ~np.isfinite(drive)
    if bad.any():
        drive[bad] = 0.0
        counters = add_counts(counters, nonfinite_samples=int(bad.sum()))
        notes.append(
            counted_note(
                "nonfinite_samples",
                f"drive block {first}: {int(bad.sum())} non-finite sample(s) sent as 0",
            )
        )
    over = np.abs(drive) > params.drive_limit_v
    if over.any():
        drive = np.clip(drive, -params.drive_limit_v, params.drive_limit_v)
        counters = add_counts(counters, clamped_samples=int(over.sum()))
    return drive, counters


def _drive_offset(
    state: BridgeState,
    first: int,
    n: int,
    clock: int,
    anchor: int,
    counters: Counters,
    params: BridgeParams,
    notes: list[Note],
) -> tuple[int, Counters, tuple[BridgeState, Outputs] | None]:
    """Where the block goes on the target's clock (offset, counts), anchored lead_samples ahead
    of the data when the stream starts, jumps or falls behind; and a late block's drop (state,
    outputs; the stream keeps its place), else None.
    """
    offset = state.drive_offset
    if offset is None or first != state.drive_expected:
        if offset is not None:
            counters = add_counts(counters, drive_reanchors=1)
            notes.append(
                counted_note(
                    "drive_reanchors",
                    f"drive stream jumped to {first} (expected "
                    f"{state.drive_expected}): re-anchored "
                    f"{params.lead_samples} samples ahead",
                )
            )
        return anchor - first, counters, None
    if first + offset + n <= clock and first + offset >= anchor:
        # The source keeps pace with the data, the bridge fell behind the target (its packets
        # waited unread): the block is late. Moving the stream ahead would change the loop's
        # delay for good, so it is dropped and the stream keeps its place.
        counters = add_counts(counters, drive_late_blocks=1)
        note = counted_note(
            "drive_late_blocks",
            f"drive block {first} dropped: {clock - first - offset} samples "
            "behind the target's clock (the bridge fell behind) "
            f"[{counters.drive_late_blocks} so far]",
        )
        late = state._replace(drive_expected=first + n, counters=counters), Outputs(notes=(note,))
        return offset, counters, late
    # the source fell behind the data: it starts again lead_samples ahead
    if first + offset < min(clock, anchor):
        counters = add_counts(counters, drive_reanchors=1)
        notes.append(
            counted_note(
                "drive_reanchors",
                f"drive block {first} is {clock - first - offset} "
                "samples behind the target's clock: re-anchored "
                f"{params.lead_samples} samples ahead "
                f"[{counters.drive_reanchors} re-anchors so far]",
            )
        )
        return anchor - first, counters, None
    return offset, counters, None


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
    clock = target_clock(state, inputs.now_s, params)
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


def release(
    state: BridgeState, params: BridgeParams, now_s: float
) -> tuple[BridgeState, tuple[bytes, ...], tuple[tuple[int, float, float], ...]]:
    """Send queued drive up to target clock + lead +
    max_ahead_samples, in packets of <= 1000 samples.
    """
    if not state.queue:
        return state, (), ()
    limit = (
        max(state.target_end, target_clock(state, now_s, params))
        + params.lead_samples
        + params.max_ahead_samples
    )
    packets: list[bytes] = []
    timing: list[tuple[int, float, float]] = []
    queue: list[tuple[int, np.ndarray]] = []
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
            counters = add_counts(counters, drive_packets=1, drive_samples=len(chunk))
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


def stop_packet(state: BridgeState) -> tuple[BridgeState, bytes]:
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
        counters=add_counts(state.counters, stop_packets=1),
    ), packet
