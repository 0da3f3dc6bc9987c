"""`identify --table`: the plant fitted to a table the simulated robot makes, started from the
table's own peaks (a robot resonant at 190 Hz against the configured 140 Hz).
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from flaair_analysis.tables.datasets import simulated_table
from flaair_analysis.tables.fit import PITCH_KEYS, STROKE_KEYS, identify_table
from flaair_model import settings
from flaair_model.model_io import load_model
from flaair_tools.discrepancy.identify import main as identify_main
from flaair_tools.discrepancy.run_inputs import InputError, load_inputs, sort_inputs
from flaair_tools.tables.table_io import write_table

pytestmark = pytest.mark.timeout(240)

FREQS = np.linspace(100.0, 300.0, 20)


def far_robot():
    m = load_model()
    plant = replace(
        m.plant,
        stroke_natural_frequency_hz=190.0,
        aero_damping_nm_s2=5.0e-11,
        actuator_gain_nm_per_v=2.4e-7,
        pitch_natural_frequency_hz=250.0,
    )
    return m, replace(m, plant=plant)


def test_a_robot_far_from_nominal_is_recovered_within_a_few_per_cent() -> None:
    s = settings.tables()
    nominal, robot = far_robot()
    rng = np.random.default_rng(3)
    table = simulated_table(robot, [25.0, 45.0, 65.0], FREQS, s, rng, missing_pitch=0.3)
    fitted, fits, start, notes = identify_table(table, nominal, s)
    assert abs(start["stroke_natural_frequency_hz"] / 190.0 - 1) < 0.05  # from the peaks
    for key, tol in zip(
        STROKE_KEYS + PITCH_KEYS, (0.005, 0.05, 0.02, 0.01, 0.05, 0.05, 0.3), strict=True
    ):
        assert getattr(fitted.plant, key) == pytest.approx(getattr(robot.plant, key), rel=tol), key
    assert all(f.chi2 / f.n < 1.5 for f in fits)
    assert notes == []


@pytest.mark.slow  # two table fits
def test_one_level_fits_and_a_table_without_its_resonance_says_so() -> None:
    s = settings.tables()
    nominal, robot = far_robot()
    rng = np.random.default_rng(4)
    one = simulated_table(robot, [45.0], FREQS, s, rng, columns=("stroke_pp_deg",))
    fitted, _, _, notes = identify_table(one, nominal, s)
    assert fitted.plant.stroke_natural_frequency_hz == pytest.approx(190.0, rel=0.01)
    assert any("no pitch column" in n for n in notes)
    low = simulated_table(robot, [25.0, 65.0], np.linspace(60.0, 120.0, 8), s, rng)
    _, _, _, notes = identify_table(low, nominal, s)
    assert any("peaks inside its frequency range" in n for n in notes)
    assert any("no point near the resonance" in n for n in notes)


@pytest.mark.slow  # three identify commands and their refusals
def test_the_command_writes_model_and_identification_and_refuses_without_writing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    s = settings.tables()
    _, robot = far_robot()
    table = simulated_table(robot, [25.0, 65.0], FREQS[::2], s, np.random.default_rng(5))
    path = tmp_path / "robot.csv"
    write_table(table, path)
    out = tmp_path / "out"
    assert identify_main(["--table", str(path), "--out", str(out)]) == 0
    doc = json.loads((out / "identification.json").read_text())
    fn = doc["parameters"]["stroke_natural_frequency_hz"]
    assert fn["nominal"] == 140.0 and fn["value"] == pytest.approx(190.0, rel=0.01)
    assert load_model(out / "model.yaml").plant.stroke_natural_frequency_hz == fn["value"]
    # the table among the inputs is told from runs by its content: the same fit
    by_content = tmp_path / "by_content"
    assert identify_main([str(path), "--out", str(by_content)]) == 0
    again = json.loads((by_content / "identification.json").read_text())
    assert again["parameters"] == doc["parameters"]
    bad = tmp_path / "bad.csv"
    bad.write_text("drive_pp_v,frequency_hz,stroke_pp_deg\n120,150,3\n120,2000,4\n")
    nothing = tmp_path / "nothing"
    capsys.readouterr()
    assert identify_main(["--table", str(bad), "--out", str(nothing)]) == 2
    err = capsys.readouterr().err
    assert "line 3, column 'frequency_hz'" in err and err.count("\n") == 1
    assert not nothing.exists()
    # outputs are never inputs, and an existing output is replaced only with --force
    before = (out / "model.yaml").read_bytes()
    assert identify_main(["--table", str(path), "--out", str(out)]) == 2
    assert "model.yaml exists (--force replaces it)" in capsys.readouterr().err
    assert (out / "model.yaml").read_bytes() == before
    model_in = ["--model", str(out / "model.yaml")]
    assert identify_main(["--table", str(path), *model_in, "--out", str(out), "--force"]) == 2
    assert "would overwrite the input" in capsys.readouterr().err
    assert (out / "model.yaml").read_bytes() == before


def test_inputs_are_told_apart_by_their_content(tmp_path: Path) -> None:
    run = tmp_path / "chirp.csv"
    run.write_text(
        "time_s,drive_v,stroke_sensor_v,pitch_sensor_v,stroke_deg,pitch_deg\n0,0,0,0,,\n"
    )
    table = tmp_path / "sweep.csv"
    table.write_text("# robot: r3\n\ndrive_amplitude_v,frequency_hz,stroke_pp_deg\n30,100,20\n")
    named = tmp_path / "named.csv"
    named.write_text("anything\n")
    bag = tmp_path / "bag"
    bag.mkdir()
    missing = tmp_path / "missing.csv"
    sorted_inputs = sort_inputs([run, table, bag, missing], [named])
    assert sorted_inputs.runs == [run, bag, missing]
    assert sorted_inputs.tables == [table, named] and sorted_inputs.others == []
    with pytest.raises(InputError, match=r"missing\.csv: no such file"):
        load_inputs([missing])
