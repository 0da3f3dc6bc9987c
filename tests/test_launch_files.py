"""FLAAIR's graphs as ROS 2 XML launch files: valid for the format, read the way `ros2 launch`
reads them, the one declaration the tools start their graphs from.
"""

from __future__ import annotations

import importlib.util
import re
import subprocess
from pathlib import Path

import pytest

from flaair_common.graph import STOP_TIMEOUT_S
from flaair_tools.orchestration import graphs, launch_file
from flaair_tools.orchestration.experiment import (
    experiment_roles,
    listeners_needed,
    load_experiments,
)
from flaair_tools.orchestration.launch_file import LaunchFileError, load
from rosproc import FLAAIR, graph_pids

LAUNCH_DIR = Path(__file__).resolve().parents[1] / "src" / "flaair_tools" / "launch"
LAUNCH_FILES = sorted(LAUNCH_DIR.glob("*.launch.xml"))
SCHEMA = Path(__file__).with_name("launch_format.xsd")


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=[p.name for p in LAUNCH_FILES])
def test_each_launch_file_is_valid_for_the_format(path: Path) -> None:
    import xmlschema

    xmlschema.XMLSchema(SCHEMA).validate(path)


def test_the_schema_refuses_what_the_format_does_not_have(tmp_path: Path) -> None:
    import xmlschema

    schema = xmlschema.XMLSchema(SCHEMA)
    bad = tmp_path / "bad.launch.xml"
    bad.write_text('<launch><node pkg="a" exec="b"><parm name="x" value="1"/></node></launch>')
    with pytest.raises(xmlschema.XMLSchemaValidationError, match="parm"):
        schema.validate(bad)
    bad.write_text('<launch><node exec="b"/></launch>')  # pkg is required
    with pytest.raises(xmlschema.XMLSchemaValidationError, match="pkg"):
        schema.validate(bad)


@pytest.mark.parametrize("path", LAUNCH_FILES, ids=[p.name for p in LAUNCH_FILES])
def test_ros2_launch_gives_each_node_the_stop_time_flaair_graphs_give(path: Path) -> None:
    # ros2 launch escalates to SIGTERM sigterm_timeout after Ctrl-C (default 5 s): a node that
    # waits up to 5 s for its readers' acks was killed mid-way on a loaded machine
    configurations = load(path, {}, find_share=lambda package: LAUNCH_DIR.parent).configurations
    assert configurations["sigterm_timeout"] == f"{STOP_TIMEOUT_S:g}"


def test_the_graphs_are_those_of_the_launch_files_and_as_the_tools_had_them() -> None:
    by_name = graphs.GRAPHS
    assert sorted(by_name) == sorted(p.name.removesuffix(".launch.xml") for p in LAUNCH_FILES)
    loop = by_name["lockstep_loop"]
    assert (loop.hot, loop.side, dict(loop.parameters)) == (
        ("plant", "frontend", "controller"),
        (),
        {"plant": {"mode": "lockstep", "min_sensor_subscribers": 1}},
    )
    experiment = by_name["experiment"]
    assert (experiment.roles, dict(experiment.parameters)) == (
        ("recorder", "health", "plant", "frontend"),
        {"plant": {"mode": "lockstep", "min_sensor_subscribers": 2, "min_truth_subscribers": 1}},
    )
    assert by_name["experiment_collision"].roles == (*experiment.roles, "collision_monitor")
    live_sim, live_target = by_name["live_sim"], by_name["live_target"]
    assert (live_sim.hot, live_sim.side, dict(live_sim.parameters)) == (
        ("plant", "frontend", "controller"),
        ("recorder", "health", "collision_monitor", "foxglove"),
        {
            "health": {"drive_topic": "/flaair/drive/applied"},  # what the realtime plant applied
            "plant": {"mode": "realtime", "noise": True},
        },
    )
    assert (live_target.hot, live_target.side, dict(live_target.parameters)) == (
        ("frontend", "controller", "bridge"),
        ("recorder", "health", "collision_monitor", "foxglove"),
        {"health": {"drive_topic": "/flaair/drive/applied"}},
    )
    assert live_sim.local_topics == loop.local_topics and not experiment.local_topics


def test_the_experiments_take_their_extra_nodes_from_their_launch_files() -> None:
    from flaair_tools.orchestration.experiment import load_experiments

    nodes = {name: spec.nodes for name, spec in load_experiments().items()}
    assert nodes == {
        "characterization_chirp": (),
        "stepped_sine": (),
        "collision": ("collision_monitor",),
        "drive_levels": (),
        "multisine": (),
        "transition": (),
        "wing_damage": (),
    }


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_args_lets_groups_namespaces_includes_remaps_and_conditions(tmp_path: Path) -> None:
    _write(
        tmp_path,
        "inner.launch.xml",
        """<launch>
      <arg name="rate"/>
      <node pkg="flaair_sim" exec="drive_node" name="drive_$(var rate)" namespace="sub">
        <param name="frequency_hz" value="$(var rate)"/>
        <param from="$(find-pkg-share flaair_model)/config/flaair.yaml"/>
        <remap from="/flaair/drive" to="/flaair/drive_b"/>
      </node>
    </launch>""",
    )
    outer = _write(
        tmp_path,
        "outer.launch.xml",
        """<launch version="0.1.1">
      <arg name="bench" default="bench1" description="where"/>
      <arg name="with_monitor" default="false"/>
      <let name="rate" value="140"/>
      <group>
        <push-ros-namespace namespace="$(var bench)"/>
        <node pkg="flaair_sim" exec="plant_node"/>
        <include file="$(dirname)/inner.launch.xml"><arg name="rate" value="$(var rate)"/></include>
      </group>
      <node pkg="flaair_control" exec="collision_monitor_node" if="$(var with_monitor)"/>
      <node pkg="flaair_sensors" exec="frontend_node" unless="$(var with_monitor)"/>
    </launch>""",
    )
    share = {"flaair_model": Path("/share/flaair_model")}
    described = load(outer, {"bench": "b2"}, find_share=share.__getitem__)
    plant, drive, frontend = described.nodes
    assert (plant.namespace, plant.name, plant.ros_args()) == ("/b2", None, ["-r", "__ns:=/b2"])
    assert drive.ros_args() == [
        "-r",
        "__node:=drive_140",
        "-r",
        "__ns:=/b2/sub",
        "--params-file",
        "/share/flaair_model/config/flaair.yaml",
        "-p",
        "frequency_hz:=140",
        "-r",
        "/flaair/drive:=/flaair/drive_b",
    ]
    assert (frontend.executable, frontend.namespace) == ("frontend_node", "/")
    assert [a.name for a in described.arguments] == ["bench", "with_monitor"]
    with_monitor = load(outer, {"with_monitor": "true"}, find_share=share.__getitem__)
    assert [n.executable for n in with_monitor.nodes][-1] == "collision_monitor_node"
    assert with_monitor.nodes[0].namespace == "/bench1"


@pytest.mark.parametrize(
    ("text", "given", "message"),
    [
        (
            '<launch><node pkg="a" exec="b"><parm name="x" value="1"/></node></launch>',
            {},
            "unknown tag <parm> in <node>",
        ),
        ('<launch><timer period="1"/></launch>', {}, "unknown or misplaced tag <timer>"),
        (
            '<launch><node pkg="a" exec="b" respawn="true"/></launch>',
            {},
            "<node> has no attribute respawn",
        ),
        ('<launch><node exec="b"/></launch>', {}, "<node> needs pkg"),
        ('<launch><arg name="x"/></launch>', {}, "launch argument 'x' is required: add x:=VALUE"),
        ('<launch><arg name="x" value="1"/></launch>', {"x": "2"}, "launch argument 'x' is fixed"),
        (
            '<launch><arg name="x" default="1"/></launch>',
            {"y": "2"},
            "no launch argument y (it takes: x)",
        ),
        ('<launch><let name="a" value="$(var b)"/></launch>', {}, "no launch configuration 'b'"),
        # upstream launch_xml's <let> takes name=, and refuses var= (InvalidLaunchFileError)
        ('<launch><let var="a" value="1"/></launch>', {}, "<let> has no attribute var"),
        (
            '<launch><let name="a" value="$(command ls)"/></launch>',
            {},
            "substitution $(command ...) is not supported",
        ),
        (
            '<launch><node pkg="a" exec="b" if="maybe"/></launch>',
            {},
            "if='maybe' is not true/false",
        ),
        ('<launch><node pkg="a" exec="b"', {}, "not well-formed XML"),
        ("<robot/>", {}, "the root element must be <launch>"),
    ],
)
def test_what_the_reader_does_not_take_is_refused_by_name(
    tmp_path: Path, text: str, given: dict, message: str
) -> None:
    path = _write(tmp_path, "bad.launch.xml", text)
    with pytest.raises(LaunchFileError, match=None) as error:
        load(path, given, find_share=lambda package: Path("/share") / package)
    assert message in str(error.value) and str(path) in str(error.value)


def test_launch_arguments_must_be_name_colon_equals_value() -> None:
    assert launch_file.parse_launch_arguments(["a:=1", "b:="]) == {"a": "1", "b": ""}
    with pytest.raises(LaunchFileError, match="'a=1' is not of the form name:=value"):
        launch_file.parse_launch_arguments(["a=1"])


def test_launch_cli_prints_the_commands_and_names_bad_input() -> None:
    shown = subprocess.run(
        [
            FLAAIR,
            "launch",
            "flaair_tools",
            "lockstep_loop.launch.xml",
            "namespace:=bench2",
            "--print",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert shown.returncode == 0, shown.stderr
    lines = shown.stdout.splitlines()
    assert [line.split()[1].rsplit("/", 1)[1] for line in lines] == [
        "plant_node",
        "frontend_node",
        "dsa_controller_node",
    ]
    assert lines[0].endswith(
        "--ros-args -r __node:=plant_node -r __ns:=/bench2 -p mode:=lockstep "
        "-p min_sensor_subscribers:=1"
    )
    listed = subprocess.run(
        [FLAAIR, "launch", "flaair_tools", "lockstep_loop.launch.xml", "--show-args"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert listed.stdout.startswith("namespace (default '/'): ROS namespace")
    bad = subprocess.run(
        [FLAAIR, "launch", "flaair_tools", "lockstep_loop.launch.xml", "nmspace:=x"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert bad.returncode == 2 and "no launch argument nmspace (it takes: namespace)" in bad.stderr
    assert "Traceback" not in bad.stderr


@pytest.mark.graph
def test_flaair_launch_runs_the_loop_in_its_namespace_and_ctrl_c_stops_every_node() -> None:
    import json
    import os
    import signal

    from rosproc import ros_processes

    with ros_processes() as procs:
        domain = procs.env["ROS_DOMAIN_ID"]
        launcher = procs.flaair(
            "launch",
            "flaair_tools",
            "lockstep_loop.launch.xml",
            "namespace:=bench2",
            "--domain-id",
            domain,
        )
        echo = procs.flaair(
            "topic",
            "echo",
            "/bench2/flaair/controller/state",
            "flaair_msgs/msg/ControllerState",
            "--json",
            "--count",
            "3",
            "--silence",
            "120",
        )
        out, err = echo.communicate(timeout=180)
        assert echo.returncode == 0, err + launcher.stderr.read()
        states = [json.loads(line) for line in out.splitlines()]
        # the loop in the namespace, stepping: the echo joins a loop already running (lockstep
        # waits for the front end, not for it), so its first states may be past the ramp's start
        stamps = [
            s["header"]["stamp"]["sec"] * 10**9 + s["header"]["stamp"]["nanosec"] for s in states
        ]
        assert len(states) == 3 and all(0.0 <= s["k_r"] <= 1.0 for s in states)
        assert stamps == sorted(stamps) and len(set(stamps)) == 3
        children = [Path(f"/proc/{pid}") for pid in graph_pids(int(domain), launcher.pid)]
        assert len(children) == 3  # one process per node of the file
        # the launcher stops its nodes one by one, each within Graph's STOP_TIMEOUT_S (a node may
        # wait up to ACK_WAIT_S for its readers); the test allows it that, and no less
        assert (
            procs.stop(launcher, signal.SIGINT, timeout_s=len(children) * STOP_TIMEOUT_S + 5.0) == 0
        ), launcher.stderr.read()
        said = launcher.stderr.read()
        assert "stopped (Ctrl-C)" in said
        # what a second terminal types to reach the graph (the conformance test uses it too)
        assert (
            f"export ROS_DOMAIN_ID={domain} ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; "
            "unset ROS_LOCALHOST_ONLY"
        ) in said
        assert not [
            p
            for p in children
            if p.exists()
            and os.path.exists(p / "environ")
            and (p / "stat").read_bytes().rsplit(b")", 1)[1].split()[0] != b"Z"
        ]


def _subscribes_to_the_drive(role: str) -> bool:
    """Whether the role's node source subscribes to the drive topic (read from the source, not
    from the experiment's own list).
    """
    module = graphs.node_of(role).component.split(":")[0]
    source = Path(importlib.util.find_spec(module).origin).read_text()
    return bool(re.search(r"subscri\w*\(\s*self,\s*(topics\.DRIVE|p\[\"drive_topic\"\])", source))


@pytest.mark.timeout(30)
def test_every_drive_listener_is_awaited_before_a_driver_starts() -> None:
    # the code before the fix waited for the plant only: the health monitor, seen late, let the
    # drive node start while the recorder's subscription was still matching (a demo's recorder
    # lost its first 301 drive blocks)
    for name, spec in load_experiments().items():
        needed = set(listeners_needed(spec))
        for role in experiment_roles(spec):
            node = graphs.node_of(role)
            if role in ("recorder", "drive", "controller") or node.component is None:
                continue
            if _subscribes_to_the_drive(role):
                assert (node.node_name, "/flaair/drive") in needed, (name, role)
        assert ("recorder_node", "/flaair/drive") in needed, name
