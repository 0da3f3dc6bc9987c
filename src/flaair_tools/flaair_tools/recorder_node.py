"""recorder_node: record FLAAIR topics into a rosbag2 (MCAP) bag, like `ros2 bag record`.

Subscribes to every /flaair topic (or the `topics` chosen) as raw serialized messages, looks
for new topics every `discovery_period_s`, and writes each message straight into the bag
without deserializing it, at its signal time (the leading header's stamp, the
/clock value, or for a header-less run marker the latest stamp: flaair_tools.recording
decides), so `play`, PlotJuggler and Foxglove show the signal's own timeline.
Subscriptions match what the publishers offer (reliable / transient-local only if every
publisher offers it); the offered QoS profiles are recorded with each topic, as rosbag2 does.

Throughput: each callback also drains the messages already queued on its subscription
(recording.drain); the subscription queue is `queue_depth` deep, slack for CPU starvation.

Durability: chunks are closed and handed to the OS when they reach `chunk_size_bytes` or
every `flush_period_s`, so after a kill -9 everything older than that stays readable
(`bin/flaair bag reindex BAG` restores the summary and metadata.yaml). SIGINT / SIGTERM close
the bag completely.

Usage:
  bin/flaair record [-o BAG] [--topics /flaair/sensor_v ...] [--clock] [--no-compression] [--use-sim-time]
  bin/flaair run flaair_tools recorder_node --ros-args -p output_path:=out/bags/run1
"""
from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from flaair_common.msgdict import message_class
from flaair_common.params import ParameterError, declare_parameters
from flaair_common.runtime import run_node
from flaair_tools import bagio, recording
from flaair_tools.recorder_io import CONFIG_FILE, NODE_NAME, RECORDER_PARAMS, RECORDING, cli_to_ros_args

PARAMS = RECORDER_PARAMS


class RecorderNode(Node):
    """Raw subscriptions -> flaair_tools.recording (log times) -> bagio.BagWriter."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.p = declare_parameters(self, PARAMS, CONFIG_FILE)
        self.chosen = recording.parse_topic_list(self.p["topics"])
        self.log_time = recording.LogTimeState()
        self.store = bagio.typestore()
        path = Path(self.p["output_path"]) if self.p["output_path"] else recording.default_output_path(time.time())
        try:
            self.writer = bagio.BagWriter(path, compression=self.p["compression"],
                                          chunk_size_bytes=self.p["chunk_size_bytes"], store=self.store)
        except bagio.BagError as exc:
            raise ParameterError(f"parameter 'output_path': {exc}") from exc
        self.subscribed: dict[str, Any] = {}
        self.skipped: set[str] = set()
        self.received: dict[str, int] = {}
        # Wall-clock (steady) timers: with use_sim_time a ROS-time timer would stop while /clock does.
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(self.p["discovery_period_s"], self.discover, clock=steady)
        self.create_timer(self.p["flush_period_s"], self.writer.flush, clock=steady)
        self.discover()
        what = ", ".join(self.chosen) if self.chosen else f"every {recording.NAMESPACE}* topic"
        self.get_logger().info(f"recording {what} to {self.writer.path}")

    def discover(self) -> None:
        """Subscribe to every wanted topic not subscribed yet."""
        for topic, types in self.get_topic_names_and_types():
            if topic in self.subscribed or topic in self.skipped:
                continue
            if not recording.wanted(topic, self.chosen, self.p["record_clock"]):
                continue
            if len(types) != 1:
                self.skip(topic, f"published with several types ({', '.join(types)})")
                continue
            msgtype = types[0]
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                # Seen through a subscriber only: wait for a publisher, whose QoS decides ours
                # and is recorded with the topic (the next discovery round picks it up).
                continue
            try:
                cls = message_class(msgtype)
                offered = [bagio.qos_from_rclpy(info.qos_profile) for info in publishers]
                self.writer.add_topic(topic, msgtype, offered)
            except (ValueError, bagio.BagError) as exc:
                self.skip(topic, str(exc))
                continue
            qos = recording.adapt_qos(offered)
            profile = QoSProfile(
                history=HistoryPolicy.KEEP_LAST, depth=self.p["queue_depth"],
                reliability=ReliabilityPolicy.RELIABLE if qos.reliable else ReliabilityPolicy.BEST_EFFORT,
                durability=DurabilityPolicy.TRANSIENT_LOCAL if qos.transient_local else DurabilityPolicy.VOLATILE,
            )
            stamped = bagio.has_leading_stamp(msgtype, self.store)
            self.received[topic] = 0
            self.subscribed[topic] = self.create_subscription(
                cls, topic, self.make_callback(topic, stamped, cls), profile, raw=True)
            self.get_logger().info(f"subscribed to {topic} [{msgtype}]")

    def skip(self, topic: str, reason: str) -> None:
        self.skipped.add(topic)
        self.get_logger().warning(f"not recording {topic}: {reason}")

    def apply(self, inputs: recording.Received | recording.Finish) -> None:
        self.log_time, writes = recording.step(self.log_time, inputs, RECORDING)
        for w in writes:
            self.writer.write(w.topic, w.log_ns, w.data, w.publish_ns)

    def make_callback(self, topic: str, stamped: bool, cls: type):
        """Callback writing the raw message of `topic`, then those queued behind it (recording.drain)."""
        def take() -> Any:
            handle = self.subscribed[topic].handle
            with handle:
                return handle.take_message(cls, True)

        def on_message(data: bytes, info: dict) -> None:
            queued = recording.drain(take, RECORDING)
            for data, info in [(data, info), *queued]:
                stamp = bagio.leading_stamp_ns(data) if stamped else None
                self.apply(recording.Received(topic, data, stamp, info.get("source_timestamp") or None))
            self.received[topic] += 1 + len(queued)

        return on_message

    def close(self) -> None:
        """Finish the bag (summary, metadata.yaml)."""
        if self.writer.closed:
            return
        self.apply(recording.Finish(time.time_ns()))
        self.writer.close()
        counts = ", ".join(f"{topic} {count}" for topic, count in sorted(self.writer.counts.items())) or "nothing"
        self.get_logger().info(f"closed {self.writer.path}: {counts}")


def main(argv: list[str] | None = None) -> int:
    """Console script (ROS arguments) or `bin/flaair record` (friendly options, argv given)."""
    if argv is None:
        return run_node(RecorderNode, PARAMS, CONFIG_FILE, NODE_NAME, executor_kind="single")
    args = cli_to_ros_args(argv, __doc__)
    sys.argv[0] = args[0]  # errors read "flaair record: ...", not "cli.py: ..."
    return run_node(RecorderNode, PARAMS, CONFIG_FILE, NODE_NAME, args, executor_kind="single")


if __name__ == "__main__":
    sys.exit(main())
