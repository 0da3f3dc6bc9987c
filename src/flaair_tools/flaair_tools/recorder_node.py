"""recorder_node: record FLAAIR topics into a rosbag2 (MCAP) bag, like `ros2 bag record`.

Subscribes to every /flaair topic (or the `topics` chosen) as raw serialized messages, looks
for new topics every `discovery_period_s`, and writes each message straight into the bag
without deserializing it. The log time of every message is its signal time, so `play`,
PlotJuggler and Foxglove show the signal's own timeline (3 s of simulated signal span 3 s):
the stamp of its leading header (a block's first sample; a status's or event's own stamp) or,
for /clock, the clock value. A header-less message (a run marker) takes the signal time of
the latest stamped message, and waits for the first one; in a bag with no stamped message at
all it keeps its receive time. The publisher's send time is kept as the MCAP publish time.
Subscriptions match what the publishers offer (reliable / transient-local only if every
publisher offers it); the offered QoS profiles are recorded with each topic, as rosbag2 does.

Throughput: each callback also drains the messages already queued on its subscription (the
rclpy executor hands over one per wake-up, too few for 20 kHz streams in 10-sample blocks),
and the subscription queue is `queue_depth` deep, slack for bursts and CPU starvation.

Durability: chunks are closed and handed to the OS when they reach `chunk_size_bytes` or
every `flush_period_s`, so after a kill -9 everything older than that stays readable
(`bin/flaair bag reindex BAG` restores the summary and metadata.yaml). SIGINT / SIGTERM close
the bag completely.

Usage:
  bin/flaair record [-o BAG] [--topics /flaair/sensor_v ...] [--clock] [--no-compression] [--use-sim-time]
  bin/flaair run flaair_tools recorder_node --ros-args -p output_path:=out/bags/run1
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from flaair_common import topics as topic_names
from flaair_common.msgdict import message_class
from flaair_common.params import ParameterError, ParamSpec, declare_parameters
from flaair_common.qos import BLOCK_STREAM
from flaair_common.runtime import help_text, run_node
from flaair_tools import bagio

NODE_NAME = "recorder_node"
CONFIG_FILE = "flaair.yaml"
NAMESPACE = "/flaair/"
DRAIN_LIMIT = BLOCK_STREAM.depth  # messages taken per callback at most, so other topics get their turn
PARAMS = [
    ParamSpec("output_path", str, "Bag directory to create (empty: out/bags/flaair_<date>_<time>)", read_only=True),
    ParamSpec("topics", str, "Comma-separated topics to record (empty: every /flaair/* topic)", read_only=True),
    ParamSpec("record_clock", bool, "Also record /clock", read_only=True),
    ParamSpec("compression", bool, "zstd-compress each MCAP chunk", read_only=True),
    ParamSpec("chunk_size_bytes", int, "Close an MCAP chunk at this size [bytes]", 1024, 2**31 - 1, read_only=True),
    ParamSpec("flush_period_s", float, "Close the open chunk and flush this often; older data survives kill -9 [s]",
              0.01, 3600.0, read_only=True),
    ParamSpec("discovery_period_s", float, "Look for new topics this often [s]", 0.01, 3600.0, read_only=True),
    ParamSpec("queue_depth", int, "Subscription queue per topic (KEEP_LAST): slack while the recorder is starved",
              1, 10**7, read_only=True),
]


# ---- functional core ------------------------------------------------------------------------
def parse_topic_list(text: str) -> tuple[str, ...]:
    """Topics from a comma- or space-separated list; each must be an absolute name."""
    names = tuple(name for name in text.replace(",", " ").split() if name)
    bad = [name for name in names if not name.startswith("/")]
    if bad:
        raise ParameterError(f"parameter 'topics': topic names must start with '/': {', '.join(bad)}")
    return names


def wanted(topic: str, chosen: tuple[str, ...], record_clock: bool) -> bool:
    """Whether to record `topic`: the chosen ones, else every /flaair topic; /clock if asked."""
    if topic == topic_names.CLOCK:
        return record_clock or topic in chosen
    if chosen:
        return topic in chosen
    return topic.startswith(NAMESPACE)


@dataclass(frozen=True)
class SubscriptionQos:
    """What the recorder subscribes with, decided from the publishers' offers."""

    reliable: bool
    transient_local: bool


def adapt_qos(offered: list[Any]) -> SubscriptionQos:
    """Reliable / transient-local only when every publisher offers it (else nothing would match)."""
    if not offered:
        return SubscriptionQos(True, False)
    reliable = all(q.reliability == bagio.QosReliability.RELIABLE for q in offered)
    transient = all(q.durability == bagio.QosDurability.TRANSIENT_LOCAL for q in offered)
    return SubscriptionQos(reliable, transient)


def default_output_path(now_s: float) -> Path:
    """out/bags/flaair_<YYYYmmdd_HHMMSS> under the working directory."""
    return Path("out") / "bags" / time.strftime("flaair_%Y%m%d_%H%M%S", time.localtime(now_s))


def cli_to_ros_args(argv: list[str], prog: str = "flaair record") -> list[str]:
    """`bin/flaair record` options as the node's --ros-args (anything after --ros-args passes through)."""
    parser = argparse.ArgumentParser(
        prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=help_text("", PARAMS, CONFIG_FILE, NODE_NAME))
    parser.add_argument("-o", "--output", help="bag directory to create")
    parser.add_argument("--topics", nargs="+", default=None, help="topics to record (default: every /flaair topic)")
    parser.add_argument("--clock", action="store_true", help="also record /clock")
    parser.add_argument("--no-compression", action="store_true", help="store chunks uncompressed")
    parser.add_argument("--use-sim-time", action="store_true",
                        help="run the node on sim time (log times are signal times with or without it)")
    ros_args: list[str] = []
    if "--ros-args" in argv:
        cut = argv.index("--ros-args")
        argv, ros_args = argv[:cut], argv[cut + 1:]
    args = parser.parse_args(argv)

    def param(name: str, value: str) -> list[str]:
        return ["-p", f"{name}:={value}"]

    def quoted(text: str) -> str:
        return "'" + text.replace("'", "''") + "'"

    out = [prog, "--ros-args"]
    if args.output:
        out += param("output_path", quoted(args.output))
    if args.topics:
        out += param("topics", quoted(",".join(args.topics)))
    if args.clock:
        out += param("record_clock", "true")
    if args.no_compression:
        out += param("compression", "false")
    if args.use_sim_time:
        out += param("use_sim_time", "true")
    return out + ros_args


# ---- ROS shell ------------------------------------------------------------------------------
class RecorderNode(Node):
    """Raw subscriptions -> bagio.BagWriter."""

    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        self.p = declare_parameters(self, PARAMS, CONFIG_FILE)
        self.chosen = parse_topic_list(self.p["topics"])
        self.signal_ns: int | None = None  # signal time of the latest stamped message
        self.pending: list[tuple[str, bytes, int | None]] = []  # header-less messages before the first stamp
        self.store = bagio.typestore()
        path = Path(self.p["output_path"]) if self.p["output_path"] else default_output_path(time.time())
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
        what = ", ".join(self.chosen) if self.chosen else f"every {NAMESPACE}* topic"
        self.get_logger().info(f"recording {what} to {self.writer.path}")

    def discover(self) -> None:
        """Subscribe to every wanted topic not subscribed yet."""
        for topic, types in self.get_topic_names_and_types():
            if topic in self.subscribed or topic in self.skipped:
                continue
            if not wanted(topic, self.chosen, self.p["record_clock"]):
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
            qos = adapt_qos(offered)
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

    def make_callback(self, topic: str, stamped: bool, cls: type):
        """Callback writing the raw message of `topic`, then every message already queued behind it.

        The executor hands over one message per wake-up; draining the subscription's queue in
        the callback keeps up with 20 kHz block streams where one-per-wake-up falls behind.
        """
        received = self.received
        subscriptions = self.subscribed

        def write(data: bytes, info: dict) -> None:
            publish_ns = info.get("source_timestamp") or None
            if stamped:
                self.signal_ns = bagio.leading_stamp_ns(data)
                for pending in self.pending:
                    self.writer.write(pending[0], self.signal_ns, pending[1], pending[2])
                self.pending.clear()
            elif self.signal_ns is None:
                self.pending.append((topic, bytes(data), publish_ns))
                return
            self.writer.write(topic, self.signal_ns, data, publish_ns)

        def on_message(data: bytes, info: dict) -> None:
            write(data, info)
            count = 1
            handle = subscriptions[topic].handle
            while count < DRAIN_LIMIT:
                with handle:
                    taken = handle.take_message(cls, True)
                if taken is None:
                    break
                write(*taken)
                count += 1
            received[topic] += count

        return on_message

    def close(self) -> None:
        """Finish the bag (summary, metadata.yaml)."""
        if self.writer.closed:
            return
        for topic, data, publish_ns in self.pending:  # no stamped message ever came: receive times
            self.writer.write(topic, publish_ns or time.time_ns(), data, publish_ns)
        self.writer.close()
        counts = ", ".join(f"{topic} {count}" for topic, count in sorted(self.writer.counts.items())) or "nothing"
        self.get_logger().info(f"closed {self.writer.path}: {counts}")


def main(argv: list[str] | None = None) -> int:
    """Console script (ROS arguments) or `bin/flaair record` (friendly options, argv given)."""
    if argv is None:
        return run_node(RecorderNode, PARAMS, CONFIG_FILE, NODE_NAME, executor_kind="single")
    args = cli_to_ros_args(argv)
    sys.argv[0] = args[0]  # errors read "flaair record: ...", not "cli.py: ..."
    return run_node(RecorderNode, PARAMS, CONFIG_FILE, NODE_NAME, args, executor_kind="single")


if __name__ == "__main__":
    sys.exit(main())
