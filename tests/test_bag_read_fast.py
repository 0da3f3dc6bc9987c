"""The bag read path: block topics decoded from raw CDR with numpy give exactly what the
typestore's per-message deserialization gives (values, dtypes, gaps, retransmissions, errors);
a bag is opened once for everything `analyze` needs.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from flaair_tools import bagio

SENSOR = "flaair_msgs/msg/SensorVoltageBlock"
WING = "flaair_msgs/msg/WingStateBlock"


def _block(
    msgtype: str,
    first: int,
    n: int,
    stamp_ns: int,
    rate: float,
    rng: np.random.Generator,
    frame: str,
    short_field: bool = False,
):
    store = bagio.typestore()
    header = bagio.new_message(
        "std_msgs/msg/Header", store, stamp=bagio.time_msg(stamp_ns, store), frame_id=frame
    )
    arrays, _ = bagio.block_array_fields(msgtype, store)
    values = {}
    for name in arrays:
        size = max(0, n - 1) if short_field and name == arrays[-1] else n
        values[name] = rng.random(size) > 0.5 if name.endswith("valid") else rng.normal(size=size)
    extra = {"source": 1} if msgtype == WING else {}
    return bagio.new_message(
        msgtype,
        store,
        header=header,
        sample_rate_hz=rate,
        first_sample_index=first,
        **values,
        **extra,
    )


# One step of a block stream: next block (its length), a retransmission of the last one, a gap,
# a repeat, a changed sample rate, a block whose arrays differ in length, another frame_id.
STEPS = st.lists(
    st.tuples(
        st.sampled_from(
            ["next", "next", "next", "retransmit", "gap", "repeat", "rate", "ragged", "frame"]
        ),
        st.integers(0, 12),
    ),
    min_size=1,
    max_size=25,
)


def _stream(msgtype: str, steps: list[tuple[str, int]], seed: int) -> list:
    rng, messages, first, stamp = np.random.default_rng(seed), [], 0, 1_000
    for kind, n in steps:
        if kind == "retransmit" and messages:
            messages.append(messages[-1])
            continue
        first += {"gap": 7, "repeat": -min(first, 3)}.get(kind, 0)
        messages.append(
            _block(
                msgtype,
                first,
                n,
                stamp,
                30000.0 if kind == "rate" else 20000.0,
                rng,
                "robot_long_frame" if kind == "frame" else "robot",
                short_field=kind == "ragged" and n > 0,
            )
        )
        first, stamp = first + n, stamp + 500_000
    return messages


def _outcome(fn):
    try:
        return fn()
    except bagio.BagError as exc:
        return (type(exc), str(exc))


@settings(max_examples=150, deadline=None)
@given(
    steps=STEPS,
    seed=st.integers(0, 2**16),
    msgtype=st.sampled_from([SENSOR, WING]),
    allow_gaps=st.booleans(),
)
def test_numpy_cdr_decoding_equals_the_typestore(steps, seed, msgtype, allow_gaps) -> None:
    store = bagio.typestore()
    messages = _stream(msgtype, steps, seed)
    datas = [bytes(store.serialize_cdr(m, msgtype)) for m in messages]
    typed = _outcome(
        lambda: bagio.assemble_blocks(
            "/t",
            msgtype,
            [store.deserialize_cdr(d, msgtype) for d in datas],
            allow_gaps=allow_gaps,
            bag="b",
        )
    )
    fast = _outcome(
        lambda: bagio.blocks_from_cdr("/t", msgtype, datas, allow_gaps=allow_gaps, bag="b")
    )
    if isinstance(typed, tuple):
        assert fast == typed
        return
    assert not isinstance(fast, tuple), fast
    for name in ("sample_index", "time_ns", "block_stamps_ns", "block_first_index"):
        assert (
            np.array_equal(getattr(fast, name), getattr(typed, name))
            and getattr(fast, name).dtype == getattr(typed, name).dtype
        )
    for got, want in ((fast.fields, typed.fields), (fast.scalars, typed.scalars)):
        assert got.keys() == want.keys()
        for key in want:
            assert got[key].dtype == want[key].dtype, key
            assert np.array_equal(got[key], want[key], equal_nan=True), key
    assert (fast.gaps, fast.sample_rate_hz, fast.first_sample_index) == (
        typed.gaps,
        typed.sample_rate_hz,
        typed.first_sample_index,
    )


def test_truncated_cdr_is_a_damaged_message_naming_the_bag() -> None:
    store = bagio.typestore()
    data = bytes(
        store.serialize_cdr(
            _block(SENSOR, 0, 10, 0, 20000.0, np.random.default_rng(0), "robot"), SENSOR
        )
    )
    with pytest.raises(
        bagio.BagError, match=r"^b: damaged flaair_msgs/msg/SensorVoltageBlock message"
    ):
        bagio.blocks_from_cdr("/t", SENSOR, [data, data[:40]], bag="b")


def test_one_open_reads_every_topic_asked_and_names_the_missing_one(tmp_path) -> None:
    store = bagio.typestore()
    with bagio.BagWriter(tmp_path / "bag", store=store) as writer:
        for k in range(3):
            writer.write_message(
                "/flaair/sensor_v",
                k,
                _block(SENSOR, 10 * k, 10, k, 20000.0, np.random.default_rng(k), "robot"),
            )
        writer.write_message(
            bagio.RUN_MARKER_TOPIC,
            0,
            bagio.new_message(
                bagio.RUN_MARKER_TYPE,
                store,
                data=bagio.RunMarker("r1", 0, 30, "r1.csv", 20000.0, 0).to_json(),
            ),
        )
    contents = bagio.read_bag(
        tmp_path / "bag", ["/flaair/sensor_v", bagio.RUN_MARKER_TOPIC, "/flaair/drive"]
    )
    assert contents.blocks("/flaair/sensor_v").n_samples == 30
    assert [m.run for m in contents.run_markers()] == ["r1"]
    assert not contents.has("/flaair/drive") and contents.messages("/flaair/drive") == []
    with pytest.raises(
        bagio.BagTopicError,
        match=r"no topic '/flaair/drive' in the bag \(it has: /flaair/run_marker, "
        r"/flaair/sensor_v\)",
    ):
        contents.blocks("/flaair/drive")
