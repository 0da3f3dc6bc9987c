"""Live view over real DDS and a real WebSocket:
per-sample messages at their signal times, wingbeats.
"""

from __future__ import annotations

import json
import socket
import sys

import numpy as np
import pytest

from flaair_analysis import wingbeat
from flaair_tools.liveview import live_view
from flaair_tools.liveview.foxglove_client import FoxgloveClient
from flaair_tools.liveview.foxglove_io import foxglove_node_args
from rosproc import REPO_ROOT, ros_processes, wait_for

FS, BLOCK, BLOCKS, START_S = 20000.0, 10, 400, 3.0
# Publishes CollisionStatus (colliding, 3 deg vs 1 deg) and ControllerState (K_r 0.25) first, then
# BLOCKS wing-state blocks (20 deg stroke / 30 deg pitch sine at 140 Hz) and as many sensor blocks,
# stamped from START_S, once the live view subscribes.
PUBLISHER = r"""
import sys, time
import numpy as np
import rclpy
from flaair_common import cdr
from flaair_common.qos import BLOCK_STREAM, EVENTS, STATUS
from flaair_msgs.msg import CollisionStatus, ControllerState, SensorVoltageBlock, WingStateBlock
from flaair_msgs.msg import HealthEvent, HealthStatus
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
fs, block, blocks, start_s = 20000.0, 10, int(sys.argv[1]), float(sys.argv[2])
rclpy.init()
node = rclpy.create_node("test_publisher")
wing = node.create_publisher(WingStateBlock, "/flaair/wing_state", BLOCK_STREAM)
sensor = node.create_publisher(SensorVoltageBlock, "/flaair/sensor_v", BLOCK_STREAM)
status = node.create_publisher(CollisionStatus, "/flaair/collision/status", STATUS)
controller = node.create_publisher(ControllerState, "/flaair/controller/state", BLOCK_STREAM)
diagnostics = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
health = node.create_publisher(HealthStatus, "/flaair/health", BLOCK_STREAM)
health_events = node.create_publisher(HealthEvent, "/flaair/health/events", EVENTS)
deadline = time.monotonic() + 60.0
readers = (wing, sensor, status, controller, diagnostics, health, health_events)
while time.monotonic() < deadline and min(p.get_subscription_count() for p in readers) == 0:
    time.sleep(0.05)
time.sleep(0.5)
message = CollisionStatus(wingbeat_index=7, colliding=True, spectrum_rmse_deg=3.0,
                          threshold_deg=1.0)
message.header.stamp.sec = 3
status.publish(message)
controller.publish(ControllerState(k_r=0.25))
diagnostics.publish(DiagnosticArray(status=[DiagnosticStatus(
    level=b"\x02", name="bridge_node: UDP bridge", message="target silent: no sensor packet",
    hardware_id="/bridge_node", values=[KeyValue(key="lost_packets", value="3")])]))
estimate = HealthStatus(wingbeat_index=12, sample_index=62400, wingbeat_frequency_hz=140.0,
                        valid=True, wing_inertia_ratio=0.8, wing_inertia_stderr=0.01,
                        stroke_film_gain_ratio=1.0, pitch_film_gain_ratio=1.01)
estimate.header.stamp.sec, estimate.header.stamp.nanosec = 3, 120_000_000
health.publish(estimate)
change = HealthEvent(parameter="wing_inertia", ratio=0.8, stderr=0.02, sample_index=62400,
                     time_s=3.12, wingbeat_index=12)
change.header.stamp.sec, change.header.stamp.nanosec = 3, 120_000_000
health_events.publish(change)
time.sleep(1.0)
wing_codec = cdr.FixedCodec(cdr.WING_STATE_BLOCK, block, "robot")
sensor_codec = cdr.FixedCodec(cdr.SENSOR_VOLTAGE_BLOCK, block, "robot")
for i in range(blocks):
    n = np.arange(i * block, (i + 1) * block)
    t = n / fs
    stamp_ns = int(round(start_s * 1e9)) + int(round(i * block / fs * 1e9))
    stroke = 20.0 * np.sin(2 * np.pi * 140.0 * t)
    head = {"sample_rate_hz": fs, "first_sample_index": int(n[0])}
    wing.publish(wing_codec.encode(stamp_ns, {
        **head, "stroke_deg": stroke, "pitch_deg": 30.0 * np.cos(2 * np.pi * 140.0 * t),
        "stroke_velocity_deg_s": n.astype(float), "stroke_valid": np.ones(block, bool),
        "pitch_valid": n // 10 != 100}))
    sensor.publish(sensor_codec.encode(stamp_ns, {
        **head, "stroke_sensor_v": 1.0 + n, "pitch_sensor_v": -1.0 - n}))
    time.sleep(0.001)
from rclpy.duration import Duration
for p in readers:   # every reader has them before this participant goes
    p.wait_for_all_acked(Duration(seconds=30))
print("published", flush=True)
"""


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.mark.graph
def test_websocket_client_gets_every_sample_at_its_signal_time_and_wingbeats() -> None:
    port = _free_port()
    topics = [
        live_view.STREAMS["wing_state"].topic,
        live_view.STREAMS["sensor_v"].topic,
        live_view.WINGBEAT_TOPIC,
        live_view.COLLISION_TOPIC,
        "/diagnostics",
        "/flaair/health",
        "/flaair/health/events",
    ]
    with ros_processes() as procs:
        node = procs.flaair(*foxglove_node_args(f"127.0.0.1:{port}"), "-p", "reliable:=true")
        client = None

        def connected() -> bool:
            nonlocal client
            try:
                client = FoxgloveClient(f"ws://127.0.0.1:{port}", open_timeout_s=2.0)
                return True
            except OSError:
                assert node.poll() is None, node.stderr.read()
                return False

        assert wait_for(connected, 60.0, interval_s=0.5)
        client.wait_for_channels(topics, timeout_s=30.0)
        assert client.channels[topics[0]]["encoding"] == "cdr"
        assert client.channels[topics[0]]["schemaEncoding"] == "ros2msg"
        client.subscribe(topics)
        publisher = procs.start(sys.executable, "-c", PUBLISHER, str(BLOCKS), str(START_S))
        expected = BLOCKS * BLOCK
        received = client.received
        while (
            len(received.messages[topics[0]]) < expected
            or len(received.messages[topics[1]]) < expected
        ):
            if not client.receive(timeout_s=30.0):
                break
        while client.receive(timeout_s=1.0):  # the last wingbeats and time broadcasts
            pass
        client.close()
        assert publisher.wait(timeout=60) == 0, publisher.stderr.read()
    sample_ns = int(START_S * 1e9) + np.round(np.arange(expected) * 1e9 / FS).astype(np.int64)
    # every sample one message, its log time and stamp its own signal time
    wing = received.messages[topics[0]]
    assert len(wing) == expected
    decoded = [
        live_view.decode_sample(live_view.STREAMS["wing_state"], payload) for _, payload in wing
    ]
    np.testing.assert_array_equal([t for t, _ in wing], sample_ns)
    np.testing.assert_array_equal([d["stamp_ns"] for d in decoded], sample_ns)
    np.testing.assert_array_equal(
        [d["stroke_velocity_deg_s"] for d in decoded], np.arange(expected)
    )
    np.testing.assert_array_equal(
        [d["pitch_valid"] for d in decoded], np.arange(expected) // 10 != 100
    )
    sensor = [
        live_view.decode_sample(live_view.STREAMS["sensor_v"], payload)
        for _, payload in received.messages[topics[1]]
    ]
    np.testing.assert_array_equal([d["stroke_sensor_v"] for d in sensor], 1.0 + np.arange(expected))
    np.testing.assert_array_equal([t for t, _ in received.messages[topics[1]]], sample_ns)
    # wingbeats: those of the same core over the whole
    # record, with the latest K_r and collision score
    n = np.arange(expected)
    stroke, pitch = (
        20.0 * np.sin(2 * np.pi * 140.0 * n / FS),
        30.0 * np.cos(2 * np.pi * 140.0 * n / FS),
    )
    truth = wingbeat.summarize(
        stroke, pitch, n // 10 != 100, wingbeat.WingbeatParams(FS, 2.0, 30.0, 400.0)
    )
    beats = [json.loads(p) for _, p in received.messages[live_view.WINGBEAT_TOPIC]]
    # upward crossings every 142.86 samples: 27 in 4000 samples, 26 wingbeats; the invalid block at
    # samples 1000-1009 hides the crossing at 1000 and spoils the wingbeats on both sides of it
    assert len(beats) == truth.end_sample.size == 24
    np.testing.assert_allclose([b["amplitude_deg"] for b in beats], truth.amplitude_deg, rtol=1e-12)
    np.testing.assert_allclose([b["amplitude_deg"] for b in beats], 20.0, rtol=1e-3)
    np.testing.assert_allclose([b["pitch_amplitude_deg"] for b in beats], 30.0, rtol=1e-3)
    np.testing.assert_allclose([b["frequency_hz"] for b in beats], 140.0, rtol=1e-5)
    assert all(
        b["k_r"] == 0.25 and b["collision_score"] == 3.0 and b["colliding"] is True for b in beats
    )
    end_ns = [t for t, _ in received.messages[live_view.WINGBEAT_TOPIC]]
    np.testing.assert_allclose(end_ns, START_S * 1e9 + truth.end_sample * 1e9 / FS, atol=1.0)
    status = [json.loads(p) for _, p in received.messages[live_view.COLLISION_TOPIC]]
    assert status == [
        {
            "stamp": {"sec": 3, "nsec": 0},
            "wingbeat_index": 7,
            "colliding": True,
            "spectrum_rmse_deg": 3.0,
            "threshold_deg": 1.0,
            "collision_score": 3.0,
        }
    ]
    assert received.messages[live_view.COLLISION_TOPIC][0][0] == 3_000_000_000
    # every node's health, as ROS's DiagnosticArray in JSON (Foxglove's Diagnostics panels)
    ((_, health),) = received.messages["/diagnostics"]
    assert json.loads(health)["status"] == [
        {
            "level": 2,
            "name": "bridge_node: UDP bridge",
            "message": "target silent: no sensor packet",
            "hardware_id": "/bridge_node",
            "values": [{"key": "lost_packets", "value": "3"}],
        }
    ]
    # the health monitor's estimates and events as they are (CDR, their ros2msg definitions),
    # at their header stamps
    from flaair_tools.bagio.messages import typestore

    for topic, msgtype in live_view.RELAYED.items():
        channel = client.channels[topic]
        assert (channel["encoding"], channel["schemaName"], channel["schemaEncoding"]) == (
            "cdr",
            msgtype,
            "ros2msg",
        )
    ((log_ns, data),) = received.messages["/flaair/health"]
    estimate = typestore().deserialize_cdr(data, "flaair_msgs/msg/HealthStatus")
    assert log_ns == 3_120_000_000 and estimate.wingbeat_index == 12
    assert (estimate.wing_inertia_ratio, estimate.pitch_film_gain_ratio) == (0.8, 1.01)
    ((log_ns, data),) = received.messages["/flaair/health/events"]
    change = typestore().deserialize_cdr(data, "flaair_msgs/msg/HealthEvent")
    assert log_ns == 3_120_000_000
    assert (change.parameter, change.ratio, change.time_s) == ("wing_inertia", 0.8, 3.12)
    # the server told the client the latest signal time
    assert received.times_ns and max(received.times_ns) == sample_ns[-1] + int(1e9 / FS)


def _msg_fields(msgtype: str) -> set[str]:
    """The field names of a flaair_msgs message, read from its .msg file."""
    path = REPO_ROOT / "src" / "flaair_msgs" / "msg" / f"{msgtype.rsplit('/', 1)[1]}.msg"
    lines = (line.split("#", 1)[0].split() for line in path.read_text().splitlines())
    return {words[1] for words in lines if len(words) >= 2 and "=" not in words[1]}


@pytest.mark.timeout(60)
def test_the_shipped_layout_plots_fields_the_live_view_serves() -> None:
    """config/foxglove_layout.json is the layout live_view builds, valid JSON; every plotted path
    is TOPIC.FIELD of a channel the live view serves and a field its messages have (the health
    panel's in the HealthStatus / HealthEvent definitions).
    """
    shipped = (REPO_ROOT / "config" / "foxglove_layout.json").read_text()
    assert shipped == live_view.layout_json()
    layout = json.loads(shipped)

    def panels(node):
        if isinstance(node, dict):
            if node.get("type") == "panel":
                yield node
            for value in node.values():
                yield from panels(value)
        elif isinstance(node, list):
            for value in node:
                yield from panels(value)

    fields = {stream.topic: {n for n, _ in stream.fields} for stream in live_view.STREAMS.values()}
    fields[live_view.WINGBEAT_TOPIC] = set(live_view.WINGBEAT_SCHEMA["properties"])
    fields[live_view.COLLISION_TOPIC] = set(live_view.COLLISION_SCHEMA["properties"])
    fields.update({topic: _msg_fields(kind) for topic, kind in live_view.RELAYED.items()})
    served = live_view.served_topics()
    assert {"/flaair/health", "/flaair/health/events"} <= set(served)
    plotted = [
        series["value"]
        for panel in panels(layout)
        if panel["panelType"] in ("Plot", "StateTransitions")
        for series in panel["config"]["paths"]
    ]
    for path in plotted:
        topic, _, field = path.rpartition(".")
        assert topic in served and field in fields[topic], path
    health = {p for p in plotted if p.startswith("/flaair/health")}
    assert health == {
        "/flaair/health.wing_inertia_ratio",
        "/flaair/health.stroke_film_gain_ratio",
        "/flaair/health.pitch_film_gain_ratio",
        "/flaair/health/events.ratio",
    }
    raw = {
        panel["config"]["topicPath"] for panel in panels(layout) if "topicPath" in panel["config"]
    }
    assert raw == {live_view.WINGBEAT_TOPIC, "/flaair/health/events"}


def _wing_blocks(firsts: list[int], block: int = BLOCK, frame: str = "robot") -> list[bytes]:
    from flaair_common import cdr

    codec = cdr.FixedCodec(cdr.WING_STATE_BLOCK, block, frame)
    out = []
    for first in firsts:
        n = np.arange(first, first + block)
        out.append(
            codec.encode(
                int(3e9) + round(first * 1e9 / FS),
                {
                    "sample_rate_hz": FS,
                    "first_sample_index": first,
                    "stroke_deg": 20.0 * np.sin(2 * np.pi * 140.0 * n / FS),
                    "pitch_deg": 30.0 * np.cos(2 * np.pi * 140.0 * n / FS),
                    "stroke_velocity_deg_s": n * 1.0,
                    "stroke_valid": np.ones(block, bool),
                    "pitch_valid": n // 10 != 100,
                },
            )
        )
    return out


@pytest.mark.parametrize("decimation", [1, 3, 10])
def test_a_batch_of_blocks_is_served_exactly_as_block_by_block(decimation: int) -> None:
    """One numpy pass over many blocks (with a gap, another block size, a bad message) gives the
    same messages at the same times as serving each block alone; bad bytes are counted, not served.
    """
    from flaair_common import cdr

    stream = live_view.STREAMS["wing_state"]
    datas = (
        _wing_blocks([0, 10, 20, 50, 60])
        + _wing_blocks([70], block=7)
        + [b"\x00\x01\x00\x00garbage"]
    )
    batches, bad = live_view.fixed_blocks(cdr.WING_STATE_BLOCK, datas, {})
    assert bad == 1 and [len(b) for b in batches] == [5, 1]
    times, payloads = [], []
    for blocks in batches:
        t, p = live_view.blocks_samples(stream, blocks, decimation)
        times, payloads = times + t, payloads + p
    want_t, want_p = [], []
    for data in datas[:-1]:
        message = cdr.decode(cdr.WING_STATE_BLOCK, data)
        t, p = live_view.block_samples(stream, message, cdr.stamp_ns(message), decimation)
        want_t, want_p = want_t + t, want_p + p
    assert times == want_t and payloads == want_p
    assert len(times) == len([i for i in (*range(30), *range(50, 77)) if i % decimation == 0])
    assert live_view.blocks_end_ns(batches[0], "stroke_deg") == int(3e9) + round(70 * 1e9 / FS)
    assert live_view.contiguous_runs(batches[0], "stroke_deg") == [slice(0, 3), slice(3, 5)]


def test_wingbeats_of_a_batch_are_those_of_block_by_block() -> None:
    from flaair_common import cdr

    params = wingbeat.WingbeatParams(FS, 2.0, 30.0, 400.0)
    # a gap at 3000-3500
    datas = _wing_blocks(list(range(0, 3000, BLOCK)) + list(range(3500, 6000, BLOCK)))
    (blocks,), _ = live_view.fixed_blocks(cdr.WING_STATE_BLOCK, datas, {})
    state, batched = wingbeat.initial_state(params), []
    for start in range(0, len(blocks), 20):  # batches of 20 blocks, as the node serves them
        state, beats = live_view.wingbeat_batch(
            state, blocks[start : start + 20], len(batched), 2.0, 0.5, True, params
        )
        batched += beats
    state, alone = wingbeat.initial_state(params), []
    for data in datas:
        message = cdr.decode(cdr.WING_STATE_BLOCK, data)
        valid = np.logical_and(message["stroke_valid"], message["pitch_valid"])
        state, beats = wingbeat.step(
            state,
            wingbeat.WingbeatInputs(
                message["first_sample_index"],
                message["stroke_deg"],
                message["pitch_deg"],
                valid,
                2.0,
                0.5,
            ),
            params,
        )
        alone += live_view.wingbeat_messages(
            beats, len(alone), cdr.stamp_ns(message), message["first_sample_index"], FS, True
        )
    assert len(batched) > 30 and batched == alone
