"""The in-process bus of composed nodes (flaair_common.intra): the hot FIFO first, background
subscribers (collision monitor, recorder) batched on the main thread, everything flushed at the
end; and the bytes a composed recorder writes are the bytes DDS would have carried.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

from flaair_common import cdr, intra, topics
from flaair_tools import bagio

FS = 20000.0


def block(first: int, n: int = 10) -> dict:
    stamp_ns = round(first / FS * 1e9)
    return {
        "sample_rate_hz": FS,
        "first_sample_index": first,
        "drive_v": np.arange(first, first + n, dtype=float),
        "sec": stamp_ns // 1_000_000_000,
        "nanosec": stamp_ns % 1_000_000_000,
        "frame_id": "",
    }


def test_background_waits_for_a_batch_and_never_runs_before_the_hot_path() -> None:
    bus = intra.Bus({topics.DRIVE}, background_batch=5)
    calls: list[tuple[str, int, int]] = []
    bus.subscribe(
        topics.DRIVE, lambda f: calls.append(("hot", f["first_sample_index"], len(f["drive_v"])))
    )
    bus.subscribe(
        topics.DRIVE,
        lambda f: calls.append(("monitor", f["first_sample_index"], len(f["drive_v"]))),
        background=True,
    )
    bus.subscribe(
        topics.DRIVE,
        lambda f: calls.append(("recorder", f["first_sample_index"], len(f["drive_v"]))),
        background=True,
        join=False,
    )
    bus.deliver(topics.DRIVE, block(0))
    bus.deliver(topics.DRIVE, block(10))
    # 4 background blocks wait
    assert calls == [("hot", 0, 10), ("hot", 10, 10)] and not bus.pending()
    # 6: a batch, after the hot one
    bus.deliver(topics.DRIVE, block(20))
    # the monitor's joined
    assert calls[2:] == [
        ("hot", 20, 10),
        ("monitor", 0, 30),
        ("recorder", 0, 10),
        ("recorder", 10, 10),
        ("recorder", 20, 10),
    ]
    # a gap: 30 never came
    bus.deliver(topics.DRIVE, block(40))
    bus.deliver(topics.DRIVE, block(50))
    assert calls[-1] == ("hot", 50, 10)
    bus.flush()
    assert calls[-3:] == [("monitor", 40, 20), ("recorder", 40, 10), ("recorder", 50, 10)]


def test_background_runs_only_on_the_main_thread() -> None:
    bus = intra.Bus({topics.DRIVE}, background_batch=1)
    ran: list[str] = []
    bus.subscribe(
        topics.DRIVE, lambda f: ran.append(threading.current_thread().name), background=True
    )
    reader = threading.Thread(target=lambda: bus.deliver(topics.DRIVE, block(0)), name="udp-reader")
    reader.start()
    reader.join()
    assert ran == [] and bus.pending()
    bus.drain()
    assert ran == [threading.main_thread().name]


@pytest.mark.parametrize("topic", sorted(topics.BLOCK_STREAM_TYPES))
def test_a_composed_recorder_writes_the_bytes_dds_would_carry(topic: str) -> None:
    """encode_fields (what the composed recorder writes) == the publisher's FixedCodec bytes, and
    rosbags (an independent CDR reader) reads the values back.
    """
    msgtype = topics.BLOCK_STREAM_TYPES[topic]
    layout = cdr.layout_of(msgtype)
    rng = np.random.default_rng(1)
    fields: dict = {}
    for name, kind in layout.fields:
        fields[name] = (
            rng.normal(size=10)
            if kind == "float64[]"
            else rng.random(10) > 0.3
            if kind == "bool[]"
            else "a fault"
            if kind == "string"
            else True
            if kind == "bool"
            else 1.5
            if kind == "float64"
            else FS
            if name == "sample_rate_hz"
            else 1
            if kind == "uint8"
            else 12340
        )
    has_string = any(kind == "string" for _, kind in layout.fields)
    publisher_codec = (
        cdr.GeneralCodec(layout, topics.FRAME_ID)
        if has_string
        else cdr.FixedCodec(layout, 10, topics.FRAME_ID)
    )
    stamp_ns = 617_000_050_000
    dds_bytes = publisher_codec.encode(stamp_ns, fields)
    handed_over = {
        **fields,
        "sec": stamp_ns // 10**9,
        "nanosec": stamp_ns % 10**9,
        "frame_id": topics.FRAME_ID,
    }
    got_stamp, recorded = cdr.encode_fields(layout, handed_over, {})
    assert got_stamp == stamp_ns and recorded == dds_bytes
    message = bagio.typestore().deserialize_cdr(recorded, msgtype)
    assert message.header.frame_id == topics.FRAME_ID
    for name, kind in layout.fields:
        if not kind.endswith("[]"):
            assert (
                getattr(message, name) == pytest.approx(fields[name])
                if kind != "string"
                else getattr(message, name) == fields[name]
            )
        else:
            np.testing.assert_array_equal(np.asarray(getattr(message, name)), fields[name])


class _RecordingPublisher:
    """Stands in for an rclpy publisher with one DDS subscriber: keeps the bytes it is given."""

    def __init__(self) -> None:
        self.sent: list[bytes] = []

    def get_subscription_count(self) -> int:
        return 1

    def publish(self, data: bytes) -> None:
        self.sent.append(data)


class _Node:
    def __init__(self) -> None:
        self.publisher = _RecordingPublisher()

    def create_publisher(self, *_args):
        return self.publisher


def test_dds_copies_are_joined_batches_in_process_subscribers_get_every_block() -> None:
    """With dds_batch 4: in-process subscribers see each 10-sample block at once; DDS gets one
    40-sample message per 4 contiguous blocks, a shorter one at a gap and at flush, published by
    the main thread, readable by rosbags with every sample in order.
    """
    bus = intra.Bus({topics.DRIVE}, dds_batch=4)
    seen: list[int] = []
    bus.subscribe(topics.DRIVE, lambda f: seen.append(f["first_sample_index"]))
    intra.install(bus)
    try:
        node = _Node()
        publisher = intra.BlockPublisher(
            node, None, topics.DRIVE, cdr.FixedCodec(cdr.DRIVE_COMMAND_BLOCK, 10), None
        )
    finally:
        intra.install(None)
    firsts = [0, 10, 20, 30, 40, 50, 70, 80]  # 60 never came
    for first in firsts:
        fields = block(first)
        publisher.publish(
            int(first / FS * 1e9),
            {k: fields[k] for k in ("sample_rate_hz", "first_sample_index", "drive_v")},
        )
        assert seen[-1] == first
    # nothing on DDS from the publishing (hot) thread
    assert node.publisher.sent == []
    bus.run_deferred()  # the main thread publishes
    assert len(node.publisher.sent) == 2  # 0-30 joined; 40, 50 closed by the gap
    bus.flush()
    messages = [
        bagio.typestore().deserialize_cdr(data, "flaair_msgs/msg/DriveCommandBlock")
        for data in node.publisher.sent
    ]
    assert [(m.first_sample_index, len(m.drive_v)) for m in messages] == [
        (0, 40),
        (40, 20),
        (70, 20),
    ]
    for m in messages:
        first = m.first_sample_index
        np.testing.assert_array_equal(
            m.drive_v, np.arange(first, first + len(m.drive_v), dtype=float)
        )
        assert m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == int(first / FS * 1e9)


def test_a_reader_thread_sends_deferred_copies_one_per_gap_and_the_main_thread_only_stragglers(
    monkeypatch,
) -> None:
    """Deferred DDS copies: the thread that answered a block sends one per gap (use_gap), in
    order; the main thread leaves fresh ones to it and sends only those waiting past the backstop;
    a copy another thread is sending is never overtaken.
    """
    clock = [100.0]
    monkeypatch.setattr(intra.time, "monotonic", lambda: clock[0])
    bus = intra.Bus({topics.DRIVE})
    sent: list[int] = []
    for k in range(4):
        bus.defer(lambda k=k: sent.append(k))
    intra.install(bus)
    try:
        intra.use_gap()
        assert sent == [0]
        # fresh: left to the reader's gaps
        assert bus.run_deferred(older_than_s=0.05) == 0
        clock[0] += 0.06
        intra.use_gap()
        assert sent == [0, 1]
        # stragglers, in order
        assert bus.run_deferred(older_than_s=0.05) == 2 and sent == [0, 1, 2, 3]
        bus.defer(lambda: sent.append(4))
        with bus._deferring:  # another thread is sending one
            intra.use_gap()
        assert sent == [0, 1, 2, 3]
        intra.use_gap()
        assert sent == [0, 1, 2, 3, 4]
    finally:
        intra.install(None)
    intra.use_gap()  # outside a container: nothing to do


class _CountingPublisher:
    """A publisher whose DDS subscription count the test sets; counts rclpy's queries."""

    def __init__(self) -> None:
        self.subscribers, self.queries = 0, 0

    def get_subscription_count(self) -> int:
        self.queries += 1
        return self.subscribers


@pytest.mark.timeout(10)
def test_a_per_block_listener_check_queries_dds_once_every_refresh_blocks() -> None:
    publisher = _CountingPublisher()
    listeners = intra.ListenerCount(publisher)
    n = intra.LISTENER_REFRESH_BLOCKS
    assert [listeners() for _ in range(n)] == [0] * n  # no listener: nothing written
    assert publisher.queries == 1  # one rclpy query for n blocks
    publisher.subscribers = 2  # a listener matches: seen at the next refresh, not later
    assert listeners() == 2
    assert publisher.queries == 2
    assert [listeners() for _ in range(n - 1)] == [2] * (n - 1)
    assert publisher.queries == 2
