"""The composed closed loop (plant, front end, controller in one container) with FLAAIR_PROFILE.

The container prints each node callback's CPU and wall time per block at exit; the plant and
controller skip their truth, /clock and ControllerState writes when nobody listens, and a
listener that is there still gets every block of them.
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import pytest

from flaair_common.intra import Bus, CallbackProfile
from flaair_tools.orchestration.graphs import GRAPHS
from rosproc import ros_processes, wait_for

FS_HZ = 20000.0
BLOCK = 10
NODES = tuple(node.component for node in GRAPHS["lockstep_loop"].nodes())  # the declared loop
PROFILE = re.compile(
    r"profile: (\w+)\.(\w+): (\d+) calls, ([\d.]+) us CPU, ([\d.]+) us wall per call"
)


class _Node:
    def __init__(self) -> None:
        self.seen: list[int] = []

    def get_name(self) -> str:
        return "busy_node"

    def on_block(self, fields: dict) -> None:
        self.seen.append(fields["i"])
        end = time.thread_time() + 0.002  # 2 ms of CPU
        while time.thread_time() < end:
            pass


def test_callback_profile_counts_each_subscriber_and_its_cpu() -> None:
    node = _Node()
    bus = Bus({"/t"}, profile=True)
    bus.subscribe("/t", node.on_block)
    for i in range(5):
        bus.deliver("/t", {"i": i})
    # delivered in order, through the wrapper
    assert node.seen == [0, 1, 2, 3, 4]
    (line,) = bus.profile.report()
    name, callback, calls, cpu_us, wall_us = PROFILE.match(line).groups()
    assert (name, callback, int(calls)) == ("busy_node", "on_block", 5)
    # each call burnt 2 ms of its thread's CPU (the process clock may also count other threads)
    assert float(cpu_us) >= 1900.0 and float(wall_us) >= 1900.0
    # off by default: callbacks unwrapped
    assert Bus({"/t"}).profile is None
    assert CallbackProfile().report() == []


@pytest.mark.graph
def test_composed_loop_profiles_its_nodes_and_a_listener_gets_every_truth_and_state_block(
    tmp_path: Path,
) -> None:
    n_blocks = 400
    params = tmp_path / "params.yaml"
    params.write_text(
        json.dumps(
            {
                "plant_node": {"ros__parameters": {"mode": "lockstep"}},
                # The loop starts start_delay_s after the controller sees its peers: time for the
                # two listeners (started first) to match the container's truth and state writers.
                "dsa_controller_node": {
                    "ros__parameters": {
                        "run_time_s": n_blocks * BLOCK / FS_HZ,
                        "start_delay_s": 5.0,
                        "watchdog_timeout_s": 30.0,
                    }
                },
            }
        )
    )
    with ros_processes() as procs:
        ready = [tmp_path / "truth.ready", tmp_path / "state.ready"]
        truth = procs.flaair(
            "topic",
            "echo",
            "--json",
            "/flaair/wing_state/truth",
            "flaair_msgs/msg/WingStateBlock",
            "--count",
            str(n_blocks),
            "--silence",
            "300",
            "--ready-file",
            str(ready[0]),
        )
        state = procs.flaair(
            "topic",
            "echo",
            "--json",
            "/flaair/controller/state",
            "flaair_msgs/msg/ControllerState",
            "--count",
            str(n_blocks),
            "--silence",
            "300",
            "--ready-file",
            str(ready[1]),
        )
        procs.env = {**procs.env, "FLAAIR_PROFILE": "1"}
        container = procs.flaair(
            "run", "flaair_common", "container", *NODES, "--ros-args", "--params-file", str(params)
        )
        assert wait_for(lambda: all(p.exists() for p in ready), timeout_s=120)
        truth_out, err = truth.communicate(timeout=330)
        assert truth.returncode == 0, err
        state_out, err = state.communicate(timeout=120)
        assert state.returncode == 0, err
        assert procs.stop(container) == 0
        log = container.stderr.read() + container.stdout.read()
    assert "run complete" in log, log[-2000:]
    # The plant stepped from sample 0 with the listener matched: every truth block, in order.
    assert [json.loads(line)["first_sample_index"] for line in truth_out.splitlines()] == list(
        range(0, n_blocks * BLOCK, BLOCK)
    )
    states = [json.loads(line) for line in state_out.splitlines()]
    assert len(states) == n_blocks and all(s["watchdog"] == 0 for s in states)
    profile = {
        node: (int(calls), float(cpu), float(wall))
        for node, _, calls, cpu, wall in PROFILE.findall(log)
    }
    assert set(profile) == {"plant_node", "frontend_node", "dsa_controller_node"}, log[-2000:]
    for node, (calls, cpu_us, wall_us) in profile.items():
        assert calls >= n_blocks, node  # one callback per block
        assert 0.0 < cpu_us <= wall_us * 1.05, node
