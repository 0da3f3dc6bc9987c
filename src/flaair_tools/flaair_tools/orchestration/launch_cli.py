"""`flaair launch PACKAGE FILE [name:=value ...]`: run a ROS 2 XML launch file (stands in for
`ros2 launch`, which PyPI does not carry).

Reads the file (the subset FLAAIR's files use: node, param, remap, arg, let, group with
push-ros-namespace, include; flaair_tools.orchestration.launch_file) and starts each node as
`bin/flaair run` would, one process each, on a private ROS domain with localhost discovery
(--subnet: the whole subnet; --domain-id: a fixed one, to share it with other programs), every
child dying with this process. Runs until Ctrl-C or SIGTERM, then stops the nodes in reverse
start order and exits 0; a node that dies ends the launch with its log's last lines, exit 1.
Every node's name, namespace, parameter names and remaps (launch arguments reach them through
$(var ...)) are checked against the ROS name rules before anything is printed or started (one
line naming the value, exit 2); --print quotes each command line for a shell (shlex).

Examples
--------
  bin/flaair launch flaair_tools lockstep_loop.launch.xml namespace:=bench2
  bin/flaair launch flaair_tools record.launch.xml output_path:=out/bags/run1 --domain-id 7
  bin/flaair launch flaair_tools live_sim.launch.xml --print     # what it would start
  bin/flaair launch flaair_tools lockstep_loop.launch.xml --show-args

Terms (lockstep): docs/GLOSSARY.md.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import tempfile
import time
from pathlib import Path

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

from flaair_common.cli_help import HelpFormatter
from flaair_common.graph import (
    Graph,
    GraphError,
    Terminated,
    is_termination,
    node_argv,
    terminate_raises,
)
from flaair_tools.orchestration import launch_file, second_terminal
from flaair_tools.orchestration.graphs import LAUNCH_PACKAGE, launch_dir

POLL_S = 0.2  # how often the launch looks for a node that died


def find_launch_file(package: str, name: str) -> Path:
    """PACKAGE's launch file NAME (its share/PACKAGE/launch, or the checkout's for FLAAIR's)."""
    if Path(name).is_file():
        return Path(name)
    if package == LAUNCH_PACKAGE:
        return launch_dir() / name
    try:
        return Path(get_package_share_directory(package)) / "launch" / name
    except PackageNotFoundError:
        raise launch_file.LaunchFileError(f"package '{package}' is not installed") from None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="flaair launch",
        description=__doc__,
        formatter_class=HelpFormatter,
    )
    parser.add_argument("package", help="package holding the launch file, e.g. flaair_tools")
    parser.add_argument("file", help="launch file name in its share/PACKAGE/launch, or a path")
    parser.add_argument(
        "arguments",
        nargs="*",
        metavar="name:=value",
        help="launch arguments (--show-args lists them)",
    )
    parser.add_argument(
        "--print",
        action="store_true",
        dest="print_only",
        help="print each node's command line and exit",
    )
    parser.add_argument("--show-args", action="store_true", help="list the launch arguments")
    parser.add_argument(
        "--domain-id",
        type=int,
        help="ROS domain to run on (default: a private one no other FLAAIR graph holds)",
    )
    parser.add_argument(
        "--subnet", action="store_true", help="discover the whole subnet (default: localhost only)"
    )
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.domain_id is not None and not 0 <= args.domain_id <= 232:
        parser.error(
            f"--domain-id {args.domain_id}: a ROS domain is 0-232 (1-101 are safe on Linux)"
        )
    try:
        path = find_launch_file(args.package, args.file)
        if args.show_args:
            described = launch_file.load(path, find_share=None, allow_missing_arguments=True)
            for argument in described.arguments:
                default = (
                    f" (default {argument.default!r})"
                    if argument.default is not None
                    else " (required)"
                )
                print(f"{argument.name}{default}: {argument.description}")
            return 0
        described = launch_file.load(path, launch_file.parse_launch_arguments(args.arguments))
        commands = [
            (node, node_argv(node.package, node.executable, node.ros_args()))
            for node in described.nodes
        ]
    except (launch_file.LaunchFileError, GraphError) as exc:
        print(f"flaair launch: {exc}", file=sys.stderr)
        return 2
    if args.print_only:
        for _, command in commands:
            print(shlex.join(command))  # quoted: pasted into a shell, a value stays a value
        return 0
    return _run(commands, args)


def _run(commands: list, args: argparse.Namespace) -> int:
    terminate_raises()
    log_dir = Path(tempfile.mkdtemp(prefix="flaair-launch-"))
    try:
        with Graph(domain_id=args.domain_id, localhost=not args.subnet, log_dir=log_dir) as graph:
            print(
                f"flaair launch: {len(commands)} node(s) on {graph.describe()}; logs in "
                f"{log_dir}; Ctrl-C stops\n{second_terminal.hint(graph.env)}",
                file=sys.stderr,
            )
            for node, command in commands:
                where = node.namespace.strip("/").replace("/", "_")
                graph.start(f"{where}_{node.name or node.executable}".lstrip("_"), command)
            while True:
                graph.check_alive()
                time.sleep(POLL_S)
    except KeyboardInterrupt:
        print("flaair launch: stopped (Ctrl-C)", file=sys.stderr)
        return 0
    except (Terminated, RuntimeError) as exc:
        if isinstance(exc, Terminated) or is_termination(exc):
            print("flaair launch: stopped (SIGTERM)", file=sys.stderr)
            return 0
        if isinstance(exc, GraphError):
            print(f"flaair launch: {exc}", file=sys.stderr)
            return 1
        raise


if __name__ == "__main__":
    sys.exit(main())
