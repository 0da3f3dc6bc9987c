"""Control nodes over real DDS: closed loop, collision response, watchdog, bad blocks, collision monitor."""
from __future__ import annotations

import json
import math
import signal
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from contextlib import contextmanager

from rosproc import REPO_ROOT, ros_processes, wait_for
from tuning import FRONTEND_TUNING

FS_HZ = 20000.0
BLOCK = 10
CONTROLLER = ("run", "flaair_control", "dsa_controller_node", "--ros-args")




@contextmanager
def _ros():
    """rosproc.ros_processes: a leased domain of its own (no other graph on this machine uses it)."""
    with ros_processes() as procs:
        yield procs


def _lines(path: Path) -> list[dict]:
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:  # a line being written
            break
    return out


def _echo(procs, topic: str, type_name: str, path: Path, count: int = 0, timeout_s: float = 120.0,
          ready_file: Path | None = None):
    """`flaair topic echo` to a JSON-lines file; with `ready_file`, the echo creates it once matched."""
    ready = ("--ready-file", str(ready_file)) if ready_file is not None else ()
    return procs.flaair("topic", "echo", topic, type_name, "--count", str(count), "--timeout", str(timeout_s),
                        *ready, stdout=open(path, "w"))


def _pub(procs, topic: str, type_name: str, values: dict, count: int = 1) -> None:
    pub = procs.flaair("topic", "pub", topic, type_name, json.dumps(values), "--wait-subscribers", "1",
                       "--count", str(count), "--rate", "20")
    assert pub.wait(timeout=60) == 0, pub.stderr.read()


def _wing_state(index: int, n: int = BLOCK, velocity: float = 0.0, valid: bool = True) -> dict:
    return {"sample_rate_hz": FS_HZ, "first_sample_index": index, "stroke_deg": [0.0] * n, "pitch_deg": [0.0] * n,
            "stroke_velocity_deg_s": [velocity] * n, "stroke_valid": [valid] * n, "pitch_valid": [valid] * n}


def test_closed_loop_runs_reacts_to_collisions_and_stops_when_the_controller_is_killed(tmp_path) -> None:
    states, sensors, sensors_ready = tmp_path / "state.jsonl", tmp_path / "sensor.jsonl", tmp_path / "sensor.ready"
    with _ros() as procs:
        _echo(procs, "/flaair/controller/state", "flaair_msgs/msg/ControllerState", states)
        sensor_echo = _echo(procs, "/flaair/sensor_v", "flaair_msgs/msg/SensorVoltageBlock", sensors, ready_file=sensors_ready)
        # No drive watchdog in the plant: after the kill it must simply stop. (Its 2 s watchdog would
        # ring the wing down for 400 blocks just as the quiet wait below ends: test_faults tests that.)
        procs.flaair("run", "flaair_sim", "plant_node", "--ros-args", "-p", "command_timeout_s:=0.0")
        procs.flaair("run", "flaair_sensors", "frontend_node")
        # The lockstep loop runs as fast as the machine allows once the controller starts it: the
        # sensor echo must be matched to the plant first, or it misses the loop's first blocks
        # (a loaded machine brought the echo up 1,340 samples into the run).
        assert wait_for(sensors_ready.exists, 120), sensor_echo.stderr.read() if sensor_echo.poll() is not None else ""
        # no K_r ramp while the events come (onsets during one are not acted on: collision_ramp_guard_s)
        controller = procs.flaair(*CONTROLLER, "-p", "collision_response:=reduce_amplitude",
                                  "-p", "collision_reduction_factor:=0.25", "-p", "watchdog_timeout_s:=30.0",
                                  "-p", "kr_ramp_start_s:=1000.0")
        assert wait_for(lambda: len(_lines(states)) >= 100, 90), controller.stderr.read() if controller.poll() else ""
        _pub(procs, "/flaair/collision/events", "flaair_msgs/msg/CollisionEvent",
             {"kind": 1, "wingbeat_index": 7, "spectrum_rmse_deg": 3.2})
        assert wait_for(lambda: any(s["amplitude_scale"] == 0.25 for s in _lines(states)), 30)
        n_reduced = len(_lines(states))
        _pub(procs, "/flaair/collision/events", "flaair_msgs/msg/CollisionEvent",
             {"kind": 2, "wingbeat_index": 12, "spectrum_rmse_deg": 0.2})
        assert wait_for(lambda: _lines(states)[-1]["amplitude_scale"] == 1.0, 30)
        # kill -9: no zero block, no goodbye; the lockstep plant must simply stop
        procs.stop(controller, signal.SIGKILL)
        # The plant must stop: the sensor stream goes quiet (once the echo has drained its
        # backlog) and stays quiet.
        deadline = time.monotonic() + 60.0
        n_after_kill, quiet_since = len(_lines(sensors)), time.monotonic()
        while time.monotonic() - quiet_since < 2.0 and time.monotonic() < deadline:
            time.sleep(0.25)
            n_now = len(_lines(sensors))
            if n_now != n_after_kill:
                n_after_kill, quiet_since = n_now, time.monotonic()
        assert time.monotonic() - quiet_since >= 2.0, "the plant kept stepping after the controller was killed"
        time.sleep(1.5)
        assert len(_lines(sensors)) == n_after_kill
    blocks = _lines(sensors)
    first = blocks[0]["first_sample_index"]  # the plant's writer may match the echo a moment after the echo does
    assert first <= 5 * BLOCK
    assert [b["first_sample_index"] for b in blocks] == list(range(first, first + len(blocks) * BLOCK, BLOCK))
    all_states = _lines(states)
    assert all(s["watchdog"] == 0 and s["fault"] == "" for s in all_states), {s["fault"] for s in all_states}
    scales = [s["amplitude_scale"] for s in all_states]
    assert scales[0] == 1.0 and 0.25 in scales[n_reduced - 5:] and scales[-1] == 1.0
    assert all(abs(s["drive_v"]) <= 150.0 for s in all_states)
    assert any(abs(s["sync_drive_v"]) > 10.0 for s in all_states)   # synchronous 20 V sine at the start


def test_controller_waits_for_a_state_listener_when_asked(tmp_path) -> None:
    """min_state_subscribers:=1: plant and front end up, yet no loop until /flaair/controller/state
    has a listener; then it starts, and the listener sees the loop from its first block."""
    states, sensors, sensors_ready = tmp_path / "state.jsonl", tmp_path / "sensor.jsonl", tmp_path / "sensor.ready"
    with _ros() as procs:
        _echo(procs, "/flaair/sensor_v", "flaair_msgs/msg/SensorVoltageBlock", sensors, ready_file=sensors_ready)
        procs.flaair("run", "flaair_sim", "plant_node", "--ros-args", "-p", "command_timeout_s:=0.0")
        procs.flaair("run", "flaair_sensors", "frontend_node")
        assert wait_for(sensors_ready.exists, 120)
        controller = procs.flaair(*CONTROLLER, "-p", "min_state_subscribers:=1", "-p", "start_delay_s:=0.0",
                                  "-p", "watchdog_timeout_s:=30.0")
        assert not wait_for(lambda: len(_lines(sensors)) > 0, 6.0), "the loop started without a state listener"
        assert controller.poll() is None
        _echo(procs, "/flaair/controller/state", "flaair_msgs/msg/ControllerState", states)
        assert wait_for(lambda: len(_lines(states)) >= 50, 90), controller.stderr.read() if controller.poll() else ""
    first_states = _lines(states)[:5]
    assert first_states[0]["header"]["stamp"] == {"sec": 0, "nanosec": 0}, first_states


def test_watchdog_trips_and_ramps_the_drive_to_zero_when_wing_state_blocks_stop(tmp_path) -> None:
    drive, states = tmp_path / "drive.jsonl", tmp_path / "state.jsonl"
    # No plant (no /flaair/sensor_v publisher): the controller does not start the loop itself but
    # answers the first wing-state block, then trips: reply, 20 ms ramp, 10 ms zero hold, keepalives.
    n_drive = 1 + 40 + 20 + 3
    with _ros() as procs:
        echo_drive = _echo(procs, "/flaair/drive", "flaair_msgs/msg/DriveCommandBlock", drive, n_drive, 60)
        _echo(procs, "/flaair/controller/state", "flaair_msgs/msg/ControllerState", states, 0, 60)
        controller = procs.flaair(*CONTROLLER, "-p", "watchdog_timeout_s:=0.3", "-p", "ramp_down_s:=0.02",
                                  "-p", "zero_hold_s:=0.01", "-p", "keepalive_period_s:=0.2", "-p", "start_delay_s:=0.0",
                                  "-p", "sync_amplitude_v:=40.0", "-p", "sync_frequency_hz:=100.0")
        # repeated for 6 s: the controller joins once it sees the echo's subscription (discovery took
        # over 2 s in 1 of ~8 runs on this machine); later copies are duplicates
        _pub(procs, "/flaair/wing_state", "flaair_msgs/msg/WingStateBlock", _wing_state(0), count=120)
        echo_drive.wait(timeout=60)
        # states keep coming with the keepalive blocks (a burst may overrun the status queue)
        assert wait_for(lambda: any(s["watchdog"] == 1 for s in _lines(states)), 30)
        assert controller.poll() is None
        procs.stop(controller)
        log = controller.stderr.read()
    blocks = _lines(drive)
    assert len(blocks) == n_drive
    assert [b["first_sample_index"] for b in blocks] == list(range(0, n_drive * BLOCK, BLOCK))
    x = np.concatenate([b["drive_v"] for b in blocks])
    assert np.isfinite(x).all() and np.abs(x).max() <= 150.0
    assert np.abs(x[:BLOCK]).max() > 5.0                           # driving before the trip
    tripped = [s for s in _lines(states) if s["watchdog"] == 1]
    assert tripped and "no wing-state block for" in tripped[0]["fault"] and "wall-clock" in tripped[0]["fault"]
    # ramp: the envelope of each 5 ms (100-sample) window after the trip never grows, then exact zeros
    after = x[BLOCK:]
    peaks = np.abs(after[: len(after) // 100 * 100]).reshape(-1, 100).max(axis=1)
    assert np.all(np.diff(peaks) <= 1e-9) and peaks[0] > 1.0
    assert np.abs(after[int(0.02 * FS_HZ)]) < 1e-9 and np.all(after[int(0.02 * FS_HZ) + 1:] == 0.0)
    assert "WATCHDOG TRIPPED" in log and "duplicate or out of order" in log


def test_invalid_wing_state_blocks_are_counted_and_the_loop_goes_on(tmp_path) -> None:
    drive = tmp_path / "drive.jsonl"
    with _ros() as procs:
        echo = _echo(procs, "/flaair/drive", "flaair_msgs/msg/DriveCommandBlock", drive, 6, 90)
        controller = procs.flaair(*CONTROLLER, "-p", "watchdog_timeout_s:=60.0", "-p", "start_delay_s:=0.0")
        sequence = [
            _wing_state(0, velocity=100.0),
            _wing_state(10, velocity=math.nan),         # NaN velocity: invalid
            _wing_state(20, velocity=100.0, valid=False),  # front end says invalid
            _wing_state(30, n=5),                       # wrong length: rejected
            _wing_state(40, velocity=100.0),
        ]
        _pub(procs, "/flaair/wing_state", "flaair_msgs/msg/WingStateBlock", sequence[0], count=40)  # joined, then duplicates
        assert wait_for(lambda: len(_lines(drive)) >= 1, 30)
        for values in sequence[1:]:
            _pub(procs, "/flaair/wing_state", "flaair_msgs/msg/WingStateBlock", values)
        assert wait_for(lambda: len(_lines(drive)) >= 5, 30)   # one answer per block (no plant: no start block)
        assert controller.poll() is None                # did not crash
        procs.stop(controller)                          # SIGINT: close() sends a zero block
        echo.wait(timeout=30)
        log = controller.stderr.read()
    blocks = _lines(drive)
    assert [b["first_sample_index"] for b in blocks] == [0, 10, 20, 30, 40, 50]
    assert all(np.isfinite(b["drive_v"]).all() for b in blocks)
    assert blocks[-1]["drive_v"] == [0.0] * BLOCK
    assert "[2 invalid so far]" in log and "block has 5 samples, expected 10" in log
    assert "5 wing-state blocks (2 invalid, 1 rejected, " in log and "0 gaps), " in log and "watchdog ok" in log


def _monitor_run(tmp_path: Path, name: str, effects: dict) -> tuple[list[dict], list[dict]]:
    model = yaml.safe_load((REPO_ROOT / "config" / "model.yaml").read_text())
    model["effects"] = effects
    model_file = tmp_path / f"{name}.yaml"
    model_file.write_text(yaml.safe_dump(model))
    status, events = tmp_path / f"{name}_status.jsonl", tmp_path / f"{name}_events.jsonl"
    duration = 1.0   # long enough for 24 verdicts even if the front end matches the plant late
    with _ros() as procs:
        echo = _echo(procs, "/flaair/collision/status", "flaair_msgs/msg/CollisionStatus", status, 24, 60)
        _echo(procs, "/flaair/collision/events", "flaair_msgs/msg/CollisionEvent", events, 0, 60)
        # Known drive frequency here (drive_node's sine starts at phase 0). The estimate from
        # /flaair/drive is tested in-process below: over DDS the monitor's /flaair/drive
        # subscription could start the lockstep drive_node before the plant has subscribed.
        nodes = [
            procs.flaair("run", "flaair_control", "collision_monitor_node", "--ros-args", "-p", "drive_frequency_hz:=100.0"),
            procs.flaair("run", "flaair_sensors", "frontend_node"),
            procs.flaair("run", "flaair_sim", "plant_node", "--ros-args", "-p", f"model_file:={model_file}"),
        ]
        # The lockstep run lasts about a second: front end and monitor must listen before it starts.
        for topic in ("/flaair/sensor_v", "/flaair/wing_state"):
            assert procs.flaair("topic", "wait", topic, "--publishers", "1", "--subscribers", "1", "--timeout", "120").wait(150) == 0
        nodes += [
            procs.flaair("run", "flaair_sim", "drive_node", "--ros-args", "-p", "pacing:=lockstep", "-p", "waveform:=sine",
                         "-p", "frequency_hz:=100.0", "-p", "amplitude_v:=75.0", "-p", f"run_time_s:={duration}"),
        ]
        ok = echo.wait(timeout=90) == 0
        time.sleep(0.5)
        if not ok:
            for node in nodes:
                procs.stop(node)
            logs = "\n".join(node.stderr.read()[-3000:] for node in nodes)
            raise AssertionError(f"{name}: fewer than 24 statuses ({len(_lines(status))}); logs:\n{logs}")
    return _lines(status), _lines(events)


def test_collision_monitor_reports_every_wingbeat_and_flags_an_obstacle(tmp_path) -> None:
    """Paper scenario over DDS: 100 Hz, 75 V about the bias, obstacle at 20 deg against a 28 deg free
    stroke (the free robot and the drive-frequency estimate: in process, below)."""
    status, events = _monitor_run(tmp_path, "hit", {"collision": {"stroke_limit_deg": 20.0}})
    assert [s["wingbeat_index"] for s in status] == list(range(len(status)))
    assert all(s["wingbeat_frequency_hz"] == 100.0 and s["threshold_deg"] == 1.0 for s in status)
    rmse = [s["spectrum_rmse_deg"] for s in status if math.isfinite(s["spectrum_rmse_deg"])]
    assert rmse and min(rmse) > 1.0 and status[-1]["colliding"]
    assert [e["kind"] for e in events] == [1]
    onset = events[0]
    assert onset["spectrum_rmse_deg"] > 1.0
    assert status[onset["wingbeat_index"]]["colliding"] and not status[onset["wingbeat_index"] - 1]["colliding"]


@pytest.mark.parametrize("obstacle", [False, True])
def test_collision_monitor_locks_to_the_estimated_drive_frequency(monkeypatch, obstacle) -> None:
    """In-process (no DDS): drive and wing-state messages from the simulated robot, free or with an obstacle."""
    import rclpy

    from flaair_control.collision_monitor_node import CollisionMonitorNode
    from flaair_sensors import frontend
    from flaair_model.model import with_effects
    from flaair_model.model_io import load_model
    from flaair_sim.plant import simulate

    model = load_model()
    fs, n = FS_HZ, int(0.5 * FS_HZ)
    drive = 75.0 * np.sin(2 * np.pi * 100.0 * np.arange(n) / fs + 1.0)   # unknown phase
    out = simulate(drive, fs, with_effects(model, {"collision": {"stroke_limit_deg": 20.0}}) if obstacle else model)
    est = frontend.estimate(out.stroke_sensor_v, out.pitch_sensor_v, frontend.params_from_model(model, fs, **FRONTEND_TUNING))
    if rclpy.ok():
        rclpy.shutdown()
    owns_rclpy = True   # the paper's decision (the default is the per-wingbeat one)
    rclpy.init(args=["test", "--ros-args", "-p", "decision:=paper"])
    try:
        node = CollisionMonitorNode()
        statuses, events = [], []
        monkeypatch.setattr(node.status_pub, "publish", statuses.append)
        monkeypatch.setattr(node.event_pub, "publish", events.append)
        for k in range(0, n, BLOCK):   # blocks as the in-process bus hands them over: fields by name
            stamp = {"sec": k // int(fs), "nanosec": int(round((k % int(fs)) / fs * 1e9))}
            node.on_drive({"sample_rate_hz": fs, "first_sample_index": k, "drive_v": drive[k:k + BLOCK], **stamp})
            node.on_wing_state({"sample_rate_hz": fs, "first_sample_index": k, **stamp,
                                "stroke_deg": np.degrees(est.stroke_rad[k:k + BLOCK]),
                                "pitch_deg": np.degrees(est.pitch_rad[k:k + BLOCK]),
                                "stroke_valid": est.stroke_valid[k:k + BLOCK], "pitch_valid": est.pitch_valid[k:k + BLOCK]})
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
    else:   # paper: 0.53 deg without a collision
        assert rmse and max(rmse) < 0.5 and not any(s.colliding for s in statuses) and events == []


def test_controller_kr_ramp_service_collision_stop_and_watchdog_reset_in_process(monkeypatch) -> None:
    """The parameter 'service' (kr_ramp_duration_s / reset_watchdog) and the stop response, without DDS."""
    import rclpy
    from rclpy.parameter import Parameter
    from rclpy.serialization import deserialize_message, serialize_message

    from flaair_common.blocks import from_array
    from flaair_common import cdr
    from flaair_control.dsa_controller_node import DsaControllerNode
    from flaair_control.supervisor import LOOP, TRIPPED
    from flaair_msgs.msg import CollisionEvent, ControllerState, DriveCommandBlock, WingStateBlock

    if rclpy.ok():
        rclpy.shutdown()
    rclpy.init(args=["test", "--ros-args", "-p", "collision_response:=stop", "-p", "wait_for_peers:=false",
                     "-p", "start_delay_s:=0.0", "-p", "ramp_down_s:=0.005", "-p", "zero_hold_s:=0.0",
                     "-p", "mu_nm_s_per_rad:=1.0e-3"])   # huge gain: the clamp must act
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
        monkeypatch.setattr(node.state_pub.publisher, "get_subscription_count", lambda: 1)   # a listener: states are written

        def feed(k: int) -> None:
            message = WingStateBlock(sample_rate_hz=FS_HZ, first_sample_index=k * BLOCK)
            t = (k * BLOCK + np.arange(BLOCK)) / FS_HZ
            message.stroke_deg = from_array(10 * np.sin(2 * np.pi * 140 * t))
            message.stroke_velocity_deg_s = from_array(10 * 2 * np.pi * 140 * np.cos(2 * np.pi * 140 * t))
            message.stroke_valid = [True] * BLOCK
            message.header.frame_id = "robot"
            node.on_wing_state(cdr.decode(cdr.WING_STATE_BLOCK, serialize_message(message)))

        node.on_timer()                                   # starts: one block in flight
        assert node.state.mode == LOOP and [d[0] for d in drive] == [0]
        for k in range(100):
            feed(k)
        assert all(s[0] == 1.0 for s in states)          # synchronous until kr_ramp_start_s (0.5 s)
        result = node.set_parameters([Parameter("kr_ramp_duration_s", value=0.005)])[0]   # ramp to 0 now
        assert result.successful
        for k in range(100, 130):
            feed(k)
        kr = [s[0] for s in states[-31:]]     # from the last block before the request
        assert kr[0] == 1.0 and kr[-1] == 0.0 and np.all(np.diff(kr) <= 0)
        assert all(abs(s[4]) <= 150.0 for s in states) and any(s[3] for s in states[-10:])   # clamped
        node.on_collision_event(CollisionEvent(kind=CollisionEvent.ONSET, wingbeat_index=2, spectrum_rmse_deg=2.5))
        assert node.state.mode == LOOP             # within collision_ramp_guard_s (0.1 s) of the ramp: not acted on
        for k in range(130, 360):
            feed(k)
        node.on_collision_event(CollisionEvent(kind=CollisionEvent.ONSET, wingbeat_index=3, spectrum_rmse_deg=2.5))
        assert node.state.mode == TRIPPED and "collision onset at wingbeat 3" in node.state.fault
        n_before = len(drive)
        feed(360)                                         # tripped: the timer paces, no reply
        assert len(drive) == n_before
        time.sleep(0.05)
        node.on_timer()
        ramp = np.concatenate([d[1] for d in drive[n_before:]])
        # zero from trip + ramp_down_s on (the boundary sample itself is ~1e-13 V: float rounding in the core)
        assert ramp.size >= 101 and abs(ramp[100]) < 1e-9 and np.all(ramp[101:] == 0.0) and states[-1][1] == 1
        assert node.set_parameters([Parameter("reset_watchdog", value=True)])[0].successful
        assert node.state.mode == LOOP and node.state.fault == "" and node.state.safety.status == 0
        node.destroy_node()
    finally:
        rclpy.shutdown()
