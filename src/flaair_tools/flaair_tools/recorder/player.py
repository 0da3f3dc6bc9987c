"""player: republish a bag's messages onto their topics, like `ros2 bag play`.

Messages leave in the bag's log-time order, as recorded (serialized bytes, never decoded),
paced by their log times (which `flaair record` sets to each message's signal time, so a
replay follows the signal's own clock, not the recording machine's) at real time (`--rate 1`),
N times real time (`--rate N`) or as fast as possible (`--fast`). With `--clock`, /clock
carries the bag's time (for nodes with use_sim_time) and a recorded /clock topic is not
replayed. Publishers offer what the recording's publishers offered (reliable / transient-local
if any of them did).

`--fast` can outrun a slow subscriber: a reliable KEEP_LAST queue then drops the oldest.

Usage:
  bin/flaair play BAG [--rate N | --fast] [--topics /flaair/sensor_v ...] [--clock]
                      [--wait-subscribers]
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from dataclasses import dataclass
from typing import Any

import rclpy
from builtin_interfaces.msg import Time
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from flaair_common import topics as topic_names
from flaair_common.cli_help import HelpFormatter
from flaair_common.msgdict import message_class
from flaair_common.qos import BLOCK_STREAM
from flaair_model.config import ConfigError, node_parameters
from flaair_tools import bagio

CONFIG_FILE = "flaair.yaml"
SECTION = "player"
CLOCK_QOS_DEPTH = 10  # as plant_node publishes /clock
# after the last message: let reliable delivery finish before the participant goes away
DRAIN_S = 0.5


# ---- functional core ------------------------------------------------------------------------
def wall_offset_s(timestamp_ns: int, first_ns: int, rate: float) -> float:
    """Wall-clock seconds after the start at which a message of `timestamp_ns` is due (rate > 0)."""
    return (timestamp_ns - first_ns) * 1e-9 / rate


@dataclass(frozen=True)
class PublisherQos:
    """What the player offers on a topic."""

    reliable: bool
    transient_local: bool
    depth: int


def offer_qos(offered: tuple[Any, ...]) -> PublisherQos:
    """Offer reliable / transient-local if any recorded
    publisher did; the deepest recorded queue.
    """
    if not offered:
        return PublisherQos(True, False, BLOCK_STREAM.depth)
    reliable = any(q.reliability == bagio.QosReliability.RELIABLE for q in offered)
    transient = any(q.durability == bagio.QosDurability.TRANSIENT_LOCAL for q in offered)
    depth = max([q.depth for q in offered if q.depth > 0], default=BLOCK_STREAM.depth)
    return PublisherQos(reliable, transient, depth)


def parse_args(argv: list[str]) -> argparse.Namespace:
    """Command-line options; defaults from config/flaair.yaml's player section."""
    try:
        defaults = node_parameters(CONFIG_FILE, SECTION)
    except ConfigError as exc:
        raise SystemExit(f"flaair play: {exc}") from None
    parser = argparse.ArgumentParser(
        prog="flaair play",
        description=__doc__,
        formatter_class=HelpFormatter,
    )
    parser.add_argument("bag", help="bag directory")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument(
        "--rate",
        type=float,
        default=float(defaults["rate"]),
        help=f"playback speed, 1 = real time (default {defaults['rate']})",
    )
    pace.add_argument("--fast", action="store_true", help="publish as fast as possible")
    parser.add_argument(
        "--topics", nargs="+", default=None, help="replay only these topics (default: every topic)"
    )
    parser.add_argument(
        "--clock",
        action="store_true",
        default=bool(defaults["publish_clock"]),
        help="publish /clock with the bag's time",
    )
    parser.add_argument(
        "--start-delay",
        type=float,
        default=float(defaults["start_delay_s"]),
        help="seconds between creating publishers and the first message (default "
        f"{defaults['start_delay_s']})",
    )
    parser.add_argument(
        "--wait-subscribers",
        action="store_true",
        help="start only once every topic has a subscriber "
        f"(give up after {defaults['wait_subscribers_timeout_s']} s)",
    )
    args = parser.parse_args(argv)
    args.wait_timeout_s = float(defaults["wait_subscribers_timeout_s"])
    if not args.fast and not args.rate > 0:
        parser.error("--rate must be positive")
    return args


# ---- ROS shell ------------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> int:  # noqa: C901  options in order, then the playback
    """Play a bag; returns 0 when done or stopped by SIGINT/SIGTERM, 1 on a bag error."""
    args = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        info = bagio.bag_info(args.bag)
        if args.topics:
            missing = [t for t in args.topics if t not in info.topics]
            if missing:
                raise bagio.BagTopicError(
                    f"{args.bag}: no topic {', '.join(missing)} in the bag "
                    f"(it has: {', '.join(sorted(info.topics))})"
                )
    except bagio.BagError as exc:
        print(f"flaair play: {exc}", file=sys.stderr)
        return 1
    chosen = [
        t
        for t in (args.topics or sorted(info.topics))
        if not (args.clock and t == topic_names.CLOCK)
    ]

    stop = False

    def _stop(_signum: int, _frame: object) -> None:
        nonlocal stop
        stop = True

    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    node = rclpy.create_node("flaair_player")
    try:
        publishers = {}
        for topic in chosen:
            qos = offer_qos(info.topics[topic].offered_qos)
            profile = QoSProfile(
                history=HistoryPolicy.KEEP_LAST,
                depth=qos.depth,
                reliability=ReliabilityPolicy.RELIABLE
                if qos.reliable
                else ReliabilityPolicy.BEST_EFFORT,
                durability=DurabilityPolicy.TRANSIENT_LOCAL
                if qos.transient_local
                else DurabilityPolicy.VOLATILE,
            )
            publishers[topic] = node.create_publisher(
                message_class(info.topics[topic].msgtype), topic, profile
            )
        clock_pub = (
            node.create_publisher(Clock, topic_names.CLOCK, CLOCK_QOS_DEPTH) if args.clock else None
        )
        if args.wait_subscribers:
            deadline = time.monotonic() + args.wait_timeout_s
            waiting = list(publishers.values()) + ([clock_pub] if clock_pub is not None else [])
            while (
                not stop
                and time.monotonic() < deadline
                and any(p.get_subscription_count() == 0 for p in waiting)
            ):
                time.sleep(0.05)
        deadline = time.monotonic() + args.start_delay
        while not stop and time.monotonic() < deadline:
            time.sleep(0.01)
        sent = 0
        start_wall = time.monotonic()
        first_ns: int | None = None
        last_clock_ns: int | None = None
        for topic, _, timestamp_ns, data in bagio.iter_raw(args.bag, chosen):
            if stop:
                break
            if first_ns is None:
                first_ns = timestamp_ns
            if not args.fast:
                due = start_wall + wall_offset_s(timestamp_ns, first_ns, args.rate)
                while not stop and (wait := due - time.monotonic()) > 0:
                    time.sleep(min(wait, 0.1))
            if clock_pub is not None and timestamp_ns != last_clock_ns:
                sec, nanosec = divmod(timestamp_ns, 1_000_000_000)
                clock_pub.publish(Clock(clock=Time(sec=sec, nanosec=nanosec)))
                last_clock_ns = timestamp_ns
            publishers[topic].publish(bytes(data))
            sent += 1
        played_s = time.monotonic() - start_wall
        time.sleep(DRAIN_S)
        node.get_logger().info(f"played {sent} messages from {args.bag} in {played_s:.3f} s")
        return 0
    except bagio.BagError as exc:
        print(f"flaair play: {exc}", file=sys.stderr)
        return 1
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
