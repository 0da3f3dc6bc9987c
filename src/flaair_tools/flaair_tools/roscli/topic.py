r"""`flaair topic`: list, echo, hz, info and publish topics, as `ros2 topic` does them.

What ros2cli's `ros2 topic` takes, these take, with its output:
  list  [-t] [-c] [-v] [--include-hidden-topics] [--spin-time S] [--no-daemon]
  echo  TOPIC [TYPE] [--once] [--field a.b] [--timeout S] [-f] [-l N]   YAML, '---' after each
  hz    TOPIC [TYPE] [-w/--window N]                                     ros2's rate lines
  info  TOPIC [-v]                                                       the endpoints and QoS
Beyond ros2cli: `echo --json` (one JSON line a message), `echo --count N`, `echo|hz --silence S`
(end, exit 1, after S seconds without a message: config/flaair.yaml's default; 0: never; ros2cli
waits forever), `echo --ready-file`, `hz --period/--count`, `wait`, and `pub` with JSON values
and `--wait-subscribers`. `echo --timeout S` ends after S seconds as ros2cli's does (exit 1 here
if nothing came). Not covered (one line naming the real command, exit 2): QoS overrides, --csv,
--raw, --filter, --no-arr/--no-str, --flow-style, -i, `hz --filter/--wall-time`, `ros2 topic
bw|delay|find|type` and ros2cli's YAML `pub` syntax.

Examples
--------
  bin/flaair topic list -t
  bin/flaair topic echo /flaair/wing_state --once
  bin/flaair topic echo /flaair/controller/state --field k_r
  bin/flaair topic echo /flaair/collision/events --silence 0   # wait forever
  bin/flaair topic hz /flaair/sensor_v
  bin/flaair topic info -v /flaair/wing_state
  bin/flaair topic wait /flaair/sensor_v --publishers 1 --subscribers 2 --timeout 30
  bin/flaair topic pub /flaair/drive flaair_msgs/msg/DriveCommandBlock \
      '{"drive_v": [1.0, 2.0]}' --count 3

Terms (K_r): docs/GLOSSARY.md.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from pathlib import Path
from typing import Any

import rclpy
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.topic_or_service_is_hidden import topic_or_service_is_hidden

from flaair_common.cli_help import HelpFormatter
from flaair_common.msgdict import from_dict, message_class, to_dict
from flaair_common.qos import BLOCK_STREAM
from flaair_tools.roscli.node_cli import cli_defaults, run_with_node
from flaair_tools.roscli.ros2_args import (
    add_discovery_arguments,
    hidden_node_name,
    listen_until_settled,
    parse_or_refuse,
)
from flaair_tools.roscli.yaml_out import (
    DEFAULT_TRUNCATE_LENGTH,
    field_of,
    message_to_yaml,
    to_plain,
)


def rate_report(arrivals_s: list[float]) -> str:
    """`ros2 topic hz`'s report from arrival times [s]: mean rate, then the periods' spread."""
    periods = [b - a for a, b in itertools.pairwise(arrivals_s)]
    mean = sum(periods) / len(periods)
    std = (sum((p - mean) ** 2 for p in periods) / len(periods)) ** 0.5
    rate = 1.0 / mean if mean > 0 else 0.0
    return (
        f"average rate: {rate:.3f}\n\tmin: {min(periods):.3f}s max: {max(periods):.3f}s "
        f"std dev: {std:.5f}s window: {len(periods)}"
    )


def echo_text(message: object, args: argparse.Namespace) -> str:
    """One message as `ros2 topic echo` prints it (or as a JSON line with --json)."""
    if args.field:
        message = field_of(message, args.field)
    if args.json:
        plain = to_dict(message) if hasattr(message, "__slots__") else to_plain(message, None)
        return json.dumps(plain)
    if not hasattr(message, "__slots__"):  # a plain field: printed as Python prints it
        return f"{message}\n---"
    limit = None if args.full_length else args.truncate_length
    return message_to_yaml(message, limit) + "---"


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
    """Echo or hz until --count (--once), --timeout, Ctrl-C, or --silence without a message."""
    type_name = args.type or _wait_for_type(node, args.topic, args.silence or 10.0)
    cls = message_class(type_name)
    echo = args.verb == "echo"
    if echo and args.field:
        try:
            field_of(cls(), args.field)
        except ValueError as exc:
            print(f"flaair topic echo: {exc}", file=sys.stderr)
            return 2
    received, arrivals, reports = 0, [], 0
    count = 1 if getattr(args, "once", False) else args.count

    def on_message(message: object) -> None:
        nonlocal received
        received += 1
        if echo:
            print(echo_text(message, args), flush=True)
        else:
            arrivals.append(time.monotonic())
            del arrivals[: -args.window - 1]

    # hz takes the serialized bytes: no conversion cost, so the rate is the topic's, not ours
    subscription = node.create_subscription(cls, args.topic, on_message, BLOCK_STREAM, raw=not echo)
    start = last = time.monotonic()
    next_report, seen = last + getattr(args, "period", 0.0), 0
    ready = getattr(args, "ready_file", None) is None
    while count == 0 or (received if echo else reports) < count:
        rclpy.spin_once(node, timeout_sec=0.05)
        now = time.monotonic()
        if getattr(args, "timeout", None) and now - start >= args.timeout:
            if received:
                return 0
            print(
                f"flaair topic {args.verb}: no message on '{args.topic}' in {args.timeout:g} s "
                f"(--timeout)",
                file=sys.stderr,
            )
            return 1
        if received != seen:
            seen, last = received, now
        elif args.silence and now - last > args.silence:
            publishers = node.count_publishers(args.topic)
            print(
                f"flaair topic {args.verb}: no message on '{args.topic}' for {args.silence:g} s "
                f"({received} received, {publishers} publisher(s) now); --silence 0 waits "
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


def _list(node: Node, args: argparse.Namespace) -> int:
    """`ros2 topic list` [-t] [-c] [-v] [--include-hidden-topics]."""

    def topics() -> dict[str, list[str]]:
        return {
            name: types
            for name, types in node.get_topic_names_and_types()
            if args.include_hidden_topics or not topic_or_service_is_hidden(name)
        }

    names = listen_until_settled(
        lambda s: rclpy.spin_once(node, timeout_sec=s), lambda: set(topics()), args.spin_time
    )
    found = {name: types for name, types in topics().items() if name in names}
    if args.count_topics:
        print(len(found))
        return 0
    if args.verbose:
        for publishers in (True, False):
            text = ("Published" if publishers else "Subscribed") + " topics:\n"
            for name, types in sorted(found.items()):
                n = node.count_publishers(name) if publishers else node.count_subscribers(name)
                what = "publisher" if publishers else "subscriber"
                if n:
                    text += f" * {name} [{', '.join(types)}] {n} {what}{'s' if n > 1 else ''}\n"
            print(text)
        return 0
    for name, types in sorted(found.items()):
        print(f"{name} [{', '.join(types)}]" if args.show_types else name)
    return 0


def _info(node: Node, args: argparse.Namespace) -> int:
    """`ros2 topic info [-v] TOPIC`: type, counts, and with -v every endpoint with its QoS."""
    listen_until_settled(
        lambda s: rclpy.spin_once(node, timeout_sec=s),
        lambda: {n for n, _ in node.get_topic_names_and_types()},
        args.spin_time,
    )
    types = dict(node.get_topic_names_and_types()).get(args.topic)
    if not types:
        print(f"Unknown topic '{args.topic}'", file=sys.stderr)
        return 1
    end = "\n\n" if args.verbose else "\n"
    print(f"Type: {types[0] if len(types) == 1 else types}", end=end)
    print(f"Publisher count: {node.count_publishers(args.topic)}", end=end)
    for info in node.get_publishers_info_by_topic(args.topic) if args.verbose else ():
        print(info, end=end)
    print(f"Subscription count: {node.count_subscribers(args.topic)}", end=end)
    for info in node.get_subscriptions_info_by_topic(args.topic) if args.verbose else ():
        print(info, end=end)
    return 0


def _checked_type_and_values(args: argparse.Namespace) -> tuple[type | None, list[object]] | int:
    """The message class (echo, hz, pub with a type) and the messages of `pub`, checked before
    any node comes up; or 2 after one line naming what is wrong (the real tool's one line).
    """
    cls, messages = None, []
    try:
        if args.verb in ("echo", "hz", "pub") and args.type:
            cls = message_class(args.type)
        if args.verb == "pub":
            values = json.loads(args.values)
            messages = [
                from_dict(cls, v) for v in (values if isinstance(values, list) else [values])
            ]
    except ValueError as exc:
        print(f"flaair topic {args.verb}: {exc}", file=sys.stderr)
        return 2
    return cls, messages


def _parser() -> argparse.ArgumentParser:
    """`flaair topic`'s parser: one subcommand per verb, as ros2cli's (the defaults from
    config/, `cli_defaults`).
    """
    defaults = cli_defaults("flaair topic")
    parser = argparse.ArgumentParser(
        prog="flaair topic",
        description=__doc__,
        formatter_class=HelpFormatter,
    )
    sub = parser.add_subparsers(dest="verb", required=True)
    spin_s = float(defaults["discovery_s"])
    listing = sub.add_parser(
        "list", formatter_class=HelpFormatter, help="the topics, as `ros2 topic list`"
    )
    add_discovery_arguments(listing, spin_s)
    listing.add_argument("-t", "--show-types", action="store_true", help="with their types")
    listing.add_argument("-c", "--count-topics", action="store_true", help="only their number")
    listing.add_argument("-v", "--verbose", action="store_true", help="publishers, subscribers")
    listing.add_argument("--include-hidden-topics", action="store_true", help="hidden ones too")
    info = sub.add_parser(
        "info",
        formatter_class=HelpFormatter,
        help="a topic's type and endpoints, as `ros2 topic info`",
    )
    info.add_argument("topic")
    info.add_argument("-v", "--verbose", action="store_true", help="every endpoint and its QoS")
    add_discovery_arguments(info, spin_s)
    _add_listeners(sub, defaults)
    _add_wait_and_pub(sub)
    return parser


def _add_listeners(sub: Any, defaults: dict[str, Any]) -> None:
    """`echo` and `hz`: a topic listened to, ended by silence, a count or a timeout."""
    silence = float(defaults["echo_timeout_s"])
    echo = sub.add_parser(
        "echo", formatter_class=HelpFormatter, help="print messages as YAML, as `ros2 topic echo`"
    )
    hz = sub.add_parser(
        "hz", formatter_class=HelpFormatter, help="print the message rate, as `ros2 topic hz`"
    )
    for verb in (echo, hz):
        verb.add_argument("topic")
        verb.add_argument("type", nargs="?", help="pkg/msg/Name (default: discovered)")
        verb.add_argument(
            "--silence",
            type=float,
            default=silence,
            metavar="S",
            help=f"end (exit 1) after S seconds without a message (default {silence:g}; "
            "0: wait forever, as ros2cli does)",
        )
        verb.add_argument(
            "--no-daemon", action="store_true", help="accepted for ros2cli's sake (no daemon)"
        )
    echo.add_argument("--once", action="store_true", help="print the first message and end")
    echo.add_argument("--count", type=int, default=0, help="stop after N messages (0: forever)")
    echo.add_argument("--field", help="print this field only, e.g. header.stamp")
    echo.add_argument("--json", action="store_true", help="one JSON line a message, no YAML")
    echo.add_argument(
        "--timeout", type=float, metavar="S", help="end after S seconds (exit 1 if none came)"
    )
    echo.add_argument(
        "-f", "--full-length", action="store_true", help="arrays and strings not truncated"
    )
    echo.add_argument(
        "-l",
        "--truncate-length",
        type=int,
        default=DEFAULT_TRUNCATE_LENGTH,
        help=f"cut arrays and strings after N (default {DEFAULT_TRUNCATE_LENGTH})",
    )
    echo.add_argument(
        "--ready-file",
        type=Path,
        help="create this file once a publisher is matched (for scripts that must not start "
        "the source before the echo listens)",
    )
    hz.add_argument(
        "-w",
        "--window",
        type=int,
        default=int(defaults["hz_window"]),
        help=f"rate over the last N messages (default {defaults['hz_window']})",
    )
    hz.add_argument(
        "--period", type=float, default=float(defaults["hz_period_s"]), help="print this often [s]"
    )
    hz.add_argument("--count", type=int, default=0, help="stop after N reports (0: until Ctrl-C)")


def _add_wait_and_pub(sub: Any) -> None:
    """`wait` (for endpoints) and `pub` (messages given as JSON)."""
    wait = sub.add_parser(
        "wait",
        formatter_class=HelpFormatter,
        help="wait until a topic has enough publishers and subscribers (exit 1 on timeout)",
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
    pub = sub.add_parser(
        "pub", formatter_class=HelpFormatter, help="publish a message given as JSON"
    )
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


def _wait(node: Node, args: argparse.Namespace) -> int:
    """`wait`: until the topic has enough publishers and subscribers (1 on timeout)."""
    deadline = time.monotonic() + args.timeout
    publishers = subscribers = 0
    while time.monotonic() < deadline:
        publishers = node.count_publishers(args.topic)
        subscribers = node.count_subscribers(args.topic)
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


def _publish(node: Node, args: argparse.Namespace, cls: Any, messages: list[object]) -> int:
    """`pub`: the messages, once enough subscribers match, each acknowledged (1 if not)."""
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
    if not publisher.wait_for_all_acked(Duration(seconds=args.wait_timeout)):
        print(
            f"flaair topic pub: '{args.topic}': not every subscriber acknowledged the "
            f"messages within {args.wait_timeout:g} s",
            file=sys.stderr,
        )
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    args = parse_or_refuse(_parser(), argv, "topic")
    checked = _checked_type_and_values(args)
    if isinstance(checked, int):
        return checked
    cls, messages = checked
    verbs = {"list": _list, "info": _info, "wait": _wait, "echo": _listen, "hz": _listen}

    def body(node: Node) -> int:
        if args.verb in verbs:
            return verbs[args.verb](node, args)
        return _publish(node, args, cls, messages)

    return run_with_node(hidden_node_name("topic"), body)


if __name__ == "__main__":
    sys.exit(main())
