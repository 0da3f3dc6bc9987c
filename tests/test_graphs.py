"""The declared graphs (flaair_tools.orchestration.graphs)
name real nodes, and the tools use them.
"""

from __future__ import annotations

import argparse
import importlib
import inspect

import pytest

from flaair_tools.orchestration import graphs

ROLES = sorted(graphs.NODES)


@pytest.mark.parametrize("role", ROLES)
def test_each_declared_node_is_built_and_its_component_class_exists(role: str) -> None:
    from flaair_common.graph import node_argv

    node = graphs.NODES[role]
    assert node_argv(node.package, node.executable)  # installed, like `ros2 run`
    if node.component:
        module, cls = node.component.split(":")
        assert inspect.isclass(getattr(importlib.import_module(module), cls))
        assert module.startswith(node.package + ".") and module.endswith(node.executable)


def test_every_graph_names_declared_roles_and_overrides_only_its_own_nodes() -> None:
    for graph in graphs.GRAPHS.values():
        assert set(graph.roles) <= set(graphs.NODES), graph.name
        assert set(graph.parameters) <= set(graph.roles), graph.name
        assert len(set(graph.roles)) == len(graph.roles), graph.name
    with pytest.raises(KeyError, match="no node plays 'camera'"):
        graphs.node_of("camera")


def test_live_and_experiment_bring_up_the_declared_graphs() -> None:
    from flaair_tools.orchestration import experiment, live_args

    sim = argparse.Namespace(
        sim=True,
        calibration=None,
        processes=False,
        out=None,
        controller="dsa",
        foxglove=None,
        health_baseline=None,
    )
    sections = live_args.node_parameters_for(sim)
    assert sections["plant_node"]["ros__parameters"] == dict(
        graphs.GRAPHS["live_sim"].parameters["plant"]
    )
    assert live_args.live_graph(sim).hot == ("plant", "frontend", "controller")
    # a calibration reaches the health monitor as it does the front end
    calibrated = live_args.node_parameters_for(
        argparse.Namespace(**{**vars(sim), "calibration": "c.yaml"})
    )
    assert calibrated["health_node"]["ros__parameters"] == {
        "calibration_file": "c.yaml",
        "drive_topic": "/flaair/drive/applied",
    }
    assert calibrated["frontend_node"]["ros__parameters"]["calibration_file"] == "c.yaml"
    assert sections["health_node"]["ros__parameters"] == {"drive_topic": "/flaair/drive/applied"}
    # so does a saved health baseline
    saved = live_args.node_parameters_for(
        argparse.Namespace(**{**vars(sim), "health_baseline": "h.json"})
    )
    assert saved["health_node"]["ros__parameters"]["baseline_file"] == "h.json"
    spec = next(iter(experiment.load_experiments().values()))
    roles = experiment.experiment_roles(spec)
    common = graphs.GRAPHS["experiment"].roles
    assert roles[: len(common)] == common and roles[-1] in ("drive", "controller")


def test_a_live_run_ends_on_both_clocks_or_on_the_sensor_clock_after_the_grace() -> None:
    """`live --duration`: the drive's samples lead the sensor's while the controller loops; after a
    trip they come one zero block per keepalive period and would need ~100x the duration (a run
    against a target silent for 3 s never ended before the fix).
    """
    from flaair_tools.orchestration.live import DRIVE_GRACE_S, run_end

    assert DRIVE_GRACE_S == 2.0
    assert run_end(0.3, -0.1, 0.0) is None  # the sensor still needs 0.3 s
    assert run_end(0.0, -0.1, 0.0) == "covered"
    assert run_end(-0.01, None, 0.0) == "covered"  # no controller: the sensor alone
    assert run_end(-0.01, 0.2, 1.99) is None  # a loaded executor's backlog: wait
    why = run_end(-0.01, 11.74, 2.0)
    assert why == (
        "ending on the sensor clock: the drive is still 11.74 s of signal short of the "
        "duration 2.0 s after the sensor reached it (the controller tripped or stopped: "
        "see the loop's log)"
    )
