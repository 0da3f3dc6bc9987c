"""`bin/flaair foxglove [HOST:PORT]`: serve the running
graph to Foxglove / Lichtblick (foxglove_node).
"""

from __future__ import annotations

import argparse
import sys

from flaair_common.cli_help import HelpFormatter
from flaair_common.runtime import help_text, run_node
from flaair_tools.liveview import foxglove_node
from flaair_tools.liveview.foxglove_io import CONFIG_FILE, NODE_NAME, PARAMS, foxglove_node_args
from flaair_tools.liveview.foxglove_node import FoxgloveNode


def main(argv: list[str]) -> int:
    """Parse HOST:PORT (and pass anything after --ros-args through), then run the node."""
    parser = argparse.ArgumentParser(
        prog="flaair foxglove",
        description=foxglove_node.__doc__,
        formatter_class=HelpFormatter,
        epilog=help_text("", PARAMS, CONFIG_FILE, NODE_NAME),
    )
    parser.add_argument(
        "listen",
        nargs="?",
        help="HOST:PORT to serve on (default: host and port in config/flaair.yaml)",
    )
    cut = argv.index("--ros-args") if "--ros-args" in argv else len(argv)
    listen, ros_args = parser.parse_args(argv[:cut]).listen, argv[cut + 1 :]
    try:
        ros_args = (foxglove_node_args(listen)[4:] if listen else []) + ros_args
    except ValueError as exc:
        print(f"flaair foxglove: {exc}", file=sys.stderr)
        return 2
    sys.argv[0] = "flaair foxglove"  # errors read "flaair foxglove: ..."
    return run_node(
        FoxgloveNode, PARAMS, CONFIG_FILE, NODE_NAME, ["flaair foxglove", "--ros-args", *ros_args]
    )
