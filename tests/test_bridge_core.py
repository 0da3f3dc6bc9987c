"""The bridge's pure core: sequence tracking, loss
marking, re-blocking, drive scheduling, watchdogs.
"""

from __future__ import annotations

import socket
import struct
import time
from dataclasses import fields

import numpy as np
import pytest

from flaair_bridge.core import bridge, bridge_params, protocol
from flaair_bridge.core.bridge_state import DriveBlock, SensorDatagram, Stop, Tick
from flaair_bridge.emulated_target import (
    DAMAGE_KEYS,
    TargetCore,
    count_lag,
    damage_factors,
    decide_counting,
    sensor_packet,
)
from flaair_bridge.udp import DatagramEndpoint
from flaair_sim.core.damage import DamageParams

FS = 20000.0
N = 10
LEAD = 20


def params(**overrides) -> bridge_params.BridgeParams:
    values = dict(
        sample_rate_hz=FS,
        block_size=N,
        lead_samples=LEAD,
        drive_limit_v=150.0,
        max_ahead_samples=400,
        max_fill_samples=20000,
        resync_packets=5,
        drive_timeout_s=0.02,
        sensor_timeout_s=0.02,
        target_host="",
        target_port=0,
    )
    values.update(overrides)
    return bridge_params.BridgeParams(**values)


def packet(sequence: int, first: int, n: int = N, flags: int = 0, rate: float = FS) -> bytes:
    """A sensor packet packed by the emulated target (independent of protocol.py): sample i holds
    drive i/10, stroke 1 + i/1000, pitch 2 - i/1000 of its absolute index i.
    """
    i = np.arange(first, first + n)
    return sensor_packet(sequence, first, rate, flags, i / 10, 1 + i / 1000, 2 - i / 1000)


def run(inputs, p=None, state=None):
    """Feed inputs; return the final state and every output concatenated."""
    p = p or params()
    state = state or bridge.initial_state(p)
    blocks, packets, timing, notes = [], [], [], []
    for item in inputs:
        state, out = bridge.step(state, item, p)
        blocks += out.blocks
        packets += [protocol.unpack_drive(data) for data in out.packets]
        timing += out.timing
        notes += out.notes
    return state, blocks, packets, timing, notes


def stream(blocks) -> tuple[np.ndarray, np.ndarray]:
    """Published indices and stroke samples of the blocks, checked contiguous."""
    firsts = [b.first_sample_index for b in blocks]
    assert firsts == list(range(firsts[0], firsts[0] + N * len(firsts), N))
    return (
        np.arange(firsts[0], firsts[0] + N * len(firsts)),
        np.concatenate([b.stroke_sensor_v for b in blocks]),
    )


def test_in_order_packets_pass_through_as_blocks_with_the_targets_values() -> None:
    state, blocks, *_ = run([SensorDatagram(packet(s, 100 + s * N), s * 5e-4) for s in range(4)])
    index, stroke = stream(blocks)
    assert index[0] == 100 and len(index) == 40
    np.testing.assert_array_equal(stroke, (1 + index / 1000).astype(np.float32))
    np.testing.assert_array_equal(
        np.concatenate([b.drive_v for b in blocks]), (index / 10).astype(np.float32)
    )
    c = state.counters
    assert (c.sensor_packets, c.published_blocks, c.lost_packets, c.stale_packets, c.malformed) == (
        4,
        4,
        0,
        0,
        0,
    )


def test_lost_packets_are_counted_and_published_as_nan_never_invented() -> None:
    sequences = [0, 1, 4, 5]  # 2 and 3 lost
    state, blocks, _, _, notes = run(
        [SensorDatagram(packet(s, s * N), s * 5e-4) for s in sequences]
    )
    index, stroke = stream(blocks)
    assert len(index) == 60
    lost = (index >= 20) & (index < 40)
    assert (
        np.isnan(stroke[lost]).all()
        and np.isnan(np.concatenate([b.pitch_sensor_v for b in blocks])[lost]).all()
    )
    np.testing.assert_array_equal(stroke[~lost], (1 + index[~lost] / 1000).astype(np.float32))
    assert state.counters.lost_packets == 2 and state.counters.lost_samples == 20
    assert any("2 sensor packet(s) lost before sequence 4" in n.text for n in notes)


def test_duplicates_and_older_packets_are_stale_and_dropped() -> None:
    inputs = [SensorDatagram(packet(s, s * N), 0.0) for s in (0, 1, 2, 1, 2, 0, 3)]
    state, blocks, *_ = run(inputs)
    index, stroke = stream(blocks)
    assert len(index) == 40 and not np.isnan(stroke).any()
    assert state.counters.stale_packets == 3 and state.counters.sensor_packets == 4


def test_sequence_wraps_at_2_32_without_loss() -> None:
    top = 2**32 - 2
    state, blocks, *_ = run(
        [SensorDatagram(packet((top + k) % 2**32, k * N), 0.0) for k in range(4)]
    )
    assert (
        len(blocks) == 4 and state.counters.lost_packets == 0 and state.counters.stale_packets == 0
    )


def test_malformed_datagrams_are_counted_and_change_nothing_else() -> None:
    good = packet(0, 0)
    garbage = [
        b"",
        b"hello",
        good[:-1],
        good + b"\x00",
        b"FLD1" + good[4:],
        packet(1, N, rate=10000.0),
        good[:24] + np.full(30, np.nan, "<f4").tobytes(),
    ]
    state, blocks, _, _, notes = run(
        [SensorDatagram(good, 0.0)]
        + [SensorDatagram(g, 0.0) for g in garbage]
        + [SensorDatagram(packet(1, N), 0.0)]
    )
    assert state.counters.malformed == len(garbage) and state.counters.lost_packets == 0
    assert len(blocks) == 2 and blocks[1].first_sample_index == N
    assert any("sample_rate_hz 10000, the bridge runs at 20000" in n.text for n in notes)


def test_packets_of_other_sizes_are_reblocked() -> None:
    # 40 samples
    state, blocks, *_ = run([SensorDatagram(packet(s, s * 4, n=4), 0.0) for s in range(10)])
    index, stroke = stream(blocks)
    assert len(index) == 40 and state.pending.shape == (3, 0)
    np.testing.assert_array_equal(stroke, (1 + index / 1000).astype(np.float32))


def test_drive_is_scheduled_lead_samples_ahead_then_contiguous_and_timed() -> None:
    inputs = []
    for k in range(5):
        # ends at sample (k+1)N - 1
        inputs.append(SensorDatagram(packet(k, k * N), 1.0 + k * 5e-4))
        # answers it
        inputs.append(DriveBlock(1000 + k * N, np.full(N, float(k + 1)), 1.0 + k * 5e-4 + 2e-4))
    state, _, packets, timing, _ = run(inputs)
    assert [p.first_sample_index for p in packets] == [N + LEAD + k * N for k in range(5)]
    assert [p.drive_v[0] for p in packets] == [1, 2, 3, 4, 5] and not any(p.stop for p in packets)
    assert [p.sequence for p in packets] == [0, 1, 2, 3, 4]
    # each drive packet paired with the sensor packet that ended at its first index - 1 - lead
    assert [t[0] for t in timing] == [p.first_sample_index for p in packets]
    np.testing.assert_allclose([t[2] - t[1] for t in timing], 2e-4)
    assert state.counters.drive_reanchors == 0


def test_late_drive_is_reanchored_ahead_of_the_target_clock() -> None:
    # -> target 10 + 20 = 30
    inputs = [SensorDatagram(packet(0, 0), 0.0), DriveBlock(0, np.ones(N), 0.0)]
    # clock now 60
    inputs += [SensorDatagram(packet(k, k * N), 0.0) for k in range(1, 6)]
    # contiguous 40 < 60: late
    inputs += [DriveBlock(N, np.ones(N), 0.0)]
    state, _, packets, _, notes = run(inputs)
    assert [p.first_sample_index for p in packets] == [30, 60 + LEAD]
    assert state.counters.drive_reanchors == 1
    assert any("20 samples behind the target's clock" in n.text for n in notes)


def test_a_bridge_behind_the_target_drops_late_blocks_and_keeps_the_loops_delay() -> None:
    # Packets 0-9 arrive every 0.5 ms but are read together at t = 1.005 (the bridge stalled),
    # then the bridge keeps up. The drive answering packet k belongs at (k + 1) N + LEAD (the
    # protocol: data up to k -> drive from k + 1 + lead). Answers already behind the target's
    # clock (extrapolated from the arrival times: 110 at t = 1.005) are dropped as late; the stream
    # never moves ahead, so the loop's delay stays the one the controller compensates.
    inputs = []
    for k in range(20):
        arrival = 1.0 + k * 5e-4
        now = max(1.005, arrival)
        inputs += [
            SensorDatagram(packet(k, k * N), arrival, now),
            DriveBlock(k * N, np.ones(N), now),
        ]
    state, _, packets, _, notes = run(inputs)
    assert [x.first_sample_index for x in packets] == [N + LEAD] + [
        (k + 1) * N + LEAD for k in range(8, 20)
    ]
    assert state.counters.drive_late_blocks == 7 and state.counters.drive_reanchors == 0
    assert any("behind the target's clock (the bridge fell behind)" in n.text for n in notes)


def test_a_source_faster_than_real_time_drops_its_queue_and_reanchors() -> None:
    p = params(max_ahead_samples=20)
    inputs = [SensorDatagram(packet(0, 0), 0.0)] + [
        DriveBlock(k * N, np.ones(N), 0.0) for k in range(110)
    ]
    state, _, _packets, _, notes = run(inputs, p)
    queued = sum(len(d) for _, d in state.queue)
    assert state.counters.drive_overflow_blocks > 0 and state.counters.drive_reanchors == 1
    assert queued <= 20 + protocol.MAX_SAMPLES and any("already wait" in n.text for n in notes)


def test_drive_is_clamped_nonfinite_zeroed_and_stale_or_early_blocks_dropped() -> None:
    # no target clock yet
    state, _, packets, _, _ = run(
        [
            DriveBlock(0, np.ones(N), 0.0),
            SensorDatagram(packet(0, 0), 0.0),
            DriveBlock(0, np.array([500.0, -500.0, np.nan] + [1.0] * 7), 0.0),
            # duplicate
            DriveBlock(0, np.ones(N), 0.0),
        ]
    )
    assert len(packets) == 1
    np.testing.assert_array_equal(packets[0].drive_v[:4], [150.0, -150.0, 0.0, 1.0])
    c = state.counters
    assert (
        c.drive_unscheduled_blocks,
        c.clamped_samples,
        c.nonfinite_samples,
        c.drive_stale_blocks,
    ) == (1, 2, 1, 1)


def test_drive_far_ahead_waits_for_the_target_clock() -> None:
    p = params(max_ahead_samples=20)
    inputs = [SensorDatagram(packet(0, 0), 0.0)] + [
        DriveBlock(k * N, np.ones(N), 0.0) for k in range(6)
    ]
    state, _, packets, _, _ = run(inputs, p)
    # up to clock 10 + 20 + 20
    assert [x.first_sample_index for x in packets] == [30, 40]
    state, _, packets, _, _ = run([SensorDatagram(packet(1, N), 0.0)], p, state)
    assert [x.first_sample_index for x in packets] == [50]
    assert len(state.queue) == 3


def test_drive_watchdog_sends_a_stop_when_a_nonzero_stream_falls_silent() -> None:
    inputs = [SensorDatagram(packet(0, 0), 0.0), DriveBlock(0, np.ones(N), 0.0), Tick(0.019)]
    state, _, packets, _, _ = run(inputs)
    assert len(packets) == 1
    state, _, packets, _, notes = run([Tick(0.021), Tick(0.05)], state=state)
    assert len(packets) == 1 and packets[0].stop and packets[0].first_sample_index == N
    assert state.counters.watchdog_stops == 1 and "DRIVE WATCHDOG" in notes[0].text
    # a zero stream falling silent needs no stop; a resumed stream is anchored afresh
    state, _, packets, _, _ = run(
        [SensorDatagram(packet(1, N), 0.06), DriveBlock(N, np.zeros(N), 0.06), Tick(0.2)],
        state=state,
    )
    assert [x.first_sample_index for x in packets] == [
        2 * N + LEAD
    ] and state.counters.watchdog_stops == 1


def test_silent_target_stops_the_drive_and_its_samples_are_published_as_lost() -> None:
    inputs = [SensorDatagram(packet(0, 0), 0.0), DriveBlock(0, np.ones(N), 0.0)]
    # 40 ms silent
    inputs += [DriveBlock(k * N, np.ones(N), 0.001 * k) for k in range(1, 40)] + [Tick(0.0401)]
    state, blocks, packets, _, notes = run(inputs)
    assert packets[-1].stop and state.counters.silences == 1
    assert any("TARGET SILENT" in n.text for n in notes)
    index, stroke = stream(blocks)
    # lost samples at the real-time rate
    assert index[-1] + 1 == N + int(0.0401 * FS) // N * N
    assert np.isnan(stroke[N:]).all()
    # the target comes back: what was already published as lost is dropped, the rest goes on
    state, more, *_ = run(
        [SensorDatagram(packet(1, 500), 0.05), SensorDatagram(packet(2, 1000), 0.0505)], state=state
    )
    index2, stroke2 = stream(blocks + more)
    # published up to 810: the packet at 500 is all overlap, 810..1000 lost, then data again
    assert (
        index2[-1] == 1009
        and state.counters.overlap_samples == N
        and state.counters.lost_samples == 190
    )
    assert np.isnan(stroke2[(index2 >= N) & (index2 < 1000)]).all()
    np.testing.assert_array_equal(
        stroke2[-10:], (1 + np.arange(1000, 1010) / 1000).astype(np.float32)
    )


def test_a_backlog_in_the_bridge_is_not_taken_for_a_silent_target() -> None:
    # packets that arrived 50 ms ago and are read only
    # now: the target is not silent, the bridge is late
    inputs = [
        SensorDatagram(packet(k, k * N), 1.0 + k * 5e-4, 1.05 + k * 1e-5) for k in range(5)
    ] + [Tick(1.051)]
    state, blocks, _, _, notes = run(inputs)
    assert state.counters.silences == 0 and len(blocks) == 5 and not notes


def test_a_bridge_that_stalled_with_datagrams_unread_does_not_call_the_target_silent() -> None:
    # 40 ms without a read, but the socket holds unread datagrams (the process stalled: a GIL-heavy
    # start-up, a long callback): no silence, no stop, no samples published as lost
    inputs = [
        SensorDatagram(packet(0, 0), 0.0),
        DriveBlock(0, np.zeros(N), 0.0),
        Tick(0.0401, backlog=True),
    ]
    state, blocks, packets, _, notes = run(inputs)
    assert state.counters.silences == 0 and not any("SILENT" in n.text for n in notes)
    assert not any(p.stop for p in packets) and len(blocks) == 1
    state, *_ = run([Tick(0.0402)], state=state)  # nothing waiting any more: now it is a silence
    assert state.counters.silences == 1


def test_a_new_target_flooding_a_stalled_bridge_is_learnt_once_the_old_one_is_silent() -> None:
    # The old target (port 1000) ends; a fresh one (port 2000) streams so fast that the bridge,
    # behind on a loaded machine, always has datagrams unread. Those it reads are from the new
    # sender and arrived after the old one's timeout: the old target is silent whatever waits.
    old, new = ("127.0.0.1", 1000), ("127.0.0.1", 2000)
    inputs = [SensorDatagram(packet(0, 0), 0.0, sender=old)]
    inputs += [SensorDatagram(packet(k, k * N), 0.0301 + k * 5e-4, sender=new) for k in range(3)]
    inputs += [Tick(0.0402, backlog=True)]
    inputs += [SensorDatagram(packet(3, 3 * N), 0.0416, sender=new)]
    state, _, _, _, notes = run(inputs)
    assert state.counters.silences == 1 and state.source == new
    assert any("now from 127.0.0.1:2000" in n.text for n in notes)
    # datagrams unread with the old target's last one within its timeout: a stall, not a silence
    state, *_ = run(
        [
            SensorDatagram(packet(0, 0), 0.0, sender=old),
            SensorDatagram(packet(0, 0), 0.015, sender=new),
            Tick(0.0402, backlog=True),
        ]
    )
    assert state.counters.silences == 0 and state.source == old


def test_target_restart_is_followed_after_resync_packets_stale_ones() -> None:
    inputs = [SensorDatagram(packet(s, 5000 + s * N), 0.0) for s in range(100, 103)]
    # the target restarted at 0
    inputs += [SensorDatagram(packet(s, s * N), 0.0) for s in range(6)]
    state, blocks, _, _, _notes = run(inputs)
    assert state.counters.stale_packets == 4 and state.counters.resyncs == 1
    index, stroke = stream(blocks)
    # published index keeps running
    assert len(index) == 3 * N + 2 * N
    np.testing.assert_array_equal(stroke[-N:], (1 + np.arange(50, 60) / 1000).astype(np.float32))


def test_stop_input_sends_a_stop_packet_at_the_target_clock() -> None:
    state, _, packets, _, _ = run(
        [SensorDatagram(packet(0, 70), 0.0), DriveBlock(0, np.ones(N), 0.0), Stop(0.0, "end")]
    )
    assert packets[-1].stop and packets[-1].first_sample_index == 80 and packets[-1].sequence == 1
    assert state.counters.stop_packets == 1 and not state.driving


@pytest.mark.parametrize(
    "name, value",
    [
        ("block_size", 0),
        ("lead_samples", -1),
        ("drive_timeout_s", 0.0),
        ("sample_rate_hz", float("nan")),
        ("resync_packets", 0),
    ],
)
def test_parameters_out_of_range_are_named(name: str, value) -> None:
    with pytest.raises(bridge_params.BridgeParameterError, match=f"'{name}'"):
        params(**{name: value})


def drive_datagram(first: int, values, flags: int = 0) -> bytes:
    return struct.pack(f"<4sIQHH{len(values)}f", b"FLD1", 0, first, len(values), flags, *values)


def test_emulated_target_holds_then_zeroes_clamps_discards_late_and_honours_stop() -> None:
    core = TargetCore(hold_samples=3, drive_limit_v=150.0)
    core.receive(drive_datagram(0, [1.0, 2.0, 300.0, -400.0, 5.0]))
    drive, flags = core.decide(10)
    # held 3 samples, then zero
    np.testing.assert_array_equal(drive, [1, 2, 150, -150, 5, 5, 5, 5, 0, 0])
    assert flags == 1 and core.counts["watchdog_trips"] == 1 and core.counts["clamped_samples"] == 2
    # 8, 9 already passed: late; 10, 11 in time
    core.receive(drive_datagram(8, [7.0] * 4))
    drive, flags = core.decide(4)
    # fresh, then held again
    np.testing.assert_array_equal(drive, [7, 7, 7, 7])
    assert flags == 0 and core.counts["late_samples"] == 2 and core.counts["watchdog_trips"] == 1
    core.receive(drive_datagram(14, [9.0] * 10))
    # stop: zero now, the buffered drive is gone
    core.receive(drive_datagram(14, [0.0], flags=1))
    drive, flags = core.decide(10)
    assert np.all(drive == 0.0) and flags == 0 and core.counts["stop_packets"] == 1
    core.receive(b"FLD1" + bytes(3))  # malformed: dropped
    core.receive(drive_datagram(30, [float("nan")]))
    assert core.counts["dropped_packets"] == 2


def test_emulated_target_counts_the_machine_stalls_and_the_samples_missed_in_them() -> None:
    """A packet sent more than stall_s late is a stall; samples missing until as long again
    after it count as the stall's, later ones do not.
    """
    stats = {"overruns": 0, "stalls": 0, "stall_missing_samples": 0, "max_lag_ms": 0.0}
    until = count_lag(stats, 0.0003, 10.0, 0.0005, 0.001, -np.inf)  # on time: no stall
    assert until == -np.inf and stats["overruns"] == 0 and stats["stalls"] == 0
    until = count_lag(stats, 0.004, 10.1, 0.0005, 0.001, until)  # held 4 ms
    assert until == pytest.approx(10.104) and stats["stalls"] == 1 and stats["overruns"] == 1
    assert stats["max_lag_ms"] == pytest.approx(4.0)
    core = TargetCore(hold_samples=3, drive_limit_v=150.0)
    core.receive(drive_datagram(0, [1.0] * 10))
    decide_counting(core, 10, stats, in_stall=False)  # armed, all fresh
    decide_counting(core, 10, stats, in_stall=True)  # nothing came: 10 missing, the stall's
    decide_counting(core, 10, stats, in_stall=False)  # 10 more missing, FLAAIR's
    assert core.counts["missing_samples"] == 20 and stats["stall_missing_samples"] == 10


def _same(a, b) -> bool:
    """Equal NamedTuples, tuples and arrays, field by field (NaN equal to NaN)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)
    if isinstance(a, tuple) and isinstance(b, tuple):
        return (
            type(a) is type(b)
            and len(a) == len(b)
            and all(_same(x, y) for x, y in zip(a, b, strict=True))
        )
    return a == b


@pytest.mark.parametrize("block_size", [N, 2 * N])
def test_the_in_order_fast_path_gives_what_the_general_path_gives_watchdog_flag_included(
    block_size,
) -> None:
    """Every packet the fast path takes (in order; a whole block, or part of one as a target's
    0.5 ms packets are of 1 ms blocks; the target's watchdog flag set or not) gives the state and
    outputs the general path gives, with drive queued and released.
    """
    p = params(block_size=block_size)
    state = bridge.initial_state(p)
    rng = np.random.default_rng(7)
    compared = flagged = 0
    for k in range(80):
        now = 1.0 + k * 5e-4
        flags = protocol.FLAG_TARGET_WATCHDOG if rng.random() < 0.3 else 0
        item = SensorDatagram(packet(k, k * N, flags=flags), now, now + 1e-4)
        decoded = protocol.unpack_sensor(item.data)
        if bridge.in_order(state, decoded, p):
            fast = bridge.in_order_packet(state, decoded, item.now_s, item.read_s, p)
            general = bridge.any_packet(state, decoded, item, p)
            assert _same(fast, general), k
            compared, flagged = compared + 1, flagged + bool(flags)
        state, _ = bridge.step(state, item, p)
        if (k + 1) * N % block_size == 0:  # the loop answers each whole block with a drive block
            state, _out = bridge.step(
                state,
                DriveBlock(k * N + N - block_size, np.full(block_size, float(k)), now + 2e-4),
                p,
            )
    assert compared == 79 and flagged > 15 and state.counters.drive_packets > 30


@pytest.mark.timeout(10)
def test_an_endpoint_reads_only_once_started() -> None:
    """A target already sending when the bridge starts: its first datagram must not reach the
    callback before the node holds the endpoint (the composed loop answers from inside the
    callback through it; before the fix the reader thread died on the node's missing
    `endpoint`). Datagrams that arrive before `start` wait in the socket.
    """
    got: list[bytes] = []
    endpoint = DatagramEndpoint("127.0.0.1", 0, 1 << 16, lambda data, *_: got.append(data))
    address = endpoint.sock.getsockname()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as target:
        target.sendto(b"first", address)
        deadline = time.monotonic() + 2.0
        while not endpoint.pending() and time.monotonic() < deadline:
            time.sleep(0.01)
        # queued in the socket, no reader running: nothing can reach the callback yet
        assert endpoint.pending() and not endpoint.reader.is_alive() and got == []
        endpoint.start()
        target.sendto(b"second", address)
        deadline = time.monotonic() + 2.0
        while len(got) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
    endpoint.close()
    assert got == [b"first", b"second"]


def test_the_emulated_targets_damage_is_named_by_key() -> None:
    """--damage KEY=FACTOR: the damage schedule's factors, every other one 1; a bad item is
    refused naming it.
    """
    # the option's keys are the damage schedule's factors (written out: --help answers before
    # the target loads the plant)
    assert tuple(f.name for f in fields(DamageParams) if f.name != "time_s") == DAMAGE_KEYS
    factors = damage_factors(["inertia_factor=0.95", "stroke_film_gain=0.9"])
    assert factors == {
        "inertia_factor": 0.95,
        "stiffness_factor": 1.0,
        "stroke_film_gain": 0.9,
        "pitch_film_gain": 1.0,
        "actuator_gain": 1.0,
    }
    with pytest.raises(ValueError, match=r"'wing=0\.9': expected KEY=FACTOR"):
        damage_factors(["wing=0.9"])
    with pytest.raises(ValueError, match="'abc' is not a number"):
        damage_factors(["actuator_gain=abc"])
