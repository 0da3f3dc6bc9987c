"""`flaair service`: list services and call one, as `ros2 service` does.

`call NAME TYPE [REQUEST]`: the request is a YAML mapping of its fields (empty: all defaults; a
nested message a mapping, a sequence of messages a list of mappings; a value of the wrong type:
one line naming the field, exit 2);
the output is ros2cli's ("requester: making request: ...", then "response:" and the answer's
repr); `--json` prints the answer alone as one JSON line. `list [-t] [-c]
[--include-hidden-services]`. Exit 0 when answered, 1 when no service answered in --timeout
(ros2cli waits forever), 2 for a bad type or request. Not covered (one line naming the real
command, exit 2): `call -r/--rate`, `--stdin`, `ros2 service type|find|echo|info`.

Examples
--------
  bin/flaair service list
  bin/flaair service call /dsa_controller_node/reset_watchdog std_srvs/srv/Trigger
"""

from __future__ import annotations

import argparse
import json
import sys

import rclpy
import yaml
from rclpy.topic_or_service_is_hidden import topic_or_service_is_hidden

from flaair_common.cli_help import HelpFormatter
from flaair_common.msgdict import from_dict, message_class, to_dict
from flaair_tools.roscli.node_cli import cli_defaults, run_with_node
from flaair_tools.roscli.ros2_args import (
    SPIN_TIME_S,
    hidden_node_name,
    listen_until_settled,
    parse_or_refuse,
)


def parse_request(service_class: type, text: str) -> object:
    """The request message from YAML/JSON `text` (ValueError naming what is wrong)."""
    try:
        values = yaml.safe_load(text) if text.strip() else {}
    except yaml.YAMLError as exc:
        first = str(exc).strip().splitlines()[0]
        raise ValueError(f"request is not plain YAML or JSON ({first})") from None
    if not isinstance(values, dict):
        raise ValueError(f"request must be a mapping of field names to values, got {text!r}")
    return from_dict(service_class.Request, values)


def main(argv: list[str] | None = None) -> int:
    defaults = cli_defaults("flaair service")
    parser = argparse.ArgumentParser(
        prog="flaair service",
        description=__doc__,
        formatter_class=HelpFormatter,
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
    parser.add_argument("--json", action="store_true", help="call: the answer as one JSON line")
    parser.add_argument("-t", "--show-types", action="store_true", help="list: with types")
    parser.add_argument("-c", "--count-services", action="store_true", help="list: the number")
    parser.add_argument("--include-hidden-services", action="store_true", help="list: all")
    parser.add_argument(
        "--no-daemon", action="store_true", help="accepted for ros2cli's sake (no daemon)"
    )
    args = parse_or_refuse(parser, argv, "service")
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

    def body(node) -> int:
        if args.verb == "list":
            found = listen_until_settled(
                lambda s: rclpy.spin_once(node, timeout_sec=s),
                lambda: {
                    name
                    for name, _ in node.get_service_names_and_types()
                    if args.include_hidden_services or not topic_or_service_is_hidden(name)
                },
                SPIN_TIME_S,
            )
            services = [(n, t) for n, t in node.get_service_names_and_types() if n in found]
            if args.count_services:
                print(len(services))
            for name, types in [] if args.count_services else sorted(services):
                print(f"{name} [{', '.join(types)}]" if args.show_types else name)
            return 0
        client = node.create_client(service_class, args.service)
        if not client.service_is_ready() and not args.json:
            print("waiting for service to become available...", flush=True)
        if not client.wait_for_service(timeout_sec=args.timeout):
            print(
                f"flaair service call: no service '{args.service}' within {args.timeout:g} s",
                file=sys.stderr,
            )
            return 1
        if not args.json:
            print(f"requester: making request: {request!r}\n", flush=True)
        future = client.call_async(request)
        rclpy.spin_until_future_complete(node, future, timeout_sec=args.timeout)
        if not future.done() or future.result() is None:
            print(
                f"flaair service call: '{args.service}' did not answer within {args.timeout:g} s",
                file=sys.stderr,
            )
            return 1
        if args.json:
            print(json.dumps(to_dict(future.result()), allow_nan=False))
        else:
            print(f"response:\n{future.result()!r}\n")
        return 0

    return run_with_node(hidden_node_name("service"), body)


if __name__ == "__main__":
    sys.exit(main())
