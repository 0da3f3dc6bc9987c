"""`bin/flaair health` on bags imported from simulated runs: events, series, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import health_sim as hs
from rosproc import FLAAIR, isolated_env, run, run_offline


def _csv(path: Path, vs, vp, dv) -> None:
    from flaair_common.runcsv import write_run

    n = vs.size
    nan = np.full(n, np.nan)
    write_run(
        path,
        {
            "time_s": np.arange(n) / hs.FS,
            "drive_v": dv,
            "stroke_sensor_v": vs,
            "pitch_sensor_v": vp,
            "stroke_deg": nan,
            "pitch_deg": nan.copy(),
        },
    )


def _import(tmp: Path, csv: Path, name: str) -> Path:
    result = run_offline([FLAAIR, "import", str(csv), "--out", str(tmp / name)], isolated_env())
    assert result.returncode == 0, result.stderr
    return tmp / name


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> tuple[Path, Path]:
    from flaair_model.model import with_effects
    from flaair_model.model_io import load_model

    tmp = tmp_path_factory.mktemp("health")
    model = load_model()
    damaged = with_effects(model, {"wing_damage": {"inertia_factor": 0.8}})
    _csv(tmp / "damaged.csv", *hs.run(model, 3.0, damaged, 2.0))
    n = int(0.3 * hs.FS)
    vref = model.sensors.reference_voltage_v
    quiet = vref + 0.002 * np.random.default_rng(3).standard_normal(n)
    _csv(tmp / "quiet.csv", quiet, quiet.copy(), np.zeros(n))
    return _import(tmp, tmp / "damaged.csv", "damaged"), _import(tmp, tmp / "quiet.csv", "quiet")


@pytest.mark.slow  # records a damaged robot's bag, then runs the health command on it
def test_health_reports_the_damage_with_its_series(bags, tmp_path: Path) -> None:
    damaged, quiet = bags
    out = tmp_path / "out"
    result = run_offline(
        [FLAAIR, "health", str(damaged), str(quiet), "--out", str(out)], isolated_env()
    )
    assert result.returncode == 0, result.stderr
    doc = json.loads((out / "health.json").read_text())  # strict: no NaN
    assert [e["parameter"] for e in doc["events"]] == ["wing_inertia"]
    ev = doc["events"][0]
    assert ev["ratio"] == pytest.approx(0.8, abs=0.04)
    assert 2.0 < ev["time_s"] < 2.0 + 20 / 170.0
    assert ev["sample_index"] == round(ev["time_s"] * hs.FS)
    series = doc["bags"][0]["wingbeats"]
    assert len(series["wing_inertia"]) == len(series["time_s"]) > 300
    assert doc["bags"][1]["estimated"] == 0 and "too quiet" in doc["bags"][1]["note"]
    assert "too quiet" in result.stderr
    assert (out / "health.png").stat().st_size > 10000
    # an existing output is replaced only with --force, and a bag is never an output
    before = (out / "health.json").read_bytes()
    again = run_offline([FLAAIR, "health", str(damaged), "--out", str(out)], isolated_env())
    assert again.returncode == 2 and "health.json exists (--force replaces it)" in again.stderr
    assert (out / "health.json").read_bytes() == before
    into = run_offline([FLAAIR, "health", str(damaged), "--out", str(damaged)], isolated_env())
    assert into.returncode == 2 and "--out" in into.stderr and "Traceback" not in into.stderr


@pytest.mark.slow  # writes bags missing each topic and runs the command on each
def test_bag_without_the_films_or_the_drive_is_refused_by_name(tmp_path: Path) -> None:
    from flaair_tools import bagio

    with bagio.BagWriter(tmp_path / "empty"):
        pass
    # through bin/flaair in a new process, as a person runs it (the other test: run_offline)
    result = run(
        [FLAAIR, "health", str(tmp_path / "empty"), "--out", str(tmp_path / "o")], isolated_env()
    )
    assert result.returncode == 2
    assert "/flaair/sensor_v" in result.stderr and "/flaair/drive" in result.stderr
    assert "Traceback" not in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_film_gains_are_ratios_to_a_given_calibration(bags, tmp_path: Path) -> None:
    from flaair_model.model_io import load_model

    model = load_model()
    cal = tmp_path / "calibration.yaml"
    cal.write_text(
        f"stroke: {{gain_deg_per_v: {model.stroke_gain_deg_per_v}, polarity: "
        f"{model.stroke_polarity}, lag_s: 0.0}}\n"
        f"pitch: {{gain_deg_per_v: {2 * model.pitch_gain_deg_per_v}, polarity: "
        f"{model.pitch_polarity}, lag_s: 0.0}}\n"
    )
    out = tmp_path / "out"
    args = [FLAAIR, "health", str(bags[0]), "--out", str(out), "--calibration", str(cal)]
    result = run_offline(args, isolated_env())
    assert result.returncode == 0, result.stderr
    doc = json.loads((out / "health.json").read_text())
    series = doc["bags"][0]["wingbeats"]
    t = np.array(series["time_s"])
    pitch = np.array([np.nan if v is None else v for v in series["pitch_film_gain"]])
    stroke = np.array([np.nan if v is None else v for v in series["stroke_film_gain"]])
    # the calibration says the pitch film gives half the volts per radian the model's does
    assert np.nanmean(pitch[(t > 1.5) & (t < 2.0)]) == pytest.approx(2.0, abs=0.02)
    assert np.nanmean(stroke[(t > 1.5) & (t < 2.0)]) == pytest.approx(1.0, abs=0.01)
    assert [e["parameter"] for e in doc["events"]] == ["wing_inertia"]
    cal.write_text("stroke: {gain_deg_per_v: 25.0}\n")
    bad_args = [FLAAIR, "health", str(bags[0]), "--out", str(tmp_path / "o2"), "--calibration"]
    bad = run_offline([*bad_args, str(cal)], isolated_env())
    assert bad.returncode == 2 and "lag_s" in bad.stderr


@pytest.mark.slow  # imports two ramped runs, then runs the command four times
def test_a_saved_baseline_is_judged_against_from_the_first_wingbeat(tmp_path: Path) -> None:
    """A healthy run's health.json carries its baseline; given with --baseline, a 5 % inertia
    loss during the configured K_r ramp (learned into the run's own baseline otherwise) is
    reported. A baseline file that is not one healthy run's, or was learned against another
    calibration, is refused in one line before a bag is read.
    """
    from flaair_model.model import with_effects
    from flaair_model.model_io import load_model

    model = load_model()
    ramp = (1.0, 0.0, 0.5, 0.5)
    damaged = with_effects(model, {"wing_damage": {"inertia_factor": 0.95}})
    _csv(tmp_path / "healthy.csv", *hs.run(model, 3.0, kr=ramp, seed=3))
    _csv(tmp_path / "ramp_damage.csv", *hs.run(model, 3.0, damaged, 0.75, kr=ramp))
    healthy = _import(tmp_path, tmp_path / "healthy.csv", "healthy")
    ramp_damage = _import(tmp_path, tmp_path / "ramp_damage.csv", "ramp_damage")

    def health(*args: str) -> tuple[int, str, dict | None]:
        out = tmp_path / f"out{len(list(tmp_path.glob('out*')))}"
        result = run_offline([FLAAIR, "health", *args, "--out", str(out)], isolated_env())
        doc = json.loads((out / "health.json").read_text()) if result.returncode == 0 else None
        return result.returncode, result.stderr, doc

    code, err, learned = health(str(healthy))
    assert code == 0, err
    baseline = learned["bags"][0]["baseline"]
    assert baseline["watched"][0] == "wing_inertia" and 130 < baseline["frequency_hz"] < 180
    assert baseline["mean"][0] == pytest.approx(1.0, abs=0.01)
    saved = tmp_path / "out0" / "health.json"
    code, err, alone = health(str(ramp_damage))
    assert code == 0 and alone["events"] == []
    code, err, judged = health(str(ramp_damage), "--baseline", str(saved))
    assert code == 0, err
    assert [e["parameter"] for e in judged["events"]] == ["wing_inertia"]
    assert judged["events"][0]["ratio"] == pytest.approx(0.95, abs=0.02)
    assert judged["bags"][0]["baseline_given"] is True
    # refusals, one line each, nothing written
    both = tmp_path / "both.json"
    both.write_text(json.dumps({"bags": [learned["bags"][0]] * 2}))
    cal = tmp_path / "calibration.yaml"
    cal.write_text(
        f"stroke: {{gain_deg_per_v: {1.1 * model.stroke_gain_deg_per_v}, lag_s: 0.0}}\n"
        f"pitch: {{gain_deg_per_v: {model.pitch_gain_deg_per_v}, lag_s: 0.0}}\n"
    )
    garbage = tmp_path / "garbage.json"
    garbage.write_text("{not json")
    for args, said in (
        (("--baseline", str(both)), "2 bag(s) with a learned baseline"),
        (("--baseline", str(saved), "--calibration", str(cal)), "another model or film"),
        (("--baseline", str(garbage)), "not a readable health.json"),
    ):
        code, err, _ = health(str(ramp_damage), *args)
        assert code == 2 and said in err and "Traceback" not in err, err
        assert len(err.strip().splitlines()) == 1
