"""Recorder and player over real DDS: exact counts, clean SIGINT, kill -9 survivable, replay."""

from __future__ import annotations

import json
import os
import re
import signal
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.exceptions import EndOfFile
from mcap.reader import NonSeekingReader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag2 import Reader

from flaair_common.qos import BLOCK_STREAM, EVENTS
from flaair_tools import bagio
from rosproc import FLAAIR, ros_processes, run, wait_for

# Publishes `blocks` SensorVoltageBlocks (index i*10, values from i) on /flaair/sensor_v, `events`
# CollisionEvents (transient local) on /flaair/collision/events and as many Strings on
# /other/chatter (outside /flaair: must not be recorded), once the recorder(s) subscribed.
PUBLISHER = r"""
import json, sys, time
import numpy as np
import rclpy
from flaair_common.blocks import from_array
from flaair_common.qos import BLOCK_STREAM, EVENTS
from flaair_msgs.msg import CollisionEvent, SensorVoltageBlock
from std_msgs.msg import String
cfg = json.loads(sys.argv[1])
rclpy.init()
node = rclpy.create_node("test_publisher")
blocks = node.create_publisher(SensorVoltageBlock, "/flaair/sensor_v", BLOCK_STREAM)
events = node.create_publisher(CollisionEvent, "/flaair/collision/events", EVENTS)
other = node.create_publisher(String, "/other/chatter", BLOCK_STREAM)
deadline = time.monotonic() + 30.0
while time.monotonic() < deadline and (
        blocks.get_subscription_count() < cfg.get("block_subscribers", 1)
        or events.get_subscription_count() == 0):
    time.sleep(0.02)
next_t = time.monotonic()
for i in range(cfg["blocks"]):
    message = SensorVoltageBlock(sample_rate_hz=20000.0, first_sample_index=10 * i)
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(i * 500_000, 1_000_000_000)
    message.stroke_sensor_v = from_array(i + 0.1 * np.arange(10))
    message.pitch_sensor_v = from_array(-i - 0.1 * np.arange(10))
    blocks.publish(message)
    if i < cfg["events"]:
        events.publish(CollisionEvent(kind=1, wingbeat_index=i, spectrum_rmse_deg=0.5 * i))
        other.publish(String(data=str(i)))
    next_t += 1.0 / cfg["rate"]
    delay = next_t - time.monotonic()
    if delay > 0:
        time.sleep(delay)
from rclpy.duration import Duration
for publisher in (blocks, events, other):   # every reader has them before this participant goes
    publisher.wait_for_all_acked(Duration(seconds=30))
print("published", flush=True)
"""


def _publisher(procs, **cfg):
    return procs.start(sys.executable, "-c", PUBLISHER, json.dumps(cfg))


def _check_blocks_exact(blocks: bagio.Blocks, n: int) -> None:
    i = np.repeat(np.arange(n), 10)
    assert np.array_equal(blocks.sample_index, np.arange(10 * n))
    assert np.array_equal(blocks["stroke_sensor_v"], i + 0.1 * np.tile(np.arange(10), n))
    assert np.array_equal(blocks["pitch_sensor_v"], -i - 0.1 * np.tile(np.arange(10), n))


@pytest.mark.graph
def test_counts_in_bag_equal_counts_published_and_sigint_closes(tmp_path: Path) -> None:
    bag, sim_bag = tmp_path / "rec", tmp_path / "sim"
    with ros_processes() as procs:
        recorder = procs.flaair("record", "-o", str(bag))
        sim_recorder = procs.flaair(
            "record", "-o", str(sim_bag), "--topics", "/flaair/sensor_v", "--use-sim-time"
        )
        # publish only after both recorders are up: topics must be found by periodic discovery
        # (with use_sim_time and no /clock, a ROS-time discovery timer would never fire)
        assert wait_for(
            lambda: all((b / f"{b.name}_0.mcap").exists() for b in (bag, sim_bag)), 60.0
        )
        publisher = _publisher(procs, blocks=600, events=40, rate=2000.0, block_subscribers=2)
        assert publisher.wait(timeout=60) == 0, publisher.stderr.read()
        assert procs.stop(recorder, signal.SIGINT) == 0
        assert procs.stop(sim_recorder, signal.SIGTERM) == 0
        log = recorder.stderr.read()
    assert "closed" in log, log
    # SIGTERM closes too; --topics chose one topic; with
    # use_sim_time the log time is the header stamp
    assert bagio.message_counts(sim_bag) == {"/flaair/sensor_v": 600}
    stamps = [t for _, _, t, _ in bagio.iter_raw(sim_bag)]
    assert stamps == [i * 500_000 for i in range(600)]
    assert (bag / "metadata.yaml").exists()
    assert bagio.message_counts(bag) == {"/flaair/sensor_v": 600, "/flaair/collision/events": 40}
    info = bagio.bag_info(bag)
    assert {t: i.count for t, i in info.topics.items()} == {
        "/flaair/sensor_v": 600,
        "/flaair/collision/events": 40,
    }
    assert (
        info.topics["/flaair/collision/events"].offered_qos[0].durability
        == bagio.QosDurability.TRANSIENT_LOCAL
    )
    # history and depth do not travel in DDS discovery: recorded as unknown / 0, as rosbag2 does
    assert (
        info.topics["/flaair/sensor_v"].offered_qos[0].reliability == bagio.QosReliability.RELIABLE
    )
    _check_blocks_exact(bagio.read_blocks(bag, "/flaair/sensor_v"), 600)
    events = [m for _, _, m in bagio.iter_messages(bag, ["/flaair/collision/events"])]
    assert [e.wingbeat_index for e in events] == list(range(40))


@pytest.mark.graph
def test_sigkill_leaves_flushed_chunks_readable(tmp_path: Path) -> None:
    bag = tmp_path / "killed"
    with ros_processes() as procs:
        recorder = procs.flaair("record", "-o", str(bag), "--ros-args", "-p", "flush_period_s:=0.2")
        _publisher(procs, blocks=8000, events=0, rate=2000.0)
        mcap_file = bag / f"{bag.name}_0.mcap"
        assert wait_for(lambda: mcap_file.exists() and mcap_file.stat().st_size > 60_000, 60.0)
        os.killpg(recorder.pid, signal.SIGKILL)
        recorder.wait(timeout=10)
    assert not (bag / "metadata.yaml").exists()
    with pytest.raises(bagio.BagUnfinishedError, match="bin/flaair bag reindex"):
        bagio.read_blocks(bag, "/flaair/sensor_v")

    # the mcap library's non-summary reader decodes every flushed message, then meets the cut
    indices = []
    with open(mcap_file, "rb") as stream:
        reader = NonSeekingReader(stream, decoder_factories=[DecoderFactory()])
        with pytest.raises(EndOfFile):
            for _, channel, _, decoded in reader.iter_decoded_messages(log_time_order=False):
                assert channel.topic == "/flaair/sensor_v"
                indices.append(decoded.first_sample_index)
    assert len(indices) > 100 and indices == list(range(0, 10 * len(indices), 10))

    result = run([FLAAIR, "bag", "reindex", str(bag)], procs.env)
    assert result.returncode == 0, result.stderr
    with Reader(bag) as reader:  # rosbags, through the rebuilt summary and metadata.yaml
        assert reader.message_count == len(indices)
    _check_blocks_exact(bagio.read_blocks(bag, "/flaair/sensor_v"), len(indices))


@pytest.mark.graph
def test_player_replays_a_bag_at_rate_with_clock(tmp_path: Path) -> None:
    source = tmp_path / "source"
    store = bagio.typestore()
    n, period_ns, rate = 200, 5_000_000, 2.0  # 1 s of bag time, played in 0.5 s
    with bagio.BagWriter(source, store=store) as writer:
        for i in range(n):
            stamp_ns = 10_000_000_000 + i * period_ns
            message = bagio.new_message(
                "flaair_msgs/msg/SensorVoltageBlock",
                store,
                header=bagio.new_message(
                    "std_msgs/msg/Header", store, stamp=bagio.time_msg(stamp_ns, store)
                ),
                sample_rate_hz=20000.0,
                first_sample_index=10 * i,
                stroke_sensor_v=i + 0.1 * np.arange(10),
                pitch_sensor_v=-i - 0.1 * np.arange(10),
            )
            writer.write_message(
                "/flaair/sensor_v", stamp_ns, message, [bagio.qos_from_rclpy(BLOCK_STREAM)]
            )
            if i % 50 == 0:
                marker = bagio.new_message("std_msgs/msg/String", store, data=f"run {i}")
                writer.write_message(
                    bagio.RUN_MARKER_TOPIC, stamp_ns, marker, [bagio.qos_from_rclpy(EVENTS)]
                )
    replay = tmp_path / "replay"
    with ros_processes() as procs:
        recorder = procs.flaair("record", "-o", str(replay), "--clock")
        player = procs.flaair(
            "play", str(source), "--rate", str(rate), "--clock", "--wait-subscribers"
        )
        assert player.wait(timeout=60) == 0, player.stderr.read()
        player_log = player.stderr.read()
        assert procs.stop(recorder, signal.SIGINT) == 0
    counts = bagio.message_counts(replay)
    assert counts["/flaair/sensor_v"] == n and counts[bagio.RUN_MARKER_TOPIC] == 4
    assert counts["/clock"] >= n  # one /clock per distinct bag time
    original = [data for _, _, _, data in bagio.iter_raw(source, ["/flaair/sensor_v"])]
    replayed = [data for _, _, _, data in bagio.iter_raw(replay, ["/flaair/sensor_v"])]
    assert replayed == original  # the same bytes, in the same order
    # Paced: the player never sends a message before it is due, so the play lasts at least the
    # bag's span / rate however loaded the machine (unpaced it takes milliseconds). How close to
    # the schedule it stays is a speed figure: bench/bench_recorder.py.
    played_s = float(re.search(r"played 204 messages from \S+ in ([0-9.]+) s", player_log).group(1))
    assert played_s >= (n - 1) * period_ns * 1e-9 / rate, player_log
    clocks = [
        m.clock.sec * 1_000_000_000 + m.clock.nanosec
        for _, _, m in bagio.iter_messages(replay, ["/clock"])
    ]
    assert clocks[0] == 10_000_000_000 and clocks[-1] == 10_000_000_000 + (n - 1) * period_ns
