"""Real-time target protocol: byte layout from the protocol text, round trips, and random bytes.

The layout is checked against struct formats written from docs/REALTIME_PROTOCOL.md (an
independent reading of the same table), and against the emulated target's own packing.
"""

from __future__ import annotations

import contextlib
import math
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from flaair_bridge import emulated_target
from flaair_bridge.core import protocol
from flaair_bridge.core.protocol import DrivePacket, ProtocolError, SensorPacket

F32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
U32 = st.integers(0, 2**32 - 1)
U64 = st.integers(0, 2**64 - 1)
U16 = st.integers(0, 2**16 - 1)


@st.composite
def sensor_packets(draw) -> SensorPacket:
    n = draw(st.integers(1, protocol.MAX_SAMPLES))
    columns = [draw(hnp.arrays(np.float32, n, elements=F32)) for _ in range(3)]
    rate = draw(st.floats(min_value=0.5, max_value=1e7, width=32))
    return SensorPacket(draw(U32), draw(U64), rate, draw(U16), *columns)


@st.composite
def drive_packets(draw) -> DrivePacket:
    m = draw(st.integers(1, protocol.MAX_SAMPLES))
    drive = draw(hnp.arrays(np.float32, m, elements=F32))
    return DrivePacket(draw(U32), draw(U64), draw(U16), drive)


def test_lab_sensor_packet_has_the_documented_bytes() -> None:
    n = 10
    drive = np.linspace(-100, 100, n)
    stroke, pitch = 1.25 + 0.01 * np.arange(n), 1.25 - 0.02 * np.arange(n)
    data = protocol.pack_sensor(SensorPacket(7, 123456789012, 20000.0, 1, drive, stroke, pitch))
    assert len(data) == 24 + 12 * n
    assert struct.unpack_from("<4sIQfHH", data) == (b"FLS1", 7, 123456789012, 20000.0, 10, 1)
    samples = struct.unpack_from(f"<{3 * n}f", data, 24)
    np.testing.assert_array_equal(samples[0::3], drive.astype(np.float32))
    np.testing.assert_array_equal(samples[1::3], stroke.astype(np.float32))
    np.testing.assert_array_equal(samples[2::3], pitch.astype(np.float32))
    # the emulated target's independent packing gives the same bytes
    assert emulated_target.sensor_packet(7, 123456789012, 20000.0, 1, drive, stroke, pitch) == data


def test_drive_packet_has_the_documented_bytes_and_the_stop_flag() -> None:
    data = protocol.pack_drive(
        DrivePacket(2**32 - 1, 40, protocol.FLAG_STOP, np.array([0.0, -150.0, 12.5]))
    )
    assert len(data) == 20 + 4 * 3
    assert struct.unpack("<4sIQHH3f", data) == (b"FLD1", 2**32 - 1, 40, 3, 1, 0.0, -150.0, 12.5)
    packet = protocol.unpack_drive(data)
    assert packet.stop and packet.m == 3 and packet.sequence == 2**32 - 1


@settings(max_examples=200, deadline=None)
@given(sensor_packets())
def test_sensor_packets_round_trip(packet: SensorPacket) -> None:
    back = protocol.unpack_sensor(protocol.pack_sensor(packet))
    assert (back.sequence, back.first_sample_index, back.flags, back.n) == (
        packet.sequence,
        packet.first_sample_index,
        packet.flags,
        len(packet.drive_v),
    )
    assert back.sample_rate_hz == float(np.float32(packet.sample_rate_hz))
    for name in ("drive_v", "stroke_sensor_v", "pitch_sensor_v"):
        np.testing.assert_array_equal(getattr(back, name), getattr(packet, name))
    assert back.target_watchdog_tripped == bool(packet.flags & 1)


@settings(max_examples=200, deadline=None)
@given(drive_packets())
def test_drive_packets_round_trip_and_the_emulator_reads_them(packet: DrivePacket) -> None:
    data = protocol.pack_drive(packet)
    back = protocol.unpack_drive(data)
    assert (back.sequence, back.first_sample_index, back.flags) == (
        packet.sequence,
        packet.first_sample_index,
        packet.flags,
    )
    np.testing.assert_array_equal(back.drive_v, packet.drive_v)
    # the emulated target (its own struct decoding) accepts every valid packet
    core = emulated_target.TargetCore(hold_samples=40, drive_limit_v=150.0)
    core.receive(data)
    assert core.counts["dropped_packets"] == 0 and core.counts["drive_packets"] == 1


@settings(max_examples=500, deadline=None)
@given(st.binary(max_size=200))
def test_random_bytes_raise_only_protocol_error(data: bytes) -> None:
    for unpack in (protocol.unpack_sensor, protocol.unpack_drive):
        with contextlib.suppress(ProtocolError):
            unpack(data)


@pytest.mark.slow  # property test: many corrupted packets
@settings(max_examples=300, deadline=None)
@given(sensor_packets(), st.integers(0, 12 * 1000 + 24), st.binary(min_size=1, max_size=4))
def test_corrupted_sensor_packets_raise_only_protocol_error(
    packet: SensorPacket, position: int, junk: bytes
) -> None:
    data = bytearray(protocol.pack_sensor(packet))
    position %= len(data)
    mutated = [
        bytes(data[:position]),
        bytes(data[:position] + junk + data[position:]),
        bytes(data[:position] + junk + data[position + len(junk) :]),
    ]
    for candidate in mutated:
        try:
            back = protocol.unpack_sensor(candidate)
        except ProtocolError:
            continue
        # what is accepted is a valid packet: finite values, the right length
        assert len(candidate) == 24 + 12 * back.n
        assert all(
            np.isfinite(getattr(back, f)).all()
            for f in ("drive_v", "stroke_sensor_v", "pitch_sensor_v")
        )


@pytest.mark.parametrize(
    "data, message",
    [
        (b"FLS1" + bytes(10), "shorter than its 24-byte header"),
        (b"XXXX" + bytes(20 + 12), "magic"),
        (struct.pack("<4sIQfHH", b"FLS1", 0, 0, 20000.0, 0, 0), "n = 0 samples"),
        (
            struct.pack("<4sIQfHH", b"FLS1", 0, 0, 20000.0, 1001, 0) + bytes(12 * 1001),
            "n = 1001 samples",
        ),
        (
            struct.pack("<4sIQfHH", b"FLS1", 0, 0, 20000.0, 2, 0) + bytes(12),
            "must be 48 bytes, got 36",
        ),
        (
            struct.pack("<4sIQfHH", b"FLS1", 0, 0, 20000.0, 2, 0) + bytes(36),
            "must be 48 bytes, got 60",
        ),
        (
            struct.pack("<4sIQfHH3f", b"FLS1", 0, 0, 20000.0, 1, 0, 0.0, math.nan, 0.0),
            "stroke_sensor_v[0] is not finite",
        ),
        (
            struct.pack("<4sIQfHH3f", b"FLS1", 0, 0, math.inf, 1, 0, 0.0, 0.0, 0.0),
            "sample_rate_hz inf",
        ),
    ],
)
def test_invalid_sensor_packets_name_what_is_wrong(data: bytes, message: str) -> None:
    with pytest.raises(ProtocolError, match=message.replace("[", r"\[").replace("]", r"\]")):
        protocol.unpack_sensor(data)


def test_invalid_drive_packets_and_unpackable_values() -> None:
    with pytest.raises(ProtocolError, match=r"drive_v\[1\] is not finite"):
        protocol.unpack_drive(struct.pack("<4sIQHH2f", b"FLD1", 0, 0, 2, 0, 1.0, math.inf))
    with pytest.raises(ProtocolError, match="magic"):
        protocol.unpack_drive(
            protocol.pack_sensor(SensorPacket(0, 0, 20000.0, 0, *np.zeros((3, 1))))
        )
    with pytest.raises(ProtocolError, match="not a finite float32"):
        protocol.pack_drive(DrivePacket(0, 0, 0, np.array([1e39])))  # overflows float32
    with pytest.raises(ProtocolError, match="m = 0"):
        protocol.pack_drive(DrivePacket(0, 0, 0, np.zeros(0)))
    with pytest.raises(ProtocolError, match="sequence"):
        protocol.pack_drive(DrivePacket(2**32, 0, 0, np.zeros(1)))


def test_sequence_delta_wraps_at_2_32() -> None:
    assert protocol.sequence_delta(0, 2**32 - 1) == 1
    assert protocol.sequence_delta(5, 5) == 0
    assert protocol.sequence_delta(2**32 - 1, 0) == -1
    assert protocol.sequence_delta(3, 10) == -7
