"""Run a FLAAIR node: parameter errors become one clear line, Ctrl-C and SIGTERM shut down cleanly."""
from __future__ import annotations

import os
import signal
import sys
from typing import Callable

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from flaair_model.config import node_parameters
from flaair_common.params import ParameterError, ParamSpec


def help_text(doc: str, specs: list[ParamSpec], config_file: str, node_name: str) -> str:
    """The node's --help: its docstring and a table of parameters with defaults and ranges."""
    try:
        defaults = node_parameters(config_file, node_name)
    except ValueError:
        defaults = {}
    lines = [doc.strip(), "", f"Parameters (defaults from config/{config_file}; set with --ros-args -p NAME:=VALUE):"]
    for spec in specs:
        allowed = ""
        if spec.choices:
            allowed = " {" + "|".join(spec.choices) + "}"
        elif spec.min_value is not None or spec.max_value is not None:
            allowed = f" [{spec.min_value}, {spec.max_value}]"
        lines.append(f"  {spec.name} ({spec.type.__name__}, default {defaults.get(spec.name)!r}){allowed}")
        lines.append(f"      {spec.description}")
    return "\n".join(lines)


def make_executor(default: str = "events"):
    """rclpy's C++ EventsExecutor by default, or the SingleThreadedExecutor.

    The EventsExecutor takes a third of the CPU per message (bench/bench_closed_loop.py:
    ping-pong ~200 us vs ~600 us on the 2-core machine), which bounds a graph moving 2000
    blocks/s per stream. FLAAIR_EXECUTOR=single|events overrides `default` for every node
    (for comparisons, or should the experimental executor misbehave on another install).
    """
    kind = os.environ.get("FLAAIR_EXECUTOR", default)
    if kind not in ("single", "events"):
        raise ValueError(f"FLAAIR_EXECUTOR must be 'single' or 'events', got {kind!r}")
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    return SingleThreadedExecutor()


def run_node(
    make_node: Callable[[], Node],
    specs: list[ParamSpec],
    config_file: str,
    node_name: str,
    args: list[str] | None = None,
    executor_kind: str = "events",
) -> int:
    """Initialise rclpy, build the node, spin until shutdown; return a process exit code.

    executor_kind is the default of `make_executor` (the recorder drains its queues inside
    a callback, which only the SingleThreadedExecutor allows).

    A refused parameter prints `<node>: <reason>` and returns 2. SIGINT and SIGTERM stop
    spinning, call the node's `close()` if it has one (flush files, zero the drive), then
    destroy the node and shut rclpy down.
    """
    args = sys.argv if args is None else args
    if any(a in ("-h", "--help") for a in args[1:]) and "--ros-args" not in args:
        print(help_text(sys.modules[make_node.__module__].__doc__ or "", specs, config_file, node_name))
        return 0
    rclpy.init(args=args, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node: Node | None = None
    executor = make_executor(executor_kind)

    stop_requested = False

    def _stop(signum: int, _frame: object) -> None:
        # Only set a flag: shutting the context down here would break a callback mid-publish.
        nonlocal stop_requested
        stop_requested = True

    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    try:
        node = make_node()
    except ParameterError as exc:
        print(f"{sys.argv[0].rsplit('/', 1)[-1]}: {exc}", file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    executor.add_node(node)
    try:
        while not stop_requested and rclpy.ok():
            executor.spin_once(timeout_sec=0.05)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        close = getattr(node, "close", None)
        if callable(close):
            close()
        executor.remove_node(node)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def warn_counted(logger, count: int, text: str, every_up_to: int = 10) -> None:
    """Log a warning every time for the first `every_up_to` occurrences, then at most once a second.

    rclpy fixes a call site's throttle on its first call (changing it raises), so the two
    regimes are two call sites.
    """
    if count <= every_up_to:
        logger.warning(text)
    else:
        logger.warning(text, throttle_duration_sec=1.0)
