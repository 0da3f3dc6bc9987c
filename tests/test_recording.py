"""flaair_tools.recorder.recording: the recorder's log-time
rule and drain, message by message, without ROS.
"""

from __future__ import annotations

import pytest
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

from flaair_model.schema import ParameterError
from flaair_tools.recorder import recording as rec

PARAMS = rec.RecordingParams(drain_limit=4)
START = rec.LogTimeState()


def run(events, state=START):
    writes = []
    for event in events:
        state, out = rec.step(state, event, PARAMS)
        writes += out
    return state, writes


def test_header_less_messages_wait_for_the_first_stamp_then_take_the_latest():
    marker = rec.Received("/flaair/run_marker", bytearray(b"run 1"), None, 111)
    state, writes = run([marker])
    assert (
        writes == []
        and state.pending[0].data == b"run 1"
        and isinstance(state.pending[0].data, bytes)
    )
    marker.data[:] = b"XXXXX"  # the middleware reuses its buffer: the pending copy is unaffected
    state, writes = run(
        [
            rec.Received("/flaair/sensor_v", b"s", 5_000, 222),
            rec.Received("/flaair/run_marker", b"run 2", None, 333),
            rec.Received("/clock", b"c", 7_000, None),
            rec.Received("/flaair/run_marker", b"run 3", None, None),
        ],
        state,
    )
    assert [(w.topic, w.log_ns, bytes(w.data), w.publish_ns) for w in writes] == [
        ("/flaair/run_marker", 5_000, b"run 1", 111),  # released by the first stamp, at its time
        ("/flaair/sensor_v", 5_000, b"s", 222),
        ("/flaair/run_marker", 5_000, b"run 2", 333),
        ("/clock", 7_000, b"c", None),
        ("/flaair/run_marker", 7_000, b"run 3", None),
    ]
    assert state == rec.LogTimeState(7_000, ())


def test_diagnostics_are_logged_on_the_signals_timeline_not_at_their_stamp():
    # a node's health is stamped by its wall clock, not the signal's (in simulation they differ):
    # it takes the latest signal time, as a run marker does, and sets none
    state, writes = run(
        [
            rec.Received("/diagnostics", b"d", 9_000_000, None),
            rec.Received("/flaair/sensor_v", b"s", 5_000, None),
            rec.Received("/diagnostics", b"e", 9_500_000, None),
            rec.Received("/flaair/run_marker", b"run 2", None, None),
        ]
    )
    assert [(w.topic, w.log_ns) for w in writes] == [
        ("/diagnostics", 5_000),
        ("/flaair/sensor_v", 5_000),
        ("/diagnostics", 5_000),
        ("/flaair/run_marker", 5_000),
    ]
    assert state == rec.LogTimeState(5_000, ())


def test_finish_without_any_stamp_keeps_publish_or_receive_times():
    state, _ = run([rec.Received("/a", b"1", None, 40), rec.Received("/b", b"2", None, None)])
    state, writes = rec.step(state, rec.Finish(now_ns=99), PARAMS)
    assert [(w.topic, w.log_ns) for w in writes] == [("/a", 40), ("/b", 99)] and state.pending == ()
    assert rec.step(rec.LogTimeState(5, ()), rec.Finish(99), PARAMS) == (
        rec.LogTimeState(5, ()),
        (),
    )


def test_drain_takes_queued_messages_up_to_the_limit():
    queue = list(range(10))
    # 1 + 3 = limit 4
    assert rec.drain(lambda: queue.pop(0) if queue else None, PARAMS) == [0, 1, 2]
    assert rec.drain(lambda: queue.pop(0) if queue else None, PARAMS, already=3) == [3]
    queue[:] = [7]
    # stops at an empty queue
    assert rec.drain(lambda: queue.pop(0) if queue else None, PARAMS) == [7]


def test_topic_choice_and_qos_adaptation():
    assert rec.parse_topic_list("/a, /b /c") == ("/a", "/b", "/c")
    with pytest.raises(ParameterError, match=r"'topics'.*flaair/x"):
        rec.parse_topic_list("/a,flaair/x")
    assert rec.wanted("/flaair/drive", (), False) and not rec.wanted("/rosout", (), False)
    assert (
        not rec.wanted("/clock", (), False)
        and rec.wanted("/clock", (), True)
        and rec.wanted("/clock", ("/clock",), False)
    )
    assert not rec.wanted("/flaair/drive", ("/flaair/sensor_v",), False)
    # a recorder in a namespace records its own bench's streams, not another's
    assert rec.wanted("/bench2/flaair/drive", (), False, "/bench2")
    assert not rec.wanted("/flaair/drive", (), False, "/bench2")
    assert not rec.wanted("/bench1/flaair/drive", (), False, "/bench2")
    assert not rec.wanted("/bench2/flaair/drive", (), False)
    # a run's health and its sample clocks' anchoring are in every bag, topics chosen or not
    assert rec.wanted("/diagnostics", (), False) and rec.wanted("/diagnostics", ("/a",), False)
    assert rec.wanted("/flaair/time_anchor", ("/a",), False)
    assert rec.wanted("/bench2/flaair/time_anchor", ("/a",), False, "/bench2")
    assert not rec.wanted("/bench1/flaair/time_anchor", ("/a",), False, "/bench2")

    def qos(reliability, durability):
        return Qos(
            QosHistory.KEEP_LAST,
            10,
            reliability,
            durability,
            QosTime(0, 0),
            QosTime(0, 0),
            QosLiveliness.AUTOMATIC,
            QosTime(0, 0),
            False,
        )

    reliable = qos(QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL)
    best_effort = qos(QosReliability.BEST_EFFORT, QosDurability.VOLATILE)
    assert rec.adapt_qos([reliable]) == rec.SubscriptionQos(True, True)
    assert rec.adapt_qos([reliable, best_effort]) == rec.SubscriptionQos(False, False)
    assert rec.adapt_qos([]) == rec.SubscriptionQos(True, False)
