"""Control nodes, in process and deterministic: the node classes composed on one bus with a fake
clock (tests/composed.py), so every check is exact. The same loop over real DDS in separate
processes is tested end to end in test_faults (kill -9 of the controller) and test_replay.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from composed import BLOCK, FS_HZ, composed, joined
from flaair_common import topics
from tuning import FRONTEND_TUNING


def _loop_classes() -> list[type]:
    from flaair_control.dsa_controller_node import DsaControllerNode
    from flaair_sensors.frontend_node import FrontendNode
    from flaair_sim.plant_node import PlantNode

    return [PlantNode, FrontendNode, DsaControllerNode]


def _wing_state(index: int, n: int = BLOCK, velocity: float = 0.0, valid: bool = True) -> dict:
    """A wing-state block as the in-process bus hands it over (fields by name)."""
    return {
        "sample_rate_hz": FS_HZ,
        "first_sample_index": index,
        "sec": 0,
        "nanosec": 0,
        "frame_id": "robot",
        "stroke_deg": np.zeros(n),
        "pitch_deg": np.zeros(n),
        "stroke_velocity_deg_s": np.full(n, velocity),
        "stroke_valid": np.full(n, valid),
        "pitch_valid": np.full(n, valid),
    }


def _stamp_index(block: dict) -> int:
    return round((block["sec"] + block["nanosec"] * 1e-9) * FS_HZ)


def test_closed_loop_scales_the_drive_at_a_collision_onset_and_restores_it_at_clearance(
    monkeypatch, tmp_path
) -> None:
    """Plant (lockstep), front end and controller composed: a ControllerState with every drive
    block; an onset scales the drive by collision_reduction_factor from the next block on, the
    clearance restores it; the sensor stream is gap-free from sample 0.
    """
    from flaair_msgs.msg import CollisionEvent

    params = {
        "plant_node": {"command_timeout_s": 0.0},
        "dsa_controller_node": {
            "collision_response": "reduce_amplitude",
            "collision_reduction_factor": 0.25,
            # no K_r ramp
            "watchdog_timeout_s": 30.0,
            "kr_ramp_start_s": 1000.0,
        },
    }
    with composed(monkeypatch, _loop_classes(), params, tmp_path) as loop:
        states, sensors = loop.sink(topics.CONTROLLER_STATE), loop.sink(topics.SENSOR_VOLTAGE)
        controller = loop.node("dsa_controller_node")
        loop.run_until(lambda: len(states) >= 100)
        # the first drive block computed after the event
        onset_index = controller.state.next_index
        controller.on_collision_event(
            CollisionEvent(kind=CollisionEvent.ONSET, wingbeat_index=7, spectrum_rmse_deg=3.2)
        )
        loop.run_until(lambda: len(states) >= 200)
        clear_index = controller.state.next_index
        controller.on_collision_event(
            CollisionEvent(kind=CollisionEvent.CLEARANCE, wingbeat_index=12, spectrum_rmse_deg=0.2)
        )
        loop.run_until(lambda: len(states) >= 300)
    assert sensors[0]["first_sample_index"] == 0
    joined(sensors, "stroke_sensor_v")  # gap-free
    # one state per drive block, each block's exactly once (in-process delivery may reorder a few)
    states.sort(key=_stamp_index)
    index = np.array([_stamp_index(s) for s in states])
    assert list(index) == list(range(0, len(states) * BLOCK, BLOCK))
    scales = np.array([s["amplitude_scale"] for s in states])
    reduced = (index >= onset_index) & (index < clear_index)
    assert 0 < onset_index < clear_index < index[-1]
    assert np.all(scales[reduced] == 0.25) and np.all(scales[~reduced] == 1.0)
    assert all(s["watchdog"] == 0 and s["fault"] == "" for s in states)
    assert max(abs(s["drive_v"]) for s in states) <= 150.0
    sync = np.array([s["sync_drive_v"] for s in states])
    # the synchronous 20 V sine ...
    assert np.abs(sync).max() > 19.0
    drive_v = np.array([s["drive_v"] for s in states])
    # ... scaled (K_r = 1)
    np.testing.assert_allclose(drive_v, scales * sync, rtol=1e-12, atol=1e-12)


def test_controller_waits_for_a_state_listener_when_asked(monkeypatch, tmp_path) -> None:
    """min_state_subscribers:=1: plant and front end up, yet no loop until /flaair/controller/state
    has a listener; then it starts, and the listener sees the loop from its first block.
    """
    params = {
        "plant_node": {"command_timeout_s": 0.0},
        "dsa_controller_node": {
            "min_state_subscribers": 1,
            "start_delay_s": 0.0,
            "watchdog_timeout_s": 30.0,
        },
    }
    with composed(monkeypatch, _loop_classes(), params, tmp_path) as loop:
        sensors = loop.sink(topics.SENSOR_VOLTAGE)
        loop.run_for(5.0)
        assert sensors == [] and loop.stepped_blocks == 0, (
            "the loop started without a state listener"
        )
        states = loop.sink(topics.CONTROLLER_STATE)
        loop.run_until(lambda: len(states) >= 50)
    assert min(_stamp_index(s) for s in states) == 0
    assert sensors[0]["first_sample_index"] == 0


def test_watchdog_trips_and_ramps_the_drive_to_zero_when_wing_state_blocks_stop(
    monkeypatch, tmp_path, capfd
) -> None:
    """No plant: the controller does not start the loop itself but answers the first wing-state
    block, then trips on the wall clock: reply, 20 ms ramp, 10 ms zero hold, keepalives.
    """
    from flaair_control.dsa_controller_node import DsaControllerNode

    params = {
        "dsa_controller_node": {
            "watchdog_timeout_s": 0.3,
            "ramp_down_s": 0.02,
            "zero_hold_s": 0.01,
            "keepalive_period_s": 0.2,
            "start_delay_s": 0.0,
            "sync_amplitude_v": 40.0,
            "sync_frequency_hz": 100.0,
        }
    }
    with composed(monkeypatch, [DsaControllerNode], params, tmp_path) as loop:
        drive, states = loop.sink(topics.DRIVE), loop.sink(topics.CONTROLLER_STATE)
        t_first, sent_at_s = loop.clock.now_s, []
        loop.bus.subscribe(
            topics.DRIVE, lambda _fields: sent_at_s.append(round(loop.clock.now_s - t_first, 6))
        )
        loop.bus.deliver(topics.WING_STATE, _wing_state(0))
        loop.bus.deliver(topics.WING_STATE, _wing_state(0))  # a duplicate: ignored
        loop.run_for(0.98)
    log = capfd.readouterr().err
    # the reply at once; the trip at the first 10 ms tick after 0.3 s; the ramp and zero hold paced
    # at the real-time rate (20 blocks a tick; the tick that ends the hold sends its 20 whole);
    # then one zero block per keepalive_period_s (0.2 s, on the 10 ms tick)
    assert sent_at_s == [0.0] + [0.32] * 19 + [0.33] * 20 + [0.34] * 20 + [0.35] * 20 + [
        0.56,
        0.77,
        0.98,
    ]
    assert [b["first_sample_index"] for b in drive] == list(range(0, len(drive) * BLOCK, BLOCK))
    x = joined(drive, "drive_v")
    assert np.isfinite(x).all() and np.abs(x).max() <= 150.0
    assert np.abs(x[:BLOCK]).max() > 5.0  # driving before the trip
    tripped = [s for s in states if s["watchdog"] == 1]
    assert tripped and "no wing-state block for 310 ms of wall-clock time" in tripped[0]["fault"]
    # ramp: the envelope of each 5 ms (100-sample) window
    # after the trip never grows, then exact zeros
    after = x[BLOCK:]
    peaks = np.abs(after[: len(after) // 100 * 100]).reshape(-1, 100).max(axis=1)
    assert np.all(np.diff(peaks) <= 1e-9) and peaks[0] > 1.0
    assert np.abs(after[int(0.02 * FS_HZ)]) < 1e-9 and np.all(after[int(0.02 * FS_HZ) + 1 :] == 0.0)
    assert "WATCHDOG TRIPPED" in log and "duplicate or out of order" in log


def test_invalid_wing_state_blocks_are_counted_and_the_loop_goes_on(
    monkeypatch, tmp_path, capfd
) -> None:
    from flaair_control.dsa_controller_node import DsaControllerNode

    with composed(
        monkeypatch,
        [DsaControllerNode],
        {"dsa_controller_node": {"watchdog_timeout_s": 60.0, "start_delay_s": 0.0}},
        tmp_path,
    ) as loop:
        drive = loop.sink(topics.DRIVE)
        controller = loop.node("dsa_controller_node")
        sequence = [
            _wing_state(0, velocity=100.0),
            _wing_state(10, velocity=math.nan),  # NaN velocity: invalid
            _wing_state(20, velocity=100.0, valid=False),  # front end says invalid
            _wing_state(30, n=5),  # wrong length: rejected
            _wing_state(40, velocity=100.0),
        ]
        for block in sequence:
            loop.bus.deliver(topics.WING_STATE, block)
            loop.fire_due_timers()
        # one answer per block (no plant: no start block)
        assert len(drive) == 5
        controller.close()  # shutdown: a zero block
        loop.bus.flush()
    log = capfd.readouterr().err
    assert [b["first_sample_index"] for b in drive] == [0, 10, 20, 30, 40, 50]
    assert all(np.isfinite(b["drive_v"]).all() for b in drive)
    assert list(drive[-1]["drive_v"]) == [0.0] * BLOCK
    assert "[2 invalid so far]" in log and "block has 5 samples, expected 10" in log


def test_collision_monitor_reports_every_wingbeat_and_flags_an_obstacle(
    monkeypatch, tmp_path
) -> None:
    """Paper scenario, the nodes composed: 100 Hz, 75 V about the bias, obstacle at 20 deg against a
    28 deg free stroke; the monitor's verdicts, one per wingbeat, and exactly one onset.
    """
    import yaml

    from composed import REPO_ROOT
    from flaair_control.collision_monitor_node import CollisionMonitorNode
    from flaair_sensors.frontend_node import FrontendNode
    from flaair_sim.plant_node import PlantNode

    model = yaml.safe_load((REPO_ROOT / "config" / "model.yaml").read_text())
    model["effects"] = {"collision": {"stroke_limit_deg": 20.0}}
    model_file = tmp_path / "hit.yaml"
    model_file.write_text(yaml.safe_dump(model))
    params = {
        "plant_node": {"model_file": str(model_file), "command_timeout_s": 0.0},
        "collision_monitor_node": {"drive_frequency_hz": 100.0},
    }
    n = int(1.0 * FS_HZ)
    drive_v = 75.0 * np.sin(2 * np.pi * 100.0 * np.arange(n) / FS_HZ)  # drive_node's sine: phase 0
    with composed(
        monkeypatch, [PlantNode, FrontendNode, CollisionMonitorNode], params, tmp_path
    ) as loop:
        monitor = loop.node("collision_monitor_node")
        status, events = [], []
        monkeypatch.setattr(monitor.status_pub, "publish", status.append)
        monkeypatch.setattr(monitor.event_pub, "publish", events.append)
        for k in range(0, n, BLOCK):  # the lockstep drive, one block at a time
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
    assert len(status) == 100  # 1 s at 100 Hz: a verdict per wingbeat
    assert [s.wingbeat_index for s in status] == list(range(len(status)))
    assert all(s.wingbeat_frequency_hz == 100.0 and s.threshold_deg == 1.0 for s in status)
    rmse = [s.spectrum_rmse_deg for s in status if math.isfinite(s.spectrum_rmse_deg)]
    assert rmse and min(rmse) > 1.0 and status[-1].colliding
    assert [e.kind for e in events] == [1]
    onset = events[0]
    assert onset.spectrum_rmse_deg > 1.0
    assert status[onset.wingbeat_index].colliding and not status[onset.wingbeat_index - 1].colliding


@pytest.mark.parametrize("obstacle", [False, True])
def test_collision_monitor_locks_to_the_estimated_drive_frequency(monkeypatch, obstacle) -> None:
    """In-process (no DDS): drive and wing-state messages
    from the simulated robot, free or with an obstacle.
    """
    import rclpy

    from flaair_control.collision_monitor_node import CollisionMonitorNode
    from flaair_model.model import with_effects
    from flaair_model.model_io import load_model
    from flaair_sensors.core import frontend, frontend_params
    from flaair_sim.core.plant import simulate

    model = load_model()
    fs, n = FS_HZ, int(0.5 * FS_HZ)
    drive = 75.0 * np.sin(2 * np.pi * 100.0 * np.arange(n) / fs + 1.0)  # unknown phase
    out = simulate(
        drive,
        fs,
        with_effects(model, {"collision": {"stroke_limit_deg": 20.0}}) if obstacle else model,
    )
    est = frontend.estimate(
        out.stroke_sensor_v,
        out.pitch_sensor_v,
        frontend_params.params_from_model(model, fs, **FRONTEND_TUNING),
    )
    if rclpy.ok():
        rclpy.shutdown()
    owns_rclpy = True  # the paper's decision (the default is the per-wingbeat one)
    rclpy.init(args=["test", "--ros-args", "-p", "decision:=paper"])
    try:
        node = CollisionMonitorNode()
        statuses, events = [], []
        monkeypatch.setattr(node.status_pub, "publish", statuses.append)
        monkeypatch.setattr(node.event_pub, "publish", events.append)
        # blocks as the in-process bus hands them over: fields by name
        for k in range(0, n, BLOCK):
            stamp = {"sec": k // int(fs), "nanosec": round((k % int(fs)) / fs * 1e9)}
            node.on_drive(
                {
                    "sample_rate_hz": fs,
                    "first_sample_index": k,
                    "drive_v": drive[k : k + BLOCK],
                    **stamp,
                }
            )
            node.on_wing_state(
                {
                    "sample_rate_hz": fs,
                    "first_sample_index": k,
                    **stamp,
                    "stroke_deg": np.degrees(est.stroke_rad[k : k + BLOCK]),
                    "pitch_deg": np.degrees(est.pitch_rad[k : k + BLOCK]),
                    "stroke_valid": est.stroke_valid[k : k + BLOCK],
                    "pitch_valid": est.pitch_valid[k : k + BLOCK],
                }
            )
        node.destroy_node()
    finally:
        if owns_rclpy:
            rclpy.shutdown()
    assert node.state.lock.locked_hz == 100.0
    assert len(statuses) >= 35 and all(s.wingbeat_frequency_hz == 100.0 for s in statuses)
    rmse = [s.spectrum_rmse_deg for s in statuses if math.isfinite(s.spectrum_rmse_deg)]
    if obstacle:
        assert rmse and min(rmse) > 1.0 and statuses[-1].colliding
        assert [e.kind for e in events] == [1] and events[0].spectrum_rmse_deg > 1.0
    else:  # paper: 0.53 deg without a collision
        assert rmse and max(rmse) < 0.5 and not any(s.colliding for s in statuses) and events == []


def test_controller_kr_ramp_service_collision_stop_and_watchdog_reset_in_process(
    monkeypatch,
) -> None:
    """The parameter 'service' (kr_ramp_duration_s), the stop response, the watchdog's health
    and its reset service, without DDS.
    """
    import rclpy
    from rclpy.parameter import Parameter
    from rclpy.serialization import deserialize_message, serialize_message
    from std_srvs.srv import Trigger

    from flaair_common import cdr
    from flaair_common.blocks import from_array
    from flaair_common.diagnostics import ERROR, OK
    from flaair_control.core.loop_state import LOOP, TRIPPED
    from flaair_control.dsa_controller_node import DsaControllerNode
    from flaair_control.dsa_io import controller_health
    from flaair_msgs.msg import CollisionEvent, ControllerState, DriveCommandBlock, WingStateBlock

    if rclpy.ok():
        rclpy.shutdown()
    rclpy.init(
        args=[
            "test",
            "--ros-args",
            "-p",
            "collision_response:=stop",
            "-p",
            "wait_for_peers:=false",
            "-p",
            "start_delay_s:=0.0",
            "-p",
            "ramp_down_s:=0.005",
            "-p",
            "zero_hold_s:=0.0",
            "-p",
            "mu_nm_s_per_rad:=1.0e-3",
        ]
    )  # huge gain: the clamp must act
    try:
        node = DsaControllerNode()
        drive, states = [], []
        # The node publishes CDR bytes; rclpy's own deserializer reads them back.

        def on_drive(data: bytes) -> None:
            m = deserialize_message(data, DriveCommandBlock)
            drive.append((m.first_sample_index, list(m.drive_v)))

        def on_state(data: bytes) -> None:
            m = deserialize_message(data, ControllerState)
            states.append((m.k_r, m.watchdog, m.fault, m.drive_clamped, m.drive_v))

        monkeypatch.setattr(node.drive.publisher, "publish", on_drive)
        monkeypatch.setattr(node.state_pub.publisher, "publish", on_state)
        # a listener: states are written
        monkeypatch.setattr(node.state_pub.publisher, "get_subscription_count", lambda: 1)

        def feed(k: int) -> None:
            message = WingStateBlock(sample_rate_hz=FS_HZ, first_sample_index=k * BLOCK)
            t = (k * BLOCK + np.arange(BLOCK)) / FS_HZ
            message.stroke_deg = from_array(10 * np.sin(2 * np.pi * 140 * t))
            message.stroke_velocity_deg_s = from_array(
                10 * 2 * np.pi * 140 * np.cos(2 * np.pi * 140 * t)
            )
            message.stroke_valid = [True] * BLOCK
            message.header.frame_id = "robot"
            node.on_wing_state(cdr.decode(cdr.WING_STATE_BLOCK, serialize_message(message)))

        node.on_timer()  # starts: one block in flight
        assert node.state.mode == LOOP and [d[0] for d in drive] == [0]
        for k in range(100):
            feed(k)
        assert all(s[0] == 1.0 for s in states)  # synchronous until kr_ramp_start_s (0.5 s)
        # ramp to 0 now
        result = node.set_parameters([Parameter("kr_ramp_duration_s", value=0.005)])[0]
        assert result.successful
        for k in range(100, 130):
            feed(k)
        kr = [s[0] for s in states[-31:]]  # from the last block before the request
        assert kr[0] == 1.0 and kr[-1] == 0.0 and np.all(np.diff(kr) <= 0)
        # clamped
        assert all(abs(s[4]) <= 150.0 for s in states) and any(s[3] for s in states[-10:])
        node.on_collision_event(
            CollisionEvent(kind=CollisionEvent.ONSET, wingbeat_index=2, spectrum_rmse_deg=2.5)
        )
        # within collision_ramp_guard_s (0.1 s) of the ramp: not acted on
        assert node.state.mode == LOOP
        for k in range(130, 360):
            feed(k)
        node.on_collision_event(
            CollisionEvent(kind=CollisionEvent.ONSET, wingbeat_index=3, spectrum_rmse_deg=2.5)
        )
        assert node.state.mode == TRIPPED and "collision onset at wingbeat 3" in node.state.fault
        n_before = len(drive)
        feed(360)  # tripped: the timer paces, no reply
        assert len(drive) == n_before
        time.sleep(0.05)
        node.on_timer()
        ramp = np.concatenate([d[1] for d in drive[n_before:]])
        # zero from trip + ramp_down_s on (the boundary sample
        # itself is ~1e-13 V: float rounding in the core)
        assert (
            ramp.size >= 101
            and abs(ramp[100]) < 1e-9
            and np.all(ramp[101:] == 0.0)
            and states[-1][1] == 1
        )
        # /diagnostics says so: ERROR, the fault, one trip; the clamping was in an earlier period
        tripped = controller_health(node.state, node.state)
        assert (tripped.level, dict(tripped.values)["trips"], dict(tripped.values)["watchdog"]) == (
            ERROR,
            "1",
            "tripped",
        ) and "collision onset at wingbeat 3" in tripped.message
        assert controller_health(node.state, None).message.endswith("block(s)")  # clamped: WARN
        # the std_srvs/Trigger service ~/reset_watchdog re-arms it (called as the executor would)
        reply = node.on_reset_watchdog(Trigger.Request(), Trigger.Response())
        assert reply.success and "watchdog reset by request" in reply.message
        assert node.state.mode == LOOP and node.state.fault == "" and node.state.safety.status == 0
        assert controller_health(node.state, node.state).level == OK
        node.destroy_node()
    finally:
        rclpy.shutdown()
