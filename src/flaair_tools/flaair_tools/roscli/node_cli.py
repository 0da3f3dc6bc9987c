"""`flaair node list`: the running nodes of the graph, as `ros2 node list` prints them.

Takes ros2cli's flags: `-a/--all` (hidden nodes too: names starting with '_', such as ros2cli's
own `_ros2cli_PID` and this command's `_flaair_node_PID`), `-c/--count-nodes`, `--spin-time S`,
`--no-daemon`. Listens at least --spin-time, then as long again once no new node appeared and
every topic endpoint's node is listed (at most 5 s; ros2cli reads the graph once after its spin
time, and misses nodes under load).
Beyond ros2cli: `--wait-for NODE` (keep listening until NODE is seen, up to `--timeout`; exit 1
if it never appears). Not covered: `ros2 node info`; any other flag ends with one line naming
the real command (exit 2).

Examples
--------
  bin/flaair node list
  bin/flaair node list -a --spin-time 2
  bin/flaair node list --wait-for /dsa_controller_node --timeout 60
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException

from flaair_common.cli_help import HelpFormatter
from flaair_model.config import ConfigError, node_parameters
from flaair_tools.roscli.ros2_args import (
    add_discovery_arguments,
    hidden_node_name,
    listen_until_settled,
    parse_or_refuse,
)

CONFIG_FILE = "flaair.yaml"
SECTION = "flaair_cli"


def run_with_node(name: str, body: Callable[[Any], int]) -> int:
    """Rclpy up, `body(node)` on a node called `name` (hidden: `ros2_args.hidden_node_name`),
    everything torn down after; Ctrl-C: 130.
    """
    rclpy.init()
    node = rclpy.create_node(name)
    try:
        return body(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        return 130
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def cli_defaults(prog: str) -> dict:
    """Defaults of the `flaair topic | node | param` commands (config/flaair.yaml, flaair_cli);
    a broken config prints one line naming it and exits 2.
    """
    try:
        return node_parameters(CONFIG_FILE, SECTION)
    except ConfigError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


def full_name(name: str, namespace: str) -> str:
    """'/ns/name' from rclpy's (name, namespace) pair."""
    return f"{namespace.rstrip('/')}/{name}"


def is_hidden(full: str) -> bool:
    """A hidden node: its own name (the last part) starts with '_', as ros2node decides."""
    return full.rsplit("/", 1)[-1].startswith("_")


def main(argv: list[str] | None = None) -> int:
    defaults = cli_defaults("flaair node")
    parser = argparse.ArgumentParser(
        prog="flaair node",
        description=__doc__,
        formatter_class=HelpFormatter,
    )
    sub = parser.add_subparsers(dest="verb", required=True)
    listing = sub.add_parser(
        "list", formatter_class=HelpFormatter, help="names of the running nodes, one a line"
    )
    add_discovery_arguments(listing, float(defaults["discovery_s"]))
    listing.add_argument("-a", "--all", action="store_true", help="hidden nodes too")
    listing.add_argument(
        "-c", "--count-nodes", action="store_true", help="only the number of nodes"
    )
    listing.add_argument(
        "--wait-for",
        metavar="NODE",
        action="append",
        default=[],
        help="keep listening until NODE (a full name, e.g. /dsa_controller_node) "
        "is seen, up to --timeout; repeatable. Exit 1 if one never appears",
    )
    listing.add_argument(
        "--timeout",
        type=float,
        default=float(defaults["wait_for_timeout_s"]),
        help=f"longest wait for the --wait-for nodes (default {defaults['wait_for_timeout_s']} s)",
    )
    args = parse_or_refuse(parser, argv, "node")
    if args.spin_time < 0 or args.timeout <= 0:
        parser.error("--spin-time must be >= 0 and --timeout > 0")

    def body(node) -> int:
        def names() -> set[str]:
            found = {full_name(n, ns) for n, ns in node.get_node_names_and_namespaces() if n}
            return found if args.all else {n for n in found if not is_hidden(n)}

        def unlisted() -> bool:  # an endpoint whose node has not announced itself yet
            listed = {full_name(n, ns) for n, ns in node.get_node_names_and_namespaces()}
            for topic, _ in node.get_topic_names_and_types():
                for end in [
                    *node.get_publishers_info_by_topic(topic),
                    *node.get_subscriptions_info_by_topic(topic),
                ]:
                    if full_name(end.node_name, end.node_namespace) not in listed:
                        return True
            return False

        wanted = set(args.wait_for)
        start = time.monotonic()
        seen = listen_until_settled(
            lambda s: rclpy.spin_once(node, timeout_sec=s), names, args.spin_time, unlisted
        )
        while wanted - seen and time.monotonic() - start < args.timeout:
            rclpy.spin_once(node, timeout_sec=0.05)
            seen = names()
        if args.count_nodes:
            print(len(seen))
        elif seen:
            print(*sorted(seen), sep="\n")
        if wanted - seen:
            print(
                f"flaair node list: {', '.join(sorted(wanted - seen))} not seen in "
                f"{args.timeout:g} s on ROS_DOMAIN_ID {node.context.get_domain_id()}",
                file=sys.stderr,
            )
            return 1
        return 0

    return run_with_node(hidden_node_name("node"), body)


if __name__ == "__main__":
    sys.exit(main())
