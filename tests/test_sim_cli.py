"""`bin/flaair simulate`: a lab's recorded drive in, the measured-run format out."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from rosproc import FLAAIR, isolated_env, run, run_offline


def _write_drive_csv(path: Path, fs_hz: float, n: int) -> np.ndarray:
    t = np.arange(n) / fs_hz
    drive = 100.0 * np.sin(2 * np.pi * 140.0 * t)
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["drive_v", "time_s", "stroke_deg"])  # other order, truth column empty
        for k in range(n):
            writer.writerow([f"{drive[k]:.17g}", f"{t[k]:.17g}", ""])
    return drive


@pytest.mark.slow  # the simulate command through bin/flaair
def test_simulate_replays_drive_and_matches_the_core(tmp_path: Path) -> None:
    from flaair_model.model_io import load_model
    from flaair_sim.core.plant import simulate

    drive = _write_drive_csv(tmp_path / "in.csv", 20000.0, 4000)
    # through bin/flaair in a new process, as a person runs it (other tests: run_offline)
    result = run(
        [FLAAIR, "simulate", str(tmp_path / "in.csv"), "--out", str(tmp_path / "out.csv")],
        isolated_env(),
    )
    assert result.returncode == 0, result.stderr
    with open(tmp_path / "out.csv", newline="") as handle:  # independent reader: csv module
        rows = list(csv.DictReader(handle))
    assert list(rows[0]) == [
        "time_s",
        "drive_v",
        "stroke_sensor_v",
        "pitch_sensor_v",
        "stroke_deg",
        "pitch_deg",
    ]
    stroke_deg = np.array([float(r["stroke_deg"]) for r in rows])
    expected = np.degrees(simulate(drive, 20000.0, load_model()).stroke_rad)
    assert np.allclose(stroke_deg, expected, rtol=1e-7, atol=1e-7)
    assert np.max(np.abs(stroke_deg)) > 20.0  # near resonance at 200 Vpp: a large stroke


def test_simulate_refuses_malformed_input_naming_line_and_column(tmp_path: Path) -> None:
    (tmp_path / "bad.csv").write_text("time_s,drive_v\n0,1.0\n5e-05,abc\n")
    result = run_offline(
        [FLAAIR, "simulate", str(tmp_path / "bad.csv"), "--out", str(tmp_path / "o.csv")],
        isolated_env(),
    )
    assert result.returncode == 2
    assert "bad.csv: line 3, column drive_v" in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "o.csv").exists()


def test_simulate_refuses_unknown_effect_in_model(tmp_path: Path) -> None:
    _write_drive_csv(tmp_path / "in.csv", 20000.0, 10)
    model = Path(__file__).resolve().parents[1] / "config" / "model.yaml"
    (tmp_path / "m.yaml").write_text(
        model.read_text().replace("effects: {}", "effects:\n  warp_drive: {factor: 2}")
    )
    result = run_offline(
        [
            FLAAIR,
            "simulate",
            str(tmp_path / "in.csv"),
            "--model",
            str(tmp_path / "m.yaml"),
            "--out",
            str(tmp_path / "o.csv"),
        ],
        isolated_env(),
    )
    assert result.returncode == 2 and "warp_drive" in result.stderr, result.stderr
