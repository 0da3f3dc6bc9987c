"""`flaair service`: list services and call one (stands in for `ros2 service`).

The request is a YAML or JSON mapping of the request's fields (empty: all defaults); the answer
is printed as one JSON line. Exit 0 when answered, 1 when no service answered in --timeout,
2 for a bad type or request.

Examples
--------
  bin/flaair service list
  bin/flaair service call /dsa_controller_node/reset_watchdog std_srvs/srv/Trigger
"""

from __future__ import annotations

import argparse
import json
import sys

import yaml

from flaair_common.msgdict import from_dict, message_class, to_dict
from flaair_tools.roscli.node_cli import cli_defaults, run_with_node


def parse_request(service_class: type, text: str) -> object:
    """The request message from YAML/JSON `text` (ValueError naming what is wrong)."""
    try:
        values = yaml.safe_load(text) if text.strip() else {}
    except yaml.YAMLError as exc:
        raise ValueError(f"request is not YAML or JSON: {exc}") from None
    if not isinstance(values, dict):
        raise ValueError(f"request must be a mapping of field names to values, got {text!r}")
    return from_dict(service_class.Request, values)


def main(argv: list[str] | None = None) -> int:
    defaults = cli_defaults("flaair service")
    parser = argparse.ArgumentParser(
        prog="flaair service",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("verb", choices=("list", "call"))
    parser.add_argument(
        "service", nargs="?", help="service name (call), e.g. /dsa_controller_node/reset_watchdog"
    )
    parser.add_argument("type", nargs="?", help="service type (call), e.g. std_srvs/srv/Trigger")
    parser.add_argument("request", nargs="?", default="", help="request fields as YAML (call)")
    parser.add_argument(
        "--timeout",
        type=float,
        default=float(defaults["service_timeout_s"]),
        help="seconds to wait for the service and for its answer (default "
        f"{defaults['service_timeout_s']})",
    )
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.verb == "call" and not (args.service and args.type):
        parser.error("call needs a service name and type: bin/flaair service call NAME TYPE")
    request = None
    if args.verb == "call":
        try:
            service_class = message_class(args.type)
            if not hasattr(service_class, "Request"):
                raise ValueError(f"'{args.type}' is not a service type (pkg/srv/Name)")
            request = parse_request(service_class, args.request)
        except ValueError as exc:
            print(f"flaair service call: {exc}", file=sys.stderr)
            return 2
    import rclpy

    def body(node) -> int:
        if args.verb == "list":
            wait_s = min(args.timeout, 2.0)  # discovery: what answers within a moment
            rclpy.spin_once(node, timeout_sec=wait_s)
            for name, types in sorted(node.get_service_names_and_types()):
                print(f"{name} [{', '.join(types)}]")
            return 0
        client = node.create_client(service_class, args.service)
        if not client.wait_for_service(timeout_sec=args.timeout):
            print(
                f"flaair service call: no service '{args.service}' within {args.timeout:g} s",
                file=sys.stderr,
            )
            return 1
        future = client.call_async(request)
        rclpy.spin_until_future_complete(node, future, timeout_sec=args.timeout)
        if not future.done() or future.result() is None:
            print(
                f"flaair service call: '{args.service}' did not answer within {args.timeout:g} s",
                file=sys.stderr,
            )
            return 1
        print(json.dumps(to_dict(future.result()), allow_nan=False))
        return 0

    return run_with_node("flaair_service", body)


if __name__ == "__main__":
    sys.exit(main())
