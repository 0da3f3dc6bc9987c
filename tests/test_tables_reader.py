"""Frequency-response tables (docs/TABLES.md): reading, refusals by line and column, summary,
and `flaair import-table`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from flaair_analysis.tables import TableInputError, TableLimits, read_table, summarise
from flaair_tools.tables.import_cli import main as import_main

pytestmark = pytest.mark.timeout(60)

LIMITS = TableLimits(20.0, 1000.0, 150.0)
EXAMPLE = """# robot: bench_robot_3, clamped, 2 kHz video
drive_pp_v,frequency_hz,stroke_pp_deg,pitch_pp_deg
120,150,29.6,
120,180,43.6,74.5
80,180,30.1,50.0
80,150,20.0,
"""


def test_the_example_reads_in_si_names_with_levels_and_missing_cells() -> None:
    (t,) = read_table(EXAMPLE, "lab/robot3.csv", LIMITS)
    assert t.name == "robot3"
    np.testing.assert_array_equal(t.drive_amplitude_v, [40.0, 40.0, 60.0, 60.0])
    np.testing.assert_array_equal(t.frequency_hz, [150.0, 180.0, 150.0, 180.0])
    np.testing.assert_array_equal(t.levels_v, [40.0, 60.0])
    np.testing.assert_array_equal(t.level_index, [0, 0, 1, 1])
    np.testing.assert_array_equal(t.line, [6, 5, 3, 4])
    assert np.isnan(t.responses["pitch_pp_deg"][2])
    assert t.responses["pitch_pp_deg"][3] == 74.5
    assert t.comments == ("robot: bench_robot_3, clamped, 2 kHz video",)
    peaks = summarise(t)
    assert [(s.peak_frequency_hz, s.peak_value) for s in peaks] == [(180.0, 30.1), (180.0, 43.6)]


def test_robots_in_one_file_are_separate_tables_and_bias_is_read() -> None:
    text = "robot,frequency_hz,drive_amplitude_v,drive_bias_v,stroke_amplitude_deg\n"
    text += "a,100,50,10,12\nb,100,50,,13\na,120,50,10,15\n"
    a, b = read_table(text, "x.csv", LIMITS)
    assert (a.name, a.n_points, b.name, b.n_points) == ("a", 2, "b", 1)
    assert a.drive_bias_v.tolist() == [10.0, 10.0] and b.drive_bias_v.tolist() == [0.0]


@pytest.mark.parametrize(
    "text, message",
    [
        ("drive_pp_v,frequency_hz,stroke_pp_deg\n120,abc,3\n", "line 2, column 'frequency_hz'"),
        ("drive_pp_v,frequency_hz,stroke_pp_deg\n120,-5,3\n", "line 2, column 'frequency_hz'"),
        ("drive_pp_v,frequency_hz,stroke_pp_deg\n0,100,3\n", "line 2, column 'drive_pp_v'"),
        ("drive_pp_v,frequency_hz,stroke_pp_deg\n120,100,\n", "line 2: no response measured"),
        ("drive_pp_v,frequency_hz,stroke_pp_deg\n120,5000,3\n", "outside the plant's range"),
        ("drive_pp_v,frequency_hz,stroke_pp_deg\n400,100,3\n", "beyond the actuator's"),
        ("drive_v,frequency_hz,stroke_pp_deg\n120,100,3\n", "line 1, column 'drive_v'"),
        ("drive_pp_mv,frequency_hz,stroke_pp_deg\n1,100,3\n", "column 'drive_pp_mv'"),
        ("drive_pp_v,frequency_hz\n120,100\n", "line 1: no response column"),
        ("drive_pp_v,frequency_hz,stroke_pp_deg\n120,100,3,4\n", "line 2: 4 cells"),
        ("drive_pp_v,frequency_hz,stroke_pp_deg\n120,100,-3\n", "line 2, column 'stroke_pp_deg'"),
        (
            "drive_pp_v,frequency_hz,stroke_pp_deg\n120,100,3\n#x\n120,100,4\n",
            "line 4, column 'frequency_hz': this drive level and frequency are already on line 2",
        ),
        ("# nothing\n", "no header rows"),
    ],
)
def test_bad_tables_are_refused_by_line_and_column(text: str, message: str) -> None:
    with pytest.raises(TableInputError) as info:
        read_table(text, "t.csv", LIMITS)
    assert str(info.value).startswith("t.csv")
    assert message in str(info.value)


def test_import_table_prints_the_summary_and_refuses_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = tmp_path / "robot3.csv"
    good.write_text(EXAMPLE)
    assert import_main([str(good)]) == 0
    out = capsys.readouterr().out
    assert "robot3: 4 points, 2 drive level(s), 150-180 Hz" in out
    assert "stroke_pp_deg (4), pitch_pp_deg (2)" in out
    assert "drive 60 V amplitude: 2 points, 150-180 Hz, peak 43.6 (stroke_pp_deg) at 180 Hz" in out
    one = tmp_path / "one.csv"
    one.write_text("drive_pp_v,frequency_hz,stroke_pp_deg\n120,150,3\n")
    assert import_main([str(one)]) == 0
    assert "the effects search needs two or more" in capsys.readouterr().out
    bad = tmp_path / "bad.csv"
    bad.write_text("drive_pp_v,frequency_hz,stroke_pp_deg\n120,150,x\n")
    assert import_main([str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "line 2, column 'stroke_pp_deg'" in err
