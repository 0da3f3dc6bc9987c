"""Bags on the signal's clock: 3 s of simulated signal
span 3 s of log time, read with the mcap library.
"""

from __future__ import annotations

import signal
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from flaair_tools import bagio
from rosproc import ros_processes, wait_for

pytestmark = pytest.mark.graph  # ROS 2 processes exchanging data in real time: run after the others

FS, BLOCK, RUN_S = 20000.0, 10, 3.0
# A simulated robot's streams as the plant stamps them (block i at i * 0.5 ms of signal time, /clock
# with it, a collision status at 1.5 s), sent as fast as DDS takes them, so the wall-clock span
# differs from the signal's; a header-less run marker goes out before the first sample.
PUBLISHER = r"""
import sys, time
import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String
from flaair_common import cdr
from flaair_common.qos import BLOCK_STREAM, EVENTS, STATUS
from flaair_msgs.msg import CollisionStatus, SensorVoltageBlock, WingStateBlock
fs, block, run_s = 20000.0, 10, float(sys.argv[1])
rclpy.init()
node = rclpy.create_node("signal_source")
sensor = node.create_publisher(SensorVoltageBlock, "/flaair/sensor_v", BLOCK_STREAM)
truth = node.create_publisher(WingStateBlock, "/flaair/wing_state/truth", BLOCK_STREAM)
clock = node.create_publisher(Clock, "/clock", BLOCK_STREAM)  # as deep as the data: a starved
# recorder must lose none, and a 1000-deep writer history had overwritten 30 unacknowledged
status = node.create_publisher(CollisionStatus, "/flaair/collision/status", STATUS)
marker = node.create_publisher(String, "/flaair/run_marker", EVENTS)
deadline = time.monotonic() + 120.0
readers = (sensor, truth, clock, status, marker)
while time.monotonic() < deadline and min(p.get_subscription_count() for p in readers) == 0:
    time.sleep(0.05)
time.sleep(1.0)
marker.publish(String(data="run 1"))
time.sleep(0.5)
sensor_codec = cdr.FixedCodec(cdr.SENSOR_VOLTAGE_BLOCK, block, "robot")
truth_codec = cdr.FixedCodec(cdr.WING_STATE_BLOCK, block, "robot")
for i in range(int(run_s * fs / block)):
    stamp_ns = int(round(i * block / fs * 1e9))
    values = {"sample_rate_hz": fs, "first_sample_index": i * block}
    sensor.publish(sensor_codec.encode(stamp_ns,
                                       {**values, "stroke_sensor_v": np.full(block, 1.0 * i)}))
    truth.publish(truth_codec.encode(stamp_ns, {**values, "stroke_deg": np.full(block, 1.0 * i)}))
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    clock.publish(Clock(clock=Time(sec=sec, nanosec=nanosec)))
    if i == 3000:
        message = CollisionStatus(wingbeat_index=1)
        message.header.stamp = Time(sec=sec, nanosec=nanosec)
        status.publish(message)
    if i % 200 == 0:
        time.sleep(0.02)  # a few pauses: the recorder drains its queues meanwhile
from rclpy.duration import Duration
# every reader has them before this participant goes
for p in readers:
    p.wait_for_all_acked(Duration(seconds=30))
print("published", flush=True)
"""


def test_three_seconds_of_simulated_signal_span_three_seconds_of_log_time(tmp_path: Path) -> None:
    bag = tmp_path / "signal_clock"
    n_blocks = int(RUN_S * FS / BLOCK)
    with ros_processes() as procs:
        recorder = procs.flaair("record", "-o", str(bag), "--clock")
        assert wait_for(lambda: (bag / f"{bag.name}_0.mcap").exists(), 120.0)
        source = procs.start(sys.executable, "-c", PUBLISHER, str(RUN_S))
        assert source.wait(timeout=300) == 0, source.stderr.read()
        assert procs.stop(recorder, signal.SIGINT, timeout_s=60) == 0
    # an independent reader: the mcap library, ROS 2 messages decoded by mcap_ros2
    (mcap_file,) = bag.glob("*.mcap")
    log_ns: dict[str, list[int]] = {}
    stamp_ns: dict[str, list[int]] = {}
    publish_ns: list[int] = []
    with open(mcap_file, "rb") as handle:
        for _, channel, message, decoded in make_reader(
            handle, decoder_factories=[DecoderFactory()]
        ).iter_decoded_messages():
            log_ns.setdefault(channel.topic, []).append(message.log_time)
            if channel.topic == "/clock":
                stamp_ns.setdefault("/clock", []).append(
                    decoded.clock.sec * 10**9 + decoded.clock.nanosec
                )
            elif hasattr(decoded, "header"):
                stamp_ns.setdefault(channel.topic, []).append(
                    decoded.header.stamp.sec * 10**9 + decoded.header.stamp.nanosec
                )
            if channel.topic == "/flaair/sensor_v":
                publish_ns.append(message.publish_time)
    for topic in ("/flaair/sensor_v", "/flaair/wing_state/truth"):
        times = np.array(log_ns[topic])
        # every block, its log time its first sample's signal time: 0, 0.5 ms, ... 3 s - 0.5 ms
        assert log_ns[topic] == stamp_ns[topic], topic
        np.testing.assert_array_equal(times, np.round(np.arange(n_blocks) * BLOCK / FS * 1e9))
        # 3 s of signal (+ the last block), 3 s of log time
        assert times[-1] - times[0] + 500_000 == 3_000_000_000
    assert log_ns["/clock"] == stamp_ns["/clock"] and len(log_ns["/clock"]) == n_blocks
    assert log_ns["/flaair/collision/status"] == [1_500_000_000]
    # the run marker, published before the first sample, sits at the first signal time
    assert log_ns[bagio.RUN_MARKER_TOPIC] == [0]
    # the send times (wall clock) are kept as MCAP publish times, apart from the log times
    assert min(publish_ns) > 1_000_000_000 * 10**9
