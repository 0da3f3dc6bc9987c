"""Front-end node: live wing state equals the offline core on the same voltages."""

from __future__ import annotations

import numpy as np

from tuning import FRONTEND_TUNING

FS_HZ = 20000.0


def test_frontend_node_matches_offline_core_and_tracks_truth(monkeypatch, tmp_path) -> None:
    """Plant and front-end nodes composed in process (tests/composed.py), driven in lockstep: the
    node's wing-state blocks equal the offline core on the same samples, from sample 0.
    """
    from composed import composed, joined
    from flaair_common import topics
    from flaair_model.model_io import load_model
    from flaair_sensors.core import frontend, frontend_params
    from flaair_sensors.frontend_node import FrontendNode
    from flaair_sim.core.drive import DriveParams, drive_record
    from flaair_sim.core.plant import simulate
    from flaair_sim.plant_node import PlantNode

    n_blocks, block = 400, 10
    drive = drive_record(
        DriveParams(kind="sine", amplitude_v=100.0, frequency_hz=140.0), FS_HZ, n_blocks * block
    )
    with composed(
        monkeypatch, [PlantNode, FrontendNode], {"plant_node": {"command_timeout_s": 0.0}}, tmp_path
    ) as loop:
        wing = loop.sink(topics.WING_STATE)
        for k in range(0, n_blocks * block, block):
            loop.bus.deliver(
                topics.DRIVE,
                {
                    "sample_rate_hz": FS_HZ,
                    "first_sample_index": k,
                    "sec": 0,
                    "nanosec": 0,
                    "frame_id": "",
                    "drive_v": drive[k : k + block],
                },
            )
            loop.bus.flush()
    assert [b["first_sample_index"] for b in wing] == list(range(0, n_blocks * block, block))
    assert all(b["source"] == 0 for b in wing)
    stroke_deg, velocity = joined(wing, "stroke_deg"), joined(wing, "stroke_velocity_deg_s")
    model = load_model()
    sim = simulate(drive, FS_HZ, model)
    offline = frontend.estimate(
        sim.stroke_sensor_v,
        sim.pitch_sensor_v,
        frontend_params.params_from_model(model, FS_HZ, **FRONTEND_TUNING),
    )
    assert np.array_equal(stroke_deg, np.degrees(offline.stroke_rad))  # bit for bit
    assert np.array_equal(velocity, np.degrees(offline.stroke_velocity_rad_s))
    truth = np.degrees(sim.stroke_rad)
    settled = slice(len(truth) // 2, None)  # after the drift tracker's start-up
    assert np.sqrt(np.mean((stroke_deg[settled] - truth[settled]) ** 2)) < 0.5
    assert np.max(np.abs(truth)) > 20.0
