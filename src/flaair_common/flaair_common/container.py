r"""container: several FLAAIR nodes in one process and one executor (ROS 2 composition).

The same node classes that `bin/flaair run` starts one per process are built here side by
side; the block streams named by --local-topics travel between them in-process, without
serialization (`flaair_common.intra`), and every topic is still published on DDS for the
recorder and any outside listener. `flaair live` runs its hot loop (bridge or plant, front end,
controller) this way by default.

Usage:
  bin/flaair run flaair_common container [--local-topics T1,T2,...] MODULE:CLASS [MODULE:CLASS ...]
      [--background MODULE:CLASS ...] [--ros-args --params-file FILE ...]
Example:
  bin/flaair run flaair_common container flaair_sim.plant_node:PlantNode \
      flaair_sensors.frontend_node:FrontendNode \
      flaair_control.dsa_controller_node:DsaControllerNode --ros-args -p mode:=lockstep

FLAAIR_PROFILE=1 times every in-process callback (thread CPU and wall) and prints one line per
node callback at exit: `profile: plant_node.on_command: N calls, X us CPU, Y us wall per call`.

Node parameters: each node reads its own section of config/flaair.yaml; give per-node
overrides in a --params-file with one section per node name (a plain -p applies to every node
that declares the parameter).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Callable

from flaair_common import intra, topics
from flaair_common.realtime import take_realtime_priority
from flaair_common.runtime import run_nodes

HOT_TOPICS = (topics.DRIVE, topics.SENSOR_VOLTAGE, topics.WING_STATE)


def load_class(spec: str) -> Callable:
    """`module.path:ClassName` -> the class; a clear error when it is not there."""
    module_name, _, class_name = spec.partition(":")
    if not class_name:
        raise ValueError(f"{spec!r}: expected MODULE:CLASS, e.g. flaair_sim.plant_node:PlantNode")
    try:
        return getattr(importlib.import_module(module_name), class_name)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"{spec!r}: {exc}") from exc


def _built_in_background(cls: Callable, bus: object | None) -> Callable:
    """A maker of `cls` whose in-process subscriptions go to the bus's background FIFO."""

    def make():
        if bus is not None:
            bus.building_background = True
        try:
            return cls()
        finally:
            if bus is not None:
                bus.building_background = False

    return make


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv if argv is None else argv
    ros_at = argv.index("--ros-args") if "--ros-args" in argv else len(argv)
    parser = argparse.ArgumentParser(
        prog="container", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "nodes", nargs="+", metavar="MODULE:CLASS", help="node classes to build, in order"
    )
    parser.add_argument(
        "--local-topics",
        default=",".join(HOT_TOPICS),
        help="block topics delivered in-process between the nodes (comma-separated; '' for none)",
    )
    parser.add_argument(
        "--background",
        action="append",
        default=[],
        metavar="MODULE:CLASS",
        help="a node off the hot path (the collision monitor, the recorder): built "
        "first and closed last; its in-process blocks are handled by the main "
        "thread after the hot loop's (repeatable)",
    )
    parser.add_argument(
        "--dds-batch",
        type=int,
        default=1,
        metavar="N",
        help="the local block "
        "streams reach DDS "
        "(recorder, monitor, "
        "outside listeners) "
        "joined, N blocks to "
        "a message "
        "(in-process "
        "subscribers still "
        "get every block at "
        "once)",
    )
    parser.add_argument(
        "--realtime-priority",
        type=int,
        default=0,
        metavar="P",
        help="run every thread of the container SCHED_FIFO at priority P (1-99; 0: "
        "normal "
        "scheduling): a thread that holds the interpreter lock is then never "
        "preempted "
        "by other processes while the loop waits for it",
    )
    parser.add_argument(
        "--executor",
        choices=("events", "single"),
        default="events",
        help="rclpy executor (single: for nodes that create subscriptions while "
        "spinning, "
        "as a composed recorder does; rclpy's EventsExecutor fails on that)",
    )
    args = parser.parse_args(argv[1:ros_at])
    try:
        makers = [load_class(spec) for spec in args.nodes]
        background = [load_class(spec) for spec in args.background]
    except ValueError as exc:
        print(f"container: {exc}", file=sys.stderr)
        return 2

    local = {t for t in args.local_topics.split(",") if t}
    if not 0 <= args.realtime_priority <= 99:
        print(
            f"container: --realtime-priority {args.realtime_priority}: must be 0..99",
            file=sys.stderr,
        )
        return 2
    # before rclpy starts its threads: they inherit the policy
    if error := take_realtime_priority(args.realtime_priority):
        print(
            f"container: WARNING: runs without real-time priority {args.realtime_priority} "
            f"({error}); run as root or grant CAP_SYS_NICE",
            file=sys.stderr,
        )
    if args.dds_batch < 1:
        print(f"container: --dds-batch {args.dds_batch}: must be >= 1", file=sys.stderr)
        return 2
    bus = (
        intra.Bus(
            local,
            profile=os.environ.get("FLAAIR_PROFILE", "0") not in ("", "0"),
            dds_batch=args.dds_batch,
        )
        if local
        else None
    )
    # Built first, closed last: a composed recorder records the loop's closing zero block and stop.
    makers = [_built_in_background(cls, bus) for cls in background] + makers
    code = run_nodes(makers, [argv[0], *argv[ros_at:]], executor_kind=args.executor, bus=bus)
    if bus is not None and bus.profile is not None:  # FLAAIR_PROFILE=1: each node's time per block
        print("\n".join(bus.profile.report()), file=sys.stderr, flush=True)
    return code


if __name__ == "__main__":
    raise SystemExit(main())
