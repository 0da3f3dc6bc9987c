"""Every custom block message crosses DDS between separate processes with its values intact."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from rosproc import ros_processes

pytestmark = pytest.mark.graph  # ROS 2 processes exchanging data in real time: run after the others

MESSAGES = {
    "flaair_msgs/msg/SensorVoltageBlock": {
        "header": {"stamp": {"sec": 12, "nanosec": 345000}, "frame_id": "robot"},
        "sample_rate_hz": 20000.0,
        "first_sample_index": 123456789012,
        "stroke_sensor_v": [1.25, 1.2500001, -3.5e-7, 2.4999],
        "pitch_sensor_v": [0.0, 1e300, -1e-300, 1.75],
    },
    "flaair_msgs/msg/WingStateBlock": {
        "header": {"stamp": {"sec": 1, "nanosec": 500}, "frame_id": "robot"},
        "sample_rate_hz": 20000.0,
        "first_sample_index": 10,
        "source": 1,
        "stroke_deg": [45.123456789, -45.0],
        "pitch_deg": [12.5, -60.25],
        "stroke_velocity_deg_s": [28000.5, -1.0],
        "stroke_valid": [True, False],
        "pitch_valid": [False, True],
    },
    "flaair_msgs/msg/DriveCommandBlock": {
        "header": {"stamp": {"sec": 3, "nanosec": 999999999}, "frame_id": ""},
        "sample_rate_hz": 20000.0,
        "first_sample_index": 20,
        "drive_v": [100.0, -99.999, 0.125] * 4,
    },
    "flaair_msgs/msg/CollisionStatus": {
        "header": {"stamp": {"sec": 4, "nanosec": 0}, "frame_id": "robot"},
        "wingbeat_index": 77,
        "wingbeat_frequency_hz": 100.0,
        "colliding": True,
        "spectrum_rmse_deg": 3.23,
        "time_rmse_deg": 15.81,
        "threshold_deg": 1.0,
    },
    "flaair_msgs/msg/CollisionEvent": {
        "header": {"stamp": {"sec": 5, "nanosec": 1}, "frame_id": "robot"},
        "kind": 2,
        "wingbeat_index": 78,
        "spectrum_rmse_deg": 0.53,
    },
    "flaair_msgs/msg/ControllerState": {
        "header": {"stamp": {"sec": 6, "nanosec": 2}, "frame_id": "robot"},
        "k_r": 0.25,
        "async_drive_v": -12.5,
        "sync_drive_v": 80.0,
        "drive_v": 100.0,
        "drive_clamped": True,
        "watchdog": 1,
        "fault": "no sensor block for 0.020 s",
        "amplitude_scale": 0.5,
        "stroke_frequency_hz": 151.2,
    },
}


def test_every_message_type_crosses_processes_intact(tmp_path) -> None:
    """One graph: an echo and a publisher per message type, each in a process of its own."""
    topics = {name: "/flaair/test/" + name.rsplit("/", 1)[-1].lower() for name in MESSAGES}
    with ros_processes() as procs:
        outs = {name: tmp_path / f"{name.rsplit('/', 1)[-1]}.jsonl" for name in MESSAGES}
        echoes = {
            name: procs.flaair(
                "topic",
                "echo",
                "--json",
                topics[name],
                name,
                "--count",
                "1",
                "--silence",
                "120",
                stdout=open(outs[name], "w"),  # noqa: SIM115  the child's log
                stderr=open(f"{outs[name]}.err", "w"),  # noqa: SIM115  the child's log
            )
            for name in MESSAGES
        }
        # each publisher sends only once its echo is matched (and fails if it never is)
        pubs = {
            name: procs.flaair(
                "topic",
                "pub",
                topics[name],
                name,
                json.dumps(values),
                "--count",
                "1",
                "--wait-subscribers",
                "1",
                "--wait-timeout",
                "120",
                stdout=open(f"{outs[name]}.pub", "w"),  # noqa: SIM115  the child's log
                stderr=subprocess.STDOUT,
            )
            for name, values in MESSAGES.items()
        }
        for name in MESSAGES:
            assert echoes[name].wait(timeout=150) == 0, Path(f"{outs[name]}.err").read_text()
            assert pubs[name].wait(timeout=150) == 0, Path(f"{outs[name]}.pub").read_text()
    for name, values in MESSAGES.items():
        received = json.loads(outs[name].read_text().strip().splitlines()[0])
        for key, expected in values.items():
            assert received[key] == expected, (name, key)
