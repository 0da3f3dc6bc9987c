"""`flaair node`: the running nodes of the graph (ros2cli's `ros2 node` is not installable here).

Examples
--------
  bin/flaair node list
  bin/flaair node list --discovery-s 3
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

from flaair_model.config import ConfigError, node_parameters

CONFIG_FILE = "flaair.yaml"
SECTION = "flaair_cli"


def run_with_node(name: str, body: Callable[[Any], int]) -> int:
    """Rclpy up, `body(node)` on a node called `name`, everything torn down after; Ctrl-C: 130."""
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


def main(argv: list[str] | None = None) -> int:
    defaults = cli_defaults("flaair node")
    parser = argparse.ArgumentParser(
        prog="flaair node",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="verb", required=True)
    listing = sub.add_parser("list", help="names of the running nodes, one a line")
    listing.add_argument(
        "--discovery-s",
        type=float,
        default=float(defaults["discovery_s"]),
        help="listen this long for nodes to announce themselves (default "
        f"{defaults['discovery_s']} s)",
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
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.discovery_s < 0 or args.timeout <= 0:
        parser.error("--discovery-s must be >= 0 and --timeout > 0")

    def body(node) -> int:
        me = full_name(node.get_name(), node.get_namespace())
        wanted = set(args.wait_for)
        start = time.monotonic()
        names: set[str] = set()
        while True:
            rclpy.spin_once(node, timeout_sec=0.05)
            names = {full_name(n, ns) for n, ns in node.get_node_names_and_namespaces()} - {me}
            waited_s = time.monotonic() - start
            if waited_s >= args.discovery_s and (wanted <= names or waited_s >= args.timeout):
                break
        for name in sorted(names):
            print(name)
        domain = node.context.get_domain_id()
        if wanted - names:
            print(
                f"flaair node list: {', '.join(sorted(wanted - names))} not seen in "
                f"{args.timeout:g} s on ROS_DOMAIN_ID {domain}",
                file=sys.stderr,
            )
            return 1
        if not names:
            print(
                f"flaair node list: no nodes seen in {args.discovery_s:g} s on ROS_DOMAIN_ID "
                f"{domain}",
                file=sys.stderr,
            )
        return 0

    return run_with_node("flaair_node_cli", body)


if __name__ == "__main__":
    sys.exit(main())
