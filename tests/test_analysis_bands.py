"""The analysis bands come from config once; calibrate, analyze and the cores agree on them."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from flaair_model.config import config_dir
from flaair_model.schema import ParameterError
from flaair_sensors.analysis_io import AnalysisBands, analysis_bands_from_config
from rosproc import FLAAIR, isolated_env, run_offline


def test_bands_are_the_config_values_and_bad_ones_are_named() -> None:
    section = yaml.safe_load((config_dir() / "flaair.yaml").read_text())["analyze"][
        "ros__parameters"
    ]
    bands = analysis_bands_from_config()
    assert bands == AnalysisBands(
        tuple(section["amplitude_band_hz"]), tuple(section["time_band_hz"])
    )
    assert analysis_bands_from_config(
        {"amplitude_band_hz": [110, 190.5], "time_band_hz": [100.0, 190.0]}
    ) == AnalysisBands((110.0, 190.5), (100.0, 190.0))
    assert AnalysisBands((110.0, 190.0), (100.0, 190.5)).label("time_band_hz") == "100-190.5 Hz"
    for bad, match in (
        ({"time_band_hz": [1.0, 2.0]}, "analyze.amplitude_band_hz: missing"),
        (
            {"amplitude_band_hz": [190.0, 110.0], "time_band_hz": [1.0, 2.0]},
            "amplitude_band_hz: must satisfy",
        ),
        (
            {"amplitude_band_hz": [1.0, 2.0], "time_band_hz": "100-190"},
            r"time_band_hz: must be \[low, high\]",
        ),
        ({"amplitude_band_hz": [1.0, float("nan")], "time_band_hz": [1.0, 2.0]}, "must satisfy"),
    ):
        with pytest.raises(ParameterError, match=match):
            analysis_bands_from_config(bad)


def test_cores_take_the_bands_as_required_arguments() -> None:
    from flaair_sensors.core import calibration, characterization

    with pytest.raises(TypeError, match="amplitude_band_hz"):
        calibration.calibrate({}, 1.25)
    with pytest.raises(TypeError, match="amplitude_band_hz"):
        characterization.characterize_run({}, None, "chirp")


def test_calibrate_cli_band_defaults_to_config_and_reaches_the_output(tmp_path: Path) -> None:
    """Without --band-hz the calibration's band is the configured one; --band-hz overrides it."""
    from flaair_common.runcsv import write_run
    from flaair_model.model_io import load_model
    from flaair_sim.core.drive import DriveParams, drive_record
    from flaair_sim.core.measured_run import synthesize_measured_run

    fs = 20000.0
    drive = drive_record(
        DriveParams(kind="chirp", amplitude_v=100.0, start_hz=20.0, stop_hz=200.0, duration_s=1.0),
        fs,
        20000,
    )
    write_run(
        tmp_path / "run.csv",
        synthesize_measured_run(drive, fs, load_model(), np.random.default_rng(3)),
    )
    imported = run_offline(
        [FLAAIR, "import", str(tmp_path / "run.csv"), "--out", str(tmp_path / "bag")],
        isolated_env(),
        120,
    )
    assert imported.returncode == 0, imported.stderr
    configured = list(analysis_bands_from_config().amplitude_band_hz)
    for extra, expected in (([], configured), (["--band-hz", "120", "170"], [120.0, 170.0])):
        out = tmp_path / f"cal{len(extra)}"
        done = run_offline(
            [FLAAIR, "calibrate", str(tmp_path / "bag"), "--out", str(out), *extra],
            isolated_env(),
            120,
        )
        assert done.returncode == 0, done.stderr
        result = json.loads((out / "calibration.json").read_text())
        assert (
            result["stroke"]["amplitude_band_hz"]
            == result["runs"][0]["pitch"]["amplitude_band_hz"]
            == expected
        )


def test_hilbert_settings_come_from_the_analyze_section() -> None:
    from flaair_control.core.transition import HilbertParams
    from flaair_control.transition_io import hilbert_params_from_config

    section = yaml.safe_load((config_dir() / "flaair.yaml").read_text())["analyze"][
        "ros__parameters"
    ]
    assert hilbert_params_from_config() == HilbertParams(
        band_hz=tuple(section["hilbert_band_hz"]),
        band_order=section["hilbert_band_order"],
        savgol_window_s=section["hilbert_savgol_window_s"],
        savgol_order=section["hilbert_savgol_order"],
        edge_s=section["hilbert_edge_s"],
    )
    with pytest.raises(ParameterError, match="analyze: missing hilbert_edge_s"):
        hilbert_params_from_config({k: v for k, v in section.items() if k != "hilbert_edge_s"})
    with pytest.raises(ParameterError, match="analyze: savgol_order must be >= 0"):
        hilbert_params_from_config({**section, "hilbert_savgol_order": -1})
    with pytest.raises(ParameterError, match=re.escape("analyze.hilbert_band_hz: must satisfy")):
        hilbert_params_from_config({**section, "hilbert_band_hz": [400.0, 40.0]})
