"""What the stand-ins share with ros2cli: its discovery flags, its node naming, and one line for a
flag they do not cover.

ros2cli without its daemon (`--no-daemon`) creates a hidden node (`_ros2cli_PID`), spins it for
`--spin-time` (0.5 s) so discovery can fill the graph, then reads the graph once. The stand-ins
do the same with a hidden node of their own (`_flaair_VERB_PID`, so neither lists the other), and
for `node list` / `topic list` keep listening while names still appear (at most `MAX_SETTLE_S`):
under load the graph arrives over seconds, and a fixed window misses part of it. `node list` also
waits while a topic endpoint belongs to a node not listed yet (its name still unknown). There is no
daemon here: `--no-daemon` is accepted and changes nothing.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable, Sequence

__all__ = [
    "MAX_SETTLE_S",
    "SPIN_TIME_S",
    "add_discovery_arguments",
    "hidden_node_name",
    "listen_until_settled",
    "parse_or_refuse",
]

SPIN_TIME_S = 0.5  # ros2cli's DirectNode default (--spin-time)
MAX_SETTLE_S = 5.0  # the longest a list keeps listening for late names


def hidden_node_name(verb: str) -> str:
    """The stand-in's own node name: hidden (leading '_'), as ros2cli's `_ros2cli_PID`."""
    return f"_flaair_{verb}_{os.getpid()}"


def add_discovery_arguments(parser: argparse.ArgumentParser, spin_time_s: float) -> None:
    """ros2cli's `--spin-time` and `--no-daemon` (the latter accepted, there being no daemon)."""
    parser.add_argument(
        "--spin-time",
        type=float,
        default=spin_time_s,
        metavar="S",
        help=f"listen at least this long for discovery (default {spin_time_s:g} s; "
        f"then longer while names still appear, at most {MAX_SETTLE_S:g} s)",
    )
    parser.add_argument(
        "--no-daemon", action="store_true", help="accepted for ros2cli's sake (no daemon here)"
    )


def listen_until_settled(
    spin: Callable[[float], None],
    names: Callable[[], set[str]],
    spin_time_s: float,
    pending: Callable[[], bool] = lambda: False,
) -> set[str]:
    """Names seen after `spin_time_s` of spinning, and after as long again with none new and
    nothing `pending` (at most MAX_SETTLE_S in all).
    """
    start = time.monotonic()
    seen: set[str] = set()
    last_new = start
    while True:
        spin(0.05)
        now, current = time.monotonic(), names()
        if current - seen:
            last_new = now
        seen = current
        if now - start >= MAX_SETTLE_S or (
            now - start >= spin_time_s and now - last_new >= spin_time_s and not pending()
        ):
            return seen


def parse_or_refuse(
    parser: argparse.ArgumentParser, argv: Sequence[str] | None, command: str
) -> argparse.Namespace:
    """`parser`'s arguments; a flag or word it does not take ends the command (exit 2) with one
    line naming it and the real `ros2 COMMAND ...` line to use on a full install.
    """
    words = list(sys.argv[1:] if argv is None else argv)
    try:  # flags among the positionals (`call --json NAME TYPE`), as ros2cli takes them
        args, extra = parser.parse_known_intermixed_args(words)
    except TypeError:  # a parser with sub-commands: argparse cannot intermix those
        args, extra = parser.parse_known_args(words)
    if extra:
        print(
            f"flaair {command}: {extra[0]} is not covered by this stand-in (see --help); on a "
            f"full ROS 2 install: ros2 {command} {' '.join(words)}",
            file=sys.stderr,
        )
        raise SystemExit(2)
    return args
