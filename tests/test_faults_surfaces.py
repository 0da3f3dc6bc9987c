"""Fault suite, issue 52: the live, ros2 and output surfaces.

Outputs are staged and renamed into place whole (SIGTERM or Ctrl-C while writing leaves nothing
new and keeps an earlier result; an output that is a link is never written through), the ros2cli
stand-ins answer bad input in one line, `live` filters the target's packets by sender and bounds
a sequence jump, child processes get absolute paths, `launch --print` quotes, sparse DLTdv
exports are recognised by their layout, file text reaches every figure literally, and `analyze`
says which run its headline comes from. Each test fails on the code before the fix.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import ClassVar

import pytest

from rosproc import FLAAIR, REPO_ROOT, isolated_env, run_offline
from test_bridge_core import params as bridge_test_params  # the core tests' parameters

pytestmark = pytest.mark.timeout(120)


def _offline(args: list[str]) -> tuple[int, list[str], str]:
    try:
        result = run_offline([FLAAIR, *args], isolated_env(), 60)
    except KeyboardInterrupt:  # the command's own interruption (raised by the test's fake)
        return -1, ["KeyboardInterrupt escaped the command"], "KeyboardInterrupt escaped"
    return result.returncode, result.stderr.strip().splitlines(), result.stderr


def _one_line(code: int, lines: list[str], stderr: str, expect_code: int, text: str) -> None:
    assert code == expect_code, stderr[-3000:]
    assert "Traceback" not in stderr and len(lines) == 1, stderr[-3000:]
    assert text in lines[0], lines


# ----------------------------------------------------------------- 4, 5, 6: staged outputs

HEALTH_RESULT = "{'bag': str(bag), 'events': [], 'wingbeats': {}, 'estimated': 0, 'note': None}"

# A command run in a new process whose writer sends the process SIGTERM once it has written
# part of its output (in the write phase): the default action would leave that part behind.
SIGTERM_SCRIPTS = {
    "health": f"""
from flaair_tools.analysis import health_cli as m
m.run_bag = lambda bag, values, model: {HEALTH_RESULT}
def writer(results, path):
    Path(path).write_bytes(b"partial")
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(10)
m.write_figure = writer
sys.exit(m.main([str(BAG), "--out", str(OUT)]))
""",
    "discrepancy --table": """
from types import SimpleNamespace
from flaair_common.outputs import check_output
from flaair_model.model_io import load_model
from flaair_tools.discrepancy import cli as m
def computed(prog, args, files, compute, protected=()):
    written = check_output(args.out, [], args.force, files)
    inputs = SimpleNamespace(table=SimpleNamespace(), s=None, runs=[])
    return written, inputs, (SimpleNamespace(model_out=load_model()), None), 0.0
m.run_command = computed
m.TableDiscrepancy = SimpleNamespace  # the fake result is the table's
def writer(result, table, s, out):
    (Path(out) / "discrepancy.json").write_text("{")
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(10)
m.write_table_report = writer
sys.exit(m.main(["--table", str(BAG), "--out", str(OUT)]))
""",
}


# slow: a new interpreter imports numpy, scipy and matplotlib (7-9 s at load average 8)
@pytest.mark.slow
@pytest.mark.parametrize("command", sorted(SIGTERM_SCRIPTS))
def test_sigterm_while_writing_leaves_no_partial_output(command, tmp_path) -> None:
    """In a new process: SIGTERM's default action cannot be shown in the test's own."""
    bag = tmp_path / "in.csv"
    bag.write_text("x\n")
    out = tmp_path / "out"
    head = "import os, signal, sys, time\nfrom pathlib import Path\n"
    code = f"{head}BAG, OUT = Path({str(bag)!r}), Path({str(out)!r})\n{SIGTERM_SCRIPTS[command]}"
    done = subprocess.run(
        [sys.executable, "-c", code],
        env={**os.environ, **isolated_env()},
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=90,
    )
    assert done.returncode == 130, (done.returncode, done.stderr[-3000:])
    assert "Traceback" not in done.stderr and "interrupted; nothing written" in done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.csv"]  # no out, no stage


def _health_out(tmp_path: Path, monkeypatch, writer) -> tuple[Path, Path]:
    from flaair_tools.analysis import health_cli

    monkeypatch.setattr(
        health_cli,
        "run_bag",
        lambda bag, values, model: {
            "bag": str(bag),
            "events": [],
            "wingbeats": {},
            "estimated": 3,
            "note": None,
        },
    )
    monkeypatch.setattr(health_cli, "write_figure", writer)
    bag = tmp_path / "bag"
    bag.mkdir()
    return bag, tmp_path / "out"


def test_force_then_ctrl_c_keeps_the_earlier_result_whole(tmp_path, monkeypatch) -> None:
    def interrupted(results, path):
        Path(path).write_bytes(b"new, partial")
        raise KeyboardInterrupt  # Ctrl-C once the new health.json is written

    bag, out = _health_out(tmp_path, monkeypatch, interrupted)
    out.mkdir()
    (out / "health.json").write_text('{"old": true}')
    (out / "health.png").write_bytes(b"old png")
    (out / "notes.txt").write_text("mine")
    _one_line(*_offline(["health", str(bag), "--out", str(out), "--force"]), 130, "interrupted")
    assert (out / "health.json").read_text() == '{"old": true}'
    assert (out / "health.png").read_bytes() == b"old png"
    assert sorted(p.name for p in out.iterdir()) == ["health.json", "health.png", "notes.txt"]


def test_force_replaces_the_earlier_result_whole(tmp_path, monkeypatch) -> None:
    bag, out = _health_out(tmp_path, monkeypatch, lambda r, path: Path(path).write_bytes(b"new"))
    out.mkdir(mode=0o755)
    (out / "health.json").write_text('{"old": true}')
    code, _, stderr = _offline(["health", str(bag), "--out", str(out), "--force"])
    assert code == 0, stderr
    assert (out / "health.png").read_bytes() == b"new"
    assert '"estimated": 3' in (out / "health.json").read_text()
    assert sorted(p.name for p in out.iterdir()) == ["health.json", "health.png"]
    fresh = tmp_path / "fresh"
    assert _offline(["health", str(bag), "--out", str(fresh)])[0] == 0
    assert fresh.stat().st_mode & 0o777 == 0o777 & ~_umask()  # not the stage's 0700
    assert (fresh / "health.json").stat().st_mode & 0o777 == 0o666 & ~_umask()


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@pytest.mark.parametrize("dangling", [False, True], ids=["to a file", "dangling"])
def test_an_output_that_is_a_symlink_is_never_written_through(
    dangling, tmp_path, monkeypatch
) -> None:
    bag, out = _health_out(tmp_path, monkeypatch, lambda r, path: Path(path).write_bytes(b"png"))
    out.mkdir()
    victim = tmp_path / "victim.txt"
    if not dangling:
        victim.write_text("precious")
    (out / "health.json").symlink_to(victim)
    _one_line(*_offline(["health", str(bag), "--out", str(out), "--force"]), 2, "symbolic link")
    assert victim.read_text() == "precious" if not dangling else not victim.exists()
    assert (out / "health.json").is_symlink() and not (out / "health.png").exists()


# ----------------------------------------------------------------- 3: the ros2cli stand-ins


def _no_node(name, body):
    raise AssertionError("a node came up before the input was checked")


@pytest.mark.parametrize(
    ("argv", "text"),
    [
        (["topic", "echo", "/x", "not/a/Type", "--once"], "unknown message type 'not/a/Type'"),
        (["topic", "pub", "--count", "1", "/x", "not/a/Type", "{}"], "unknown message type"),
        (["topic", "pub", "/x", "std_msgs/msg/String", '{"data": 5}'], "String.data"),
        (["param", "set", "/plant_node", "kr_target", "{a: 1}"], "is a mapping"),
        (
            ["param", "set", "/plant_node", "mode", "!!python/object/apply:os.system ['true']"],
            "not a plain YAML value",
        ),
        (["param", "set", "/plant_node", "block_size", "99999999999999999999"], "64-bit"),
        (["param", "set", "/plant_node", "block_size", "[1, 99999999999999999999]"], "64-bit"),
        (
            [
                "service",
                "call",
                "/n/get_parameters",
                "rcl_interfaces/srv/GetParameters",
                "{names: 5}",
            ],
            "GetParameters_Request.names",
        ),
        (
            [
                *("service", "call", "/n/set_parameters", "rcl_interfaces/srv/SetParameters"),
                "{parameters: [{name: 5}]}",
            ],
            "Parameter.name",
        ),
    ],
    ids=[
        "echo type",
        "pub type",
        "pub value",
        "mapping",
        "yaml tag",
        "int64",
        "int64 array",
        "names: 5",
        "nested",
    ],
)
def test_ros2_stand_ins_refuse_bad_input_in_one_line(argv, text, monkeypatch, capsys) -> None:
    from flaair_tools import cli
    from flaair_tools.roscli import param, service, topic

    for module in (param, service, topic):
        monkeypatch.setattr(module, "run_with_node", _no_node)
    code = cli.main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and text in err[0], err


def test_a_service_request_takes_nested_messages() -> None:
    from rcl_interfaces.msg import ParameterType
    from rcl_interfaces.srv import SetParameters

    from flaair_tools.roscli.service import parse_request

    request = parse_request(
        SetParameters, "{parameters: [{name: kr_target, value: {type: 3, double_value: 0.5}}]}"
    )
    (parameter,) = request.parameters
    assert parameter.name == "kr_target"
    assert parameter.value.type == ParameterType.PARAMETER_DOUBLE
    assert parameter.value.double_value == 0.5


def test_param_set_reads_values_as_ros2_does() -> None:
    from rcl_interfaces.msg import ParameterType

    from flaair_tools.roscli.param import parameter_value

    assert parameter_value("0.25").double_value == 0.25
    assert parameter_value(str(2**63 - 1)).integer_value == 2**63 - 1
    assert parameter_value("[1, a]").type == ParameterType.PARAMETER_STRING  # as rclpy
    assert parameter_value("{a").string_value == "{a"  # unparsable YAML: a string, as rclpy


def test_param_list_into_a_closed_pipe_ends_quietly(monkeypatch, capsys) -> None:
    """`param list NODE | head`: the pipe's reader has gone when the names are printed."""
    import io
    from types import SimpleNamespace

    from flaair_tools import cli
    from flaair_tools.roscli import param

    class ClosedPipe(io.TextIOBase):
        def write(self, text: str) -> int:
            raise BrokenPipeError(32, "Broken pipe")

    names = SimpleNamespace(result=SimpleNamespace(names=[f"p{k}" for k in range(50)]))
    answered = SimpleNamespace(done=lambda: True, result=lambda: names)
    client = SimpleNamespace(wait_for_services=lambda timeout_sec: True)
    client.list_parameters = lambda: answered
    monkeypatch.setattr(param, "AsyncParameterClient", lambda node, name: client)
    monkeypatch.setattr(
        param, "rclpy", SimpleNamespace(spin_until_future_complete=lambda *a, **k: None)
    )
    monkeypatch.setattr(param, "run_with_node", lambda name, body: body(None))
    monkeypatch.setattr(sys, "stdout", ClosedPipe())
    assert cli.main(["param", "list", "/plant_node"]) == 141
    assert capsys.readouterr().err == ""


# ----------------------------------------------------------------- 8, 17: live and experiment


class _FakeGraph:
    """live's Graph without processes: what it was asked to start, in order."""

    started: ClassVar[list[tuple[str, list[str]]]] = []
    log_dirs: ClassVar[list[Path]] = []

    def __init__(self, localhost: bool = True, log_dir: Path | None = None) -> None:
        self.env = {"ROS_DOMAIN_ID": "7", "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
        _FakeGraph.log_dirs.append(log_dir)

    def describe(self) -> str:
        return "ROS domain 7"

    def start(self, role: str, argv: list[str]) -> str:
        _FakeGraph.started.append((role, argv))
        return role

    def stop(self, process: str, timeout_s: float) -> None:
        pass

    def close(self) -> None:
        pass


class _CtrlCAtHealth:
    """live's Watcher, Ctrl-C pressed while it waits for the health monitor."""

    def __init__(self, graph, args) -> None:
        pass

    recorder_listens = monitor_listens = health_listens = None

    def spin_until(self, predicate, timeout_s: float, what: str) -> None:
        if "health" in what:
            raise KeyboardInterrupt

    def close(self) -> None:
        pass


@pytest.fixture
def fake_live(monkeypatch, tmp_path):
    from flaair_tools.orchestration import live

    monkeypatch.setattr(live, "Graph", _FakeGraph)
    monkeypatch.setattr(live, "Watcher", _CtrlCAtHealth)
    monkeypatch.setattr(_FakeGraph, "started", [])
    monkeypatch.setattr(_FakeGraph, "log_dirs", [])
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # not the repository's root
    handler = signal.getsignal(signal.SIGTERM)
    yield live
    signal.signal(signal.SIGTERM, handler)


def test_ctrl_c_before_the_loop_starts_claims_no_bag(fake_live, capsys) -> None:
    assert fake_live.main(["--sim", "--out", "bag"]) == 0
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert "interrupted" in last and "closed" not in last and "no bag written" in last, last
    assert "zero drive sent" not in last  # the loop never ran


def test_live_from_another_directory_hands_its_children_absolute_paths(fake_live) -> None:
    import yaml

    fake_live.main(["--sim", "--out", "bag"])
    roles = dict(_FakeGraph.started)
    argv = roles["recorder"]
    params = Path(argv[argv.index("--params-file") + 1])
    assert params.is_absolute() and params.is_file(), argv
    recorder = yaml.safe_load(params.read_text())["recorder_node"]["ros__parameters"]
    assert recorder["output_path"] == str(Path.cwd() / "bag")


def test_experiment_from_another_directory_uses_absolute_paths(monkeypatch, tmp_path) -> None:
    from flaair_tools.orchestration import experiment

    class Stop(Exception):
        pass

    def graph(log_dir: Path, **_kwargs):
        _FakeGraph.log_dirs.append(log_dir)
        raise Stop

    monkeypatch.setattr(_FakeGraph, "log_dirs", [])
    monkeypatch.setattr(experiment, "Graph", graph)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(Stop):
        experiment.run_experiment(
            experiment.load_experiments()["characterization_chirp"], Path("bag"), progress=False
        )
    assert _FakeGraph.log_dirs == [tmp_path / "bag.logs"]


def _saved_baseline(path: Path) -> Path:
    """A health.json holding one baseline learned against the configured model."""
    import json

    import numpy as np

    from flaair_control.core import change_test
    from flaair_control.health_io import baseline_dict, health_params_from_config

    n = len(change_test.WATCHED)
    baseline = change_test.Baseline(np.ones(n), np.full(n, 0.01), 140.0)
    doc = {"bags": [{"baseline": baseline_dict(baseline, health_params_from_config())}]}
    path.write_text(json.dumps(doc))
    return path


def test_experiment_refuses_a_bad_health_baseline_before_any_node_starts(
    monkeypatch, tmp_path, capsys
) -> None:
    from flaair_tools.orchestration import experiment

    def no_graph(*_args, **_kwargs):
        raise AssertionError("a graph was started")

    monkeypatch.setattr(experiment, "Graph", no_graph)
    garbage = tmp_path / "garbage.json"
    garbage.write_text("{not json")
    argv = ["characterization_chirp", "--out", str(tmp_path / "bag")]
    assert experiment.main([*argv, "--health-baseline", str(garbage)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "baseline_file" in err[0] and "not a readable health.json" in err[0]
    assert not (tmp_path / "bag").exists()


def test_experiment_hands_the_health_monitor_its_saved_baseline(tmp_path) -> None:
    from flaair_control.health_io import check_baseline_file
    from flaair_tools.orchestration import experiment

    saved = _saved_baseline(tmp_path / "health.json")
    spec = experiment.load_experiments()["characterization_chirp"]
    args = (spec, tmp_path / "bag", tmp_path, True, True, None)
    parameters = experiment.run_parameters(*args, saved)
    assert parameters["health"]["baseline_file"] == str(saved)
    assert "baseline_file" not in experiment.run_parameters(*args, None)["health"]
    check_baseline_file(saved, None)  # the check `main` runs first accepts it


# ----------------------------------------------------------------- 18: launch --print


def test_launch_refuses_a_namespace_that_is_not_a_ros_name_before_printing(capsys) -> None:
    from flaair_tools.orchestration import launch_cli

    argv = ["flaair_tools", "lockstep_loop.launch.xml", "namespace:=$(touch PWNED);x", "--print"]
    assert launch_cli.main(argv) == 2
    out, err = capsys.readouterr()
    assert out == "" and len(err.strip().splitlines()) == 1, err
    assert "namespace '/$(touch PWNED);x' is not a valid ROS name" in err


def test_launch_print_quotes_each_word_for_a_shell(capsys) -> None:
    import shlex

    from flaair_tools.orchestration import launch_cli

    value = "out/bags/a b;touch PWNED"
    argv = ["flaair_tools", "record.launch.xml", f"output_path:={value}", "--print"]
    assert launch_cli.main(argv) == 0
    (line,) = capsys.readouterr().out.strip().splitlines()
    assert f"output_path:={value}" in shlex.split(line)  # one word, as it was given


# ----------------------------------------------------------------- 19: DLTdv sparse exports


@pytest.mark.parametrize(
    "title",
    [
        "Sparse format 2D camera coordinates file",
        "Sparse format camera coordinates file",
        "sparse format 2D coordinates file,,",
    ],
)
def test_a_sparse_2d_export_is_recognised_by_its_layout(title, tmp_path) -> None:
    import numpy as np

    import lab_writers as lw
    from flaair_tools.bagio.dlt_tracks import read_xy_point

    t = np.arange(50) / 50.0
    tip = np.column_stack([320 + 40 * np.sin(2 * np.pi * t), 240 + 10 * np.cos(2 * np.pi * t)])
    tip[7] = np.nan  # a frame not tracked
    path = lw.write_sparse_track(tmp_path / "tip_xypts.csv", tip, 2, title=title)
    got = read_xy_point(path, 1, 1, "points.actuator_tip")
    np.testing.assert_allclose(got, tip, rtol=1e-14)


# ----------------------------------------------------------------- 20: file text in figures

TEX_NAME = "$\\frac{a}{$"  # a run name that is broken mathtext


@pytest.mark.slow  # the four discrepancy figures drawn (8-11 s at load average 8, imports included)
def test_discrepancy_figures_draw_a_run_named_like_tex_literally(tmp_path) -> None:
    from types import SimpleNamespace

    import numpy as np

    from flaair_analysis.discrepancy.runs import Run
    from flaair_analysis.discrepancy.vocabulary import CHANNELS
    from flaair_tools.discrepancy.report_figures import write_figures

    fs, n = 20000.0, 2000
    t = np.arange(n) / fs
    drive = 100.0 * np.sin(2 * np.pi * 150.0 * t)
    run = Run(
        TEX_NAME, fs, drive, 1.6 + 0.01 * drive, 1.6 + 0.002 * drive, 0.3 * drive, 0.1 * drive
    )
    sims = [{c: run.channel(c) * 1.1 for c in CHANNELS}]
    channel = SimpleNamespace(
        noise_nrmse=0.01, worst_stretch=(TEX_NAME, 0.02, 0.08, 0.0), band_nrmse={"100-200 Hz": 0.1}
    )
    diagnosis = SimpleNamespace(channels=dict.fromkeys(CHANNELS, channel))
    result = SimpleNamespace(
        diagnosis_before=diagnosis,
        diagnosis_after=diagnosis,
        gap_before=dict.fromkeys(CHANNELS, 0.2),
        gap_after=dict.fromkeys(CHANNELS, 0.05),
        status="explained",
        sims_before=sims,
        sims_after=sims,
        discovered=(),
    )
    figures = write_figures(tmp_path, [run], result)
    assert all((tmp_path / name).stat().st_size > 1000 for name in figures.values())


def test_health_figure_draws_a_bag_named_like_tex_literally(tmp_path) -> None:
    from flaair_tools.analysis.health_cli import write_figure

    series = {"time_s": [0.0, 0.1]}
    for name in ("wing_inertia", "stroke_film_gain", "pitch_film_gain", "actuator_gain"):
        series[name], series[f"{name}_stderr"] = [1.0, 1.01], [0.01, 0.01]
    result = {"bag": f"/data/{TEX_NAME}", "wingbeats": series, "events": []}
    write_figure([result], tmp_path / "health.png")
    assert (tmp_path / "health.png").stat().st_size > 1000


# ----------------------------------------------------------------- 21: analyze's headline


def _transition_bag(path: str, experiment: str, frequency_hz: float) -> dict:
    return {
        "bag": path,
        "experiment": experiment,
        "runs": {"kr_ramp": {"method": "transition"}},
        "transition": {
            "final_frequency_hz": frequency_hz,
            "final_amplitude_deg": 30.0,
            "resonance_hz": 180.0,
        },
    }


class _Bands:
    def label(self, name: str) -> str:
        return "110-190 Hz"


def test_the_headline_names_its_transition_run_and_the_lab_chooses() -> None:
    from flaair_analysis.headline import HeadlineChoiceError, headline

    bags = [
        _transition_bag("bags/paper", "transition", 190.0),
        _transition_bag("bags/damaged", "damaged_wing", 150.0),
    ]
    first = headline(bags, _Bands())["transition_final_frequency_hz"]
    assert first["flaair"] == 190.0
    assert "bags/paper" in first["source"] and "kr_ramp" in first["source"]
    assert "first of 2" in first["note"] and "bags/damaged" in first["note"]
    for name in ("damaged", "bags/damaged", "damaged_wing"):
        chosen = headline(bags, _Bands(), name)["transition_final_frequency_hz"]
        assert chosen["flaair"] == 150.0 and "bags/damaged" in chosen["source"], name
    with pytest.raises(HeadlineChoiceError, match=r"--headline-transition nowhere: .*bags/paper"):
        headline(bags, _Bands(), "nowhere")


# ----------------------------------------------------------------- 16: live --target, strangers


def _bridge_params(**overrides):
    """test_bridge_core's parameters, with the target's address configured."""
    return bridge_test_params(**({"target_host": "127.0.0.1", "target_port": 25001} | overrides))


def _sensor(sequence: int, first: int) -> bytes:
    import numpy as np

    from flaair_bridge.emulated_target import sensor_packet

    i = np.arange(first, first + 10)
    return sensor_packet(sequence, first, 20000.0, 0, i / 10, 1 + i / 1000, 2 - i / 1000)


def _feed(datagrams, p):
    import numpy as np

    from flaair_bridge.core import bridge, bridge_state

    state, published = bridge.initial_state(p), []
    for k, (data, sender) in enumerate(datagrams):
        state, out = bridge.step(
            state, bridge_state.SensorDatagram(data, 1e-3 * k, None, sender), p
        )
        published += [int(b.first_sample_index) for b in out.blocks]
    return state, np.array(published)


TARGET = ("127.0.0.1", 40000)  # the target sends from its own port (a Speedgoat's UDP Send)


@pytest.mark.parametrize(
    "stranger", [("127.0.0.1", 50000), ("10.0.0.9", 25001)], ids=["same host", "another host"]
)
def test_a_strangers_far_ahead_packets_neither_move_nor_stop_the_stream(stranger) -> None:
    datagrams = []
    for k in range(100):
        datagrams.append((_sensor(k, 10 * k), TARGET))
        if k >= 10:  # 49.9 M samples ahead, in the target's stream
            datagrams.append((_sensor(4_990_000 + k, 49_900_000 + 10 * k), stranger))
    state, published = _feed(datagrams, _bridge_params())
    assert list(published) == list(range(0, 1000, 10))  # every target packet, in place
    c = state.counters
    assert (c.foreign_packets, c.stale_packets, c.lost_packets, c.lost_samples) == (90, 0, 0, 0)
    assert state.source == TARGET


def test_the_configured_address_is_the_target_even_after_a_stranger_spoke_first() -> None:
    stranger, configured = ("127.0.0.1", 50000), ("127.0.0.1", 25001)
    datagrams = [(_sensor(7_000_000, 70_000_000), stranger)]
    datagrams += [(_sensor(k, 10 * k), configured) for k in range(20)]
    datagrams += [(_sensor(7_000_001 + k, 70_000_010 + 10 * k), stranger) for k in range(20)]
    state, published = _feed(datagrams, _bridge_params())
    c = state.counters
    assert state.source == configured and (c.foreign_packets, c.stale_packets) == (20, 0)
    assert list(published) == list(range(70_000_000, 70_000_210, 10))  # no step back, no gap


def test_a_sequence_jump_is_bounded_unless_it_persists() -> None:
    """Sender unknown (or spoofed): a far jump moves the stream only after resync_packets."""
    p = _bridge_params(target_host="", target_port=0)
    far = [(_sensor(5_000_000 + k, 50_000_000 + 10 * k), None) for k in range(3)]
    datagrams = [(_sensor(k, 10 * k), None) for k in range(10)] + far
    datagrams += [(_sensor(k, 10 * k), None) for k in range(10, 20)]
    state, published = _feed(datagrams, p)
    assert list(published) == list(range(0, 200, 10)) and state.counters.jump_packets == 3
    persisting = [(_sensor(6_000_000 + k, 60_000_000 + 10 * k), None) for k in range(6)]
    state, published = _feed(datagrams + persisting, p)
    assert state.counters.jump_packets == 3 + 4  # the fifth in a row is followed
    assert published[-1] == 60_000_050 and state.counters.lost_packets == 6_000_000 - 20 + 4


# ----------------------------------------------------------------- 7: import, SIGTERM at the end


def test_sigterm_as_the_import_completes_keeps_the_whole_bag_and_says_so(
    tmp_path, monkeypatch
) -> None:
    import numpy as np

    from flaair_common.runcsv import write_run
    from flaair_tools.bagio import import_runs

    t = np.arange(2000) / 20000.0
    drive = 100.0 * np.sin(2 * np.pi * 150.0 * t)
    columns = {
        "time_s": t,
        "drive_v": drive,
        "stroke_sensor_v": 1.6 + 0.01 * drive,
        "pitch_sensor_v": 1.6 + 0.002 * drive,
        "stroke_deg": 0.3 * drive,
        "pitch_deg": 0.1 * drive,
    }
    run = write_run(tmp_path / "run.csv", columns) or tmp_path / "run.csv"
    real = import_runs.import_runs

    class SignalledAtTheEnd(list):
        looks = 0

        def __iter__(self):  # its second reader, the summary: the bag is closed, SIGTERM comes
            self.looks += 1
            if self.looks == 2:
                signal.raise_signal(signal.SIGTERM)
            return super().__iter__()

    monkeypatch.setattr(
        import_runs, "import_runs", lambda *a, **k: SignalledAtTheEnd(real(*a, **k))
    )
    bag = tmp_path / "bag"
    result = run_offline([FLAAIR, "import", str(run), "--out", str(bag)], isolated_env())
    assert result.returncode == 0, result.stderr
    assert f"wrote {bag}" in result.stdout and "Traceback" not in result.stderr
    assert "SIGTERM came after the bag was complete: kept" in result.stderr
    assert (bag / "metadata.yaml").is_file()
