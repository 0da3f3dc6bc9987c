"""Bridge node and emulated target over real UDP sockets
on 127.0.0.1 and real DDS, separate processes.

(a) the target's samples arrive on /flaair/sensor_v and match the plant model driven by the
    drive the target applied (/flaair/drive/applied); (b) garbage datagrams are survived and
    counted; (c) a killed drive source leaves the target zeroed by its own watchdog (flag bit
    set); (d) a target that falls silent is marked as loss and the bridge stops the drive;
    (e) every run (SIGINT, SIGTERM) ends with a stop packet at the target.
"""

from __future__ import annotations

import json
import re
import signal
import socket
import time
from pathlib import Path

import numpy as np
import pytest

from rosproc import ros_processes, target_watchdog_tripped, wait_for

pytestmark = pytest.mark.graph  # ROS 2 processes exchanging data in real time: run after the others

FS = 20000.0
N = 10
BRIDGE = ("run", "flaair_bridge", "bridge_node", "--ros-args")
DRIVE = (
    "run",
    "flaair_sim",
    "drive_node",
    "--ros-args",
    "-p",
    "frequency_hz:=140.0",
    "-p",
    "amplitude_v:=60.0",
)


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def lines(path: Path) -> list[dict]:
    out = []
    for line in path.read_text().splitlines() if path.exists() else []:
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:  # a line being written
            break
    return out


def samples(blocks: list[dict], field: str) -> tuple[np.ndarray, np.ndarray]:
    index = np.concatenate([b["first_sample_index"] + np.arange(len(b[field])) for b in blocks])
    return index, np.concatenate([np.asarray(b[field], dtype=float) for b in blocks])


def tripped_for(target_log: Path, counters: Path, n_samples: int) -> bool:
    """The target's watchdog is tripped, and has been
    for `n_samples` of the target's own clock since.

    Producer-side: the target's periodic counters (its sample count, its watchdog state now, its
    trip count) against the trip its log names, not what an echo happened to receive.
    """
    trips = re.findall(r"drive watchdog tripped at sample (\d+)", target_log.read_text())
    if not trips or not target_watchdog_tripped(target_log) or not counters.exists():
        return False
    now = json.loads(counters.read_text())
    return (
        now["watchdog_tripped_now"]
        and now["watchdog_trips"] == len(trips)
        and now["samples"] - int(trips[-1]) >= n_samples
    )


def start_graph(procs, tmp_path: Path, port: int, *bridge_args: str, echo_count: int = 0):
    """Bridge and echoes of /flaair/sensor_v and /flaair/drive/applied, matched before returning."""
    bridge = procs.flaair(*BRIDGE, "-p", f"listen_port:={port}", *bridge_args)
    for topic, kind in (
        ("/flaair/sensor_v", "SensorVoltageBlock"),
        ("/flaair/drive/applied", "DriveCommandBlock"),
    ):
        procs.flaair(
            "topic",
            "echo",
            "--json",
            topic,
            f"flaair_msgs/msg/{kind}",
            "--count",
            str(echo_count),
            "--silence",
            "240",
            stdout=open(tmp_path / f"{kind}.jsonl", "w"),  # noqa: SIM115  the child's log
        )
        assert (
            procs.flaair(
                "topic",
                "wait",
                topic,
                "--publishers",
                "1",
                "--subscribers",
                "1",
                "--timeout",
                "120",
            ).wait(150)
            == 0
        ), bridge.stderr.read() if bridge.poll() is not None else ""
    return bridge


def drive_source(procs, *args: str):
    """drive_node (a real-time 140 Hz sine), once its /flaair/drive has reached the bridge."""
    process = procs.flaair(*DRIVE, *args)
    assert (
        procs.flaair(
            "topic",
            "wait",
            "/flaair/drive",
            "--publishers",
            "1",
            "--subscribers",
            "1",
            "--timeout",
            "120",
        ).wait(150)
        == 0
    )
    return process


def target(procs, tmp_path: Path, port: int, *args: str):
    """The emulated target, once its clock runs (its log line says so)."""
    log = tmp_path / "target.log"
    process = procs.flaair(
        "run",
        "flaair_bridge",
        "emulated_target",
        "--bridge",
        f"127.0.0.1:{port}",
        "--listen",
        "127.0.0.1:0",
        "--counters",
        str(tmp_path / "target.json"),
        *args,
        stderr=open(log, "w"),  # noqa: SIM115  the child's log
    )
    assert wait_for(
        lambda: "emulated target running" in log.read_text() or process.poll() is not None, 120
    ), log.read_text()
    return process


def end_of_run(procs, tmp_path: Path, port: int, bridge, sig: int) -> tuple[str, dict]:
    """A fresh target; then the bridge ends its run by
    `sig`: the bridge's log and the target's counters.
    """
    emulator = target(procs, tmp_path, port)
    target_log, bridge_log = tmp_path / "target.log", Path(bridge.stderr.name)
    # the bridge has heard the fresh target (learnt where to send), then its end sends it the stop
    address = re.search(r"drive packets on (\S+):(\d+),", target_log.read_text()).group(2)
    assert wait_for(lambda: f"target at 127.0.0.1:{address}:" in bridge_log.read_text(), 60), (
        bridge_log.read_text()[-2000:]
    )
    assert procs.stop(bridge, sig, timeout_s=60) == 0
    log = bridge.stderr.read()
    assert wait_for(lambda: "stop packet 1 received" in target_log.read_text(), 30), (
        target_log.read_text()
    )
    procs.stop(emulator, signal.SIGINT, timeout_s=60)
    return log, json.loads((tmp_path / "target.json").read_text())


def test_samples_match_the_plant_garbage_is_survived_and_sigint_ends_with_a_stop_packet(
    tmp_path,
) -> None:
    from flaair_model.model_io import load_model
    from flaair_sim.core import plant

    port, n_blocks = free_port(), 2000  # 1 s of signal
    with ros_processes() as procs:
        # a stalled emulator on a loaded machine must not be taken for a silent target here
        bridge = start_graph(
            procs, tmp_path, port, "-p", "sensor_timeout_s:=10.0", echo_count=n_blocks
        )
        drive_source(procs)
        emulator = target(procs, tmp_path, port, "--duration", str(n_blocks * N / FS))
        # garbage from another socket while the target runs: wrong magic, short, NaN, a drive packet
        assert wait_for(lambda: len(lines(tmp_path / "SensorVoltageBlock.jsonl")) >= 100, 120)
        junk = [
            b"",
            b"FLS1",
            b"hello world" * 5,
            b"FLS1" + bytes(20) + np.full(3, np.nan, "<f4").tobytes(),
            b"FLD1" + bytes(16) + np.zeros(1, "<f4").tobytes(),
        ] * 10
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender:
            for data in junk:
                sender.sendto(data, ("127.0.0.1", port))
        assert emulator.wait(timeout=180) == 0, (tmp_path / "target.log").read_text()
        assert wait_for(
            lambda: (
                len(lines(tmp_path / "SensorVoltageBlock.jsonl")) >= n_blocks
                and len(lines(tmp_path / "DriveCommandBlock.jsonl")) >= n_blocks
            ),
            180,
        )
        assert bridge.poll() is None  # survived the garbage
        # (e) SIGINT: the bridge ends the run with a stop packet; a second target run receives it
        (tmp_path / "target.json").unlink()
        log, counters = end_of_run(procs, tmp_path, port, bridge, signal.SIGINT)
    assert f"malformed {len(junk)}," in log and "lost_packets 0," in log, log[-2000:]
    assert "stop packet sent: end of run" in log
    assert counters["stop_packets"] >= 1 and counters["stopped"] is True, counters
    # (a) every sample of the first run, in order, none
    # lost, equal to the plant driven by the applied drive
    index, stroke = samples(
        lines(tmp_path / "SensorVoltageBlock.jsonl")[:n_blocks], "stroke_sensor_v"
    )
    _, pitch = samples(lines(tmp_path / "SensorVoltageBlock.jsonl")[:n_blocks], "pitch_sensor_v")
    applied_index, applied = samples(
        lines(tmp_path / "DriveCommandBlock.jsonl")[:n_blocks], "drive_v"
    )
    np.testing.assert_array_equal(index, np.arange(n_blocks * N))
    np.testing.assert_array_equal(applied_index, index)
    # the drive reached the target
    assert np.isfinite(stroke).all() and np.abs(applied).max() > 10.0
    sim = plant.simulate(applied, FS, load_model())
    np.testing.assert_allclose(stroke, sim.stroke_sensor_v.astype(np.float32), rtol=0, atol=1e-6)
    np.testing.assert_allclose(pitch, sim.pitch_sensor_v.astype(np.float32), rtol=0, atol=1e-6)
    assert np.ptp(stroke) > 0.05  # the wing moved


def test_killed_drive_source_leaves_the_target_zeroed_by_its_watchdog_and_sigterm_stops(
    tmp_path,
) -> None:
    port = free_port()
    with ros_processes() as procs:
        # the bridge's own drive watchdog slowed down, so the target's hold-then-zero acts first
        bridge = start_graph(
            procs, tmp_path, port, "-p", "drive_timeout_s:=60.0", "-p", "sensor_timeout_s:=10.0"
        )
        drive = drive_source(procs)
        emulator = target(procs, tmp_path, port)
        applied = tmp_path / "DriveCommandBlock.jsonl"
        # driven for a while (200 applied blocks above 10 V, 0.1 s), not just started
        assert wait_for(
            lambda: sum(max(map(abs, b["drive_v"])) > 10.0 for b in lines(applied)) >= 200, 120
        )
        # no goodbye, no zero block
        procs.stop(drive, signal.SIGKILL)
        target_log = tmp_path / "target.log"
        # tripped, and still tripped 0.5 s of the target's clock later: a load stall of the bridge
        # can trip the target before the drive source's last blocks reach it (the bridge re-anchors
        # a late source's blocks ahead of the target's clock); those clear it, then it trips again
        assert wait_for(lambda: tripped_for(target_log, tmp_path / "target.json", 10_000), 50), (
            target_log.read_text()
        )
        # the target's stop counter must come from the
        # bridge's SIGTERM, so read the watchdog state first
        procs.stop(emulator, signal.SIGINT, timeout_s=60)
        before_stop = json.loads((tmp_path / "target.json").read_text())
        log, after_stop = end_of_run(procs, tmp_path, port, bridge, signal.SIGTERM)
    assert before_stop["fresh_samples"] > 1000, before_stop  # it was driven
    assert before_stop["watchdog_trips"] >= 1 and before_stop["zeroed_samples"] > 0, before_stop
    # zeroed by its own watchdog: no stop packet came (a stop would also clear the trip;
    # the bridge's own drive watchdog, slowed to 60 s, sends one if this test outlasts it)
    assert before_stop["stop_packets"] == 0, before_stop
    assert (
        before_stop["watchdog_tripped_at_exit"] is True and before_stop["applied_v_at_exit"] == 0.0
    ), before_stop
    assert (
        "the target's drive watchdog has tripped" in log and "target_watchdog_packets 0," not in log
    )
    # SIGTERM ends with a stop too
    assert "stop packet sent: end of run" in log and after_stop["stop_packets"] >= 1


def test_silent_target_is_marked_as_loss_and_the_drive_is_stopped(tmp_path) -> None:
    # At 2 kHz (200 packets/s): a bridge that cannot keep up with 2000
    # packets/s on a loaded machine works through a backlog and, rightly,
    # does not call that silence; here the silence is the point.
    port, rate = free_port(), ("-p", "sample_rate_hz:=2000.0")
    with ros_processes() as procs:
        bridge = start_graph(procs, tmp_path, port, *rate)
        drive_source(procs, *rate, "-p", "frequency_hz:=50.0")
        emulator = target(procs, tmp_path, port, "--sample-rate", "2000")
        applied = tmp_path / "DriveCommandBlock.jsonl"
        assert wait_for(
            lambda: any(max(map(abs, b["drive_v"])) > 10.0 for b in lines(applied)[-200:]), 120
        )
        # the target falls silent (its socket keeps what arrives)
        emulator.send_signal(signal.SIGSTOP)
        # the fault: 1 s of silence (a stimulus, not a wait)
        time.sleep(1.0)
        emulator.send_signal(signal.SIGCONT)
        bridge_log = Path(bridge.stderr.name)
        assert wait_for(lambda: "the target is sending again" in bridge_log.read_text(), 60), (
            bridge_log.read_text()[-2000:]
        )
        assert bridge.poll() is None
        procs.stop(emulator, signal.SIGINT, timeout_s=60)
        procs.stop(bridge, signal.SIGINT, timeout_s=60)
        log = bridge.stderr.read()
        counters = json.loads((tmp_path / "target.json").read_text())
    assert "TARGET SILENT" in log and "; stop packet sent" in log, log[-3000:]
    summary = log[log.index("bridge closed") :]
    silence_samples = int(summary.split("silence_samples ")[1].split(",")[0])
    # ~1 s of silence published as lost (NaN) blocks
    assert silence_samples >= 0.5 * 2000, summary
    # the silence stop reached the target once it woke up (before the run's final one)
    assert counters["stop_packets"] >= 1, counters
