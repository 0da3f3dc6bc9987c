"""Every FLAAIR graph, declared once as data: which nodes, in which order, with which overrides.

`NODES` names each node once (its package, executable and, for the nodes `live` composes in one
process, its component class). `GRAPHS` lists the graphs the tools bring up; `experiment`,
`live`, the transition figure, the demo's build check and the tests read them instead of
writing node lists of their own. No rclpy here: `flaair_common.graph.Graph` starts the
processes.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

from flaair_common import topics

__all__ = ["NodeDecl", "GraphDecl", "NODES", "GRAPHS", "node_of", "component_modules"]


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


NODES: dict[str, NodeDecl] = {n.role: n for n in (
    NodeDecl("plant", "flaair_sim", "plant_node", "flaair_sim.plant_node:PlantNode"),
    NodeDecl("drive", "flaair_sim", "drive_node", "flaair_sim.drive_node:DriveNode"),
    NodeDecl("frontend", "flaair_sensors", "frontend_node",
             "flaair_sensors.frontend_node:FrontendNode"),
    NodeDecl("controller", "flaair_control", "dsa_controller_node",
             "flaair_control.dsa_controller_node:DsaControllerNode"),
    NodeDecl("stroke_controller", "flaair_control", "stroke_controller_node",
             "flaair_control.stroke_controller_node:StrokeControllerNode"),
    NodeDecl("collision_monitor", "flaair_control", "collision_monitor_node",
             "flaair_control.collision_monitor_node:CollisionMonitorNode"),
    NodeDecl("bridge", "flaair_bridge", "bridge_node", "flaair_bridge.bridge_node:BridgeNode"),
    NodeDecl("recorder", "flaair_tools", "recorder_node"),
    NodeDecl("foxglove", "flaair_tools", "foxglove_node"),
)}

# The streams the composed loop hands from node to node in-process (what `live` composes).
_LOOP_TOPICS = (topics.DRIVE, topics.SENSOR_VOLTAGE, topics.WING_STATE, topics.DRIVE_APPLIED,
                topics.WING_STATE_TRUTH, topics.CONTROLLER_STATE)

GRAPHS: dict[str, GraphDecl] = {g.name: g for g in (
    GraphDecl("lockstep_loop",
              "the closed dSA loop in signal time: plant (lockstep), front end, dSA controller",
              hot=("plant", "frontend", "controller"), parameters={"plant": {"mode": "lockstep"}},
              local_topics=_LOOP_TOPICS),
    GraphDecl("experiment", "a paper experiment on the simulated robot, recorded: the experiment "
                            "adds its driver (drive or controller) and its own nodes "
                            "(config/experiments.yaml)", hot=("plant", "frontend"),
              side=("recorder",), parameters={"plant": {
                  # drive is taken (and the driver starts) once the front end and the recorder
                  # listen to the sensor stream and the recorder to the truth stream
                  "mode": "lockstep", "min_sensor_subscribers": 2, "min_truth_subscribers": 1}}),
    GraphDecl("live_sim", "`flaair live --sim`: the real-time simulated robot in the loop",
              hot=("plant", "frontend", "controller"), side=(
    "recorder", "collision_monitor", "foxglove"),
              parameters={"plant": {"mode": "realtime", "noise": True}}, local_topics=_LOOP_TOPICS),
    GraphDecl("live_target",
              "`flaair live --target`: a lab's real-time target over UDP in the loop",
              hot=("frontend", "controller", "bridge"),
              side=("recorder", "collision_monitor", "foxglove"), local_topics=_LOOP_TOPICS),
)}


def node_of(role: str) -> NodeDecl:
    """The node that plays `role`, or a KeyError naming the known roles."""
    try:
        return NODES[role]
    except KeyError:
        raise KeyError(f"no node plays {role!r} (known: {', '.join(NODES)})") from None


def component_modules() -> tuple[str, ...]:
    """The modules of every composable node (those a fake clock must reach in a test)."""
    return tuple(n.component.split(":")[0] for n in NODES.values() if n.component)
