"""`flaair node`: the running nodes of the graph (ros2cli's `ros2 node` is not installable here).

Examples
--------
  bin/flaair node list
  bin/flaair node list --discovery-s 3
"""
from __future__ import annotations

import argparse
import sys
import time

import rclpy

from flaair_model.config import ConfigError, node_parameters

CONFIG_FILE = "flaair.yaml"
SECTION = "flaair_cli"


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
    parser = argparse.ArgumentParser(prog="flaair node", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="verb", required=True)
    listing = sub.add_parser("list", help="names of the running nodes, one a line")
    listing.add_argument("--discovery-s", type=float, default=float(defaults["discovery_s"]),
                         help="listen this long for nodes to announce themselves (default "
                              f"{defaults['discovery_s']} s)")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    rclpy.init()
    node = rclpy.create_node("flaair_node_cli")
    try:
        deadline = time.monotonic() + args.discovery_s
        while time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
        me = full_name(node.get_name(), node.get_namespace())
        names = sorted({full_name(n, ns) for n, ns in node.get_node_names_and_namespaces()} - {me})
        for name in names:
            print(name)
        if not names:
            print(f"flaair node list: no nodes seen in {args.discovery_s:g} s on ROS_DOMAIN_ID "
                  f"{node.context.get_domain_id()}", file=sys.stderr)
        return 0
    except KeyboardInterrupt:
        return 130
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
