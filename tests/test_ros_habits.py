"""ROS habits over real DDS: param set on the dSA controller,
node list, topic hz, echo that ends on silence.
"""

from __future__ import annotations

import json
import os
import re
import time

import pytest
from rcl_interfaces.msg import ParameterType

from flaair_tools.roscli.param import get_text
from flaair_tools.roscli.topic import rate_report
from rosproc import FLAAIR, ros_processes, run


@pytest.mark.graph
def test_param_set_changes_the_dsa_kr_target_at_run_time_and_node_list_shows_it() -> None:
    with ros_processes() as procs:
        controller = procs.flaair("run", "flaair_control", "dsa_controller_node")
        got = run(
            [
                FLAAIR,
                *("param", "get", "/dsa_controller_node", "kr_target", "--hide-type"),
                *("--timeout", "120"),
            ],
            procs.env,
            180,
        )
        assert got.returncode == 0, (
            got.stderr + controller.stderr.read() if controller.poll() is not None else got.stderr
        )
        assert float(got.stdout) == 0.0  # config/flaair.yaml
        # "1" is an integer, as ros2cli reads it: the node refuses it for a double parameter
        integer = run(
            [FLAAIR, "param", "set", "/dsa_controller_node", "kr_target", "1"], procs.env, 120
        )
        assert integer.returncode == 1 and integer.stderr == (
            "Setting parameter failed: Wrong parameter type, expected 'Type.DOUBLE' got "
            "'Type.INTEGER'\n"
        ), integer.stderr
        changed = run(
            [FLAAIR, "param", "set", "/dsa_controller_node", "kr_target", "1.0"], procs.env, 120
        )
        assert changed.returncode == 0 and changed.stdout == "Set parameter successful\n", (
            changed.stderr
        )
        # out of the declared range [0, 1]: the node refuses and says why; the value stays
        refused = run(
            [FLAAIR, "param", "set", "/dsa_controller_node", "kr_target", "1.5"], procs.env, 120
        )
        assert refused.returncode == 1 and refused.stderr.startswith(
            "Setting parameter failed: "
        ), refused.stderr
        assert (
            float(
                run(
                    [FLAAIR, "param", "get", "/dsa_controller_node", "kr_target"], procs.env, 120
                ).stdout.removeprefix("Double value is: ")
            )
            == 1.0
        )
        wrong_type = run(
            [FLAAIR, "param", "set", "/dsa_controller_node", "kr_target", "fast"], procs.env, 120
        )
        assert wrong_type.returncode == 1 and wrong_type.stderr == (
            "Setting parameter failed: Wrong parameter type, expected 'Type.DOUBLE' got "
            "'Type.STRING'\n"
        )
        missing = run(
            [FLAAIR, "param", "set", "/dsa_controller_node", "no_such", "1"], procs.env, 120
        )
        assert missing.returncode == 1 and "has no parameter 'no_such'" in missing.stderr
        nodes = run([FLAAIR, "node", "list", "--wait-for", "/dsa_controller_node"], procs.env, 120)
        assert nodes.returncode == 0 and "/dsa_controller_node" in nodes.stdout.split(), (
            nodes.stdout + nodes.stderr
        )
        absent = run(
            [FLAAIR, "node", "list", "--wait-for", "/nobody", "--timeout", "1"], procs.env, 60
        )
        assert absent.returncode == 1 and "/nobody not seen in 1 s" in absent.stderr, absent.stderr
        # health on /diagnostics, the watchdog's reset as a std_srvs/Trigger service
        health = run(
            [
                FLAAIR,
                "topic",
                "echo",
                "--json",
                "/diagnostics",
                "diagnostic_msgs/msg/DiagnosticArray",
                "--count",
                "1",
                "--silence",
                "60",
            ],
            procs.env,
            120,
        )
        assert health.returncode == 0, health.stderr
        (status,) = json.loads(health.stdout)["status"]
        assert (status["level"], status["name"], status["message"], status["hardware_id"]) == (
            0,
            "dsa_controller_node: dSA controller",
            "waiting for the loop to start",
            "/dsa_controller_node",
        )
        assert {"watchdog": "ok", "trips": "0"}.items() <= {
            v["key"]: v["value"] for v in status["values"]
        }.items()
        reset = run(
            [
                FLAAIR,
                "service",
                "call",
                "/dsa_controller_node/reset_watchdog",
                "std_srvs/srv/Trigger",
            ],
            procs.env,
            120,
        )
        assert reset.returncode == 0, reset.stderr
        assert reset.stdout.endswith(
            "response:\nstd_srvs.srv.Trigger_Response(success=False, message='reset_watchdog: "
            "watchdog not tripped, nothing to do')\n\n"
        )
        reset = run(
            [
                FLAAIR,
                *("service", "call", "--json"),
                *("/dsa_controller_node/reset_watchdog", "std_srvs/srv/Trigger"),
            ],
            procs.env,
            120,
        )
        assert json.loads(reset.stdout) == {
            "success": False,
            "message": "reset_watchdog: watchdog not tripped, nothing to do",
        }
        assert controller.poll() is None


@pytest.mark.graph
def test_topic_hz_reports_a_rate_and_echo_ends_with_a_message_when_nobody_publishes() -> None:
    with ros_processes() as procs:
        publisher = procs.flaair(
            "topic",
            "pub",
            "/flaair/hz_probe",
            "std_msgs/msg/String",
            '{"data": "x"}',
            "--count",
            "100000",
            "--rate",
            "50",
        )
        hz = run(
            [FLAAIR, "topic", "hz", "/flaair/hz_probe", "--count", "2", "--silence", "120"],
            procs.env,
            240,
        )
        assert hz.returncode == 0, hz.stderr
        reports = re.findall(r"average rate: ([0-9.]+)\n\tmin: .* window: (\d+)", hz.stdout)
        assert len(reports) == 2 and all(
            float(rate) > 0 and int(window) >= 2 for rate, window in reports
        ), hz.stdout
        procs.stop(publisher)
        # nobody publishes: the timeout ends it (its default, 10 s, is config/flaair.yaml's: below)
        start = time.monotonic()
        silent = run(
            [FLAAIR, "topic", "echo", "/flaair/nobody", "std_msgs/msg/String", "--silence", "2"],
            procs.env,
            120,
        )
        assert silent.returncode == 1
        assert (
            "no message on '/flaair/nobody' for 2 s (0 received, 0 publisher(s) now)"
            in silent.stderr
        )
        assert time.monotonic() - start >= 2.0
        short = run(
            [FLAAIR, "topic", "hz", "/flaair/nobody", "std_msgs/msg/String", "--silence", "1"],
            procs.env,
            120,
        )
        assert short.returncode == 1 and "no message on '/flaair/nobody' for 1 s" in short.stderr


def test_echo_takes_its_default_timeout_from_the_config() -> None:
    from flaair_model.config import node_parameters

    default_s = node_parameters("flaair.yaml", "flaair_cli")["echo_timeout_s"]
    result = run([FLAAIR, "topic", "echo", "--help"], dict(os.environ), 60)
    assert result.returncode == 0 and f"(default {default_s:g}; 0: wait forever" in re.sub(
        r"\s+", " ", result.stdout
    )


def test_values_print_as_ros2_param_get_and_rates_as_ros2_topic_hz() -> None:
    from rcl_interfaces.msg import ParameterValue

    double = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=0.5)
    assert get_text(double) == "Double value is: 0.5" and get_text(double, True) == "0.5"
    array = ParameterValue(type=ParameterType.PARAMETER_DOUBLE_ARRAY, double_array_value=[0.5, 1.0])
    assert get_text(array) == "Double values are: [0.5, 1.0]"
    flag = ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=True)
    assert get_text(flag) == "Boolean value is: True"
    assert get_text(ParameterValue()) == "Parameter not set."
    assert rate_report([0.0, 0.5, 1.0, 2.0]) == (
        "average rate: 1.500\n\tmin: 0.500s max: 1.000s std dev: 0.23570s window: 3"
    )
