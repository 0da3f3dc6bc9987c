"""`flaair experiment NAME --out BAG`: run a paper experiment on the simulated robot and record it.

Starts the graph (plant in lockstep with sensor noise, front end, and the experiment's extra
nodes: collision monitor, dSA controller), a recorder writing BAG (rosbag2, MCAP), then drives
each run of the experiment (config/experiments.yaml) and marks it in the bag
(/flaair/run_marker; the experiment itself on /flaair/experiment). The drive only starts once
the recorder subscribes to every topic, and the bag's block counts are checked at the end:
nothing the plant published is missing.

Experiments: {names}

Examples
--------
  bin/flaair experiment characterization_chirp --out out/bags/chirp
  bin/flaair experiment --list

Terms (dSA, lockstep): docs/GLOSSARY.md.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import rclpy
from rclpy.node import Node
from std_msgs.msg import String
from tqdm import tqdm

from flaair_common import intra, topics
from flaair_common.cli_help import HelpFormatter
from flaair_common.graph import (
    Graph,
    GraphError,
    Terminated,
    is_termination,
    node_argv,
    terminate_raises,
)
from flaair_common.qos import BLOCK_STREAM, EVENTS
from flaair_common.runtime import make_executor
from flaair_model import settings
from flaair_model.config import ConfigError, config_dir, load_yaml
from flaair_msgs.msg import CollisionStatus, DriveCommandBlock
from flaair_tools import bagio
from flaair_tools.multisine.drives import design_of, realization_runs
from flaair_tools.orchestration import second_terminal
from flaair_tools.orchestration.bench_robot import robot_model, robot_section, write_robot_model
from flaair_tools.orchestration.graphs import GRAPHS, node_of
from flaair_tools.orchestration.live_args import add_health_baseline
from flaair_tools.recorder.recorder_io import RECORDER_PARAMS

EXPERIMENT_TOPIC = "/flaair/experiment"
# recorder, plant (lockstep), front end; a spec adds its nodes and driver
GRAPH = GRAPHS["experiment"]


def experiment_nodes(name: str) -> tuple[str, ...]:
    """The roles experiment `name` runs beyond the common experiment graph: those its launch file
    (experiment_NAME.launch.xml) adds. ExperimentError when it has none.
    """
    graph = GRAPHS.get(f"experiment_{name}")
    if graph is None:
        raise ExperimentError(
            f"experiment '{name}' has no launch file experiment_{name}.launch.xml"
            " in src/flaair_tools/launch"
        )
    return tuple(role for role in graph.roles if role not in GRAPH.roles)


def experiment_roles(spec: ExperimentSpec) -> tuple[str, ...]:
    """Every node `spec` runs, in start order: the graph's, the spec's own, then its driver."""
    return (*GRAPH.roles, *spec.nodes, "controller" if spec.controller else "drive")


class ExperimentError(RuntimeError):
    """The experiment could not run or its recording is incomplete; the message says why."""


@dataclass(frozen=True)
class RunSpec:
    """One drive segment of an experiment."""

    name: str
    run_time_s: float
    drive: dict[str, Any] = field(default_factory=dict)
    markers: tuple[tuple[str, float, float], ...] = ()


@dataclass(frozen=True)
class ExperimentSpec:
    """An experiment from config/experiments.yaml."""

    name: str
    description: str
    kind: str
    runs: tuple[RunSpec, ...]
    nodes: tuple[str, ...] = ()
    rest_s: float = 0.0  # zero drive before each driven run (recorded, outside the run markers)
    plant: dict[str, Any] = field(default_factory=dict)
    controller: bool = False


def load_experiments() -> dict[str, ExperimentSpec]:
    """Every experiment of config/experiments.yaml, checked."""
    path = config_dir() / "experiments.yaml"
    document = load_yaml(path) or {}
    out: dict[str, ExperimentSpec] = {}
    for name, entry in document.items():
        if name == "robot":
            continue
        try:
            if "multisine" in entry:  # one run per realization of the design it names
                design = design_of(entry["multisine"], settings.stream().sample_rate_hz)
                entry = {**entry, "runs": realization_runs(design)}
            runs = tuple(
                RunSpec(
                    name=str(r["name"]),
                    run_time_s=float(r["run_time_s"]),
                    drive=dict(r.get("drive", {})),
                    markers=tuple(
                        (str(m[0]), float(m[1]), float(m[2])) for m in r.get("markers", [])
                    ),
                )
                for r in entry["runs"]
            )
            out[name] = ExperimentSpec(
                name=name,
                description=str(entry.get("description", "")),
                kind=str(entry["kind"]),
                runs=runs,
                nodes=experiment_nodes(name),
                plant=dict(entry.get("plant", {})),
                controller=bool(entry.get("controller", False)),
                rest_s=float(entry.get("rest_s", 0.0)),
            )
            rest_s = out[name].rest_s
            if not rest_s >= 0 or (out[name].controller and rest_s):
                raise ValueError(
                    f"rest_s must be >= 0 (and 0 for a controller experiment), got {rest_s}"
                )
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise ConfigError(f"{path}: experiment '{name}' is malformed: {exc!r}") from None
    return out


def _ros_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, list):
        return (
            "[" + ",".join(_ros_value(float(v) if isinstance(v, int) else v) for v in value) + "]"
        )
    return str(value)


def ros_args(parameters: dict[str, Any]) -> list[str]:
    """`--ros-args -p name:=value ...` for a parameter dict."""
    args = ["--ros-args"]
    for name, value in parameters.items():
        args += ["-p", f"{name}:={_ros_value(value)}"]
    return args


def start_node(graph: Graph, role: str, parameters: dict[str, Any]) -> subprocess.Popen:
    """Start one of the experiment's nodes on `graph`, its log in the graph's log directory."""
    node = node_of(role)
    try:
        argv = node_argv(node.package, node.executable)
    except GraphError as exc:
        raise ExperimentError(str(exc)) from exc
    return graph.start(role, [*argv, *ros_args(parameters)])


class Runner(Node):
    """Watches the plant's sample count and publishes run markers."""

    def __init__(self, block_size: int) -> None:
        super().__init__("flaair_experiment")
        self.sensor_end_index = 0
        # signal time of the last wingbeat the collision monitor judged
        self.monitor_end_s = 0.0
        # the sensor blocks as CDR bytes (flaair_common.cdr), on rclpy's C++ EventsExecutor: a
        # Python message a block on the SingleThreadedExecutor took more CPU than all else here
        intra.subscribe_stream(
            self, topics.SENSOR_VOLTAGE, block_size, self.on_sensor, BLOCK_STREAM, self.on_bad
        )
        self.spinner = make_executor()
        self.spinner.add_node(self)
        self.create_subscription(
            CollisionStatus, topics.COLLISION_STATUS, self.on_status, BLOCK_STREAM
        )
        self.marker_pub = self.create_publisher(String, bagio.RUN_MARKER_TOPIC, EVENTS)
        self.experiment_pub = self.create_publisher(String, EXPERIMENT_TOPIC, EVENTS)
        # Advertise the drive topic before any drive node exists so the recorder subscribes to
        # it early and the first command block is recorded.
        self.drive_advert = self.create_publisher(DriveCommandBlock, topics.DRIVE, BLOCK_STREAM)

    def on_sensor(self, fields) -> None:
        end = int(fields["first_sample_index"]) + len(fields["stroke_sensor_v"])
        self.sensor_end_index = max(self.sensor_end_index, end)

    def on_bad(self, exc: Exception) -> None:
        """An undecodable block is not counted here: the bag's check at the end names what the
        recorder lacks.
        """

    def on_status(self, message: CollisionStatus) -> None:
        self.monitor_end_s = max(
            self.monitor_end_s, message.header.stamp.sec + message.header.stamp.nanosec * 1e-9
        )

    def subscribed(self, node_name: str, topic: str) -> bool:
        """True once `node_name` has a subscription on
        `topic` (as this node's discovery sees it).
        """
        return any(
            info.node_name == node_name for info in self.get_subscriptions_info_by_topic(topic)
        )


def _spin_until(
    runner: Runner,
    graph: Graph,
    predicate,
    timeout_s: float,
    what: str,
    check_every_s: float = 0.0,
) -> None:
    """Spin `runner` until `predicate()` (asked at most every `check_every_s`: a graph query
    costs CPU the starting nodes need) or raise ExperimentError after `timeout_s`.
    """
    deadline = time.monotonic() + timeout_s
    next_check = 0.0
    while True:
        now = time.monotonic()
        if now >= next_check:
            if predicate():
                return
            next_check = now + check_every_s
        if now > deadline:
            raise ExperimentError(f"timed out after {timeout_s:g} s waiting for {what}")
        runner.spinner.spin_once(timeout_sec=0.02)
        try:
            graph.check_alive()
        except GraphError as exc:
            raise ExperimentError(str(exc)) from exc


def _announce(spec: ExperimentSpec, graph: Graph, log_dir: Path, calibrated: bool) -> None:
    """Where the graph runs, how to reach it from a second terminal, and a missing calibration."""
    print(
        f"flaair experiment: {spec.name} on {graph.describe()}; logs in {log_dir}\n"
        f"{second_terminal.hint(graph.env)}",
        file=sys.stderr,
    )
    if not calibrated:
        print(
            "flaair experiment: WARNING: no --calibration: the front end runs on the model's "
            "gains, so the sensor-derived pitch reads about 4x small (the model "
            "over-predicts the hinge sensor) and pitch figures, the collision metric among "
            "them, are off; run `bin/flaair calibrate` first",
            file=sys.stderr,
        )


def run_parameters(
    spec: ExperimentSpec,
    out: Path,
    log_dir: Path,
    noise: bool,
    nominal: bool,
    calibration_file: Path | None,
    health_baseline: Path | None,
) -> dict[str, dict[str, Any]]:
    """Each of the graph's roles' parameters for this run (the graph's own, then the run's)."""
    plant: dict[str, Any] = {"noise": noise, **spec.plant}
    if records_clock():
        plant["min_clock_subscribers"] = 1  # no tick before the recorder's /clock matches
    if not nominal and robot_section():
        plant["model_file"] = str(write_robot_model(log_dir / "robot_model.yaml"))
        plant["truth_frame_every"] = int(robot_section().get("video_frame_every", 1))
    calibrated = calibration_file is not None
    run: dict[str, dict[str, Any]] = {
        "recorder": {"output_path": str(out)},
        "plant": plant,
        "frontend": {"gains_from": "calibration", "calibration_file": str(calibration_file)}
        if calibrated
        else {},
        "health": {
            **({"calibration_file": str(calibration_file)} if calibrated else {}),
            **({"baseline_file": str(health_baseline)} if health_baseline is not None else {}),
        },
    }
    return {role: {**GRAPH.parameters.get(role, {}), **run.get(role, {})} for role in GRAPH.roles}


def _start_nodes(
    graph: Graph, spec: ExperimentSpec, parameters: dict[str, dict[str, Any]]
) -> dict[str, subprocess.Popen]:
    """The graph's nodes (the experiment's own among them) with this run's parameters."""
    started = {role: start_node(graph, role, parameters[role]) for role in GRAPH.roles}
    for role in spec.nodes:
        start_node(graph, role, {})
    return started


# The graph's roles that subscribe to the drive. A driver starts once as many subscriptions as
# the runner sees have matched it: one the runner has not seen yet would let it start before
# the recorder's has matched, and the recorder would lose the first blocks.
DRIVE_LISTENERS = ("plant", "recorder", "health", "collision_monitor")


def records_clock() -> bool:
    """The experiment's recorder records /clock (config/flaair.yaml)."""
    recorder = settings.node_section(RECORDER_PARAMS, "recorder_node", "flaair.yaml")
    return bool(recorder["record_clock"])


def listeners_needed(spec: ExperimentSpec) -> list[tuple[str, str]]:
    """(node, topic) of every subscription that must be seen before anything flows: the
    recorder on each recorded topic (/clock too when it records it), every drive listener on
    the drive, the front end on the films, the monitor and the controller on the wing state.
    """
    recorded = [
        topics.SENSOR_VOLTAGE,
        topics.WING_STATE_TRUTH,
        topics.WING_STATE,
        topics.DRIVE,
        bagio.RUN_MARKER_TOPIC,
        EXPERIMENT_TOPIC,
    ]
    if records_clock():
        # the plant publishes /clock from its first step: a late match loses its first ticks
        recorded.append(topics.CLOCK)
    node_name = {role: node_of(role).node_name for role in experiment_roles(spec)}
    consumers = [
        (node_name[role], topics.DRIVE)
        for role in DRIVE_LISTENERS
        if role in node_name and role != "recorder"
    ]
    consumers += [(node_name["frontend"], topics.SENSOR_VOLTAGE)]
    if "collision_monitor" in spec.nodes:
        recorded += [topics.COLLISION_STATUS, topics.COLLISION_EVENTS]
        consumers += [(node_name["collision_monitor"], topics.WING_STATE)]
    if spec.controller:
        consumers += [(node_name["controller"], topics.WING_STATE)]
    return [(node_name["recorder"], t) for t in recorded] + consumers


def _await_listeners(runner: Runner, graph: Graph, spec: ExperimentSpec) -> None:
    """Until every subscription of `listeners_needed` is seen (the controller's excepted: it
    starts with its run).

    Nothing may flow before: a reliable volatile publisher drops what it sent before a
    subscription matched (the front end once lost 211 blocks so).
    """
    needed = listeners_needed(spec)
    node_name = {role: node_of(role).node_name for role in experiment_roles(spec)}
    _spin_until(
        runner,
        graph,
        lambda: all(runner.subscribed(n, t) for n, t in needed if n != node_name.get("controller")),
        90.0,
        "subscriptions: " + ", ".join(f"{n} on {t}" for n, t in needed),
        check_every_s=0.1,
    )
    # discovery is seen here a moment before the publishers see it
    settle_until = time.monotonic() + 0.5
    _spin_until(runner, graph, lambda: time.monotonic() > settle_until, 5.0, "discovery to settle")


def _publish_experiment(runner: Runner, spec: ExperimentSpec, fs_hz: float) -> None:
    """The experiment's description on its topic (the bag keeps what was asked for)."""
    runs = [
        {"name": r.name, "run_time_s": r.run_time_s, "drive": r.drive, "markers": r.markers}
        for r in spec.runs
    ]
    doc = {
        "name": spec.name,
        "kind": spec.kind,
        "description": spec.description,
        "sample_rate_hz": fs_hz,
        "plant": spec.plant,
        "runs": runs,
    }
    runner.experiment_pub.publish(String(data=json.dumps(doc)))


def _publish_markers(
    runner: Runner, spec: ExperimentSpec, run: RunSpec, run_start: int, fs_hz: float
) -> None:
    """The run's markers (its parts), from its first sample after the rest."""
    for part, start_s, end_s in run.markers or ((run.name, 0.0, run.run_time_s),):
        a, b = run_start + round(start_s * fs_hz), run_start + round(end_s * fs_hz)
        marker = bagio.RunMarker(
            run=part,
            first_sample_index=a,
            n_samples=b - a,
            source_file=spec.name,
            sample_rate_hz=fs_hz,
            start_ns=int(a / fs_hz * 1e9),
        )
        runner.marker_pub.publish(String(data=marker.to_json()))


def _start_driver(
    runner: Runner,
    graph: Graph,
    spec: ExperimentSpec,
    run: RunSpec,
    first: int,
    rest: int,
    n_samples: int,
    fs_hz: float,
) -> subprocess.Popen:
    """The run's driver: the controller (the experiment's first run only) or a drive node."""
    # Every subscriber of the drive (plant, recorder, monitor) must match before the first
    # block: a lockstep plant that misses the opening window waits forever.
    listeners = len(runner.get_subscriptions_info_by_topic(topics.DRIVE))
    if spec.controller:
        if first != 0:
            raise ExperimentError(
                f"{spec.name}: a controller run must be the experiment's first run"
            )
        # the recorder subscribes to the controller's state topic only once it appears
        return start_node(
            graph,
            "controller",
            {
                "run_time_s": n_samples / fs_hz,
                "min_drive_subscribers": max(listeners, 2),
                "min_state_subscribers": 1,
            },
        )
    return start_node(
        graph,
        "drive",
        {
            "pacing": "lockstep",
            "run_time_s": n_samples / fs_hz,
            "first_sample_index": first,
            "min_subscribers": max(listeners, 2),
            "pace_on_wing_state": True,
            "lead_in_s": rest / fs_hz,
            **run.drive,
        },
    )


def _await_samples(
    runner: Runner, graph: Graph, spec: ExperimentSpec, run: RunSpec, first: int, n_samples: int,
    progress: bool,
) -> None:  # fmt: skip
    """Until the plant has stepped the run's samples, with a progress bar."""
    bar = tqdm(
        total=n_samples,
        desc=f"{spec.name}/{run.name}",
        unit="sample",
        unit_scale=True,
        disable=not progress,
        leave=False,
        mininterval=1.0,
    )
    done = 0

    def finished() -> bool:
        nonlocal done
        now = min(runner.sensor_end_index - first, n_samples)
        bar.update(now - done)
        done = now
        return done >= n_samples

    try:
        timeout_s = 120.0 + 60.0 * run.run_time_s
        _spin_until(runner, graph, finished, timeout_s, f"run {run.name} to finish")
    finally:
        bar.close()


def _run_one(
    runner: Runner,
    graph: Graph,
    spec: ExperimentSpec,
    run: RunSpec,
    shared: settings.StreamSettings,
    progress: bool,
) -> dict[str, Any]:
    """One run of the experiment: markers, driver, its samples, the monitor and the recorder
    caught up, the driver stopped; its summary.
    """
    fs_hz, block_size = shared.sample_rate_hz, shared.block_size
    # The rest (zero drive, whole blocks) lets the wing settle after the previous run; the
    # run's markers start after it.
    rest = round(spec.rest_s * fs_hz / block_size) * block_size
    first = runner.sensor_end_index
    n_samples = rest + round(run.run_time_s * fs_hz / block_size) * block_size
    _publish_markers(runner, spec, run, first + rest, fs_hz)
    driver = _start_driver(runner, graph, spec, run, first, rest, n_samples, fs_hz)
    _await_samples(runner, graph, spec, run, first, n_samples, progress)
    if "collision_monitor" in spec.nodes:
        # On a loaded machine the monitor can lag the plant by seconds: let it judge the whole
        # run (to within two of the slowest wingbeats) before anything stops.
        run_end_s = (first + n_samples) / fs_hz - 2.0 / settings.monitor().min_wingbeat_hz
        _spin_until(
            runner,
            graph,
            lambda: runner.monitor_end_s >= run_end_s,
            300.0,
            f"the collision monitor to judge the run up to {run_end_s:.2f} s",
        )
    # A stopped publisher takes with it what a lagging recorder has not fetched yet (a loaded
    # fresh-clone demo lost 219 drive blocks so): let the recorder drain first.
    drain_until = time.monotonic() + 2.0
    _spin_until(
        runner, graph, lambda: time.monotonic() > drain_until, 10.0, "the recorder to drain"
    )
    graph.stop(driver)
    return {"run": run.name, "first_sample_index": first + rest, "n_samples": n_samples - rest}


def _check_recorded(out: Path, total_blocks: int, log_dir: Path) -> dict[str, int]:
    """The bag's message counts; every block the plant stepped recorded on each block topic."""
    counts = bagio.message_counts(out)
    for topic in (topics.SENSOR_VOLTAGE, topics.WING_STATE_TRUTH, topics.WING_STATE, topics.DRIVE):
        recorded = counts.get(topic, 0)
        if topic == topics.DRIVE and recorded > total_blocks:
            # a controller's start-up retry sends its first block again: the plant ignores the copy
            recorded = bagio.read_blocks(out, topic, allow_gaps=True).block_first_index.size
        if recorded != total_blocks:
            raise ExperimentError(
                f"{out}: {recorded} blocks on {topic} recorded, the plant "
                f"stepped {total_blocks} (logs in {log_dir})"
            )
    return counts


def run_experiment(
    spec: ExperimentSpec,
    out: Path,
    *,
    noise: bool = True,
    progress: bool = True,
    nominal: bool = False,
    calibration_file: Path | None = None,
    health_baseline: Path | None = None,
) -> dict[str, Any]:
    """Run `spec` on the simulated graph and record it to the bag `out`; return a summary.

    The plant is the bench robot (nominal model + config/experiments.yaml `robot:` effects)
    unless `nominal`. The front end (and the health monitor) use the model's gains, or
    `calibration_file`; the health monitor judges against `health_baseline` (a health.json)
    from the first wingbeat if given.
    """
    if out.exists():
        raise ExperimentError(f"{out} exists; choose another --out or remove it")
    # absolute: the graph's processes run in the repository's root, not in this directory
    out = out.absolute()
    calibration_file = None if calibration_file is None else calibration_file.absolute()
    health_baseline = None if health_baseline is None else health_baseline.absolute()
    shared = settings.stream()
    log_dir = out.parent / f"{out.name}.logs"
    log_dir.mkdir(parents=True, exist_ok=True)
    graph = Graph(log_dir=log_dir)
    # This process joins the graph's private domain too (rcl reads the environment at init).
    os.environ.update({k: v for k, v in graph.env.items() if k.startswith("ROS_")})
    if progress:
        _announce(spec, graph, log_dir, calibration_file is not None)
    # Ctrl-C/SIGTERM are ours
    rclpy.init(args=[], signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    runner = Runner(shared.block_size)
    summary: dict[str, Any] = {"experiment": spec.name, "bag": str(out), "runs": []}
    try:
        parameters = run_parameters(
            spec, out, log_dir, noise, nominal, calibration_file, health_baseline
        )
        started = _start_nodes(graph, spec, parameters)
        _await_listeners(runner, graph, spec)
        _publish_experiment(runner, spec, shared.sample_rate_hz)
        for run in spec.runs:
            summary["runs"].append(_run_one(runner, graph, spec, run, shared, progress))
        # Let the last blocks (a controller's closing zero block too) reach the recorder and us.
        settle_until = time.monotonic() + 1.0
        _spin_until(runner, graph, lambda: time.monotonic() > settle_until, 5.0, "the last blocks")
        total_blocks = runner.sensor_end_index // shared.block_size
        graph.stop(started["recorder"], timeout_s=60.0)
        # the bag is closed: the other listeners and the plant stop together
        graph.stop_together([process for _, process in graph.children])
    finally:
        graph.close()
        runner.spinner.remove_node(runner)
        runner.destroy_node()
        rclpy.try_shutdown()
    summary["message_counts"] = _check_recorded(out, total_blocks, log_dir)
    return summary


def main(argv: list[str] | None = None) -> int:
    try:
        experiments = load_experiments()
    except ConfigError as exc:
        print(f"flaair experiment: {exc}", file=sys.stderr)
        return 2
    parser = argparse.ArgumentParser(
        prog="flaair experiment",
        description=__doc__.format(names=", ".join(experiments)),
        formatter_class=HelpFormatter,
    )
    parser.add_argument("name", nargs="?", help="experiment name (see --list)")
    parser.add_argument(
        "--out", type=Path, help="bag directory to create (required to run an experiment)"
    )
    parser.add_argument("--list", action="store_true", help="list the experiments and exit")
    parser.add_argument("--no-noise", action="store_true", help="simulate without sensor noise")
    parser.add_argument(
        "--calibration",
        type=Path,
        default=None,
        help="front end uses this "
        "calibration.yaml (from "
        "`flaair calibrate`) "
        "instead of the model's "
        "gains",
    )
    parser.add_argument(
        "--nominal",
        action="store_true",
        help="simulate the nominal model, not "
        "the bench robot (nominal + "
        "config/experiments.yaml robot: "
        "effects)",
    )
    add_health_baseline(parser)
    args = parser.parse_args(argv)
    if args.list or not args.name:
        for name, spec in experiments.items():
            print(f"{name:24s} {spec.description}")
        return 0 if args.list else 2
    if args.name not in experiments:
        print(
            f"flaair experiment: unknown experiment '{args.name}' (known: "
            f"{', '.join(experiments)})",
            file=sys.stderr,
        )
        return 2
    if args.out is None:
        parser.error("--out BAG is required")
    try:  # the model files and the baseline checked before any node starts
        robot_model()
        if args.health_baseline is not None:
            # deferred: the monitor's core (numba) costs 1.5 s of import; only a baseline needs it
            from flaair_control.health_io import check_baseline_file

            check_baseline_file(args.health_baseline, args.calibration)
    except (ConfigError, ValueError) as exc:
        print(f"flaair experiment: {exc}", file=sys.stderr)
        return 2
    terminate_raises()
    try:
        summary = run_experiment(
            experiments[args.name],
            args.out,
            noise=not args.no_noise,
            nominal=args.nominal,
            calibration_file=args.calibration,
            health_baseline=args.health_baseline,
        )
    except (ExperimentError, ConfigError, bagio.BagError) as exc:
        print(f"flaair experiment: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(
            f"flaair experiment: interrupted; every node stopped and the bag {args.out} closed",
            file=sys.stderr,
        )
        return 130
    except (Terminated, RuntimeError) as exc:
        if not is_termination(exc):
            raise
        print(
            f"flaair experiment: terminated; every node stopped and the bag {args.out} closed",
            file=sys.stderr,
        )
        return 143
    print(
        f"recorded {args.name} to {args.out}: "
        + ", ".join(f"{t} {c}" for t, c in sorted(summary["message_counts"].items()))
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
