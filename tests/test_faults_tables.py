"""Fault suite, issue 52: the frequency-response tables (`import-table`, `identify --table`,
`discrepancy --table` and the joint form).

Special and huge files, a byte-order mark and other separators, implausible cells, amplitudes
at 1e-199 deg, one drive level, fewer cells than parameters, phases of the opposite sign. Each
test fails on the code before the fix.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from flaair_analysis.discrepancy.evidence_search import plant_params
from flaair_analysis.tables.fit import STROKE_KEYS, fit_table
from flaair_analysis.tables.joint import identify_joint
from flaair_analysis.tables.joint_workflow import table_heldout
from flaair_analysis.tables.reader import TableInputError, TableLimits, read_table
from flaair_model import settings
from flaair_model.model_io import load_model
from flaair_tools.tables.table_io import load_tables
from rosproc import FLAAIR, REPO_ROOT, isolated_env, run_offline

pytestmark = pytest.mark.timeout(120)

# a table the configured robot makes (settings.tables() reading noise), two drive levels
GOOD = """drive_amplitude_v,drive_bias_v,frequency_hz,stroke_pp_deg,pitch_pp_deg
25,0,100,18.9559,6.8071
25,0,114.286,26.8585,13.3677
25,0,128.571,42.1199,29.0520
25,0,142.857,44.7299,40.8675
25,0,157.143,31.0960,35.2689
25,0,171.429,18.5036,26.7611
25,0,185.714,12.1945,20.2104
25,0,200,8.8298,15.5360
65,0,100,50.1046,18.1812
65,0,114.286,66.6178,34.5013
65,0,128.571,76.0843,53.7877
65,0,142.857,70.1933,69.8467
65,0,157.143,57.0457,69.8974
65,0,171.429,44.0877,62.2582
65,0,185.714,31.0378,49.6696
65,0,200,22.2791,40.6306
"""

# every command that reads a table; the joint forms read the table before the runs
COMMANDS = {
    "import-table": lambda t, out: ["import-table", str(t)],
    "identify": lambda t, out: ["identify", "--table", str(t), "--out", str(out)],
    "discrepancy": lambda t, out: ["discrepancy", "--table", str(t), "--out", str(out)],
    "joint identify": lambda t, out: ["identify", "run.csv", "--table", str(t), "--out", str(out)],
    "joint discrepancy": lambda t, out: [
        *("discrepancy", "run.csv", "--table", str(t), "--out", str(out)),
    ],
}


def flaair(*args: str):
    """`bin/flaair ARGS` (in this process, `run_offline`)."""
    return run_offline([FLAAIR, *args], isolated_env(), 120)


def one_line_refusal(result, *words: str) -> str:
    """The refusal's message: exit 2, one line, no traceback, naming each of `words`."""
    err = result.stderr.strip()
    assert result.returncode == 2, (result.returncode, result.stdout[-800:], err[-1500:])
    assert "Traceback" not in err and "\n" not in err, err
    for w in words:
        assert w in err, err
    return err


@pytest.mark.timeout(30)  # the code before the fix blocked in open() for ever
@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_a_fifo_as_a_table_is_refused_without_opening_it(command, tmp_path) -> None:
    fifo = tmp_path / "table.csv"
    os.mkfifo(fifo)  # nobody writes it
    result = flaair(*COMMANDS[command](fifo, tmp_path / "out"))
    one_line_refusal(result, "not a regular file")
    assert not (tmp_path / "out").exists()


def _load_bounded(path: Path) -> dict:
    """`load_tables([path])` in a child limited to 3 GiB of address space (the code before the
    fix read /dev/zero until it had none): its error, message and peak memory.
    """
    code = textwrap.dedent(
        f"""
        import json, resource
        resource.setrlimit(resource.RLIMIT_AS, ({3 << 30}, {3 << 30}))
        from flaair_tools.tables.table_io import load_tables
        try:
            load_tables([{str(path)!r}])
            error, message = None, ""
        except Exception as exc:
            error, message = type(exc).__name__, str(exc)
        # VmHWM: this process's own peak (ru_maxrss would carry the forking parent's)
        status = open("/proc/self/status").read().split("VmHWM:")[1]
        peak = int(status.split()[0])
        print(json.dumps(dict(error=error, message=message, peak_kib=peak)))
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=60,
        env=isolated_env(),
        cwd=REPO_ROOT,
    )
    assert done.returncode == 0, done.stderr[-1500:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.slow  # each table command in a new process
@pytest.mark.timeout(60)
def test_dev_zero_as_a_table_is_refused_without_reading_it() -> None:
    result = _load_bounded(Path("/dev/zero"))
    assert result["error"] == "TableInputError", result
    assert "not a regular file" in result["message"], result


@pytest.mark.slow  # writes a 20 MB table and runs the commands on it in new processes
@pytest.mark.timeout(60)
def test_a_20_mb_table_is_refused_by_its_size_before_it_is_read(tmp_path) -> None:
    rows = [f"{1 + k * 1e-6:.6f},0,150,40.0,30.0" for k in range(820_000)]  # 20 MB, all distinct
    table = tmp_path / "huge.csv"
    table.write_text(GOOD.splitlines()[0] + "\n" + "\n".join(rows) + "\n", encoding="utf-8")
    assert table.stat().st_size > 20_000_000
    result = _load_bounded(table)
    assert result["error"] == "TableInputError", result
    assert "bytes, more than a table file may have" in result["message"], result
    assert result["peak_kib"] < 400 << 10, result  # the code before the fix took 650 MB


def test_a_table_with_a_byte_order_mark_reads_as_without_one(tmp_path) -> None:
    table = tmp_path / "bom.csv"
    table.write_text("\ufeff# robot A, clamped\n" + GOOD, encoding="utf-8")
    result = flaair("import-table", str(table))
    assert result.returncode == 0, result.stderr
    assert "bom: 16 points, 2 drive level(s), 100-200 Hz" in result.stdout


@pytest.mark.parametrize(("sep", "named"), [(";", "semicolons"), ("\t", "tabs")])
def test_semicolon_and_tab_separated_tables_are_named_by_their_separator(
    sep, named, tmp_path
) -> None:
    table = tmp_path / "sep.csv"
    table.write_text(GOOD.replace(",", sep), encoding="utf-8")
    one_line_refusal(flaair("import-table", str(table)), "line 1", named, "commas")


def _with_cell(column: str, value: str) -> str:
    """GOOD with line 4's `column` (pitch_pp_deg, or a stroke_phase_deg added) set to `value`."""
    lines = GOOD.splitlines()
    if column == "stroke_phase_deg":
        lines = [lines[0] + ",stroke_phase_deg", *(ln + ",-20" for ln in lines[1:])]
    cells = lines[3].split(",")
    cells[lines[0].split(",").index(column)] = value
    lines[3] = ",".join(cells)
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    ("column", "value"),
    [("pitch_pp_deg", "3081"), ("pitch_pp_deg", "1e300"), ("stroke_phase_deg", "-1e300")],
)
def test_an_implausible_cell_is_refused_by_line_and_column(column, value, tmp_path) -> None:
    table = tmp_path / "typo.csv"
    table.write_text(_with_cell(column, value), encoding="utf-8")
    for command in ("import-table", "discrepancy"):
        result = flaair(*COMMANDS[command](table, tmp_path / "out"))
        one_line_refusal(result, "line 4", repr(column), value, "plausible")
    assert not (tmp_path / "out").exists()


def _scaled(factor: float) -> str:
    """GOOD with every amplitude multiplied by `factor` (the shape kept: peaks inside)."""
    lines = GOOD.splitlines()
    out = [lines[0]]
    for line in lines[1:]:
        c = line.split(",")
        c[3], c[4] = (f"{float(v) * factor:.4e}" for v in c[3:5])
        out.append(",".join(c))
    return "\n".join(out) + "\n"


@pytest.mark.parametrize("command", ["identify", "discrepancy"])
def test_amplitudes_near_1e_minus_199_deg_are_refused_in_one_line(command, tmp_path) -> None:
    table = tmp_path / "tiny.csv"
    table.write_text(_scaled(1e-200), encoding="utf-8")
    assert "7.6084e-199" in table.read_text()  # the 65 V peak, 76.08 deg x 1e-200
    result = flaair(*COMMANDS[command](table, tmp_path / "out"))
    one_line_refusal(result, "below the reading noise", "7.61e-199 deg", "no stroke motion")
    assert "lower bound" not in result.stderr
    assert not (tmp_path / "out").exists()


def test_the_joint_fit_refuses_a_table_of_amplitudes_near_1e_minus_199_deg(tmp_path) -> None:

    table = tmp_path / "tiny.csv"
    table.write_text(_scaled(1e-200), encoding="utf-8")
    (tab,) = load_tables([table])
    # the joint fit starts from the table fitted alone: the refusal comes before any run is used
    with pytest.raises(TableInputError, match="below the reading noise"):
        identify_joint([], tab, load_model(), {}, settings.tables())


def test_one_drive_level_does_not_claim_held_out_levels(tmp_path) -> None:
    table = tmp_path / "one.csv"
    table.write_text("\n".join(GOOD.splitlines()[:9]) + "\n", encoding="utf-8")  # 25 V only
    out = tmp_path / "out"
    result = flaair(*COMMANDS["discrepancy"](table, out))
    assert result.returncode == 0, result.stderr
    assert "held-out drive levels to noise" not in result.stdout
    assert "no level could be held out" in result.stdout
    assert "search did not run" in result.stdout
    doc = json.loads((out / "discrepancy.json").read_text())
    assert doc["searched"] is False
    assert "no level could be held out" in doc["summary"]


def test_the_joint_forms_check_of_a_one_level_table_is_said_to_be_in_sample(tmp_path) -> None:
    table = tmp_path / "one.csv"
    table.write_text("\n".join(GOOD.splitlines()[:9]) + "\n", encoding="utf-8")  # 25 V only
    (tab,) = load_tables([table])
    check = table_heldout(tab, load_model(), settings.tables())
    assert check.held_out is False and check.as_dict()["held_out"] is False
    assert check.kind == "in sample: one drive level, nothing held out"
    assert "held-out" not in check.kind


def test_fewer_cells_than_parameters_are_refused(tmp_path) -> None:
    table = tmp_path / "two.csv"
    table.write_text("drive_amplitude_v,frequency_hz,stroke_pp_deg\n25,130,40\n25,150,35\n")
    result = flaair(*COMMANDS["identify"](table, tmp_path / "out"))
    one_line_refusal(result, "2 measured stroke cell(s) for the 3 stroke parameters")
    assert not (tmp_path / "out").exists()


def test_a_singular_fit_is_flagged_not_given_a_made_up_correlation() -> None:

    (table,) = read_table(
        "drive_amplitude_v,frequency_hz,stroke_pp_deg\n25,130,40\n25,150,35\n",
        "two.csv",
        TableLimits(20.0, 1000.0, 150.0),
    )
    model, s = load_model(), settings.tables()
    fit = fit_table(table, model, plant_params(model, STROKE_KEYS, {}, 3.0), s, ["stroke_pp_deg"])
    assert fit.singular  # 2 cells, 3 parameters
    assert all(v == np.inf for v in fit.stderr.values())
    assert not np.isfinite(fit.correlation).any()  # before: diagonal -1.0, entries +1.543


@pytest.mark.slow  # three fits (identify twice, discrepancy once): ~10 s on a quiet machine
def test_phases_of_the_opposite_sign_are_warned_and_named(tmp_path) -> None:
    # the configured robot's stroke phases (negative = lag), written with the opposite sign
    rows = [
        (25, 100, 18.9559, -8.1251),
        (25, 120, 32.2061, -17.9682),
        (25, 140, 45.4787, -89.9327),
        (25, 160, 27.6314, -157.2472),
        (25, 180, 14.8330, -170.8472),
        (25, 200, 9.1437, -178.8373),
        (65, 100, 48.7625, -15.0855),
        (65, 120, 69.2695, -43.3869),
        (65, 140, 74.9436, -92.9959),
        (65, 160, 56.8267, -131.8033),
        (65, 180, 35.2415, -158.2460),
        (65, 200, 22.5550, -170.0456),
    ]
    header = "drive_amplitude_v,frequency_hz,stroke_pp_deg,stroke_phase_deg\n"
    right, flipped = tmp_path / "right.csv", tmp_path / "flipped.csv"
    right.write_text(header + "".join(f"{a},{f},{p},{ph}\n" for a, f, p, ph in rows))
    flipped.write_text(header + "".join(f"{a},{f},{p},{-ph}\n" for a, f, p, ph in rows))
    result = flaair(*COMMANDS["identify"](right, tmp_path / "right"))
    assert result.returncode == 0 and "warning" not in result.stderr, result.stderr
    for command in ("identify", "discrepancy"):
        result = flaair(*COMMANDS[command](flipped, tmp_path / command))
        assert result.returncode == 0, result.stderr
        warned = [ln for ln in result.stderr.splitlines() if "stroke_phase_deg" in ln]
        assert warned and "warning" in warned[0], result.stderr
        assert "x the reading noise" in warned[0]
        assert "lags with the opposite sign" in warned[0]
