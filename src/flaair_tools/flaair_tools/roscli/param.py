"""`flaair param`: read and set a running node's parameters, as `ros2 param` does.

  get NODE NAME [--hide-type]   "Double value is: 0.0" (--hide-type: the value alone)
  set NODE NAME VALUE           VALUE read as YAML, as ros2cli reads it: "1" is an integer, "1.0"
                                a double, "true" a bool, "[1.0, 2.0]" a double array. The node
                                decides: an integer for a double parameter is refused ("Setting
                                parameter failed: Wrong parameter type, expected 'Type.DOUBLE'
                                got 'Type.INTEGER'"), as is a value out of its declared range.
                                A value no parameter can hold (a mapping, a YAML tag such as
                                !!python/..., an integer beyond 64 bits): one line, exit 2
  list NODE                     its parameter names, two spaces in, as ros2cli prints them
`--timeout S` waits for the node (ros2cli: whole seconds, default 1; here config/flaair.yaml's).
Differences: a refused `set` exits 1 here (ros2cli exits 0 after printing the reason); not
covered (one line naming the real command, exit 2): `describe`, `dump`, `load`, `delete`,
`list` without a node, `--filter`, `--param-type`, `--include-hidden-nodes`.

Examples
--------
  bin/flaair param list /plant_node
  bin/flaair param get /plant_node mode
  bin/flaair param set /dsa_controller_node kr_target 0.0     # K_r ramps to asynchronous from now

Terms (K_r): docs/GLOSSARY.md.
"""

from __future__ import annotations

import argparse
import sys

import rclpy
import yaml
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rclpy.parameter import get_parameter_value
from rclpy.parameter_client import AsyncParameterClient

from flaair_common.cli_help import HelpFormatter
from flaair_tools.roscli.node_cli import cli_defaults, run_with_node
from flaair_tools.roscli.ros2_args import hidden_node_name, parse_or_refuse

LABELS = {  # ParameterType -> (ros2 param get's label, the value's field)
    ParameterType.PARAMETER_BOOL: ("Boolean value is:", "bool_value"),
    ParameterType.PARAMETER_INTEGER: ("Integer value is:", "integer_value"),
    ParameterType.PARAMETER_DOUBLE: ("Double value is:", "double_value"),
    ParameterType.PARAMETER_STRING: ("String value is:", "string_value"),
    ParameterType.PARAMETER_BYTE_ARRAY: ("Byte values are:", "byte_array_value"),
    ParameterType.PARAMETER_BOOL_ARRAY: ("Boolean values are:", "bool_array_value"),
    ParameterType.PARAMETER_INTEGER_ARRAY: ("Integer values are:", "integer_array_value"),
    ParameterType.PARAMETER_DOUBLE_ARRAY: ("Double values are:", "double_array_value"),
    ParameterType.PARAMETER_STRING_ARRAY: ("String values are:", "string_array_value"),
}


def get_text(value, hide_type: bool = False) -> str:
    """A ParameterValue as `ros2 param get` prints it."""
    if value.type == ParameterType.PARAMETER_NOT_SET:
        return "None" if hide_type else "Parameter not set."
    label, field = LABELS[value.type]
    shown = getattr(value, field)
    if value.type in (
        ParameterType.PARAMETER_INTEGER_ARRAY,
        ParameterType.PARAMETER_DOUBLE_ARRAY,
    ):
        shown = shown.tolist()
    return str(shown) if hide_type else f"{label} {shown}"


INT64 = (-(2**63), 2**63 - 1)


def parameter_value(text: str) -> ParameterValue:
    """VALUE of `param set` as `ros2 param set` reads it (rclpy's `get_parameter_value`: YAML, a
    mixed list a string), refused (ValueError, one line) where rclpy would raise: a mapping, a
    YAML tag or construct that is not a plain value, an integer outside 64 bits.
    """
    try:
        loaded = yaml.safe_load(text)
    except yaml.parser.ParserError:  # as rclpy: text YAML cannot parse is a string
        loaded = text
    except yaml.YAMLError as exc:
        first = str(exc).strip().splitlines()[0]
        raise ValueError(f"value {text!r} is not a plain YAML value ({first})") from None
    if isinstance(loaded, dict):
        raise ValueError(
            f"value {text!r} is a mapping: a parameter is a bool, an integer, a double, a string "
            "or a list of one of them"
        )
    numbers = loaded if isinstance(loaded, list) else [loaded]
    for v in numbers:
        if isinstance(v, int) and not isinstance(v, bool) and not INT64[0] <= v <= INT64[1]:
            raise ValueError(f"value {text!r}: {v} is outside the 64-bit integer range")
    return get_parameter_value(text)


def _spin(node, future, timeout_s: float, what: str):
    rclpy.spin_until_future_complete(node, future, timeout_sec=timeout_s)
    if not future.done() or future.result() is None:
        raise TimeoutError(f"no answer to {what} within {timeout_s:g} s")
    return future.result()


def main(argv: list[str] | None = None) -> int:
    defaults = cli_defaults("flaair param")
    parser = argparse.ArgumentParser(
        prog="flaair param",
        description=__doc__,
        formatter_class=HelpFormatter,
    )
    parser.add_argument("verb", choices=("get", "list", "set"))
    parser.add_argument("node", help="node name, e.g. /plant_node")
    parser.add_argument("name", nargs="?", help="parameter name (get, set)")
    parser.add_argument("value", nargs="?", help="new value (set), read as YAML")
    parser.add_argument("--hide-type", action="store_true", help="get: the value alone")
    parser.add_argument(
        "--timeout",
        type=float,
        default=float(defaults["param_timeout_s"]),
        help=f"seconds to wait for the node (default {defaults['param_timeout_s']})",
    )
    parser.add_argument(
        "--no-daemon", action="store_true", help="accepted for ros2cli's sake (no daemon)"
    )
    words = sys.argv[1:] if argv is None else list(argv)
    if words and words[0] in ("describe", "dump", "load", "delete"):
        print(
            f"flaair param: {words[0]} is not covered by this stand-in (see --help); on a full "
            f"ROS 2 install: ros2 param {' '.join(words)}",
            file=sys.stderr,
        )
        return 2
    args = parse_or_refuse(parser, words, "param")
    if args.verb in ("get", "set") and not args.name:
        parser.error(f"{args.verb} needs a parameter name")
    if args.verb == "set" and args.value is None:
        parser.error("set needs a value: bin/flaair param set NODE NAME VALUE")
    value = None
    if args.verb == "set":
        try:  # the value checked before any node comes up
            value = parameter_value(args.value)
        except ValueError as exc:
            print(f"flaair param set: {exc}", file=sys.stderr)
            return 2

    def body(node) -> int:
        try:
            client = AsyncParameterClient(node, args.node)
            if not client.wait_for_services(timeout_sec=args.timeout):
                print(
                    f"Node not found: no parameter services of '{args.node}' within "
                    f"{args.timeout:g} s",
                    file=sys.stderr,
                )
                return 1
            if args.verb == "list":
                for name in sorted(
                    _spin(
                        node, client.list_parameters(), args.timeout, "list_parameters"
                    ).result.names
                ):
                    print(f"  {name}")
                return 0
            values = _spin(
                node, client.get_parameters([args.name]), args.timeout, "get_parameters"
            ).values
            if args.verb == "get":
                if not values:
                    print("Parameter not set", file=sys.stderr)
                    return 1
                print(get_text(values[0], args.hide_type))
                return 0
            if not values or values[0].type == ParameterType.PARAMETER_NOT_SET:
                print(
                    f"flaair param: node '{args.node}' has no parameter '{args.name}'",
                    file=sys.stderr,
                )
                return 1
            message = ParameterMsg(name=args.name, value=value)
            (result,) = _spin(
                node, client.set_parameters([message]), args.timeout, "set_parameters"
            ).results
            reason = f": {result.reason}" if result.reason else ""
            if not result.successful:
                print(f"Setting parameter failed{reason}", file=sys.stderr)
                return 1
            print(f"Set parameter successful{reason}")
            return 0
        except TimeoutError as exc:
            print(f"flaair param: {exc}", file=sys.stderr)
            return 1

    return run_with_node(hidden_node_name("param"), body)


if __name__ == "__main__":
    sys.exit(main())
