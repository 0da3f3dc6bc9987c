"""Fault suite, issue 38: outputs are never inputs, and are checked before anything is computed.

simulate, identify, discrepancy, calibrate and analyze refuse an `--out` that would overwrite
one of their inputs or the project's config, replace an existing output only with `--force`,
refuse a file, a place they cannot write or a malformed --validation before the analysis,
leave no partial output when a write fails or Ctrl-C comes, and draw names from files
literally. Each test fails on the code before the fix.
"""

from __future__ import annotations

import errno
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest

from flaair_sensors.figures import literal_texts
from rosproc import FLAAIR, REPO_ROOT, isolated_env, run_offline

pytestmark = pytest.mark.timeout(240)

FS_HZ = 20000.0


def _run_csv(path: Path, n: int = 4000, seed: int = 0) -> Path:
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
    write_run(path, columns)
    return path


@pytest.fixture(scope="module")
def csv_run(tmp_path_factory) -> Path:
    return _run_csv(tmp_path_factory.mktemp("runs") / "run.csv")


def _offline(args: list[str], env: dict[str, str] | None = None):
    result = run_offline([FLAAIR, *args], env or isolated_env(), 120)
    lines = result.stderr.strip().splitlines()
    return result.returncode, lines, result.stderr


def _one_line(code: int, lines: list[str], stderr: str, expect_code: int, text: str) -> None:
    assert code == expect_code, stderr[-3000:]
    assert "Traceback" not in stderr and len(lines) == 1, stderr[-3000:]
    assert text in lines[0], lines


def _never(name: str):
    def fail(*_args, **_kwargs):
        raise AssertionError(f"{name} ran although its output was refused")

    return fail


@pytest.fixture
def config_copy(tmp_path) -> Path:
    """A copy of config/ that FLAAIR_CONFIG_DIR points to: a test may see it overwritten."""
    copy = tmp_path / "config"
    shutil.copytree(Path(REPO_ROOT) / "config", copy)
    return copy


def test_simulate_refuses_to_overwrite_its_own_input(csv_run, tmp_path) -> None:
    run = tmp_path / "R.csv"
    shutil.copy(csv_run, run)
    before = run.read_bytes()
    _one_line(*_offline(["simulate", str(run), "--out", str(run)]), 2, "would overwrite the input")
    assert run.read_bytes() == before


def test_an_existing_output_is_replaced_only_with_force(csv_run, tmp_path) -> None:
    out = tmp_path / "sim.csv"
    out.write_text("keep me\n")
    _one_line(*_offline(["simulate", str(csv_run), "--out", str(out)]), 2, "--force")
    assert out.read_text() == "keep me\n"
    code, _, stderr = _offline(["simulate", str(csv_run), "--out", str(out), "--force"])
    assert code == 0, stderr
    assert out.read_text().startswith("time_s,")


@pytest.mark.parametrize("command", ["identify", "discrepancy"])
def test_an_existing_model_yaml_in_out_is_kept_and_nothing_computed(
    command, csv_run, tmp_path, monkeypatch
) -> None:
    from flaair_tools.discrepancy import cli, identify

    monkeypatch.setattr(identify, "identify_evidence", _never("identify_evidence"))
    monkeypatch.setattr(cli, "analyse_evidence", _never("the discrepancy workflow"))
    out = tmp_path / "out"
    out.mkdir()
    (out / "model.yaml").write_text("# my model\n")
    _one_line(*_offline([command, str(csv_run), "--out", str(out)]), 2, "exists (--force")
    assert (out / "model.yaml").read_text() == "# my model\n"


@pytest.mark.parametrize("command", ["identify", "discrepancy", "calibrate"])
def test_out_config_never_replaces_the_projects_model(
    command, csv_run, config_copy, monkeypatch
) -> None:
    from flaair_tools.discrepancy import cli, identify

    monkeypatch.setattr(identify, "identify_evidence", _never("identify_evidence"))
    monkeypatch.setattr(cli, "analyse_evidence", _never("the discrepancy workflow"))
    env = {**isolated_env(), "FLAAIR_CONFIG_DIR": str(config_copy)}
    before = (config_copy / "model.yaml").read_bytes()
    args = [command, str(csv_run), "--out", str(config_copy), "--force"]
    _one_line(*_offline(args, env), 2, "project's config")
    assert (config_copy / "model.yaml").read_bytes() == before


@pytest.mark.parametrize("where", ["a file", "read-only"])
@pytest.mark.parametrize("command", ["identify", "discrepancy"])
def test_an_out_that_cannot_be_written_is_refused_before_the_analysis(
    command, where, csv_run, tmp_path, monkeypatch
) -> None:
    from flaair_tools.discrepancy import cli, identify

    monkeypatch.setattr(identify, "identify_evidence", _never("identify_evidence"))
    monkeypatch.setattr(cli, "analyse_evidence", _never("the discrepancy workflow"))
    if where == "a file":
        out = tmp_path / "report.txt"
        out.write_text("x")
        text = "is a file"
    else:
        out = Path("/proc/flaair_out")  # read-only even for root
        text = "cannot write"
    _one_line(*_offline([command, str(csv_run), "--out", str(out)]), 2, text)


def test_a_full_disk_leaves_no_partial_output(csv_run, tmp_path, monkeypatch) -> None:
    from flaair_sim import simulate_cli

    def full(path, columns):
        Path(path).write_text("time_s,drive_v\n0,")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(simulate_cli, "write_run", full)
    out = tmp_path / "sim.csv"
    _one_line(*_offline(["simulate", str(csv_run), "--out", str(out)]), 2, "No space left")
    assert not out.exists()


@pytest.mark.parametrize(
    "content",
    [
        "[" * 100_000 + "]" * 100_000,
        '{"confusion": {"columns": ["a"], "rows": ["b"], "counts": [[1, 2]]}}',
        '{"confusion": 3}',
        "[]",
        '{"confusion": {"columns": ["a"], "rows": ["a"], "counts": [[1]], "correct": 1, '
        '"total": 1}, "cases": [5]}',
    ],
    ids=["deep", "ragged", "not a table", "a list", "a case not a mapping"],
)
def test_a_malformed_validation_file_is_refused_before_the_analysis(
    content, csv_run, tmp_path, monkeypatch
) -> None:
    from flaair_tools.discrepancy import cli

    monkeypatch.setattr(cli, "analyse_evidence", _never("the discrepancy workflow"))
    validation = tmp_path / "validation.json"
    validation.write_text(content)
    out = tmp_path / "out"
    args = ["discrepancy", str(csv_run), "--validation", str(validation), "--out", str(out)]
    _one_line(*_offline(args), 2, "--validation")
    assert not out.exists()


def test_ctrl_c_in_discrepancy_exits_130_in_one_line_and_writes_nothing(
    csv_run, tmp_path, monkeypatch
) -> None:
    from flaair_tools.discrepancy import cli

    def interrupted(*_args, **_kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "analyse_evidence", interrupted)
    out = tmp_path / "out"
    _one_line(*_offline(["discrepancy", str(csv_run), "--out", str(out)]), 130, "interrupted")
    assert not out.exists()


@pytest.mark.slow  # waits up to 2 s in a new process before its Ctrl-C
@pytest.mark.parametrize("delay_s", [0.6, 1.2, 2.0])
def test_ctrl_c_in_imports_first_seconds_exits_130_without_a_traceback(
    delay_s, csv_run, tmp_path
) -> None:
    """Through bin/flaair in a new process, as a person presses Ctrl-C while it starts."""
    bag = tmp_path / "bag"
    err, out = tmp_path / "err.txt", tmp_path / "out.txt"
    with open(err, "w") as stderr, open(out, "w") as stdout:
        process = subprocess.Popen(
            [FLAAIR, "import", str(csv_run), "--out", str(bag)],
            env=isolated_env(),
            cwd=REPO_ROOT,
            stdout=stdout,
            stderr=stderr,
            start_new_session=True,
        )
        time.sleep(delay_s)
        os.killpg(process.pid, signal.SIGINT)
        code = process.wait(timeout=60)
    text = err.read_text()
    # the import finished first (a fast machine): the Ctrl-C met the exit, the bag is whole
    if code == 0 or f"wrote {bag}" in out.read_text():
        return
    assert code in (130, -signal.SIGINT), text
    assert "Traceback" not in text and len(text.strip().splitlines()) <= 1, text
    assert not bag.exists()


# A command module whose import fails as a pybind11 module's does when Ctrl-C arrives during its
# initialisation (ImportError caused by the KeyboardInterrupt), or as a loader that raises its own
# ImportError while handling that one (rpyutils' wording), or for a reason that is no Ctrl-C.
_FAILING_IMPORTS = {
    "plain": (
        "try:\n    raise KeyboardInterrupt\n"
        "except KeyboardInterrupt as interrupt:\n"
        "    raise ImportError('initialization failed') from interrupt\n"
    ),
    "wrapped": (
        "try:\n    try:\n        raise KeyboardInterrupt\n"
        "    except KeyboardInterrupt as interrupt:\n"
        "        raise ImportError('initialization failed') from interrupt\n"
        "except ImportError:\n"
        '    raise ImportError("The C extension ... isn\'t present on the system")\n'
    ),
    "no_interrupt": "raise ImportError('libfoo.so: cannot open shared object file')\n",
}


def _command_failing_to_import(kind: str, tmp_path: Path, monkeypatch):
    from flaair_tools import cli

    module = f"flaair_test_failing_{kind}"
    (tmp_path / f"{module}.py").write_text(_FAILING_IMPORTS[kind])
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(cli.SUBCOMMANDS, "import", (module, "a command that cannot import"))
    return cli


@pytest.mark.parametrize("kind", ["plain", "wrapped"])
def test_ctrl_c_inside_a_compiled_modules_initialisation_is_an_interrupt(
    kind, tmp_path, monkeypatch, capsys
) -> None:
    """pybind11 turns a Ctrl-C during its module's init into ImportError caused by it."""
    cli = _command_failing_to_import(kind, tmp_path, monkeypatch)
    code = cli.main(["import", "run.csv", "--out", "bag"])
    err = capsys.readouterr().err
    assert code == 130, err
    assert "interrupted" in err and len(err.strip().splitlines()) == 1, err


def test_an_import_error_not_caused_by_ctrl_c_still_raises(tmp_path, monkeypatch) -> None:
    cli = _command_failing_to_import("no_interrupt", tmp_path, monkeypatch)
    with pytest.raises(ImportError, match="libfoo"):
        cli.main(["import", "run.csv"])


def test_experiment_with_an_invalid_model_file_is_one_line(config_copy, monkeypatch, capsys):
    from flaair_tools.orchestration import experiment

    (config_copy / "model.yaml").write_text("plant: [1, 2\n")
    monkeypatch.setenv("FLAAIR_CONFIG_DIR", str(config_copy))
    name = "characterization_chirp"
    code = experiment.main([name, "--out", str(config_copy.parent / "bag")])
    err = capsys.readouterr().err
    assert code == 2 and "model.yaml" in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize("name", ["$\\frac{a}{$", "run_\udcff\udcfe"])
def test_run_names_from_files_are_drawn_literally(name, tmp_path) -> None:
    from matplotlib.figure import Figure

    from flaair_sensors.figures import save_figure

    fig = Figure()
    ax = fig.subplots()
    ax.plot([1, 2], [1, 2], label=name)
    ax.set_title(f"{name}: sensor vs truth")
    ax.set_xscale("log")
    ax.legend()
    path = save_figure(fig, tmp_path / "f.png")
    assert path.stat().st_size > 1000


@pytest.mark.slow  # the analyze command draws its figures for each name
def test_analyze_draws_runs_named_like_mathtext_or_not_utf8(csv_run, tmp_path) -> None:
    from flaair_tools.bagio.import_runs import import_runs

    bags = []
    for k, name in enumerate(["$\\frac{a}{$", os.fsdecode(b"run_\xff")]):
        path = tmp_path / f"{name}.csv"
        shutil.copy(csv_run, path)
        bags.append(tmp_path / f"bag{k}")
        import_runs([path], bags[-1], gap_s=0.1, block_size=10, frame_id="robot")
    out = tmp_path / "report"
    args = ["analyze", *map(str, bags), "--out", str(out), "--allow-partial"]
    code, _, stderr = _offline(args)
    assert code == 0 and "Traceback" not in stderr, stderr[-3000:]
    assert (out / "report.html").exists() and len(list(out.glob("*.png"))) >= 2


@pytest.mark.timeout(30)
def test_literal_texts_keep_a_figures_line_breaks_and_replace_other_controls() -> None:
    # the code before the fix drew a figure's own two-line note as "noise?in any band"
    fig, ax = plt.subplots()
    note = ax.text(0.5, 0.5, "no model error above the noise\nin any band")
    title = ax.set_title("run\x07$x$")
    literal_texts(fig)
    assert note.get_text() == "no model error above the noise\nin any band"
    assert title.get_text() == "run?$x$" and not title.get_parse_math()
    plt.close(fig)
