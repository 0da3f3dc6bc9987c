"""Every FLAAIR graph, declared once, as a ROS 2 launch file: which nodes, in which order, with
which overrides.

`NODES` names each kind of node once (its package, executable and, for the nodes `live` composes
in one process, its component class). `GRAPHS` holds the graphs of the launch files in
src/flaair_tools/launch (installed to share/flaair_tools/launch): `flaair launch` runs them as
they are, and `experiment`, `live`, the transition figure, the demo's build check and the tests
read them instead of writing node lists of their own. No rclpy here:
`flaair_common.graph.Graph` starts the processes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from ament_index_python.packages import get_package_share_directory

from flaair_common import topics
from flaair_common.graph import repo_root
from flaair_model.config import ConfigError
from flaair_tools.orchestration import launch_file

__all__ = [
    "GRAPHS",
    "LAUNCH_PACKAGE",
    "NODES",
    "GraphDecl",
    "NodeDecl",
    "component_modules",
    "graph_from_launch",
    "launch_dir",
    "node_of",
]


@dataclass(frozen=True)
class NodeDecl:
    """One node: `bin/flaair run PACKAGE EXECUTABLE`; `component` ("module:Class") if it can be
    composed into one process with others (the hot loop of `live`).
    """

    role: str
    package: str
    executable: str
    component: str | None = None

    @property
    def node_name(self) -> str:
        """Its ROS node name (and its section in config/flaair.yaml)."""
        return self.executable


@dataclass(frozen=True)
class GraphDecl:
    """A graph: its nodes by role in start order, each role's parameter overrides, and the block
    streams handed in-process when its hot nodes are composed.

    `side` roles run beside the loop, each in a process of its own (off the hot path); `hot`
    roles are the closed loop itself.
    """

    name: str
    description: str
    hot: tuple[str, ...]
    side: tuple[str, ...] = ()
    parameters: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    local_topics: tuple[str, ...] = ()

    @property
    def roles(self) -> tuple[str, ...]:
        """Every role, side ones first (they listen before the loop starts)."""
        return self.side + self.hot

    def nodes(self) -> tuple[NodeDecl, ...]:
        return tuple(NODES[role] for role in self.roles)


NODES: dict[str, NodeDecl] = {
    n.role: n
    for n in (
        NodeDecl("plant", "flaair_sim", "plant_node", "flaair_sim.plant_node:PlantNode"),
        NodeDecl("drive", "flaair_sim", "drive_node", "flaair_sim.drive_node:DriveNode"),
        NodeDecl(
            "frontend",
            "flaair_sensors",
            "frontend_node",
            "flaair_sensors.frontend_node:FrontendNode",
        ),
        NodeDecl(
            "controller",
            "flaair_control",
            "dsa_controller_node",
            "flaair_control.dsa_controller_node:DsaControllerNode",
        ),
        NodeDecl(
            "stroke_controller",
            "flaair_control",
            "stroke_controller_node",
            "flaair_control.stroke_controller_node:StrokeControllerNode",
        ),
        NodeDecl(
            "collision_monitor",
            "flaair_control",
            "collision_monitor_node",
            "flaair_control.collision_monitor_node:CollisionMonitorNode",
        ),
        NodeDecl(
            "health", "flaair_control", "health_node", "flaair_control.health_node:HealthNode"
        ),
        NodeDecl("bridge", "flaair_bridge", "bridge_node", "flaair_bridge.bridge_node:BridgeNode"),
        NodeDecl("recorder", "flaair_tools", "recorder_node"),
        NodeDecl("foxglove", "flaair_tools", "foxglove_node"),
    )
}

# The streams the composed loop hands from node to node in-process (what `live` composes).
_LOOP_TOPICS = (
    topics.DRIVE,
    topics.SENSOR_VOLTAGE,
    topics.WING_STATE,
    topics.DRIVE_APPLIED,
    topics.WING_STATE_TRUTH,
    topics.CONTROLLER_STATE,
)

LAUNCH_PACKAGE = "flaair_tools"


def launch_dir() -> Path:
    """The directory of FLAAIR's launch files: the checkout's (src/flaair_tools/launch), else the
    installed package's share/flaair_tools/launch.
    """
    try:
        source = repo_root() / "src" / LAUNCH_PACKAGE / "launch"
    except ConfigError:
        source = Path("/nonexistent")
    if source.is_dir():
        return source
    return Path(get_package_share_directory(LAUNCH_PACKAGE)) / "launch"


def graph_from_launch(path: Path) -> GraphDecl:
    """The graph a launch file declares: its nodes as roles in launch order, their parameters,
    the loop's nodes (`loop_nodes`, what `live` composes) and its description
    (`graph_description`). LaunchFileError for a node FLAAIR does not know.
    """
    described = launch_file.load(path)
    by_executable = {(n.package, n.executable): n.role for n in NODES.values()}
    loop = described.configurations.get("loop_nodes", "").split()
    roles, parameters = [], {}
    for node in described.nodes:
        role = by_executable.get((node.package, node.executable))
        if role is None:
            raise launch_file.LaunchFileError(
                f"{path}: node {node.package}/{node.executable} is not one of FLAAIR's"
            )
        roles.append(role)
        if node.parameters:
            parameters[role] = {k: yaml.safe_load(v) for k, v in node.parameters}
    hot = tuple(
        r for r, n in zip(roles, described.nodes, strict=True) if (n.name or n.executable) in loop
    )
    return GraphDecl(
        path.name.removesuffix(".launch.xml"),
        described.configurations.get("graph_description", ""),
        hot=hot,
        side=tuple(r for r in roles if r not in hot),
        parameters=parameters,
        local_topics=_LOOP_TOPICS if hot else (),
    )


# Every graph, one per launch file (src/flaair_tools/launch/NAME.launch.xml): the one declaration
GRAPHS: dict[str, GraphDecl] = {
    g.name: g
    for g in (graph_from_launch(path) for path in sorted(launch_dir().glob("*.launch.xml")))
}


def node_of(role: str) -> NodeDecl:
    """The node that plays `role`, or a KeyError naming the known roles."""
    try:
        return NODES[role]
    except KeyError:
        raise KeyError(f"no node plays {role!r} (known: {', '.join(NODES)})") from None


def component_modules() -> tuple[str, ...]:
    """The modules of every composable node (those a fake clock must reach in a test)."""
    return tuple(n.component.split(":")[0] for n in NODES.values() if n.component)
