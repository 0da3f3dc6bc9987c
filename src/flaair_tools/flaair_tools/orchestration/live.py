r"""`flaair live`: bring up the live graph around a real bench (or the simulated robot), record it.

  bin/flaair live (--target HOST:PORT --listen HOST:PORT | --sim) [--controller dsa|none]
                  [--duration S] [--out BAGDIR] [--foxglove HOST:PORT] [--calibration FILE]
                  [--no-health | --health-baseline HEALTH.json]

The hot loop (the real-time target's bridge, or with --sim the simulated plant paced in real
time; the front end; the dSA controller) runs composed in one process, its block streams
delivered in-process (`flaair_common.container`; --processes runs one process per node
instead). The collision monitor (per-wingbeat decision, stroke-locked windows: the flapping
frequency is free) and the recorder (--out) run in processes of their own, off the hot path:
the loop's block streams reach them over DDS joined into 10 ms messages (config/flaair.yaml
live.dds_batch_blocks), so the loop's interpreter spends its core on the loop. Beside them: the
health monitor (/flaair/health, /flaair/health/events; --no-health leaves it out) and the
Foxglove live view (--foxglove).
The controller runs the configured K_r schedule (config/flaair.yaml dsa_controller_node: the
transition experiment's), synchronous first, then self-excited.

The run ends after --duration seconds, or at Ctrl-C / SIGTERM, the same way: the controller
sends zero drive, the bridge a stop packet to the target, then the monitor, the live view and
the recorder stop and the bag is closed; exit 0. The graph runs in a private ROS domain with
localhost discovery (--subnet: discover the whole subnet), said at the start; two `live` or
`experiment` runs on one machine never see each other.

Against a target, live says where it waits for the first sensor packet as soon as the bridge
listens, and gives up after --first-packet-timeout (a mistyped port looks like a hang otherwise).

Exit status: 0 the run ended (duration, Ctrl-C, SIGTERM); 2 bad arguments, or the graph could not
run (a port in use, a node that failed); 3 no sensor packet from the target in time (the stop
packet sent, the bag closed).

The protocol: docs/formats/REALTIME_PROTOCOL.md; a first session on hardware (safety limits,
watchdogs, what to look at first): docs/HARDWARE_SESSION.md; terms (dSA, K_r): docs/GLOSSARY.md.
Rehearse without hardware against the emulated target:
  bin/flaair run flaair_bridge emulated_target --bridge 127.0.0.1:25000 --listen 127.0.0.1:25001 &
  bin/flaair live --target 127.0.0.1:25001 --listen 127.0.0.1:25000 --duration 5 \
      --out out/bags/bench
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import rclpy
import yaml
from rclpy.node import Node

from flaair_common import cdr, topics
from flaair_common.cli_help import HelpFormatter
from flaair_common.graph import (
    Graph,
    GraphError,
    Terminated,
    is_termination,
    node_argv,
    terminate_raises,
)
from flaair_common.msgdict import message_class
from flaair_common.qos import BLOCK_STREAM
from flaair_model import settings
from flaair_model.config import ConfigError
from flaair_model.schema import ParameterError
from flaair_tools.orchestration import second_terminal
from flaair_tools.orchestration.graphs import node_of
from flaair_tools.orchestration.live_args import (
    LiveError,
    add_health_baseline,
    host_port,
    live_graph,
    node_parameters_for,
    port_free,
)


def _argv(role: str, ros_args: list[str]) -> list[str]:
    node = node_of(role)
    return node_argv(node.package, node.executable, ros_args)


LISTEN_AGAIN_S = 1.0  # the watcher listens to the signal again this long before the duration is up
# Once the sensor blocks cover --duration, the drive's own samples get this much longer (wall clock)
# to: they lead the sensor by the loop's delay while the controller loops, but a tripped controller
# sends one zero block per keepalive period, a drive clock at a hundredth of the signal's rate
DRIVE_GRACE_S = 2.0
# a process of the graph gets this long to close (the recorder: write its backlog, close the bag)
LOOP_CLOSE_S = 180.0


class SilentTarget(LiveError):
    """No sensor packet from the target within first_packet_timeout_s of the bridge listening."""


EXIT_USAGE, EXIT_SILENT_TARGET = 2, 3


class Watcher:
    """live's own ROS node: advertises the loop's topics
    early, sees the recorder listen, counts signal time.
    """

    def __init__(self, graph: Graph, args: argparse.Namespace) -> None:
        os.environ.update({k: v for k, v in graph.env.items() if k.startswith("ROS_")})
        self.rclpy, self.graph, self.args = rclpy, graph, args
        # Ctrl-C/SIGTERM are ours
        rclpy.init(args=[], signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
        self.node = Node("flaair_live")
        self.end = {"index": -1, "rate": 0.0, "wall": time.monotonic()}
        self.topics = {
            topics.SENSOR_VOLTAGE: "flaair_msgs/msg/SensorVoltageBlock",
            topics.WING_STATE: "flaair_msgs/msg/WingStateBlock",
            topics.DRIVE: "flaair_msgs/msg/DriveCommandBlock",
        }
        if args.controller == "dsa":
            self.topics[topics.CONTROLLER_STATE] = "flaair_msgs/msg/ControllerState"
        self.topics[topics.COLLISION_STATUS] = "flaair_msgs/msg/CollisionStatus"
        if args.sim:
            self.topics[topics.WING_STATE_TRUTH] = "flaair_msgs/msg/WingStateBlock"
        # Advertised before the loop exists, so the recorder subscribes before the first block.
        self.adverts = [
            self.node.create_publisher(message_class(kind), topic, BLOCK_STREAM)
            for topic, kind in self.topics.items()
        ]
        self.listen_to_sensor = lambda: self.node.create_subscription(
            message_class(self.topics[topics.SENSOR_VOLTAGE]),
            topics.SENSOR_VOLTAGE,
            self.on_sensor,
            BLOCK_STREAM,
            raw=True,
        )
        # the controller's first drive sample: the loop runs
        self.first_drive_index: int | None = None
        self.drive_end = {"index": -1, "rate": 0.0, "wall": time.monotonic()}
        self.listen_to_drive = lambda: self.node.create_subscription(
            message_class(self.topics[topics.DRIVE]),
            topics.DRIVE,
            self.on_drive,
            BLOCK_STREAM,
            raw=True,
        )
        self.listening = [self.listen_to_sensor(), self.listen_to_drive()]
        # Every other batched stream of the loop too, until it starts: the controller waits for
        # two listeners on each (this process and the recorder), so a recorder matched late on one
        # of them cannot lose that stream's first blocks (a soak run lost 179 drive blocks so).
        for topic, kind in (
            (topics.WING_STATE, "WingStateBlock"),
            (topics.WING_STATE_TRUTH, "WingStateBlock"),
            (topics.DRIVE_APPLIED, "DriveCommandBlock"),
        ):
            self.listening.append(
                self.node.create_subscription(
                    message_class(f"flaair_msgs/msg/{kind}"),
                    topic,
                    lambda _data: None,
                    BLOCK_STREAM,
                    raw=True,
                )
            )

    def on_sensor(self, data: bytes) -> None:
        m = cdr.decode(cdr.SENSOR_VOLTAGE_BLOCK, data)
        self.end.update(
            index=int(m["first_sample_index"]) + len(m["stroke_sensor_v"]),
            rate=float(m["sample_rate_hz"]),
            wall=time.monotonic(),
        )

    def on_drive(self, data: bytes) -> None:
        m = cdr.decode(cdr.DRIVE_COMMAND_BLOCK, data)
        if self.first_drive_index is None:
            self.first_drive_index = int(m["first_sample_index"])
        self.drive_end.update(
            index=int(m["first_sample_index"]) + len(m["drive_v"]),
            rate=float(m["sample_rate_hz"]),
            wall=time.monotonic(),
        )

    def spin_until(self, predicate, timeout_s: float, what: str) -> None:
        deadline = time.monotonic() + timeout_s
        while not predicate():
            self.rclpy.spin_once(self.node, timeout_sec=0.05)
            self.graph.check_alive()
            if time.monotonic() > deadline:
                raise LiveError(
                    f"timed out after {timeout_s:g} s waiting for {what} (see the logs)"
                )

    def wait_for_the_target(self) -> None:
        """Once the bridge listens: say where packets are awaited, and give up (SilentTarget) if the
        target's first sensor packet has not come within --first-packet-timeout.
        """
        # the bridge's own publisher (this node advertises the topic too, for the recorder)
        self.spin_until(
            lambda: any(
                info.node_name != self.node.get_name()
                for info in self.node.get_publishers_info_by_topic(topics.SENSOR_VOLTAGE)
            ),
            120.0,
            "the bridge to start",
        )
        (target_host, target_port), (listen_host, listen_port) = self.args.target, self.args.listen
        timeout_s = self.args.first_packet_timeout
        print(
            "flaair live: waiting for the target's first sensor packet on "
            f"{listen_host}:{listen_port} (drive goes to {target_host}:{target_port}); giving up "
            f"after {timeout_s:g} s",
            file=sys.stderr,
            flush=True,
        )
        deadline = time.monotonic() + timeout_s
        while self.end["index"] < 0:
            self.rclpy.spin_once(self.node, timeout_sec=0.05)
            self.graph.check_alive()
            if time.monotonic() > deadline:
                raise SilentTarget(
                    "no sensor packet from the target on "
                    f"{listen_host}:{listen_port} in {timeout_s:g} s (drive was "
                    f"addressed to {target_host}:{target_port}): is the target "
                    "running, and sending to this address and port?"
                )

    def recorder_listens(self) -> bool:
        return self.args.out is None or all(
            any(
                i.node_name == node_of("recorder").node_name
                for i in self.node.get_subscriptions_info_by_topic(t)
            )
            for t in self.topics
        )

    def monitor_listens(self) -> bool:
        return any(
            i.node_name == node_of("collision_monitor").node_name
            for i in self.node.get_subscriptions_info_by_topic(topics.WING_STATE)
        )

    def health_listens(self) -> bool:
        return any(
            i.node_name == node_of("health").node_name
            for i in self.node.get_subscriptions_info_by_topic(topics.SENSOR_VOLTAGE)
        )

    def run_for_duration(self) -> None:
        """Wait for the loop to run (the first drive block; without a controller the first sensor
        block), then for --duration seconds of signal time.
        """
        if not self.args.sim:
            self.wait_for_the_target()
        self.spin_until(
            lambda: (
                self.end["index"] >= 0
                and (self.first_drive_index is not None or self.args.controller == "none")
            ),
            120.0,
            "the loop to start",
        )
        # from the controller's first drive sample: the sensor
        # blocks seen so far may lag it (batched, loaded)
        start = max(self.end["index"], self.first_drive_index or 0)
        print(
            f"flaair live: running from sample {start} for {self.args.duration:g} s of signal",
            file=sys.stderr,
        )
        # The run ends once both the sensor blocks and, with a controller, the drive's own samples
        # cover --duration: the sensor blocks this process has taken when the first drive block
        # comes may lag the plant by a loaded executor's backlog (a soak run timed on them alone
        # ended 0.29 s early), and the drive leads the sensor by the loop's delay.
        clocks = [(self.end, start, self.listen_to_sensor)]
        if self.first_drive_index is not None:
            clocks.append((self.drive_end, self.first_drive_index, self.listen_to_drive))
        # Listening to 2,000 blocks/s costs this process a fifth of a core, which the loop needs:
        # unsubscribe, wait out most of the duration on the wall clock (the loop runs in real
        # time), then listen again to end on the signal's own clock.
        for subscription in self.listening:
            self.node.destroy_subscription(subscription)
        quiet_until = time.monotonic() + self.args.duration - LISTEN_AGAIN_S
        while time.monotonic() < quiet_until:
            self.rclpy.spin_once(self.node, timeout_sec=0.05)
            self.graph.check_alive()
        self.listening = [listen() for _, _, listen in clocks]
        for clock, _, _ in clocks:
            clock["wall"] = time.monotonic()
        sensor_done_wall: float | None = None
        while True:
            left_s = [
                self.args.duration - (clock["index"] - first) / clock["rate"]
                if clock["rate"] > 0
                else math.inf
                for clock, first, _ in clocks
            ]
            if left_s[0] <= 0.0 and sensor_done_wall is None:
                sensor_done_wall = time.monotonic()
            why = run_end(
                left_s[0],
                left_s[1] if len(left_s) > 1 else None,
                0.0 if sensor_done_wall is None else time.monotonic() - sensor_done_wall,
            )
            if why is not None:
                if why != "covered":
                    print(f"flaair live: {why}", file=sys.stderr)
                break
            self.rclpy.spin_once(self.node, timeout_sec=0.05)
            self.graph.check_alive()
            for clock, _, _ in clocks:
                if time.monotonic() - clock["wall"] > 10.0:
                    stream = "drive" if clock is self.drive_end else "sensor"
                    raise LiveError(
                        f"no {stream} block for 10 s after sample {clock['index']}: the "
                        f"{'plant' if self.args.sim else 'target'} stopped (see the logs)"
                    )

    def close(self) -> None:
        self.node.destroy_node()
        self.rclpy.try_shutdown()


def run_end(
    sensor_left_s: float,
    drive_left_s: float | None,
    sensor_done_for_s: float,
    grace_s: float = DRIVE_GRACE_S,
) -> str | None:
    """Whether a run of --duration is over: None (not yet), "covered" (both clocks reached it), or
    why it ends on the sensor clock alone.

    sensor_left_s, drive_left_s: signal time each stream still needs (None: no drive stream);
    sensor_done_for_s: wall time since the sensor stream covered the duration.
    """
    if sensor_left_s > 0.0:
        return None
    if drive_left_s is None or drive_left_s <= 0.0:
        return "covered"
    if sensor_done_for_s < grace_s:
        return None
    return (
        f"ending on the sensor clock: the drive is still {drive_left_s:.2f} s of signal "
        f"short of the duration {sensor_done_for_s:.1f} s after the sensor reached it (the "
        "controller tripped or stopped: see the loop's log)"
    )


def bag_written(out: Path | None) -> bool:
    """The recorder left a bag at `out` (its directory holds a file)."""
    return out is not None and out.is_dir() and any(out.iterdir())


def end_line(
    status: str, stop_packet: bool, loop_started: bool, out: Path | None, bag: bool
) -> str:
    """Live's last line: how the run ended, what was sent, and the bag only where there is one."""
    if loop_started:
        sent = f"{'stop packet' if stop_packet else 'zero drive'} sent, every node stopped"
    else:
        sent = "the loop had not started (no drive sent), every node stopped"
    if out is not None:
        sent += f", bag {out} closed" if bag else f", no bag written ({out} not created)"
    return f"flaair live: {status}; {sent}"


def _announce(args: argparse.Namespace, graph: Graph, log_dir: Path) -> None:
    """What runs where, how to reach it from a second terminal, and a missing calibration."""
    robot = (
        "simulated robot (real-time plant)"
        if args.sim
        else f"target {args.target[0]}:{args.target[1]}"
    )
    loop = "one process per node" if args.processes else "composed in one process"
    print(
        f"flaair live: {robot}, loop {loop}, on {graph.describe()}; logs in {log_dir}\n"
        f"{second_terminal.hint(graph.env)}",
        file=sys.stderr,
    )
    if args.calibration is None:
        print(
            "flaair live: WARNING: no --calibration: the front end runs on the model's gains, so "
            "the sensor-derived pitch reads about 4x small (the model over-predicts the hinge "
            "sensor); run `bin/flaair calibrate`",
            file=sys.stderr,
        )


def _start_listeners(
    graph: Graph, args: argparse.Namespace, ros_args: list[str]
) -> subprocess.Popen | None:
    """The nodes off the hot path, each in a process of its own (the loop's interpreter is for
    the loop; the monitor keeps the C++ events executor, the recorder needs the single-threaded
    one); the recorder's process, if it records.
    """
    recorder_process = None
    if args.out is not None:
        recorder_process = graph.start("recorder", _argv("recorder", ros_args[1:]))
    graph.start("collision_monitor", _argv("collision_monitor", ros_args[1:]))
    if not args.no_health:
        graph.start("health", _argv("health", ros_args[1:]))
    if args.foxglove is not None:
        graph.start("foxglove", _argv("foxglove", ros_args[1:]))
        print(
            f"flaair live: Foxglove: open ws://{args.foxglove[0]}:{args.foxglove[1]} "
            "(layout: config/foxglove_layout.json)",
            file=sys.stderr,
        )
    return recorder_process


def _start_loop(
    graph: Graph, args: argparse.Namespace, hot: list[str], local_topics: Any, ros_args: list[str]
) -> list[subprocess.Popen]:
    """The hot loop's nodes: one process each, or composed in one container process."""
    if args.processes:
        return [graph.start(role, _argv(role, ros_args[1:])) for role in hot]
    batch = settings.live().dds_batch_blocks
    priority = 0 if args.sim else settings.bridge().realtime_priority
    return [
        graph.start(
            "loop",
            [
                *node_argv("flaair_common", "container"),
                "--local-topics",
                ",".join(local_topics),
                "--dds-batch",
                str(batch),
                "--realtime-priority",
                str(priority),
                *(node_of(role).component for role in hot),
                *ros_args,
            ],
        )
    ]


def _stop(
    graph: Graph,
    loop: list[subprocess.Popen],
    recorder_process: subprocess.Popen | None,
    watcher: Watcher | None,
) -> None:
    """The loop first (zero drive, stop packet), then the listeners; the recorder last (the
    loop's process exits only once the recorder has acknowledged its last messages).
    """
    for process in reversed(loop):
        graph.stop(process, timeout_s=LOOP_CLOSE_S)
    if recorder_process is not None:
        graph.stop(recorder_process, timeout_s=LOOP_CLOSE_S)
    if watcher is not None:
        watcher.close()
    graph.close()


def run_live(args: argparse.Namespace) -> int:
    """Bring the graph up, run it for --duration (or until a signal), bring it down; exit code."""
    log_dir = (  # absolute: the graph's processes run in the repository's root
        (args.out.parent / f"{args.out.name}.logs")
        if args.out is not None
        else Path("out/live") / time.strftime("%Y%m%d_%H%M%S")
    ).absolute()
    graph = Graph(localhost=not args.subnet, log_dir=log_dir)
    params_file = log_dir / "params.yaml"
    params_file.parent.mkdir(parents=True, exist_ok=True)
    params_file.write_text(yaml.safe_dump(node_parameters_for(args), sort_keys=False))
    ros_args = ["--ros-args", "--params-file", str(params_file)]
    declared = live_graph(args)
    # In the declared order: the plant first, closed last (the controller's zero block reaches it);
    # the bridge last: its socket opens once the front end and the controller have loaded their
    # kernels (the target's packets would queue up meanwhile), and its stop packet zeroes the target
    # when it closes.
    hot = [role for role in declared.hot if role != "controller" or args.controller == "dsa"]
    _announce(args, graph, log_dir)
    loop: list[subprocess.Popen] = []
    recorder_process = None
    watcher: Watcher | None = None
    try:
        recorder_process = _start_listeners(graph, args, ros_args)
        watcher = Watcher(graph, args)
        watcher.spin_until(watcher.recorder_listens, 120.0, "the recorder to subscribe")
        # the monitors subscribe before the loop starts too
        watcher.spin_until(watcher.monitor_listens, 120.0, "the collision monitor to subscribe")
        if not args.no_health:
            watcher.spin_until(watcher.health_listens, 120.0, "the health monitor to subscribe")
        loop += _start_loop(graph, args, hot, declared.local_topics, ros_args)
        watcher.run_for_duration()
        status, silent = "duration reached", None
    except KeyboardInterrupt:
        status, silent = "interrupted", None
    # ended the same way as a run: stop packet, bag closed; then the error
    except SilentTarget as exc:
        status, silent = "no target", exc
    except (GraphError, LiveError) as exc:  # before RuntimeError: both are RuntimeErrors
        _stop(graph, loop, None, watcher)
        raise LiveError(str(exc)) from exc
    # rclpy may hand SIGTERM's exception on as a RuntimeError
    except (Terminated, RuntimeError) as exc:
        if not is_termination(exc):
            raise
        status, silent = "terminated", None
    _stop(graph, loop, recorder_process, watcher)
    print(
        end_line(status, silent is not None, bool(loop), args.out, bag_written(args.out)),
        file=sys.stderr,
    )
    if silent is not None:
        print(f"flaair live: error: {silent}", file=sys.stderr)
        return EXIT_SILENT_TARGET
    return 0


def _parser() -> argparse.ArgumentParser:
    """`flaair live`'s options."""
    parser = argparse.ArgumentParser(
        prog="flaair live",
        description=__doc__,
        formatter_class=HelpFormatter,
    )
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument(
        "--sim",
        action="store_true",
        help="the simulated robot, paced in real time (default: off; --sim or --target is "
        "required)",
    )
    where.add_argument(
        "--target",
        metavar="HOST:PORT",
        help="the real-time target's drive receiver: its UDP Receive address (default: none; "
        "--sim or --target is required)",
    )
    parser.add_argument(
        "--listen",
        metavar="HOST:PORT",
        help="where the target's sensor packets arrive: the address its UDP Send points at "
        "(default: none; required with --target)",
    )
    parser.add_argument(
        "--controller",
        choices=("dsa", "none"),
        default="dsa",
        help="dsa: close the loop with the dSA controller (the configured K_r schedule: a "
        "synchronous sine, then self-excited flapping); none: no controller, no drive sent "
        "(a target holds its last sample, then zeroes; the front end, monitors and recorder "
        "run on what it sends) (default: %(default)s)",
    )
    parser.add_argument(
        "--duration",
        type=float,
        default=5.0,
        metavar="S",
        help="run this long of signal time (default 5 s): until the sensor "
        "and drive streams both cover it; a tripped controller's drive, "
        f"which no longer keeps pace, is waited for {DRIVE_GRACE_S:g} s "
        "more at most",
    )
    parser.add_argument(
        "--out",
        type=Path,
        help="record every /flaair topic to this bag directory (default: none: not recorded)",
    )
    parser.add_argument(
        "--foxglove", metavar="HOST:PORT", help="serve the live graph to Foxglove / Lichtblick here"
    )
    parser.add_argument(
        "--calibration",
        type=Path,
        help="front end gains, and the health monitor's film lags and gains, from this "
        "calibration.yaml (default: none: the model's gains; pitch reads about 4x small on a "
        "real robot)",
    )
    parser.add_argument(
        "--lead-samples",
        type=int,
        metavar="N",
        help="bridge: drive sent N samples ahead of the target's clock (default: "
        "config/flaair.yaml bridge_node.lead_samples, 40 = 2 ms)",
    )
    parser.add_argument(
        "--first-packet-timeout",
        type=float,
        metavar="S",
        help="--target: give up (exit 3) if the target's first sensor packet has "
        "not come this long "
        "after the bridge listens (default: config/flaair.yaml "
        "live.first_packet_timeout_s)",
    )
    parser.add_argument(
        "--no-health",
        action="store_true",
        help="leave the health monitor (health_node: /flaair/health, /flaair/health/events) out "
        "of the graph; by default it runs beside the loop in a process of its own",
    )
    add_health_baseline(parser)
    parser.add_argument(
        "--processes", action="store_true", help="one process per node instead of the composed loop"
    )
    parser.add_argument(
        "--subnet", action="store_true", help="discover the whole subnet, not only this machine"
    )
    # benchmarks: bridge_node parameters NAME=VALUE (e.g. timing_file=out/t.npz)
    parser.add_argument("--bridge-param", action="append", default=[], help=argparse.SUPPRESS)
    return parser


def _checked(args: argparse.Namespace) -> None:
    """The addresses parsed and the values checked before anything starts (LiveError names the
    first one that is wrong).
    """
    if not args.sim:
        if args.listen is None:
            raise LiveError(
                "--target needs --listen HOST:PORT (where the target's sensor packets arrive)"
            )
        args.target, args.listen = (
            host_port(args.target, "--target"),
            host_port(args.listen, "--listen"),
        )
    if args.foxglove is not None:
        args.foxglove = host_port(args.foxglove, "--foxglove")
        port_free(args.foxglove, "--foxglove")
    if args.first_packet_timeout is None:
        args.first_packet_timeout = settings.live().first_packet_timeout_s
    if not (args.first_packet_timeout > 0):
        raise LiveError(f"first packet timeout {args.first_packet_timeout}: must be > 0 s")
    if not (args.duration > 0):
        raise LiveError(f"--duration {args.duration}: must be > 0 s")
    if args.out is not None and args.out.exists():
        raise LiveError(f"--out {args.out} exists; choose another or remove it")
    if args.calibration is not None and not args.calibration.is_file():
        raise LiveError(f"--calibration {args.calibration}: no such file")
    if args.health_baseline is not None:
        if args.no_health:
            raise LiveError("--health-baseline with --no-health: the monitor is left out")
        # deferred: the monitor's core (numba) costs 1.5 s of import; only a baseline needs it
        from flaair_control.health_io import check_baseline_file

        try:
            check_baseline_file(args.health_baseline, args.calibration)
        except ParameterError as exc:
            raise LiveError(f"--health-baseline: {exc}") from None


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    # absolute: the graph's processes run in the repository's root, not in this directory
    args.out = None if args.out is None else args.out.absolute()
    args.calibration = None if args.calibration is None else args.calibration.absolute()
    if args.health_baseline is not None:
        args.health_baseline = args.health_baseline.absolute()
    terminate_raises()
    try:
        _checked(args)
        return run_live(args)
    except (LiveError, ConfigError) as exc:
        print(f"flaair live: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except (KeyboardInterrupt, Terminated):
        print("flaair live: interrupted before the graph was up", file=sys.stderr)
        return 0


if __name__ == "__main__":
    sys.exit(main())
