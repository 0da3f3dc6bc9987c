"""Plant and drive nodes over real DDS: lockstep
equals the offline core; bad blocks are rejected.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
from rosgraph_msgs.msg import Clock

from rosproc import ros_processes, wait_for

FS_HZ = 20000.0
BLOCK = 10


def _echo_blocks(procs, topic: str, type_name: str, count: int, ready_file: Path | None = None):
    ready = ("--ready-file", str(ready_file)) if ready_file else ()
    return procs.flaair(
        "topic",
        "echo",
        "--json",
        topic,
        type_name,
        "--count",
        str(count),
        "--silence",
        "300",
        *ready,
    )


@pytest.mark.graph
def test_lockstep_chirps_in_two_namespaces_each_equal_their_own_offline_simulation(
    tmp_path: Path,
) -> None:
    """Two benches on one domain, each in its namespace (one with renamed nodes): each plant
    sees only its own drive, so each equals the offline simulation of that drive bit for bit.
    """
    from flaair_model.model_io import load_model
    from flaair_sim.core.drive import DriveParams, drive_record
    from flaair_sim.core.plant import simulate

    n_blocks = 200
    benches = {"/bench_a": 100.0, "/bench_b": 40.0}  # namespace: drive amplitude (V)
    with ros_processes() as procs:
        echoes, ready = {}, []
        for ns in benches:
            for name, topic, kind in (
                ("truth", "flaair/wing_state/truth", "WingStateBlock"),
                ("sensor", "flaair/sensor_v", "SensorVoltageBlock"),
            ):
                ready.append(tmp_path / f"{ns[1:]}_{name}.ready")
                echoes[ns, name] = _echo_blocks(
                    procs, f"{ns}/{topic}", f"flaair_msgs/msg/{kind}", n_blocks, ready[-1]
                )
        for ns in benches:
            # the comparison starts at sample 0: the plant takes drive commands (and so the
            # lockstep drive starts) only once both its output streams have their listener,
            # writer side. bench_b's nodes are renamed: they still find their parameters.
            rename = ("-r", "__node:=plant_b") if ns == "/bench_b" else ()
            procs.flaair(
                "run",
                "flaair_sim",
                "plant_node",
                "--ros-args",
                "-r",
                f"__ns:={ns}",
                *rename,
                "-p",
                "min_sensor_subscribers:=1",
                "-p",
                "min_truth_subscribers:=1",
            )
        # the readers' side too
        assert wait_for(lambda: all(p.exists() for p in ready), timeout_s=120)
        for ns, amplitude_v in benches.items():
            rename = ("-r", "__node:=drive_b") if ns == "/bench_b" else ()
            procs.flaair(
                "run",
                "flaair_sim",
                "drive_node",
                "--ros-args",
                "-r",
                f"__ns:={ns}",
                *rename,
                "-p",
                "pacing:=lockstep",
                "-p",
                "waveform:=chirp",
                "-p",
                f"amplitude_v:={amplitude_v}",
                "-p",
                f"run_time_s:={n_blocks * BLOCK / FS_HZ}",
            )
        outputs = {}
        for key, echo in echoes.items():
            out, err = echo.communicate(timeout=330)
            assert echo.returncode == 0, (key, err)
            outputs[key] = [json.loads(line) for line in out.splitlines()]
    for ns, amplitude_v in benches.items():
        truth, sensor_blocks = outputs[ns, "truth"], outputs[ns, "sensor"]
        assert [b["first_sample_index"] for b in truth] == list(range(0, n_blocks * BLOCK, BLOCK))
        stroke_deg = np.concatenate([b["stroke_deg"] for b in truth])
        pitch_deg = np.concatenate([b["pitch_deg"] for b in truth])
        stroke_v = np.concatenate([b["stroke_sensor_v"] for b in sensor_blocks])
        params = DriveParams(
            kind="chirp", amplitude_v=amplitude_v, start_hz=20.0, stop_hz=200.0, duration_s=1.0
        )
        offline = simulate(drive_record(params, FS_HZ, n_blocks * BLOCK), FS_HZ, load_model())
        assert np.array_equal(stroke_deg, np.degrees(offline.stroke_rad)), ns
        assert np.array_equal(pitch_deg, np.degrees(offline.pitch_rad)), ns
        assert np.array_equal(stroke_v, offline.stroke_sensor_v), ns
        assert np.max(np.abs(stroke_deg)) > 0.5  # the wing moved


def _command(index: int, values: list[float]) -> dict:
    return {"sample_rate_hz": FS_HZ, "first_sample_index": index, "drive_v": values}


def test_bad_command_blocks_are_rejected_and_the_plant_keeps_running(
    monkeypatch, tmp_path, capfd
) -> None:
    """The plant node in process: CDR bytes into its own DDS subscription callback, its sensor
    blocks read back from the bytes it publishes (no DDS delivery to wait for).
    """
    from rclpy.serialization import serialize_message

    from composed import composed
    from flaair_common import cdr
    from flaair_common.msgdict import from_dict
    from flaair_msgs.msg import DriveCommandBlock
    from flaair_sim.plant_node import PlantNode

    good = [50.0] * BLOCK
    sequence = [
        _command(0, good),
        _command(10, [float("nan"), *good[1:]]),  # NaN: rejected, zero drive for this block
        _command(10, good),  # duplicate index: rejected, no step
        _command(20, [1e9] * BLOCK),  # finite but huge: clamped to drive_limit_v
        _command(30, good),
    ]
    with composed(
        monkeypatch,
        [PlantNode],
        {"plant_node": {"command_timeout_s": 0.0}},
        tmp_path,
        local_topics=(),
    ) as loop:
        plant = loop.node("plant_node")
        published: list[bytes] = []
        monkeypatch.setattr(plant.sensor.publisher, "publish", published.append)
        (subscription,) = [s for s in plant.subscriptions if s.topic_name == "/flaair/drive"]
        for values in sequence:
            subscription.callback(serialize_message(from_dict(DriveCommandBlock, values)))
        subscription.callback(b"\x00\x01garbage")  # not CDR: dropped, counted
        subscription.callback(serialize_message(from_dict(DriveCommandBlock, _command(40, good))))
    log = capfd.readouterr().err
    blocks = [cdr.decode(cdr.SENSOR_VOLTAGE_BLOCK, data) for data in published]
    assert [b["first_sample_index"] for b in blocks] == [0, 10, 20, 30, 40]
    assert all(np.isfinite(b["stroke_sensor_v"]).all() for b in blocks)
    assert "rejected command block 10 (drive_v has 1 non-finite sample(s)" in log
    assert "duplicate or out of order" in log and "[2 rejected so far]" in log
    assert "[1 undecodable so far]" in log and plant.undecodable == 1


def test_the_plant_takes_drive_commands_only_once_its_outputs_are_listened_to(
    monkeypatch, tmp_path
) -> None:
    """min_sensor_subscribers, min_truth_subscribers, min_clock_subscribers: the plant's drive
    subscription (what a lockstep source waits for) appears only once the sensor, truth and /clock
    streams have that many listeners, /clock's counted by its DDS writer (a recorder seen in the
    graph before its /clock matched lost the first ticks).
    """
    from composed import composed
    from flaair_common import topics
    from flaair_sim.plant_node import PlantNode

    params = {
        "plant_node": {
            "min_sensor_subscribers": 2,
            "min_truth_subscribers": 2,
            "min_clock_subscribers": 1,
            "command_timeout_s": 0.0,
        }
    }
    # the harness listens to sensor_v
    with composed(monkeypatch, [PlantNode], params, tmp_path) as loop:
        loop.sink(topics.SENSOR_VOLTAGE)
        loop.sink(topics.WING_STATE_TRUTH)
        loop.run_for(1.0)
        assert loop.bus.subscriber_count(topics.DRIVE) == 0  # truth has 1 listener of 2
        loop.sink(topics.WING_STATE_TRUTH)
        loop.run_for(0.02)
        assert loop.bus.subscriber_count(topics.DRIVE) == 0  # /clock has none of 1
        plant = loop.node("plant_node")
        plant.create_subscription(Clock, topics.CLOCK, lambda _msg: None, 10)
        deadline = time.monotonic() + 10.0  # the writer's match comes in real time
        while loop.bus.subscriber_count(topics.DRIVE) == 0 and time.monotonic() < deadline:
            loop.run_for(0.01)
        assert loop.bus.subscriber_count(topics.DRIVE) == 1


def test_a_realtime_plant_publishes_the_drive_at_the_samples_it_applied_it(
    monkeypatch, tmp_path
) -> None:
    """Realtime, commands queue and are applied at the plant's own samples: /flaair/drive's
    sample indices (the controller's count) are not the films'. The plant says what it applied
    where (/flaair/drive/applied, as a target's bridge does): each applied block has the index of
    the sensor block it drove, and the commands come out in their order, clamped.
    """
    from composed import composed
    from flaair_common import topics
    from flaair_sim.plant_node import PlantNode

    params = {"plant_node": {"mode": "realtime", "command_timeout_s": 0.0, "drive_limit_v": 60.0}}
    with composed(monkeypatch, [PlantNode], params, tmp_path) as loop:
        applied, sensed = loop.sink(topics.DRIVE_APPLIED), loop.sink(topics.SENSOR_VOLTAGE)
        loop.run_for(0.01)  # zero drive while nothing is queued
        ahead = 5000  # the controller's count runs ahead of the plant's samples
        commands = [[float(10 * k + i) for i in range(BLOCK)] for k in range(1, 9)]
        for k, values in enumerate(commands):
            loop.post(topics.DRIVE, _command(ahead + k * BLOCK, values))
        loop.run_for(0.01)
    assert [b["first_sample_index"] for b in applied] == [b["first_sample_index"] for b in sensed]
    driven = [list(b["drive_v"]) for b in applied if any(b["drive_v"])]
    assert driven == [[min(v, 60.0) for v in values] for values in commands]
    first = next(b["first_sample_index"] for b in applied if any(b["drive_v"]))
    assert 0 < first < ahead  # after the zero drive, at the plant's sample, not the command's


def test_a_drive_limit_set_while_running_clamps_the_next_blocks(monkeypatch, tmp_path) -> None:
    """drive_limit_v is a live parameter: set while the plant runs, it clamps every block after."""
    from rclpy.parameter import Parameter

    from composed import composed
    from flaair_common import topics
    from flaair_sim.plant_node import PlantNode

    params = {"plant_node": {"mode": "realtime", "command_timeout_s": 0.0, "drive_limit_v": 60.0}}
    with composed(monkeypatch, [PlantNode], params, tmp_path) as loop:
        applied = loop.sink(topics.DRIVE_APPLIED)
        loop.run_for(0.01)
        loop.post(topics.DRIVE, _command(5000, [100.0] * BLOCK))
        loop.run_for(0.01)
        result = loop.node("plant_node").set_parameters([Parameter("drive_limit_v", value=25.0)])
        assert result[0].successful
        loop.post(topics.DRIVE, _command(5000 + BLOCK, [100.0] * BLOCK))
        loop.run_for(0.01)
    driven = [list(b["drive_v"]) for b in applied if any(b["drive_v"])]
    assert driven == [[60.0] * BLOCK, [25.0] * BLOCK]
