"""flaair_common.cdr against rclpy's own serialization, for any field values.

Fast DDS leaves padding bytes uninitialised and may append unused bytes, so the encodings are
compared by each side decoding the other's bytes to the same values.
"""

from __future__ import annotations

import numpy as np
import pytest
import rclpy.serialization as rclpy_serialization
from hypothesis import given, settings
from hypothesis import strategies as st

from flaair_common import cdr
from flaair_common.msgdict import from_dict, message_class, to_dict

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
any_float = st.floats(width=64)  # NaN and inf too: the codec must carry them unchanged
index = st.integers(0, 2**64 - 1)
frame = st.text(st.characters(codec="utf-8", exclude_characters="\x00"), max_size=12)
stamp = st.integers(0, 2**31 - 1).flatmap(
    lambda s: st.integers(0, 999_999_999).map(lambda ns: s * 1_000_000_000 + ns)
)


def _values(layout: cdr.Layout) -> st.SearchStrategy[dict]:
    kinds = {
        "float64": any_float,
        "uint64": index,
        "uint8": st.integers(0, 255),
        "bool": st.booleans(),
        "float64[]": st.lists(any_float, max_size=24),
        "bool[]": st.lists(st.booleans(), max_size=24),
        "string": frame,
    }
    return st.fixed_dictionaries({name: kinds[kind] for name, kind in layout.fields})


def _rclpy_message(layout: cdr.Layout, stamp_ns: int, frame_id: str, values: dict):
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    fields = {name: (list(v) if isinstance(v, list) else v) for name, v in values.items()}
    return from_dict(
        message_class(layout.type_name),
        {"header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame_id}, **fields},
    )


def _same(a, b) -> bool:
    if isinstance(b, str):
        return a == b
    return np.array_equal(np.asarray(a, dtype=float), np.asarray(b, dtype=float), equal_nan=True)


@pytest.mark.parametrize(
    "layout", list(cdr.LAYOUTS.values()), ids=lambda layout: layout.type_name.rsplit("/", 1)[-1]
)
@settings(max_examples=60, deadline=None)
@given(data=st.data(), stamp_ns=stamp, frame_id=frame)
def test_encode_equals_rclpy_and_decode_inverts_it(
    layout: cdr.Layout, data, stamp_ns: int, frame_id: str
) -> None:
    values = data.draw(_values(layout))
    message = _rclpy_message(layout, stamp_ns, frame_id, values)
    reference = rclpy_serialization.serialize_message(message)
    decoded = cdr.decode(layout, reference)
    assert decoded["stamp_ns"] == stamp_ns and decoded["frame_id"] == frame_id
    for name, value in values.items():
        assert _same(decoded[name], value), name
    # and rclpy reads what the codec writes
    back = to_dict(
        rclpy_serialization.deserialize_message(
            cdr.encode(layout, stamp_ns, frame_id, values), message_class(layout.type_name)
        )
    )
    for name, value in values.items():
        assert _same(back[name], value), name


def test_sequences_decode_as_read_only_views_without_copy() -> None:
    data = cdr.encode(cdr.DRIVE_COMMAND_BLOCK, 0, "", {"drive_v": np.arange(10.0)})
    decoded = cdr.decode(cdr.DRIVE_COMMAND_BLOCK, data)
    assert np.array_equal(decoded["drive_v"], np.arange(10.0))
    assert not decoded["drive_v"].flags.writeable


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda b: b"\x01\x00\x00\x00" + b[4:], "not little-endian CDR"),
        (lambda b: b[:-30], "run past the end"),
        (lambda b: b[:10], "malformed CDR"),
    ],
)
def test_damaged_bytes_name_the_type_and_the_fault(damage, message: str) -> None:
    data = cdr.encode(
        cdr.WING_STATE_BLOCK, 5, "robot", {"stroke_deg": np.ones(10), "stroke_valid": [True] * 10}
    )
    with pytest.raises(cdr.CdrError, match=message) as info:
        cdr.decode(cdr.WING_STATE_BLOCK, damage(data))
    assert "WingStateBlock" in str(info.value)


BLOCK_LAYOUTS = [
    layout for layout in cdr.LAYOUTS.values() if all(kind != "string" for _, kind in layout.fields)
]


@pytest.mark.parametrize(
    "layout", BLOCK_LAYOUTS, ids=lambda layout: layout.type_name.rsplit("/", 1)[-1]
)
@settings(max_examples=40, deadline=None)
@given(data=st.data(), stamp_ns=stamp, frame_id=frame, block_size=st.integers(1, 12))
def test_fixed_codec_matches_the_general_one_and_reads_rclpy(
    layout: cdr.Layout, data, stamp_ns: int, frame_id: str, block_size: int
) -> None:
    kinds = {
        "float64": any_float,
        "uint64": index,
        "uint8": st.integers(0, 255),
        "bool": st.booleans(),
        "float64[]": st.lists(any_float, min_size=block_size, max_size=block_size),
        "bool[]": st.lists(st.booleans(), min_size=block_size, max_size=block_size),
    }
    values = data.draw(st.fixed_dictionaries({name: kinds[kind] for name, kind in layout.fields}))
    codec = cdr.FixedCodec(layout, block_size, frame_id)
    assert codec.encode(stamp_ns, values) == cdr.encode(layout, stamp_ns, frame_id, values)
    record = codec.decode(
        rclpy_serialization.serialize_message(_rclpy_message(layout, stamp_ns, frame_id, values))
    )
    assert isinstance(record, np.void)  # the fixed layout, not the fallback
    assert cdr.stamp_ns(record) == stamp_ns
    for name, value in values.items():
        assert _same(record[name], value), name


def test_fixed_codec_hands_other_sizes_to_the_general_decoder() -> None:
    codec = cdr.FixedCodec(cdr.DRIVE_COMMAND_BLOCK, 10, "")
    other = cdr.encode(
        cdr.DRIVE_COMMAND_BLOCK, 7, "", {"first_sample_index": 3, "drive_v": np.arange(12.0)}
    )
    decoded = codec.decode(other)
    assert isinstance(decoded, dict) and decoded["first_sample_index"] == 3
    assert np.array_equal(decoded["drive_v"], np.arange(12.0))
