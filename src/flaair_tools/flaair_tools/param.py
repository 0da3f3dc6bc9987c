"""`flaair param`: read a running node's parameters (stands in for `ros2 param`).

Examples:
  bin/flaair param list /plant_node
  bin/flaair param get /plant_node mode
"""
from __future__ import annotations

import argparse
import sys

import rclpy
from rclpy.parameter import parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="flaair param", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("verb", choices=("get", "list"))
    parser.add_argument("node", help="node name, e.g. /plant_node")
    parser.add_argument("name", nargs="?", help="parameter name (get)")
    parser.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the node")
    args = parser.parse_args(argv)
    if args.verb == "get" and not args.name:
        parser.error("get needs a parameter name")
    rclpy.init()
    node = rclpy.create_node("flaair_param")
    try:
        client = AsyncParameterClient(node, args.node)
        if not client.wait_for_services(timeout_sec=args.timeout):
            print(f"flaair param: node '{args.node}' not found within {args.timeout:g} s", file=sys.stderr)
            return 1
        if args.verb == "list":
            future = client.list_parameters()
            rclpy.spin_until_future_complete(node, future, timeout_sec=args.timeout)
            for name in sorted(future.result().result.names):
                print(name)
            return 0
        future = client.get_parameters([args.name])
        rclpy.spin_until_future_complete(node, future, timeout_sec=args.timeout)
        values = future.result().values
        if not values or values[0].type == 0:
            print(f"flaair param: node '{args.node}' has no parameter '{args.name}'", file=sys.stderr)
            return 1
        print(parameter_value_to_python(values[0]))
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
