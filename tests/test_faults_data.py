"""Fault suite, issue 15: lose nothing, say what is wrong.

Bag recovery (cut and corrupted bags), silent wrong results (video-rate calibration, over-limit
simulate, duplicated CSV column, strict JSON) and one-line errors on plausible bad input.
Each test fails on the code before the fix.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from rosbags.rosbag2 import Reader

from rosproc import FLAAIR, isolated_env, ros_processes, run, run_offline

FS_HZ = 20000.0
HEADER = "time_s,drive_v,stroke_sensor_v,pitch_sensor_v,stroke_deg,pitch_deg\n"


def _lab_csv(path: Path, n: int, seed: int, video_stride: int = 1) -> Path:
    from flaair_common.runcsv import write_run
    from flaair_model.model_io import load_model
    from flaair_sim.core.drive import DriveParams, drive_record
    from flaair_sim.core.measured_run import synthesize_measured_run

    drive = drive_record(
        DriveParams(
            kind="chirp", amplitude_v=100.0, start_hz=20.0, stop_hz=200.0, duration_s=n / FS_HZ
        ),
        FS_HZ,
        n,
    )
    columns = synthesize_measured_run(drive, FS_HZ, load_model(), np.random.default_rng(seed))
    for name in ("stroke_deg", "pitch_deg"):
        keep = np.zeros(n, bool)
        keep[::video_stride] = True
        columns[name] = np.where(keep, columns[name], np.nan)
    write_run(path, columns)
    return path


@pytest.fixture(scope="module")
def megabyte_bag(tmp_path_factory) -> Path:
    """The issue's repro: two 0.5 s lab runs imported, 6,002 messages, ~0.9 MB of zstd chunks."""
    from flaair_tools.bagio.import_runs import import_runs

    tmp = tmp_path_factory.mktemp("bag")
    runs = [_lab_csv(tmp / f"run{k}.csv", 10000, k) for k in range(2)]
    import_runs(runs, tmp / "bag", gap_s=1.0, block_size=10, frame_id="robot")
    return tmp / "bag"


def _copy(bag: Path, tmp: Path, how: str) -> tuple[Path, bytes]:
    out = tmp / how
    shutil.copytree(bag, out)
    (mcap_file,) = out.glob("*.mcap")
    data = mcap_file.read_bytes()
    if how == "cut":
        data = data[: len(data) // 2]
    elif how == "zeroed":
        middle = len(data) // 2
        data = data[:middle] + bytes(4096) + data[middle + 4096 :]
    mcap_file.write_bytes(data)
    return out, data


def _read_both(bag: Path) -> dict[str, int]:
    """Messages per topic as rosbags and the mcap library
    (CRCs checked) read them; they must agree.
    """
    counts: dict[str, int] = {}
    with Reader(bag) as reader:
        for connection, _, _ in reader.messages():
            counts[connection.topic] = counts.get(connection.topic, 0) + 1
    other: dict[str, int] = {}
    with open(next(bag.glob("*.mcap")), "rb") as stream:
        for _, channel, _ in make_reader(stream, validate_crcs=True).iter_messages():
            other[channel.topic] = other.get(channel.topic, 0) + 1
    assert counts == other
    return counts


def test_reindex_of_a_cut_bag_recovers_the_partial_chunk_and_keeps_the_original(
    megabyte_bag: Path, tmp_path: Path
) -> None:
    from flaair_tools import bagio

    bag, cut_bytes = _copy(megabyte_bag, tmp_path, "cut")
    result = run_offline([FLAAIR, "bag", "reindex", str(bag)], isolated_env(), 120)
    assert result.returncode == 1, result.stderr  # messages were lost: not a success
    assert "Traceback" not in result.stderr
    counts = _read_both(bag)
    # the cut falls inside the first chunk: only streaming decompression gets anything back
    assert sum(counts.values()) > 2500, counts
    for topic in ("/flaair/drive", "/flaair/sensor_v", "/flaair/wing_state/truth"):
        assert (
            f"{topic}" in result.stdout
            and f"lost {2000 - counts[topic]:8d}" in result.stdout.replace("  lost", " lost")
        )
    blocks = bagio.read_blocks(bag, "/flaair/sensor_v")  # a gap-free prefix of the run
    assert blocks.sample_index[0] == 0 and blocks.n_samples == 10 * counts["/flaair/sensor_v"]
    assert (bag / "bag_0.mcap.damaged").read_bytes() == cut_bytes  # nothing of the original is lost
    assert not (bag / ".reindex").exists()
    recovered = json.loads(bagio.bag_info(bag).custom_data[bagio.RECOVERED_CUSTOM_KEY])
    assert recovered["topics"]["/flaair/sensor_v"] == {
        "kept": counts["/flaair/sensor_v"],
        "expected": 2000,
        "lost": 2000 - counts["/flaair/sensor_v"],
    }


def test_reindex_skips_a_corrupt_region_and_goes_on(megabyte_bag: Path, tmp_path: Path) -> None:
    from flaair_tools import bagio

    bag, _ = _copy(megabyte_bag, tmp_path, "zeroed")
    info = run_offline([FLAAIR, "bag", "info", str(bag)], isolated_env(), 120)
    assert info.returncode == 1 and "DAMAGED" in info.stderr and "bag reindex" in info.stderr, (
        info.stderr
    )
    report = bagio.reindex(bag)
    assert not (bag / ".reindex").exists() and report.backup is not None
    counts = _read_both(bag)
    assert counts == report.counts and 0 < report.lost < 6002 - 4000
    # the chunks after the damage are all there: the last block of the second run was recovered
    blocks = bagio.read_blocks(bag, "/flaair/sensor_v", allow_gaps=True)
    assert blocks.sample_index[-1] == 19999 and blocks.gaps
    assert report.topics["/flaair/sensor_v"].lost == 2000 - counts["/flaair/sensor_v"]


def test_reindex_never_replaces_the_original_with_an_unverified_copy(
    megabyte_bag: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from flaair_tools import bagio

    bag, cut_bytes = _copy(megabyte_bag, tmp_path, "cut")
    metadata = (bag / "metadata.yaml").read_bytes()

    def fails(*_args) -> None:
        raise bagio.BagError("verification failed")

    monkeypatch.setattr(bagio.recovery, "_verify_copy", fails)
    with pytest.raises(bagio.BagError, match="verification failed"):
        bagio.reindex(bag)
    assert (bag / "bag_0.mcap").read_bytes() == cut_bytes and (
        bag / "metadata.yaml"
    ).read_bytes() == metadata
    assert sorted(p.name for p in bag.iterdir()) == ["bag_0.mcap", "metadata.yaml"]


def test_reindex_of_a_complete_bag_changes_nothing_and_exits_0(
    megabyte_bag: Path, tmp_path: Path
) -> None:
    bag, _ = _copy(megabyte_bag, tmp_path, "whole")
    result = run_offline([FLAAIR, "bag", "reindex", str(bag)], isolated_env(), 120)
    assert result.returncode == 0, result.stderr
    assert _read_both(bag) == {
        "/flaair/drive": 2000,
        "/flaair/run_marker": 2,
        "/flaair/sensor_v": 2000,
        "/flaair/wing_state/truth": 2000,
    }
    assert not list(bag.glob("*.damaged"))
    not_a_bag = run_offline(
        [FLAAIR, "bag", "reindex", str(tmp_path / "nothing")], isolated_env(), 60
    )
    assert (
        not_a_bag.returncode == 2
        and "nothing" in not_a_bag.stderr
        and "Traceback" not in not_a_bag.stderr
    )


def test_imported_messages_carry_the_signal_time_as_log_time(megabyte_bag: Path) -> None:
    from flaair_tools import bagio

    for _, log_time_ns, message in bagio.iter_messages(megabyte_bag, ["/flaair/sensor_v"]):
        assert (
            log_time_ns == message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec
        )


def test_calibrate_on_video_rate_truth_gives_finite_rmse_and_json_safe(tmp_path: Path) -> None:
    """1 kHz video at a 20 kHz DAQ: ground truth on every 20th sample (the format allows it)."""
    _lab_csv(tmp_path / "video.csv", 20000, 3, video_stride=20)
    assert (
        run_offline(
            [FLAAIR, "import", str(tmp_path / "video.csv"), "--out", str(tmp_path / "bag")],
            isolated_env(),
            120,
        ).returncode
        == 0
    )
    result = run_offline(
        [FLAAIR, "calibrate", str(tmp_path / "bag"), "--out", str(tmp_path / "cal")],
        isolated_env(),
        300,
    )
    assert result.returncode == 0, result.stderr
    text = (tmp_path / "cal" / "calibration.json").read_text()
    values = json.loads(
        text, parse_constant=lambda name: pytest.fail(f"{name} in calibration.json")
    )
    for channel in ("stroke", "pitch"):
        assert np.isfinite(values[channel]["amplitude_rmse_deg"]) and np.isfinite(
            values[channel]["phase_rmse_deg"]
        )
        assert values[channel]["n_windows"] > 20
    # the nominal model's sensor follows its truth
    assert values["stroke"]["amplitude_rmse_deg"] < 3.0


def test_strict_json_turns_nan_into_null() -> None:
    from flaair_common.strictjson import json_safe

    text = json.dumps(
        json_safe({"a": float("nan"), "b": [np.float64("inf"), 1.5], "c": np.int64(2)}),
        allow_nan=False,
    )
    assert json.loads(text) == {"a": None, "b": [None, 1.5], "c": 2}


def test_simulate_clamps_an_over_limit_drive_and_warns(tmp_path: Path) -> None:
    from flaair_common.runcsv import read_run, write_run

    t = np.arange(4000) / FS_HZ
    write_run(
        tmp_path / "kv.csv", {"time_s": t, "drive_v": 10_000.0 * np.sin(2 * np.pi * 100.0 * t)}
    )
    write_run(
        tmp_path / "limit.csv",
        {"time_s": t, "drive_v": np.clip(10_000.0 * np.sin(2 * np.pi * 100.0 * t), -150.0, 150.0)},
    )
    result = run_offline(
        [FLAAIR, "simulate", str(tmp_path / "kv.csv"), "--out", str(tmp_path / "kv_out.csv")],
        isolated_env(),
        120,
    )
    assert result.returncode == 0, result.stderr
    assert "clamped to +-150 V" in result.stderr and "kv.csv" in result.stderr
    clamped = read_run(tmp_path / "kv_out.csv")
    assert np.abs(clamped["drive_v"]).max() == 150.0
    assert (
        run_offline(
            [
                FLAAIR,
                "simulate",
                str(tmp_path / "limit.csv"),
                "--out",
                str(tmp_path / "limit_out.csv"),
            ],
            isolated_env(),
            120,
        ).returncode
        == 0
    )
    # the clamped 10 kV run is the same as a run at the limit: a real stroke, not 1,907 degrees
    assert np.allclose(
        clamped["stroke_deg"], read_run(tmp_path / "limit_out.csv")["stroke_deg"], atol=1e-6
    )
    assert np.abs(clamped["stroke_deg"]).max() < 90.0


def test_a_diverging_model_is_blamed_not_the_drive(tmp_path: Path) -> None:
    from flaair_common.runcsv import write_run

    model = (Path(__file__).resolve().parents[1] / "config" / "model.yaml").read_text()
    (tmp_path / "strong.yaml").write_text(
        model.replace("actuator_gain_nm_per_v: 1.67e-7", "actuator_gain_nm_per_v: 1.67e+1")
    )
    t = np.arange(2000) / FS_HZ
    write_run(tmp_path / "run.csv", {"time_s": t, "drive_v": 100.0 * np.sin(2 * np.pi * 100.0 * t)})
    result = run_offline(
        [
            FLAAIR,
            "simulate",
            str(tmp_path / "run.csv"),
            "--model",
            str(tmp_path / "strong.yaml"),
            "--out",
            str(tmp_path / "o.csv"),
        ],
        isolated_env(),
        120,
    )
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    assert "strong.yaml" in result.stderr and "model's parameters are at fault" in result.stderr
    assert "clamp the drive" not in result.stderr and not (tmp_path / "o.csv").exists()


def test_duplicated_header_column_is_refused_with_line_and_column(tmp_path: Path) -> None:
    path = tmp_path / "dup.csv"
    path.write_text(
        "time_s,drive_v,stroke_sensor_v,pitch_sensor_v,stroke_deg,pitch_deg,drive_v\n"
        "0,0,1.25,1.25,0,0,9\n5e-05,0,1.25,1.25,0,0,9\n"
    )
    for command, out in (("import", "bag"), ("simulate", "o.csv")):
        result = run_offline(
            [FLAAIR, command, str(path), "--out", str(tmp_path / out)], isolated_env(), 120
        )
        assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
        assert (
            "dup.csv: line 1, column 7: duplicate column 'drive_v' (also column 2)" in result.stderr
        )


def test_a_utf8_bom_is_accepted(tmp_path: Path) -> None:
    from flaair_common.runcsv import read_run

    path = tmp_path / "excel.csv"
    path.write_bytes(
        b"\xef\xbb\xbf" + (HEADER + "0,1,1.25,1.25,,0\n5e-05,2,1.26,1.25,3,0\n").encode()
    )
    runs = read_run(path)
    assert runs["time_s"].tolist() == [0.0, 5e-05] and runs["drive_v"].tolist() == [1.0, 2.0]
    assert np.isnan(runs["stroke_deg"][0]) and runs.sample_rate_hz == pytest.approx(FS_HZ)


def test_import_refuses_a_nan_gap_and_leaves_no_bag(tmp_path: Path) -> None:
    csv = _lab_csv(tmp_path / "run.csv", 200, 0)
    result = run_offline(
        [FLAAIR, "import", str(csv), str(csv), "--out", str(tmp_path / "bag"), "--gap-s", "nan"],
        isolated_env(),
        60,
    )
    assert (
        result.returncode == 2 and "--gap-s" in result.stderr and "Traceback" not in result.stderr
    )
    assert not (tmp_path / "bag").exists()


def test_import_removes_its_bag_when_writing_fails(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from flaair_tools import bagio
    from flaair_tools.bagio import import_runs

    csv = _lab_csv(tmp_path / "run.csv", 200, 0)
    calls = {"n": 0}
    original = bagio.BagWriter.write

    def failing(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 30:
            raise KeyboardInterrupt
        return original(self, *args, **kwargs)

    monkeypatch.setattr(bagio.BagWriter, "write", failing)
    with pytest.raises(KeyboardInterrupt):
        import_runs.import_runs([csv], tmp_path / "bag", gap_s=1.0, block_size=10, frame_id="robot")
    assert not (tmp_path / "bag").exists()


@pytest.mark.parametrize("command", ["calibrate", "simulate"])
def test_malformed_model_yaml_names_file_line_and_column(
    tmp_path: Path, megabyte_bag: Path, command: str
) -> None:
    (tmp_path / "broken.yaml").write_text("plant:\n  stroke_inertia_kg_m2: [6.5e-11,\n")
    csv = _lab_csv(tmp_path / "run.csv", 200, 0)
    target = [str(megabyte_bag)] if command == "calibrate" else [str(csv)]
    result = run_offline(
        [
            FLAAIR,
            command,
            *target,
            "--model",
            str(tmp_path / "broken.yaml"),
            "--out",
            str(tmp_path / "o"),
        ],
        isolated_env(),
        120,
    )
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    assert "broken.yaml: line 3, column 1: not valid YAML" in result.stderr


@pytest.mark.parametrize(
    ("package", "executable"),
    [
        ("flaair_sim", "plant_node"),
        ("flaair_sensors", "frontend_node"),
        ("flaair_control", "dsa_controller_node"),
    ],
)
@pytest.mark.slow  # starts every node process on a malformed model
def test_every_node_names_a_malformed_model_file(
    tmp_path: Path, package: str, executable: str
) -> None:
    (tmp_path / "broken.yaml").write_text("plant: {stroke_inertia_kg_m2: 6.5e-11\n")
    result = run(
        [
            FLAAIR,
            "run",
            package,
            executable,
            "--ros-args",
            "-p",
            f"model_file:={tmp_path / 'broken.yaml'}",
        ],
        isolated_env(),
        120,
    )
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr[-2000:]
    assert "model_file" in result.stderr and "broken.yaml: line" in result.stderr


@pytest.mark.slow  # starts the front-end node process on each bad value
def test_frontend_names_a_calibration_value_that_is_not_a_number(tmp_path: Path) -> None:
    channel = "{gain_deg_per_v: %s, polarity: -1, offset_v: 0.0, lag_s: 0.0}"
    (tmp_path / "cal.yaml").write_text(
        f"reference_voltage_v: 1.25\nstroke: {channel % 'abc'}\npitch: {channel % '20.0'}\n"
    )
    result = run(
        [
            FLAAIR,
            "run",
            "flaair_sensors",
            "frontend_node",
            "--ros-args",
            "-p",
            "gains_from:=calibration",
            "-p",
            f"calibration_file:={tmp_path / 'cal.yaml'}",
        ],
        isolated_env(),
        120,
    )
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr[-2000:]
    assert "calibration['stroke']['gain_deg_per_v'] must be a number, got 'abc'" in result.stderr


def test_sigint_while_a_node_still_imports_ends_it_without_a_traceback(tmp_path: Path) -> None:
    """Ctrl-C after flaair_common.runtime is imported but before run_node (the node module still
    importing numba, seconds on a loaded machine): the node ends cleanly, exit 0, never built.
    """
    script = (
        "import os, signal, sys\n"
        # as from a terminal: Ctrl-C not ignored (a parent test process may pass SIGINT ignored)
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "sys.argv[0] = '/x/install/lib/flaair_sim/plant_node'\n"
        "from flaair_common import runtime\n"
        "os.kill(os.getpid(), signal.SIGINT)\n"
        "import numpy  # the rest of the imports go on\n"
        "def build():\n"
        "    raise SystemExit('the node was built after Ctrl-C')\n"
        "build.__module__ = '__main__'\n"
        "sys.exit(runtime.run_node(build, [], 'flaair.yaml', 'plant_node', args=['plant_node']))\n"
    )
    result = run(
        [
            str(Path(__file__).resolve().parents[1] / "scripts" / "in_env.sh"),
            "python",
            "-c",
            script,
        ],
        isolated_env(),
        120,
    )
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr and "KeyboardInterrupt" not in result.stderr


_HANGING_NODE = (
    "import sys, time\n"
    "sys.argv[0] = '/x/install/lib/flaair_sim/plant_node'\n"
    "from rclpy.node import Node\n"
    "from flaair_common import runtime\n"
    "class Hanging(Node):\n"
    "    def __init__(self):\n"
    "        super().__init__('hanging_node')\n"
    "        print('built', file=sys.stderr, flush=True)\n"
    "    def close(self):\n"
    "        while {hang_in_close}:\n"
    "            time.sleep(0.01)\n"
    "code = runtime.run_nodes([Hanging], args=['hanging_node'], exit_deadline_s={deadline_s})\n"
    "{after}\n"
    "sys.exit(code)\n"
)


def _stop_a_node_script(
    script: str, timeout_s: float, ready: str = "built"
) -> tuple[int | None, str, float]:
    """Start the node `script`, SIGTERM it once it prints `ready`; (exit code or None if still
    running after `timeout_s`, stderr, seconds from the signal to the end).
    """
    process = subprocess.Popen(
        [
            str(Path(__file__).resolve().parents[1] / "scripts" / "in_env.sh"),
            "python",
            "-c",
            script,
        ],
        env=isolated_env(),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        lines = []
        while ready not in "".join(lines[-1:]):
            lines.append(process.stderr.readline())
            assert lines[-1] or process.poll() is None, "".join(lines)
        process.send_signal(signal.SIGTERM)
        start = time.monotonic()
        try:
            _, rest = process.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            return None, "".join(lines), time.monotonic() - start
        return process.returncode, "".join(lines) + rest, time.monotonic() - start
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()


@pytest.mark.timeout(120)
def test_a_node_whose_close_hangs_ends_at_its_exit_deadline_with_its_stacks_in_its_log() -> None:
    """A node nobody waits for (its launcher killed -9: the parent-death SIGTERM reaches it) ends
    even when its stop hangs; before the fix it ran on for ever.
    """
    code, stderr, took_s = _stop_a_node_script(
        _HANGING_NODE.format(hang_in_close=True, deadline_s=1.0, after=""), timeout_s=20.0
    )
    assert code == 1, f"exit {code} after {took_s:.1f} s:\n{stderr[-2000:]}"
    assert 1.0 <= took_s < 10.0
    assert "stopping (SIGTERM)" in stderr and "ends within 1 s" in stderr
    assert "Timeout (0:00:01)!" in stderr and re.search(r"line \d+ in close\n", stderr), stderr


_STUCK_IN_C = (
    "import ctypes, sys\n"
    "sys.argv[0] = '/x/install/lib/flaair_sim/plant_node'\n"
    "from rclpy.node import Node\n"
    "from flaair_common import runtime\n"
    "libc = ctypes.CDLL(None)\n"
    "mutex = ctypes.create_string_buffer(64)   # PTHREAD_MUTEX_INITIALIZER: zeros\n"
    "class Stuck(Node):\n"
    "    def __init__(self):\n"
    "        super().__init__('stuck_node')\n"
    "        self.create_timer(0.01, self.tick)\n"
    "    def tick(self):\n"
    "        print('stuck', file=sys.stderr, flush=True)\n"
    "        libc.pthread_mutex_lock(mutex)\n"
    "        libc.pthread_mutex_lock(mutex)   # a lock that is never released, in C\n"
    "sys.exit(runtime.run_nodes([Stuck], args=['stuck_node'], exit_deadline_s=1.0))\n"
)


@pytest.mark.timeout(120)
def test_a_node_stuck_in_c_code_when_told_to_stop_ends_at_its_exit_deadline() -> None:
    """Its main thread never comes back to Python, so its SIGTERM handler never runs: the deadline
    is armed by a thread that sees the signal arrive (the interpreter's wakeup fd).
    """
    code, stderr, took_s = _stop_a_node_script(_STUCK_IN_C, timeout_s=20.0, ready="stuck")
    assert code == 1, f"exit {code} after {took_s:.1f} s:\n{stderr[-2000:]}"
    assert 1.0 <= took_s < 10.0
    assert "Timeout (0:00:01)!" in stderr and re.search(r"line \d+ in tick\n", stderr), stderr


@pytest.mark.slow  # waits for the SIGALRM that ends a hung node process
@pytest.mark.timeout(120)
def test_a_node_that_hangs_past_its_interpreter_cleanup_is_ended_by_sigalrm() -> None:
    """The second guard: a hang where faulthandler no longer runs (here: cancelled by hand, as the
    interpreter's finalisation does) is ended by SIGALRM, EXIT_ALARM_MARGIN_S later.
    """
    from flaair_common.runtime import EXIT_ALARM_MARGIN_S

    code, stderr, took_s = _stop_a_node_script(
        _HANGING_NODE.format(
            hang_in_close=False,
            deadline_s=1.0,
            after="import faulthandler; faulthandler.cancel_dump_traceback_later(); "
            "time.sleep(600)",
        ),
        timeout_s=20.0 + EXIT_ALARM_MARGIN_S,
    )
    assert code == -signal.SIGALRM, f"exit {code} after {took_s:.1f} s:\n{stderr[-2000:]}"
    assert 1.0 + EXIT_ALARM_MARGIN_S <= took_s < 10.0 + EXIT_ALARM_MARGIN_S


def test_only_a_node_process_has_an_exit_deadline(monkeypatch) -> None:
    """In a test or a CLI composing nodes in its own process, their own time limits rule."""
    from flaair_common import runtime

    assert runtime.default_exit_deadline_s() is None  # pytest's own process
    monkeypatch.setattr(sys, "argv", ["/opt/ws/install/lib/flaair_sim/plant_node"])
    assert runtime.default_exit_deadline_s() == runtime.EXIT_DEADLINE_S == 30.0


def _python_running(pid: int, executable: str) -> bool:
    """True once the process has exec'd Python on `executable` (after every launcher's exec)."""
    try:
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return False
    return Path(cmdline[0].decode()).name.startswith("python") and any(
        part.decode().endswith(executable) for part in cmdline[1:]
    )


# From the moment Python is exec'd: before its own handler (killed by the signal), while it
# imports rclpy, numpy and the node module (a KeyboardInterrupt traceback before the fix),
# building, spinning. (Each is a node start of 1-2 s; more instants found nothing more.)
_EARLY_DELAYS_S = (0.0, 0.1, 0.5, 2.0)


@pytest.mark.graph
@pytest.mark.parametrize("launcher", ["bin/flaair run", "Graph"])
def test_sigint_from_the_first_instant_of_a_node_ends_it_cleanly(launcher: str) -> None:
    """Ctrl-C at any moment after the node's Python starts, as a user starts a node
    (`bin/flaair run`, from a terminal: SIGINT at its default action) and as a graph does:
    exit 0, no traceback. Before the fix Python's own handler turned it into a
    KeyboardInterrupt traceback until flaair_common.runtime was imported.
    """
    from flaair_common.graph import node_argv

    failures = []
    for delay_s in _EARLY_DELAYS_S:
        with ros_processes() as processes:
            if launcher == "Graph":
                argv = node_argv("flaair_sim", "plant_node")
            else:  # env resets SIGINT to its default action, as a terminal's shell leaves it
                argv = ["env", "--default-signal=INT", FLAAIR, "run", "flaair_sim", "plant_node"]
            process = processes.start(*argv)
            deadline = time.monotonic() + 60.0
            while (
                not _python_running(process.pid, "/flaair_sim/plant_node")
                and time.monotonic() < deadline
            ):
                assert process.poll() is None, process.communicate()
                time.sleep(0.001)
            time.sleep(delay_s)
            os.killpg(process.pid, signal.SIGINT)
            try:
                _, stderr = process.communicate(timeout=120)
            except subprocess.TimeoutExpired:
                processes.stop(process, signal.SIGKILL)
                _, stderr = process.communicate()
            if process.returncode != 0 or "Traceback" in stderr or "KeyboardInterrupt" in stderr:
                failures.append(
                    f"SIGINT {delay_s} s after exec: exit {process.returncode}\n{stderr[-1500:]}"
                )
    assert not failures, "\n".join(failures)


@pytest.mark.graph
def test_only_node_executables_start_with_deferred_signals() -> None:
    """The launchers defer SIGINT/SIGTERM only for programs that end through flaair_common.runtime
    (which unblocks them): any other program would never see a Ctrl-C.
    """
    from flaair_common.graph import is_node_executable, with_deferred_signals

    lib = Path(__file__).resolve().parents[1] / "install" / "lib"
    scripts = sorted(path for path in lib.glob("flaair_*/*") if path.is_file())
    assert len(scripts) >= 10
    for script in scripts:
        setup = (lib.parents[1] / "src" / script.parent.name / "setup.py").read_text()
        target = re.search(rf"{re.escape(script.name)} = ([\w.]+):", setup)
        assert target, script
        source = (
            lib.parents[1] / "src" / script.parent.name / Path(*target.group(1).split("."))
        ).with_suffix(".py")
        uses_runtime = "flaair_common.runtime import" in source.read_text()
        if is_node_executable(script):
            assert uses_runtime, f"{script} would start with Ctrl-C blocked but never unblocks it"
            assert with_deferred_signals([sys.executable, str(script)])[-2:] == [
                sys.executable,
                str(script),
            ]
            assert "--block-signal=INT" in with_deferred_signals([str(script)])
        else:
            assert with_deferred_signals([sys.executable, str(script)]) == [
                sys.executable,
                str(script),
            ]
    assert with_deferred_signals(["bin/flaair", "experiment"]) == ["bin/flaair", "experiment"]
