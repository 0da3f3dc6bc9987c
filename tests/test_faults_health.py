"""Fault suite, issue 52: `health` and its calibration.

A calibration with a NaN, zero or overflowing gain, a wrong polarity, a lag of 1e300 or inf
(refused by its field, in the CLI and in the reader the live health node uses); a run logged at
10 kHz whose baseline could not be learned (said, and the scatter right at 10 kHz so the loss is
found); a chirp (outside what the monitor judges: said, no events). Each test fails on the code
before the fix.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import health_sim as hs
from flaair_common.runcsv import write_run
from flaair_control.core import health as H
from flaair_control.health_io import film_calibration, health_params_from_config
from flaair_model.model import with_effects
from flaair_model.model_io import load_model
from flaair_model.schema import ParameterError
from rosproc import FLAAIR, REPO_ROOT, isolated_env, run_offline

pytestmark = pytest.mark.timeout(120)

GOOD_CALIBRATION = {
    "stroke": {"gain_deg_per_v": 25.0, "polarity": 1, "lag_s": 0.00025},
    "pitch": {"gain_deg_per_v": 40.0, "polarity": -1, "lag_s": 0.0},
}

# (channel, field, value written in the YAML) -> the field the refusal names
BAD_FIELDS = [
    ("stroke", "gain_deg_per_v", ".nan"),
    ("pitch", "gain_deg_per_v", "0"),
    ("stroke", "gain_deg_per_v", "1e-320"),  # 1 / radians(gain) overflows to inf V/rad
    ("pitch", "polarity", "2"),
    ("stroke", "polarity", "0"),
    ("stroke", "lag_s", "1e300"),
    ("pitch", "lag_s", ".inf"),
    ("pitch", "lag_s", ".nan"),
]


def _calibration(path: Path, channel: str = "", field: str = "", value: str = "") -> Path:
    lines = []
    for c, fields in GOOD_CALIBRATION.items():
        cells = {k: str(v) for k, v in fields.items()}
        if c == channel:
            cells[field] = value
        lines.append(f"{c}: {{{', '.join(f'{k}: {v}' for k, v in cells.items())}}}")
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_sound_calibration_gives_lags_and_gains(tmp_path) -> None:
    got = film_calibration(_calibration(tmp_path / "cal.yaml"))
    assert got["stroke_film_delay_s"] == 0.00025 and got["pitch_film_delay_s"] == 0.0
    assert got["pitch_volts_per_rad"] < 0 < got["stroke_volts_per_rad"]


@pytest.mark.parametrize(("channel", "field", "value"), BAD_FIELDS)
def test_a_bad_calibration_value_is_refused_by_its_field(channel, field, value, tmp_path) -> None:
    cal = _calibration(tmp_path / "cal.yaml", channel, field, value)
    with pytest.raises(ParameterError, match=rf"{channel}\.{field}") as info:
        film_calibration(cal)  # what the live health node is given
    assert "\n" not in str(info.value) and "division" not in str(info.value)


@pytest.mark.parametrize(("channel", "field", "value"), BAD_FIELDS[:2] + BAD_FIELDS[5:6])
def test_health_refuses_a_bad_calibration_in_one_line(channel, field, value, tmp_path) -> None:
    cal = _calibration(tmp_path / "cal.yaml", channel, field, value)
    bag = tmp_path / "run.mcap"  # never read: the calibration is refused first
    bag.write_bytes(b"")
    out = tmp_path / "out"
    result = run_offline(
        [FLAAIR, "health", str(bag), "--out", str(out), "--calibration", str(cal)],
        isolated_env(),
    )
    err = result.stderr.strip()
    assert result.returncode == 2, (result.stdout, err)
    assert f"{channel}.{field}" in err and "\n" not in err and "Traceback" not in err, err
    assert not out.exists()


def _at(fs_hz: float, monkeypatch, model, *args, **kwargs):
    """health_sim's run logged at `fs_hz` (the plant, the loop and the log at that rate)."""
    monkeypatch.setattr(hs, "FS", fs_hz)
    return hs.run(model, *args, **kwargs)


@pytest.mark.parametrize("seed", [7, 8])
def test_an_inertia_loss_under_the_dsa_loop_at_10_khz_is_found(seed, monkeypatch) -> None:
    model = load_model()
    damaged = with_effects(model, {"wing_damage": {"inertia_factor": 0.8}})
    vs, vp, dv = _at(10_000.0, monkeypatch, model, 2.4, damaged, 2.0, seed=seed)
    params = replace(health_params_from_config(model=model), sample_rate_hz=10_000.0)
    _, out = H.step(H.initial_state(params), H.HealthInputs(vs, vp, dv), params)
    baselines = [n.text for n in out.notes if n.text.startswith("health baseline: ")]
    first = float(baselines[0].split("wing_inertia ")[1].split(",")[0])
    assert first == pytest.approx(1.0, abs=0.01)  # learned before the damage (before: 0.805)
    assert [e.parameter for e in out.events] == ["wing_inertia"]  # before: no event
    assert out.events[0].ratio == pytest.approx(0.8, abs=0.01)
    assert 2.0 < out.events[0].time_s < 2.15


def _import_csv(tmp_path: Path, name: str, vs, vp, dv, fs_hz: float) -> Path:
    n = vs.size
    nan = np.full(n, np.nan)
    columns = {"time_s": np.arange(n) / fs_hz, "drive_v": dv, "stroke_sensor_v": vs}
    columns |= {"pitch_sensor_v": vp, "stroke_deg": nan, "pitch_deg": nan.copy()}
    write_run(tmp_path / f"{name}.csv", columns)
    bag = tmp_path / name
    result = run_offline(
        [FLAAIR, "import", str(tmp_path / f"{name}.csv"), "--out", str(bag)], isolated_env()
    )
    assert result.returncode == 0, result.stderr
    return bag


def test_a_run_with_estimates_but_no_baseline_says_so(monkeypatch, tmp_path) -> None:
    model = load_model()
    # 0.4 s of a 140 Hz sine: 56 estimated wingbeats, fewer than warm-up + baseline (70)
    bag = _import_csv(
        tmp_path, "short", *_at(10_000.0, monkeypatch, model, 0.4, sine=(40.0, 140.0)), 10_000.0
    )
    result = run_offline(
        [FLAAIR, "health", str(bag), "--out", str(tmp_path / "out")], isolated_env()
    )
    assert result.returncode == 0, result.stderr
    assert "(0 event(s))" in result.stdout
    assert "no baseline could be learned" in result.stderr, result.stderr  # before: nothing said
    doc = json.loads((tmp_path / "out" / "health.json").read_text())
    assert doc["bags"][0]["estimated"] > 40 and "no baseline" in doc["bags"][0]["note"]


@pytest.mark.timeout(300)
def test_a_chirp_is_said_to_be_outside_what_the_monitor_judges(tmp_path) -> None:
    lab = REPO_ROOT / "examples" / "lab_session"
    bag = tmp_path / "run01"
    imported = run_offline(
        [
            FLAAIR,
            "import",
            str(lab / "run01.mat"),
            "--rig",
            str(lab / "bench_rig.yaml"),
            "--tracks",
            str(lab / "run01_xyzpts.csv"),
            "--tip-track",
            str(lab / "run01_xypts.csv"),
            "--out",
            str(bag),
        ],
        isolated_env(),
        300,
    )
    assert imported.returncode == 0, imported.stderr
    result = run_offline(
        [FLAAIR, "health", str(bag), "--out", str(tmp_path / "out")], isolated_env()
    )
    assert result.returncode == 0, result.stderr
    doc = json.loads((tmp_path / "out" / "health.json").read_text())
    assert doc["events"] == []  # before: actuator_gain x0.893, x0.956, x0.926 on an undamaged robot
    assert "the drive frequency sweeps" in result.stderr
    assert "outside what the monitor can judge" in result.stderr
