"""`flaair topic`: list, echo and publish topics (ros2cli's `ros2 topic` is not installable here).

Examples
--------
  bin/flaair topic list
  bin/flaair topic echo /flaair/wing_state --count 5
  bin/flaair topic echo /flaair/collision/events --timeout 0   # wait forever
  bin/flaair topic hz /flaair/sensor_v                         # per second, like `ros2 topic hz`
  bin/flaair topic wait /flaair/sensor_v --publishers 1 --subscribers 2 --timeout 30
  bin/flaair topic pub /flaair/drive flaair_msgs/msg/DriveCommandBlock \
      '{"drive_v": [1.0, 2.0]}' --count 3
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from pathlib import Path

import rclpy
from rclpy.node import Node

from flaair_common.msgdict import from_dict, message_class, to_dict
from flaair_common.qos import BLOCK_STREAM
from flaair_tools.roscli.node_cli import cli_defaults, run_with_node


def rate_report(arrivals_s: list[float]) -> str:
    """`ros2 topic hz`-style line from arrival times
    [s]: mean rate and the spread of the periods.
    """
    periods = [b - a for a, b in itertools.pairwise(arrivals_s)]
    mean = sum(periods) / len(periods)
    std = (sum((p - mean) ** 2 for p in periods) / len(periods)) ** 0.5
    return (
        f"average rate: {1.0 / mean:.1f} Hz  min: {min(periods) * 1e3:.3f} ms  max: "
        f"{max(periods) * 1e3:.3f} ms  std dev: {std * 1e3:.3f} ms  window: {len(arrivals_s)}"
    )


def _wait_for_type(node: Node, topic: str, timeout_s: float) -> str:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for name, types in node.get_topic_names_and_types():
            if name == topic and types:
                return types[0]
        rclpy.spin_once(node, timeout_sec=0.1)
    raise SystemExit(
        f"flaair topic: no publisher of '{topic}' seen within {timeout_s:g} s; give "
        "its type explicitly"
    )


def _listen(node: Node, args: argparse.Namespace) -> int:
    """Echo (JSON lines) or hz (rate reports) until --count, Ctrl-C, or --timeout of silence."""
    type_name = args.type or _wait_for_type(node, args.topic, args.timeout or 10.0)
    received, arrivals, reports = 0, [], 0
    echo = args.verb == "echo"

    def on_message(message: object) -> None:
        nonlocal received
        received += 1
        if echo:
            print(json.dumps(to_dict(message)), flush=True)
        else:
            arrivals.append(time.monotonic())
            del arrivals[: -args.window]

    # hz takes the serialized bytes: no conversion cost, so the rate is the topic's, not ours
    subscription = node.create_subscription(
        message_class(type_name), args.topic, on_message, BLOCK_STREAM, raw=not echo
    )
    last = time.monotonic()
    next_report, seen = last + getattr(args, "period", 0.0), 0
    ready = getattr(args, "ready_file", None) is None
    while args.count == 0 or (received if echo else reports) < args.count:
        rclpy.spin_once(node, timeout_sec=0.05)
        now = time.monotonic()
        if received != seen:
            seen, last = received, now
        elif args.timeout and now - last > args.timeout:
            publishers = node.count_publishers(args.topic)
            print(
                f"flaair topic {args.verb}: no message on '{args.topic}' for {args.timeout:g} s "
                f"({received} received, {publishers} publisher(s) now); --timeout 0 waits "
                "forever",
                file=sys.stderr,
            )
            return 1
        if not ready and subscription.get_publisher_count() > 0:
            args.ready_file.touch()
            ready = True
        if not echo and now >= next_report:
            next_report += args.period
            if len(arrivals) >= 2:
                print(rate_report(arrivals), flush=True)
                reports += 1
    return 0


def main(argv: list[str] | None = None) -> int:
    defaults = cli_defaults("flaair topic")
    silence = float(defaults["echo_timeout_s"])
    parser = argparse.ArgumentParser(
        prog="flaair topic",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="verb", required=True)
    sub.add_parser("list", help="topics and their types")
    echo = sub.add_parser("echo", help="print messages as JSON lines")
    echo.add_argument("topic")
    echo.add_argument("type", nargs="?", help="pkg/msg/Name (default: discovered)")
    echo.add_argument("--count", type=int, default=0, help="stop after N messages (0: forever)")
    echo.add_argument(
        "--timeout",
        type=float,
        default=silence,
        help=f"end (exit 1) after S seconds without a message (default {silence:g}; "
        "0: wait forever)",
    )
    echo.add_argument(
        "--ready-file",
        type=Path,
        help="create this file once a publisher is "
        "matched (for scripts that must not start "
        "the source before the echo listens)",
    )
    hz = sub.add_parser("hz", help="print the message rate, like `ros2 topic hz`")
    hz.add_argument("topic")
    hz.add_argument("type", nargs="?", help="pkg/msg/Name (default: discovered)")
    hz.add_argument(
        "--window",
        type=int,
        default=int(defaults["hz_window"]),
        help=f"rate over the last N messages (default {defaults['hz_window']})",
    )
    hz.add_argument(
        "--period", type=float, default=float(defaults["hz_period_s"]), help="print this often [s]"
    )
    hz.add_argument("--count", type=int, default=0, help="stop after N reports (0: until Ctrl-C)")
    hz.add_argument(
        "--timeout",
        type=float,
        default=silence,
        help=f"end (exit 1) after S seconds without a message (default {silence:g}; 0: "
        "wait forever)",
    )
    wait = sub.add_parser(
        "wait", help="wait until a topic has enough publishers and subscribers (exit 1 on timeout)"
    )
    wait.add_argument("topic")
    wait.add_argument("--publishers", type=int, default=0, help="at least this many publishers")
    wait.add_argument("--subscribers", type=int, default=0, help="at least this many subscribers")
    wait.add_argument("--timeout", type=float, default=30.0, help="give up after S seconds")
    wait.add_argument(
        "--settle",
        type=float,
        default=0.5,
        help="then wait this long more: the graph is seen a moment before every "
        "endpoint has matched [s]",
    )
    pub = sub.add_parser("pub", help="publish a message given as JSON")
    pub.add_argument("topic")
    pub.add_argument("type")
    pub.add_argument(
        "values", help="JSON object of field values, or a JSON list of them (published in order)"
    )
    pub.add_argument("--count", type=int, default=1)
    pub.add_argument("--rate", type=float, default=10.0, help="messages per second")
    pub.add_argument(
        "--wait-subscribers",
        type=int,
        default=0,
        help="publish only once N "
        "subscribers are matched; "
        "exit 1 without publishing if "
        "they are not within "
        "--wait-timeout",
    )
    pub.add_argument(
        "--wait-timeout",
        type=float,
        default=30.0,
        metavar="S",
        help="how long --wait-subscribers waits (default 30 s)",
    )
    args = parser.parse_args(argv)

    def body(node) -> int:
        if args.verb == "list":
            deadline = time.monotonic() + 1.0
            while time.monotonic() < deadline:
                rclpy.spin_once(node, timeout_sec=0.1)
            for name, types in sorted(node.get_topic_names_and_types()):
                print(f"{name} [{', '.join(types)}]")
            return 0
        if args.verb == "wait":
            deadline = time.monotonic() + args.timeout
            while time.monotonic() < deadline:
                publishers, subscribers = (
                    node.count_publishers(args.topic),
                    node.count_subscribers(args.topic),
                )
                if publishers >= args.publishers and subscribers >= args.subscribers:
                    time.sleep(args.settle)
                    return 0
                rclpy.spin_once(node, timeout_sec=0.05)
            print(
                f"flaair topic wait: '{args.topic}' has {publishers} publisher(s) and "
                f"{subscribers} subscriber(s) after {args.timeout:g} s; wanted {args.publishers} "
                f"and {args.subscribers}",
                file=sys.stderr,
            )
            return 1
        if args.verb in ("echo", "hz"):
            return _listen(node, args)
        cls = message_class(args.type)
        try:
            values = json.loads(args.values)
            messages = [
                from_dict(cls, v) for v in (values if isinstance(values, list) else [values])
            ]
        except (ValueError, TypeError, AssertionError) as exc:
            print(f"flaair topic pub: {exc}", file=sys.stderr)
            return 2
        publisher = node.create_publisher(cls, args.topic, BLOCK_STREAM)
        deadline = time.monotonic() + args.wait_timeout
        while publisher.get_subscription_count() < args.wait_subscribers:
            if time.monotonic() > deadline:
                print(
                    f"flaair topic pub: '{args.topic}' has {publisher.get_subscription_count()} "
                    f"subscriber(s) after {args.wait_timeout:g} s; wanted "
                    f"{args.wait_subscribers}: nothing published",
                    file=sys.stderr,
                )
                return 1
            rclpy.spin_once(node, timeout_sec=0.05)
        for _ in range(args.count):
            for message in messages:
                publisher.publish(message)
                time.sleep(1.0 / args.rate)
        # every matched reader has the messages before the participant goes away (reliable QoS)
        from rclpy.duration import Duration

        if not publisher.wait_for_all_acked(Duration(seconds=args.wait_timeout)):
            print(
                f"flaair topic pub: '{args.topic}': not every subscriber acknowledged the "
                f"messages within {args.wait_timeout:g} s",
                file=sys.stderr,
            )
            return 1
        return 0

    return run_with_node("flaair_topic", body)


if __name__ == "__main__":
    sys.exit(main())
