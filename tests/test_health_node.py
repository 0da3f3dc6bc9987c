"""health_node composed with the plant (lockstep, noise on): the plant damaged mid-run through its
damage_* parameters, the node's HealthStatus and HealthEvent against the offline core.
"""

from __future__ import annotations

import numpy as np
import pytest

from composed import BLOCK, FS_HZ, composed, joined
from flaair_common import topics


@pytest.mark.slow  # simulates the damaged wing's wingbeats twice (node core and offline)
def test_health_node_reports_a_damaged_wing_as_the_offline_core_does(monkeypatch, tmp_path):
    from rclpy.serialization import deserialize_message

    from flaair_common.diagnostics import WARN
    from flaair_control import health_io
    from flaair_control.core import health
    from flaair_control.health_node import HealthNode
    from flaair_msgs.msg import HealthStatus
    from flaair_sim.plant_node import PlantNode

    params = {
        "plant_node": {
            "command_timeout_s": 0.0,
            "noise": True,
            "damage_time_s": 0.8,
            "damage_inertia_factor": 0.8,
        },
    }
    n = int(1.4 * FS_HZ)
    drive_v = 40.0 * np.sin(2 * np.pi * 140.0 * np.arange(n) / FS_HZ)
    with composed(monkeypatch, [PlantNode, HealthNode], params, tmp_path) as loop:
        node = loop.node("health_node")
        status, events = [], []
        # the status as its CDR bytes reach DDS, read back by rclpy (an independent reader)
        monkeypatch.setattr(
            node.status_pub.publisher,
            "publish",
            lambda data: status.append(deserialize_message(data, HealthStatus)),
        )
        monkeypatch.setattr(node.event_pub, "publish", events.append)
        films = loop.sink(topics.SENSOR_VOLTAGE)
        for k in range(0, n, BLOCK):
            loop.bus.deliver(
                topics.DRIVE,
                {
                    "sample_rate_hz": FS_HZ,
                    "first_sample_index": k,
                    "sec": 0,
                    "nanosec": 0,
                    "frame_id": "",
                    "drive_v": drive_v[k : k + BLOCK],
                },
            )
            loop.bus.flush()
        diag = health_io.health_diagnostics(
            (node.state.wingbeat, node.estimated, node.events, node.state.quiet), None
        )
    assert [e.parameter for e in events] == ["wing_inertia"]
    assert events[0].ratio == pytest.approx(0.8, abs=0.04)
    assert 0.8 < events[0].time_s < 0.8 + 20 / 140.0
    assert diag.level == WARN and "wing_inertia" in diag.message
    # the same core offline on what the plant published: the same wingbeats and estimates
    p = health_io.health_params_from_config(health_io.health_values())
    vs, vp = joined(films, "stroke_sensor_v"), joined(films, "pitch_sensor_v")
    _, out = health.step(
        health.initial_state(p), health.HealthInputs(vs, vp, drive_v[: vs.size]), p
    )
    assert len(status) == len(out.wingbeats) > 150
    assert [s.sample_index for s in status] == [b.sample_index for b in out.wingbeats]
    np.testing.assert_array_equal(
        [s.wing_inertia_ratio for s in status], [b.estimate[0] for b in out.wingbeats]
    )
    assert [e.sample_index for e in events] == [e.sample_index for e in out.events]


@pytest.mark.timeout(120)
def test_health_node_takes_the_films_lags_and_gains_from_its_calibration_file(
    monkeypatch, tmp_path
):
    """The node's parameters from a calibration_file are those `bin/flaair health --calibration`
    computes (one function, health_io.health_params_from_config): lags and film gains from it.
    """
    from flaair_control import health_io
    from flaair_control.health_node import HealthNode
    from flaair_model.model_io import load_model

    model = load_model()
    cal = tmp_path / "calibration.yaml"
    cal.write_text(
        f"stroke: {{gain_deg_per_v: {2 * model.stroke_gain_deg_per_v}, polarity: "
        f"{model.stroke_polarity}, lag_s: 0.0002}}\n"
        f"pitch: {{gain_deg_per_v: {model.pitch_gain_deg_per_v}, polarity: "
        f"{model.pitch_polarity}, lag_s: 0.0003}}\n"
    )
    params = {"health_node": {"calibration_file": str(cal)}}
    with composed(monkeypatch, [HealthNode], params, tmp_path) as loop:
        got = loop.node("health_node").params
    offline = health_io.health_params_from_config(
        {**health_io.health_values(), "calibration_file": str(cal)}
    )
    assert got == offline
    assert (got.stroke_film_delay_s, got.pitch_film_delay_s) == (0.0002, 0.0003)
    nominal = health_io.health_params_from_config()
    assert got.stroke_volts_per_rad == pytest.approx(nominal.stroke_volts_per_rad / 2, rel=1e-12)
    assert got.pitch_volts_per_rad == pytest.approx(nominal.pitch_volts_per_rad, rel=1e-12)
