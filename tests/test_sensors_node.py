"""Front-end node over real DDS: live wing state equals the offline core on the same voltages."""
from __future__ import annotations

import pytest

import json

import numpy as np

from rosproc import ros_processes
from tuning import FRONTEND_TUNING

pytestmark = pytest.mark.graph   # ROS 2 processes exchanging data in real time: run alone

FS_HZ = 20000.0


def test_frontend_node_matches_offline_core_and_tracks_truth() -> None:
    from flaair_sensors import frontend
    from flaair_sim.drive import DriveParams, drive_record
    from flaair_model.model_io import load_model
    from flaair_sim.plant import simulate

    n_blocks = 400
    with ros_processes() as procs:
        # The front end may match the plant's stream a few blocks late on a loaded machine; the
        # run is longer than what is compared, and the offline core starts at the same block.
        echo = procs.flaair("topic", "echo", "/flaair/wing_state", "flaair_msgs/msg/WingStateBlock",
                            "--count", str(n_blocks), "--timeout", "300")
        procs.flaair("run", "flaair_sensors", "frontend_node")
        procs.flaair("run", "flaair_sim", "plant_node")
        # The lockstep run lasts under a second: the front end must listen before it starts.
        for topic in ("/flaair/sensor_v", "/flaair/wing_state"):
            assert procs.flaair("topic", "wait", topic, "--publishers", "1", "--subscribers", "1", "--timeout", "120").wait(150) == 0
        procs.flaair("run", "flaair_sim", "drive_node", "--ros-args", "-p", "pacing:=lockstep",
                     "-p", "waveform:=sine", "-p", "frequency_hz:=140.0", "-p", f"run_time_s:={2 * n_blocks * 10 / FS_HZ}")
        out, err = echo.communicate(timeout=330)
        assert echo.returncode == 0, err
    blocks = [json.loads(line) for line in out.splitlines()]
    first = blocks[0]["first_sample_index"]
    assert first <= 50 * 10
    assert [b["first_sample_index"] for b in blocks] == list(range(first, first + n_blocks * 10, 10))
    assert all(b["source"] == 0 for b in blocks)
    stroke_deg = np.concatenate([b["stroke_deg"] for b in blocks])
    velocity = np.concatenate([b["stroke_velocity_deg_s"] for b in blocks])
    model = load_model()
    drive = drive_record(DriveParams(kind="sine", amplitude_v=100.0, frequency_hz=140.0), FS_HZ, first + n_blocks * 10)
    sim = simulate(drive, FS_HZ, model)
    seen = slice(first, first + n_blocks * 10)
    offline = frontend.estimate(sim.stroke_sensor_v[seen], sim.pitch_sensor_v[seen], frontend.params_from_model(model, FS_HZ, **FRONTEND_TUNING))
    assert np.allclose(stroke_deg, np.degrees(offline.stroke_rad), rtol=0, atol=1e-9)
    assert np.allclose(velocity, np.degrees(offline.stroke_velocity_rad_s), rtol=0, atol=1e-6)
    truth = np.degrees(sim.stroke_rad[seen])
    settled = slice(len(truth) // 2, None)  # after the drift tracker's start-up
    assert np.sqrt(np.mean((stroke_deg[settled] - truth[settled]) ** 2)) < 0.5
    assert np.max(np.abs(truth)) > 20.0
