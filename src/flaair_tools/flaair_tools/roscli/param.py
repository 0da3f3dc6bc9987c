"""`flaair param`: read and set a running node's parameters (stands in for `ros2 param`).

`set` converts VALUE to the parameter's current type (a double takes "0" as 0.0; bools take
true/false; arrays take JSON or YAML lists) and prints the node's reason when it refuses.

Examples
--------
  bin/flaair param list /plant_node
  bin/flaair param get /plant_node mode
  bin/flaair param set /dsa_controller_node kr_target 0.0     # K_r ramps to asynchronous from now
"""

from __future__ import annotations

import argparse
import sys

import rclpy
import yaml
from rcl_interfaces.msg import ParameterType
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient

from flaair_tools.roscli.node_cli import cli_defaults, run_with_node


class ValueTypeError(ValueError):
    """VALUE does not read as the parameter's type."""


def convert(text: str, type_id: int, name: str):
    """`text` as a value of ParameterType `type_id` (ValueTypeError naming the parameter)."""
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        value = text
    kinds = {
        ParameterType.PARAMETER_BOOL: (bool,),
        ParameterType.PARAMETER_INTEGER: (int,),
        ParameterType.PARAMETER_DOUBLE: (int, float),
        ParameterType.PARAMETER_STRING: None,
    }
    if type_id == ParameterType.PARAMETER_STRING:
        return text
    if (
        type_id == ParameterType.PARAMETER_DOUBLE_ARRAY
        and isinstance(value, list)
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
    ):
        return [float(v) for v in value]
    allowed = kinds.get(type_id)
    if (
        allowed
        and isinstance(value, allowed)
        and not (isinstance(value, bool) and bool not in allowed)
    ):
        return float(value) if type_id == ParameterType.PARAMETER_DOUBLE else value
    wanted = {
        ParameterType.PARAMETER_BOOL: "true or false",
        ParameterType.PARAMETER_INTEGER: "an integer",
        ParameterType.PARAMETER_DOUBLE: "a number",
        ParameterType.PARAMETER_DOUBLE_ARRAY: "a list of numbers",
    }
    raise ValueTypeError(
        f"parameter '{name}' takes {wanted.get(type_id, f'type {type_id}')}, got {text!r}"
    )


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
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("verb", choices=("get", "list", "set"))
    parser.add_argument("node", help="node name, e.g. /plant_node")
    parser.add_argument("name", nargs="?", help="parameter name (get, set)")
    parser.add_argument("value", nargs="?", help="new value (set)")
    parser.add_argument(
        "--timeout",
        type=float,
        default=float(defaults["param_timeout_s"]),
        help=f"seconds to wait for the node (default {defaults['param_timeout_s']})",
    )
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.verb in ("get", "set") and not args.name:
        parser.error(f"{args.verb} needs a parameter name")
    if args.verb == "set" and args.value is None:
        parser.error("set needs a value: bin/flaair param set NODE NAME VALUE")

    def body(node) -> int:
        try:
            client = AsyncParameterClient(node, args.node)
            if not client.wait_for_services(timeout_sec=args.timeout):
                print(
                    f"flaair param: node '{args.node}' not found within {args.timeout:g} s",
                    file=sys.stderr,
                )
                return 1
            if args.verb == "list":
                for name in sorted(
                    _spin(
                        node, client.list_parameters(), args.timeout, "list_parameters"
                    ).result.names
                ):
                    print(name)
                return 0
            values = _spin(
                node, client.get_parameters([args.name]), args.timeout, "get_parameters"
            ).values
            if not values or values[0].type == ParameterType.PARAMETER_NOT_SET:
                print(
                    f"flaair param: node '{args.node}' has no parameter '{args.name}'",
                    file=sys.stderr,
                )
                return 1
            if args.verb == "get":
                print(parameter_value_to_python(values[0]))
                return 0
            try:
                value = convert(args.value, values[0].type, args.name)
            except ValueTypeError as exc:
                print(f"flaair param set: {exc}", file=sys.stderr)
                return 2
            (result,) = _spin(
                node,
                client.set_parameters([Parameter(args.name, value=value)]),
                args.timeout,
                "set_parameters",
            ).results
            if not result.successful:
                print(
                    f"flaair param set: {args.node} refused {args.name} = {value!r}: "
                    f"{result.reason}",
                    file=sys.stderr,
                )
                return 1
            print(f"set {args.name} = {value!r} on {args.node}")
            return 0
        except TimeoutError as exc:
            print(f"flaair param: {exc}", file=sys.stderr)
            return 1

    return run_with_node("flaair_param", body)


if __name__ == "__main__":
    sys.exit(main())
