"""Fault suite: bad parameters, bad blocks, malformed
files and damaged bags, for every node and command.

Each fault must give a clear message naming what is wrong, a non-zero exit where a command
fails, no traceback, and a node that keeps running.
"""

from __future__ import annotations

import re
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from rosproc import FLAAIR, OFFLINE_COMMANDS, isolated_env, ros_processes, run, run_offline

FS_HZ = 20000.0
BLOCK = 10

NODES = [
    ("flaair_sim", "plant_node", "drive_limit_v"),
    ("flaair_sim", "drive_node", "amplitude_v"),
    ("flaair_sensors", "frontend_node", "velocity_cutoff_hz"),
    ("flaair_tools", "recorder_node", "flush_period_s"),
    ("flaair_control", "collision_monitor_node", "drive_frequency_hz"),
    ("flaair_control", "dsa_controller_node", "drive_limit_v"),
]


BAD_VALUES = [(-1.0e9, "out of range"), ("text", "expecting type 'DOUBLE'")]


@pytest.mark.parametrize(("package", "executable", "parameter"), NODES)
@pytest.mark.parametrize(("value", "why"), BAD_VALUES)
def test_every_node_refuses_bad_parameters_by_name(
    monkeypatch,
    tmp_path: Path,
    package: str,
    executable: str,
    parameter: str,
    value: object,
    why: str,
) -> None:
    """The node class itself, built in this process from a parameters file (as a container or
    `bin/flaair run` builds it), refuses the value naming the parameter and the rule.
    """
    from composed import composed
    from flaair_common.container import load_class
    from flaair_tools.orchestration.graphs import NODES as DECLARED

    component = {n.executable: n.component for n in DECLARED.values()}.get(executable)
    if component is None:  # not composable (the recorder): its module's node class
        component = f"flaair_tools.recorder.{executable}:RecorderNode"
    node_class = load_class(component)
    with (
        pytest.raises(ValueError) as refused,
        composed(
            monkeypatch,
            [node_class],
            {executable: {parameter: value}},
            tmp_path=tmp_path,
            local_topics=(),
        ),
    ):
        pass
    assert parameter in str(refused.value) and why in str(refused.value), str(refused.value)


@pytest.mark.parametrize(
    ("package", "executable", "parameter", "value", "why"),
    [
        ("flaair_sim", "plant_node", "drive_limit_v", "-1.0e9", "out of range"),
        ("flaair_tools", "recorder_node", "flush_period_s", "'text'", "expecting type 'DOUBLE'"),
    ],
)
@pytest.mark.slow  # starts a node process per refused parameter
def test_a_refused_parameter_ends_the_node_process_with_one_line_and_exit_2(
    package: str, executable: str, parameter: str, value: str, why: str
) -> None:
    result = run(
        [FLAAIR, "run", package, executable, "--ros-args", "-p", f"{parameter}:={value}"],
        isolated_env(),
        180,
    )
    assert result.returncode == 2, result.stderr
    assert parameter in result.stderr and why in result.stderr, result.stderr
    assert "Traceback" not in result.stderr


@pytest.fixture(scope="module")
def lab_bag(tmp_path_factory) -> Path:
    from flaair_common.runcsv import write_run
    from flaair_model.model_io import load_model
    from flaair_sim.core.drive import DriveParams, drive_record
    from flaair_sim.core.measured_run import synthesize_measured_run

    tmp = tmp_path_factory.mktemp("faults")
    drive = drive_record(
        DriveParams(kind="chirp", amplitude_v=100.0, start_hz=20.0, stop_hz=200.0, duration_s=1.0),
        FS_HZ,
        8000,
    )
    write_run(
        tmp / "run.csv",
        synthesize_measured_run(drive, FS_HZ, load_model(), np.random.default_rng(0)),
    )
    assert (
        run_offline(
            [FLAAIR, "import", str(tmp / "run.csv"), "--out", str(tmp / "bag")], isolated_env(), 120
        ).returncode
        == 0
    )
    return tmp / "bag"


def _damaged(lab_bag: Path, tmp: Path, how: str) -> Path:
    bag = tmp / f"bag_{how}"
    shutil.copytree(lab_bag, bag)
    (mcap,) = bag.glob("*.mcap")
    data = mcap.read_bytes()
    if how == "truncated":
        mcap.write_bytes(data[: len(data) // 2])
    elif how == "corrupted":
        middle = len(data) // 2
        mcap.write_bytes(data[:middle] + bytes(4096) + data[middle + 4096 :])
    elif how == "no_metadata":
        (bag / "metadata.yaml").unlink()
    elif how == "empty_dir":
        shutil.rmtree(bag)
        bag.mkdir()
    elif how == "not_a_bag":
        shutil.rmtree(bag)
        bag.write_text("hello")
    return bag


COMMANDS = {
    "calibrate": lambda bag, out: ["calibrate", str(bag), "--out", str(out)],
    "analyze": lambda bag, out: ["analyze", str(bag), "--out", str(out)],
    "play": lambda bag, out: ["play", str(bag), "--fast"],
}


@pytest.mark.parametrize("how", ["truncated", "corrupted", "no_metadata", "empty_dir", "not_a_bag"])
@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_damaged_bags_give_a_clear_error(
    lab_bag: Path, tmp_path: Path, how: str, command: str
) -> None:
    bag = _damaged(lab_bag, tmp_path, how)
    runner = run_offline if command in OFFLINE_COMMANDS else run  # play joins a ROS domain
    result = runner([FLAAIR, *COMMANDS[command](bag, tmp_path / "out")], isolated_env(), 120)
    assert result.returncode != 0, (how, command, result.stdout[-500:])
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    assert bag.name in result.stderr, result.stderr[-1000:]


MALFORMED = {
    "missing_column": "time_s,drive_v,stroke_sensor_v,stroke_deg,pitch_deg\n"
    "0,0,1.25,0,0\n5e-05,0,1.25,0,0\n",
    "non_numeric": "time_s,drive_v,stroke_sensor_v,pitch_sensor_v,stroke_deg,pitch_deg\n"
    "0,0,1.25,1.25,0,0\n5e-05,0,oops,1.25,0,0\n",
    "time_backwards": "time_s,drive_v,stroke_sensor_v,pitch_sensor_v,stroke_deg,pitch_deg\n"
    "0,0,1.25,1.25,0,0\n5e-05,0,1.25,1.25,0,0\n1e-05,0,1.25,1.25,0,0\n",
    "nan_sensor": "time_s,drive_v,stroke_sensor_v,pitch_sensor_v,stroke_deg,pitch_deg\n"
    "0,0,1.25,nan,0,0\n5e-05,0,1.25,1.25,0,0\n",
    "empty": "",
    "binary": "\x00\x01\x02garbage\xff",
}


@pytest.mark.parametrize("kind", sorted(MALFORMED))
@pytest.mark.parametrize("command", ["import", "simulate"])
def test_malformed_csv_gives_file_line_column(tmp_path: Path, kind: str, command: str) -> None:
    path = tmp_path / f"{kind}.csv"
    path.write_bytes(MALFORMED[kind].encode("latin-1"))
    args = [
        FLAAIR,
        command,
        str(path),
        "--out",
        str(tmp_path / ("o.csv" if command == "simulate" else "bag")),
    ]
    result = run_offline(args, isolated_env(), 60)
    if command == "simulate" and kind == "missing_column":
        # simulate needs only time_s and drive_v: this file is fine for it
        assert result.returncode == 0, result.stderr
        return
    assert result.returncode != 0
    assert f"{kind}.csv" in result.stderr and "Traceback" not in result.stderr, result.stderr
    where = {
        "non_numeric": "line 3, column stroke_sensor_v",
        "time_backwards": "line 4, column time_s",
        "nan_sensor": "line 2, column pitch_sensor_v",
        "missing_column": "missing column(s) pitch_sensor_v",
    }
    if kind in where:
        assert where[kind] in result.stderr, result.stderr


def test_frontend_rejects_bad_blocks_counts_them_and_keeps_running(
    monkeypatch, tmp_path, capfd
) -> None:
    """The front-end node, in process: CDR bytes into its own DDS subscription callback (as rclpy
    hands them over), its wing-state blocks read back from the bytes it publishes.
    """
    from rclpy.serialization import serialize_message

    from composed import composed
    from flaair_common import cdr
    from flaair_common.msgdict import from_dict
    from flaair_msgs.msg import SensorVoltageBlock
    from flaair_sensors.frontend_node import FrontendNode

    def block(index: int, stroke: list, pitch: list, rate: float = FS_HZ) -> bytes:
        return serialize_message(
            from_dict(
                SensorVoltageBlock,
                {
                    "sample_rate_hz": rate,
                    "first_sample_index": index,
                    "stroke_sensor_v": stroke,
                    "pitch_sensor_v": pitch,
                },
            )
        )

    good = [1.25] * 10
    sequence = [
        block(0, good, good),
        block(10, [float("nan"), *good[1:]], good),  # NaN sample: marked invalid, not an angle
        block(10, good, good),  # duplicate index: ignored
        block(20, good, good[:5]),  # stroke/pitch lengths differ: rejected
        block(30, good, good, rate=1000.0),  # wrong rate: rejected
        block(40, good, good),
        b"\x00\x01garbage",  # not CDR at all: dropped, counted
    ]
    with composed(monkeypatch, [FrontendNode], tmp_path=tmp_path, local_topics=()) as loop:
        node = loop.node("frontend_node")
        published: list[bytes] = []
        monkeypatch.setattr(node.publisher.publisher, "publish", published.append)
        monkeypatch.setattr(node.publisher.publisher, "get_subscription_count", lambda: 1)
        (subscription,) = [s for s in node.subscriptions if s.topic_name == "/flaair/sensor_v"]
        for data in sequence:
            subscription.callback(data)
    log = capfd.readouterr().err
    blocks = [cdr.decode(cdr.WING_STATE_BLOCK, data) for data in published]
    assert [b["first_sample_index"] for b in blocks] == [0, 10, 40]
    nan_block = blocks[1]
    assert not nan_block["stroke_valid"][0] and not np.isfinite(nan_block["stroke_deg"][0])
    assert (
        "duplicate or out of order" in log
        and "array lengths differ" in log
        and "sample_rate_hz 1000.0" in log
    )
    # counted: the duplicate, the lengths, the rate, the
    # gap before 40 (taken all the same), the garbage
    assert "sensor block dropped" in log and node.rejected_blocks == 5


_WATCHDOG_EVENT = re.compile(
    r"^\[\w+\] \[(\d+\.\d+)\] \[plant_node\]: "
    r"(DRIVE WATCHDOG|ring-down done|drive commands "
    r"resumed)",
    re.MULTILINE,
)


def _rung_down_after(plant_log: str, killed_at_s: float) -> bool:
    """The plant's last watchdog event is a finished
    ring-down, after a trip stamped after the kill.
    """
    events = [(float(stamp), what) for stamp, what in _WATCHDOG_EVENT.findall(plant_log)]
    trips = [stamp for stamp, what in events if what == "DRIVE WATCHDOG"]
    return bool(trips) and trips[-1] > killed_at_s and events[-1][1] == "ring-down done"


@pytest.mark.graph
def test_killing_the_controller_mid_run_zeroes_the_drive_and_leaves_a_complete_bag(
    tmp_path: Path,
) -> None:
    """Kill -9 of the dSA controller in a recorded closed loop: the plant's drive watchdog zeroes
    the drive within command_timeout_s and rings the wing down; the recorder's bag (closed with
    SIGINT afterwards) holds the plant's every block up to the kill and the ring-down, in order.
    """
    import signal
    import subprocess

    from flaair_tools import bagio
    from rosproc import wait_for

    bag, timeout_s, ring_down_s = tmp_path / "killed_loop", 0.3, 0.1
    with ros_processes() as procs:
        recorder = procs.flaair("record", "-o", str(bag))
        assert wait_for(lambda: (bag / f"{bag.name}_0.mcap").exists(), 60.0)
        logs = {name: tmp_path / f"{name}.log" for name in ("plant", "controller")}
        # the plant takes drive (and the controller starts) only once the front end and the
        # recorder listen to its sensor stream: a first block published before the front end
        # matched was lost to it, and the loop never started (a soak run)
        plant = procs.flaair(
            "run",
            "flaair_sim",
            "plant_node",
            "--ros-args",
            "-p",
            f"command_timeout_s:={timeout_s}",
            "-p",
            f"ring_down_s:={ring_down_s}",
            "-p",
            "min_sensor_subscribers:=2",
            "-p",
            "min_truth_subscribers:=1",
            stderr=open(logs["plant"], "w"),  # noqa: SIM115  the child's log
        )
        procs.flaair("run", "flaair_sensors", "frontend_node")
        # 400 wing-state blocks (0.2 s of flapping) seen by an echo: the loop is mid-run
        flapping = procs.flaair(
            "topic",
            "echo",
            "/flaair/wing_state",
            "flaair_msgs/msg/WingStateBlock",
            "--count",
            "400",
            "--silence",
            "120",
            stdout=subprocess.DEVNULL,
        )
        # the recorder listens on /flaair/drive too: start only once it and the plant match
        controller = procs.flaair(
            "run",
            "flaair_control",
            "dsa_controller_node",
            "--ros-args",
            "-p",
            "min_drive_subscribers:=2",
            "-p",
            "watchdog_timeout_s:=30.0",
            stderr=open(logs["controller"], "w"),  # noqa: SIM115  the child's log
        )
        assert flapping.wait(timeout=150) == 0, logs["controller"].read_text()[-2000:]
        killed_at_s = time.time()
        procs.stop(controller, signal.SIGKILL)
        # A load stall of the live controller may trip the watchdog before the kill (the plant then
        # says "drive commands resumed"); the trip under test is the one stamped after the kill.
        assert wait_for(lambda: _rung_down_after(logs["plant"].read_text(), killed_at_s), 30.0), (
            logs["plant"].read_text()[-2000:]
        )
        # The plant exits once the recorder has acknowledged its every block (writer side); the
        # recorder then writes what it was handed before it closes the bag.
        assert procs.stop(plant, signal.SIGINT, timeout_s=30) == 0
        assert procs.stop(recorder, signal.SIGINT) == 0
        plant_log = logs["plant"].read_text()
    drive = bagio.read_blocks(bag, "/flaair/drive")  # raises on any gap
    sensor = bagio.read_blocks(bag, "/flaair/sensor_v")
    truth = bagio.read_blocks(bag, "/flaair/wing_state/truth")
    last_command = int(drive.sample_index[-1]) + 1
    # killed while driving: no goodbye block
    assert np.abs(drive["drive_v"][-BLOCK:]).max() > 0.0
    watchdog = plant_log.split("DRIVE WATCHDOG: no command block for ")[-1]
    silent_ms = float(watchdog.split(" ms")[0])
    # the log rounds to 0.1 ms: a trip 0.04 ms after the timeout reads 300.0 (the strict rule on a
    # fake clock: test_sim_actuator)
    assert silent_ms >= timeout_s * 1e3
    # The plant's own account of the last command block it stepped (the actuator core's log line).
    last_applied = int(re.search(r"after block (\d+),", watchdog).group(1)) + BLOCK
    # every applied block was stepped and recorded, then exactly the ring-down
    ring = round(ring_down_s * FS_HZ)
    assert sensor.sample_index[-1] + 1 == last_applied + ring == truth.sample_index[-1] + 1
    # The bag's drive is the killed controller's stream as the recorder got it:
    # gap-free (read_blocks) and never past the plant's last block plus the one block
    # lockstep keeps in flight (written to plant and recorder one after the other). Its
    # tail may stop short: what a reliable reader has not received when its writer is
    # killed is lost with the writer (seen: the plant's last block missing, in 2 slow
    # suite runs; 377 blocks short once in 8 runs at load average 6). That the recorder
    # keeps everything a live publisher sent is the sensor and truth check above.
    assert last_command <= last_applied + BLOCK, (last_command, last_applied)
    stroke = truth["stroke_deg"]
    before = np.abs(
        stroke[(truth.sample_index >= last_applied - ring) & (truth.sample_index < last_applied)]
    ).max()
    tail = np.abs(stroke[truth.sample_index >= last_applied + ring - 200]).max()
    assert before > 1.0 and tail < 0.5 * before  # zero drive: the wing rings down
