"""Nodes start through bin/flaair run with parameters
applied; bad parameters are refused by name.
"""

from __future__ import annotations

import pytest

from rosproc import FLAAIR, isolated_env, ros_processes, run


@pytest.mark.graph
def test_run_applies_ros_args_parameter() -> None:
    with ros_processes() as procs:
        node = procs.flaair(
            "run",
            "flaair_sim",
            "plant_node",
            "--ros-args",
            "-p",
            "mode:=realtime",
            "-p",
            "drive_limit_v:=42.5",
        )
        env = procs.env
        mode = run([FLAAIR, "param", "get", "/plant_node", "mode", "--timeout", "30"], env)
        limit = run(
            [FLAAIR, "param", "get", "/plant_node", "drive_limit_v", "--timeout", "30"], env
        )
        assert mode.returncode == 0, mode.stderr
        assert mode.stdout.strip() == "String value is: realtime"  # as ros2 param get prints
        assert limit.stdout.strip() == "Double value is: 42.5"
        assert procs.stop(node) == 0, node.stderr.read()


@pytest.mark.parametrize(
    ("override", "named", "why"),
    [
        ("drive_limit_v:=1000.0", "drive_limit_v", "out of range"),
        ("drive_limit_v:=abc", "drive_limit_v", "expecting type 'DOUBLE'"),
        ("block_size:=2.5", "block_size", "expecting type 'INTEGER'"),
        ("mode:=fast", "mode", "not one of lockstep, realtime"),
        ("modde:=realtime", "modde", "unknown parameter"),
        ("mode:=", "'-p mode:='", "bad --ros-args: Couldn't parse parameter override rule"),
    ],
)
@pytest.mark.slow  # starts a node process per bad parameter
def test_bad_parameter_refused_at_start_with_its_name(override: str, named: str, why: str) -> None:
    result = run(
        [FLAAIR, "run", "flaair_sim", "plant_node", "--ros-args", "-p", override], isolated_env()
    )
    assert result.returncode == 2
    assert named in result.stderr and why in result.stderr, result.stderr
    assert "Traceback" not in result.stderr


def test_unknown_executable_is_named() -> None:
    result = run([FLAAIR, "run", "flaair_sim", "no_such_node"], isolated_env())
    assert result.returncode == 2 and "no_such_node" in result.stderr


def test_node_help_lists_parameters_with_defaults_and_ranges() -> None:
    result = run([FLAAIR, "run", "flaair_sim", "drive_node", "--help"], isolated_env())
    assert result.returncode == 0
    assert "amplitude_v (float, default 100.0) [0.0, 300.0]" in result.stdout
    assert "waveform (str, default 'sine') {sine|chirp|stepped_sine|multisine}" in result.stdout
