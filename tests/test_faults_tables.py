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

import pytest

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
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
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


@pytest.mark.timeout(60)
def test_dev_zero_as_a_table_is_refused_without_reading_it() -> None:
    result = _load_bounded(Path("/dev/zero"))
    assert result["error"] == "TableInputError", result
    assert "not a regular file" in result["message"], result


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
