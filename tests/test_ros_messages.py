"""Every custom block message crosses DDS between separate processes with its values intact."""
from __future__ import annotations

import json

import pytest

from rosproc import ros_processes

pytestmark = pytest.mark.graph   # ROS 2 processes exchanging data in real time: run alone

MESSAGES = {
    "flaair_msgs/msg/SensorVoltageBlock": {
        "header": {"stamp": {"sec": 12, "nanosec": 345000}, "frame_id": "robot"},
        "sample_rate_hz": 20000.0, "first_sample_index": 123456789012,
        "stroke_sensor_v": [1.25, 1.2500001, -3.5e-7, 2.4999], "pitch_sensor_v": [0.0, 1e300, -1e-300, 1.75],
    },
    "flaair_msgs/msg/WingStateBlock": {
        "header": {"stamp": {"sec": 1, "nanosec": 500}, "frame_id": "robot"},
        "sample_rate_hz": 20000.0, "first_sample_index": 10, "source": 1,
        "stroke_deg": [45.123456789, -45.0], "pitch_deg": [12.5, -60.25],
        "stroke_velocity_deg_s": [28000.5, -1.0], "stroke_valid": [True, False], "pitch_valid": [False, True],
    },
    "flaair_msgs/msg/DriveCommandBlock": {
        "header": {"stamp": {"sec": 3, "nanosec": 999999999}, "frame_id": ""},
        "sample_rate_hz": 20000.0, "first_sample_index": 20, "drive_v": [100.0, -99.999, 0.125] * 4,
    },
    "flaair_msgs/msg/CollisionStatus": {
        "header": {"stamp": {"sec": 4, "nanosec": 0}, "frame_id": "robot"}, "wingbeat_index": 77,
        "wingbeat_frequency_hz": 100.0, "colliding": True, "spectrum_rmse_deg": 3.23,
        "time_rmse_deg": 15.81, "threshold_deg": 1.0,
    },
    "flaair_msgs/msg/CollisionEvent": {
        "header": {"stamp": {"sec": 5, "nanosec": 1}, "frame_id": "robot"}, "kind": 2,
        "wingbeat_index": 78, "spectrum_rmse_deg": 0.53,
    },
    "flaair_msgs/msg/ControllerState": {
        "header": {"stamp": {"sec": 6, "nanosec": 2}, "frame_id": "robot"}, "k_r": 0.25,
        "async_drive_v": -12.5, "sync_drive_v": 80.0, "drive_v": 100.0, "drive_clamped": True,
        "watchdog": 1, "fault": "no sensor block for 0.020 s", "amplitude_scale": 0.5,
        "stroke_frequency_hz": 151.2,
    },
}


@pytest.mark.parametrize("type_name", sorted(MESSAGES))
def test_message_crosses_processes_intact(type_name: str) -> None:
    values = MESSAGES[type_name]
    topic = "/flaair/test/" + type_name.rsplit("/", 1)[-1].lower()
    with ros_processes() as procs:
        echo = procs.flaair("topic", "echo", topic, type_name, "--count", "1", "--timeout", "120")
        pub = procs.flaair("topic", "pub", topic, type_name, json.dumps(values), "--count", "3",
                           "--rate", "5", "--wait-subscribers", "1")
        out, err = echo.communicate(timeout=150)
        assert echo.returncode == 0, err
        assert pub.wait(timeout=30) == 0, pub.stderr.read()
    received = json.loads(out.strip().splitlines()[0])
    for key, expected in values.items():
        assert received[key] == expected, key
