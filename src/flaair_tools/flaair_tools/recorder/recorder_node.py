"""recorder_node: record FLAAIR topics into a rosbag2 (MCAP) bag, like `ros2 bag record`.

What it records, when, and how it survives a kill: flaair_tools.recorder.recorder_io.RECORDER_HELP
(also the --help of `bin/flaair record`).
"""

from __future__ import annotations

import sys
import time
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from flaair_common import cdr, intra
from flaair_common.params import declare_parameters
from flaair_common.qos import BLOCK_STREAM
from flaair_common.runtime import run_node
from flaair_tools import bagio
from flaair_tools.recorder import recorder_io as rio
from flaair_tools.recorder import recording


class RecorderNode(Node):
    """Raw subscriptions -> flaair_tools.recorder.recording (log times) -> bagio.BagWriter."""

    def __init__(self) -> None:
        super().__init__(rio.NODE_NAME)
        self.p = declare_parameters(self, rio.RECORDER_PARAMS, rio.CONFIG_FILE)
        self.chosen = recording.parse_topic_list(self.p["topics"])
        self.log_time = recording.LogTimeState()
        self.store = bagio.typestore()
        self.writer = rio.open_writer(self.p, self.store)
        self.subscribed: dict[str, Any] = {}
        self.takers: dict[str, tuple] = {}  # topic -> (take, on_message) of its DDS subscription
        self.skipped, self.received = set(), {}
        # composed (an EventsExecutor): no take() in a callback; the block streams come in-process
        self.recording = rio.recording_settings(composed=intra.current() is not None)
        # wall-clock (steady) timers: with use_sim_time, a ROS-time timer stops when /clock does
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        bus = intra.current()
        for topic, msgtype in rio.in_process_streams(bus, self.chosen, self.p["record_clock"]):
            self.record_in_process(bus, topic, msgtype)
        self.create_timer(self.p["discovery_period_s"], self.discover, clock=steady)
        self.create_timer(self.p["flush_period_s"], self.writer.flush, clock=steady)
        self.discover()
        what = ", ".join(self.chosen) or f"every {recording.NAMESPACE}* topic"
        self.get_logger().info(f"recording {what} to {self.writer.path}")

    def discover(self) -> None:
        """Subscribe to every wanted topic not subscribed yet."""
        for topic, types in self.get_topic_names_and_types():
            known = topic in self.subscribed or topic in self.skipped
            ns, record_clock = self.get_namespace(), self.p["record_clock"]
            if known or not recording.wanted(topic, self.chosen, record_clock, ns):
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            try:
                found = rio.topic_to_record(
                    topic, types, publishers, self.writer, self.p["queue_depth"]
                )
            except rio.SkipTopic as exc:
                self.skip(topic, str(exc))
                continue
            if found is None:  # seen through a subscriber only: the next round, with a publisher
                continue
            msgtype, cls, profile = found
            self.received[topic], stamped = 0, bagio.has_leading_stamp(msgtype, self.store)
            self.subscribed[topic] = self.create_subscription(
                cls, topic, self.make_callback(topic, stamped, cls), profile, raw=True
            )
            self.get_logger().info(f"subscribed to {topic} [{msgtype}]")

    def record_in_process(self, bus: intra.Bus, topic: str, msgtype: str) -> None:
        """Record `topic` from the composed nodes' bus (each block encoded as its DDS message)."""
        layout = cdr.layout_of(msgtype)
        self.writer.add_topic(topic, msgtype, [bagio.qos_from_rclpy(BLOCK_STREAM)])
        # None: not for discover()
        self.received[topic], self.subscribed[topic], codecs = 0, None, {}

        def on_block(fields: dict) -> None:
            stamp_ns, data = cdr.encode_fields(layout, fields, codecs)
            self.apply(recording.Received(topic, data, stamp_ns, None))
            self.received[topic] += 1

        bus.subscribe(topic, on_block, background=True, join=False)
        self.get_logger().info(f"recording {topic} [{msgtype}] in-process")

    def skip(self, topic: str, reason: str) -> None:
        self.skipped.add(topic)
        self.get_logger().warning(f"not recording {topic}: {reason}")

    def apply(self, inputs: recording.Received | recording.Finish) -> None:
        self.log_time, writes = recording.step(self.log_time, inputs, self.recording)
        for w in writes:
            self.writer.write(w.topic, w.log_ns, w.data, w.publish_ns)

    def make_callback(self, topic: str, stamped: bool, cls: type):
        """Callback writing `topic`'s raw message, then those queued behind it (recording.drain)."""

        def take() -> Any:
            handle = self.subscribed[topic].handle
            with handle:
                return handle.take_message(cls, True)

        def on_message(data: bytes, info: dict) -> None:
            queued = recording.drain(take, self.recording)
            for raw, meta in [(data, info), *queued]:
                stamp = bagio.leading_stamp_ns(raw) if stamped else None
                sent = meta.get("source_timestamp") or None
                self.apply(recording.Received(topic, raw, stamp, sent))
            self.received[topic] += 1 + len(queued)

        self.takers[topic] = (take, on_message)

        # rclpy's EventsExecutor (composed) cannot hand a callback the message info
        return on_message if intra.current() is None else (lambda data: on_message(data, {}))

    def take_remaining(self) -> int:
        """Write what DDS has delivered but no callback has handled yet (a stop came first: the
        loop's last blocks, its zero drive, are often among them). Returns how many.
        """
        return rio.take_all(self.takers, self.get_logger().warning)

    def close(self) -> None:
        """Finish the bag (summary, metadata.yaml), with every message DDS had delivered."""
        if self.writer.closed:
            return
        self.take_remaining()
        self.apply(recording.Finish(time.time_ns()))
        self.writer.close()
        self.get_logger().info(rio.closed_text(self.writer.path, self.writer.counts))


def main(argv: list[str] | None = None) -> int:
    """Console script (ROS arguments) or `bin/flaair record` (friendly options, argv given)."""
    args = None if argv is None else rio.cli_to_ros_args(argv, rio.RECORDER_HELP)
    if args is not None:
        sys.argv[0] = args[0]  # errors read "flaair record: ...", not "cli.py: ..."
    params, config, name = rio.RECORDER_PARAMS, rio.CONFIG_FILE, rio.NODE_NAME
    return run_node(RecorderNode, params, config, name, args, executor_kind="single")


if __name__ == "__main__":
    sys.exit(main())
