"""`bin/flaair calibrate` on bags imported from lab
CSVs: fitted gains are the model's; files load.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rosproc import FLAAIR, isolated_env, run, run_offline
from tuning import FRONTEND_TUNING

FS_HZ = 20000.0


def _lab_csv(path: Path, model, seed: int, amplitude_v: float = 100.0) -> None:
    from flaair_common.runcsv import write_run
    from flaair_sim.core.drive import DriveParams, drive_record
    from flaair_sim.core.measured_run import synthesize_measured_run

    drive = drive_record(
        DriveParams(
            kind="chirp", amplitude_v=amplitude_v, start_hz=20.0, stop_hz=200.0, duration_s=1.0
        ),
        FS_HZ,
        20000,
    )
    columns = synthesize_measured_run(drive, FS_HZ, model, np.random.default_rng(seed))
    columns["pitch_deg"][5000:6000] = np.nan  # the video lost the wing for 50 ms
    write_run(path, columns)


@pytest.fixture(scope="module")
def imported_bag(tmp_path_factory) -> Path:
    from flaair_model.model import with_effects
    from flaair_model.model_io import load_model

    tmp = tmp_path_factory.mktemp("cal")
    model = with_effects(
        load_model(),
        {
            "strain_transfer_loss": {"efficiency": 0.5, "channel": "pitch"},
            "sensor_delay": {"delay_s": 2e-4, "channel": "stroke"},
        },
    )
    _lab_csv(tmp / "run_full.csv", model, 1)
    _lab_csv(tmp / "run_half.csv", model, 2, amplitude_v=50.0)
    result = run_offline(
        [
            FLAAIR,
            "import",
            str(tmp / "run_full.csv"),
            str(tmp / "run_half.csv"),
            "--out",
            str(tmp / "bag"),
        ],
        isolated_env(),
        120,
    )
    assert result.returncode == 0, result.stderr
    return tmp / "bag"


def test_calibrate_recovers_hidden_gain_and_lag(imported_bag: Path, tmp_path: Path) -> None:
    result = run_offline(
        [FLAAIR, "calibrate", str(imported_bag), "--out", str(tmp_path / "cal")],
        isolated_env(),
        120,
    )
    assert result.returncode == 0, result.stderr
    cal = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    assert cal["stroke"]["gain_deg_per_v"] == pytest.approx(25.39, rel=0.01)
    # efficiency 0.5 hidden
    assert cal["pitch"]["gain_deg_per_v"] == pytest.approx(2 * 24.87, rel=0.01)
    assert cal["stroke"]["lag_s"] == pytest.approx(2e-4, rel=0.05)
    assert abs(cal["pitch"]["lag_s"]) < 1e-5
    for channel in ("stroke", "pitch"):
        for key in ("amplitude_rmse_deg", "phase_rmse_deg", "amplitude_rmse_band_deg"):
            assert np.isfinite(cal[channel][key])
    assert len(cal["runs"]) == 2


def test_calibration_yaml_loads_into_the_front_end(imported_bag: Path, tmp_path: Path) -> None:
    from flaair_model.config import load_yaml
    from flaair_sensors.core.frontend_params import params_from_calibration

    assert (
        run_offline(
            [FLAAIR, "calibrate", str(imported_bag), "--out", str(tmp_path)], isolated_env(), 120
        ).returncode
        == 0
    )
    params = params_from_calibration(
        load_yaml(tmp_path / "calibration.yaml"), FS_HZ, **FRONTEND_TUNING
    )
    assert abs(np.degrees(1 / params.pitch_volts_per_rad)) == pytest.approx(2 * 24.87, rel=0.01)


@pytest.mark.slow  # writes and calibrates bags missing each topic
def test_calibrate_names_missing_topic(tmp_path: Path) -> None:
    from flaair_tools import bagio

    with bagio.BagWriter(tmp_path / "empty"):  # a bag with only a run marker
        pass
    # through bin/flaair in a new process, as a person runs it (other tests: run_offline)
    result = run(
        [FLAAIR, "calibrate", str(tmp_path / "empty"), "--out", str(tmp_path / "o")], isolated_env()
    )
    assert (
        result.returncode == 2
        and "/flaair/sensor_v" in result.stderr
        and "Traceback" not in result.stderr
    )
