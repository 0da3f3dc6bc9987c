"""Calibration against ground truth: closed-form recoveries on simulated runs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from flaair_model.model import with_effects
from flaair_model.model_io import load_model
from flaair_sensors.core import frontend as fe
from flaair_sensors.core import frontend_params
from flaair_sensors.core.calibration import CalibrationError, calibrate
from flaair_sim.core.drive import chirp
from flaair_sim.core.measured_run import synthesize_measured_run
from flaair_sim.core.plant import simulate
from tuning import FRONTEND_TUNING

FS = 20000.0
BAND = {"amplitude_band_hz": (110.0, 190.0)}  # the stroke-to-pitch resonance band (paper)


def _chirp_drive():
    """Paper chirp: 20-200 Hz over 1 s, Vpp = 200 V."""
    t = np.arange(int(FS)) / FS
    return np.asarray(chirp(t, 100.0, 20.0, 200.0, 1.0), float)


@pytest.fixture(scope="module")
def model():
    return load_model()


@pytest.fixture(scope="module")
def drive():
    return _chirp_drive()


def _run(model, drive, shift_samples=0):
    out = simulate(drive, FS, model)
    sv, pv = out.stroke_sensor_v, out.pitch_sensor_v
    if shift_samples:
        sv = np.r_[np.full(shift_samples, sv[0]), sv[:-shift_samples]]
        pv = np.r_[np.full(shift_samples, pv[0]), pv[:-shift_samples]]
    return {
        "time_s": np.arange(drive.size) / FS,
        "drive_v": drive,
        "stroke_sensor_v": sv,
        "pitch_sensor_v": pv,
        "stroke_deg": np.degrees(out.stroke_rad),
        "pitch_deg": np.degrees(out.pitch_rad),
    }


@pytest.fixture(scope="module")
def nominal(model, drive):
    return _run(model, drive)


@pytest.fixture(scope="module")
def nominal_cal(model, nominal):
    return calibrate(nominal, model.sensors.reference_voltage_v, **BAND)


def test_nominal_gains_equal_model_gains(model, nominal_cal):
    s, p = nominal_cal["stroke"], nominal_cal["pitch"]
    assert s["gain_deg_per_v"] == pytest.approx(model.stroke_gain_deg_per_v, rel=0.01)
    assert p["gain_deg_per_v"] == pytest.approx(model.pitch_gain_deg_per_v, rel=0.01)
    # shared/model-spec.md: 25.39 deg/V and 24.87 deg/V, polarity -1.
    assert s["gain_deg_per_v"] == pytest.approx(25.39, rel=0.01)
    assert p["gain_deg_per_v"] == pytest.approx(24.87, rel=0.01)
    assert s["polarity"] == model.stroke_polarity == -1
    assert p["polarity"] == model.pitch_polarity == -1
    for ch in (s, p):
        assert abs(ch["lag_s"]) < 1e-6
        assert abs(ch["offset_v"]) < 1e-6
        assert ch["amplitude_rmse_deg"] < 1e-3 and ch["phase_rmse_deg"] < 1e-2
    json.loads(json.dumps(nominal_cal))  # plain JSON


@pytest.mark.parametrize("efficiency", [0.5, 0.8])
def test_strain_transfer_loss_scales_pitch_gain(model, drive, nominal_cal, efficiency):
    lossy = with_effects(
        model, {"strain_transfer_loss": {"efficiency": efficiency, "channel": "pitch"}}
    )
    cal = calibrate(_run(lossy, drive), model.sensors.reference_voltage_v, **BAND)
    ratio = cal["pitch"]["gain_deg_per_v"] / nominal_cal["pitch"]["gain_deg_per_v"]
    assert ratio == pytest.approx(1.0 / efficiency, rel=0.01)
    assert cal["stroke"]["gain_deg_per_v"] == pytest.approx(
        nominal_cal["stroke"]["gain_deg_per_v"], rel=1e-3
    )


def test_sensor_delay_effect_recovered_as_lag(model, drive):
    delay = 3e-4
    delayed = with_effects(model, {"sensor_delay": {"delay_s": delay}})
    cal = calibrate(_run(delayed, drive), model.sensors.reference_voltage_v, **BAND)
    for ch in ("stroke", "pitch"):
        assert cal[ch]["lag_s"] == pytest.approx(delay, rel=0.05)
        assert cal[ch]["gain_deg_per_v"] == pytest.approx(
            getattr(model, f"{ch}_gain_deg_per_v"), rel=0.01
        )
        # Uncorrected, a pure delay shows as a phase error of 360 f tau (23 deg at 200 Hz).
        assert cal[ch]["phase_rmse_deg"] > 5.0


def test_fractional_delay_and_array_shift_recovered(model, drive, nominal):
    delayed = with_effects(model, {"sensor_delay": {"delay_s": 2.23e-4, "channel": "pitch"}})
    cal = calibrate(_run(delayed, drive), model.sensors.reference_voltage_v, **BAND)
    assert cal["pitch"]["lag_s"] == pytest.approx(2.23e-4, rel=0.05)
    assert abs(cal["stroke"]["lag_s"]) < 1e-6
    shifted = calibrate(
        _run(model, drive, shift_samples=7), model.sensors.reference_voltage_v, **BAND
    )
    assert shifted["stroke"]["lag_s"] == pytest.approx(7 / FS, rel=0.05)
    assert shifted["pitch"]["lag_s"] == pytest.approx(7 / FS, rel=0.05)


def test_truth_gaps_and_low_frame_rate(model, nominal, nominal_cal):
    run = dict(nominal)
    y = run["pitch_deg"].copy()
    y[5000:9000] = np.nan  # video lost the wing
    y[np.arange(y.size) % 4 != 0] = np.nan  # video at a quarter of the DAQ rate
    run["pitch_deg"] = y
    s = run["stroke_deg"].copy()
    s[12000:12500] = np.nan
    run["stroke_deg"] = s
    cal = calibrate(run, model.sensors.reference_voltage_v, **BAND)
    for ch in ("stroke", "pitch"):
        assert cal[ch]["gain_deg_per_v"] == pytest.approx(
            nominal_cal[ch]["gain_deg_per_v"], rel=1e-4
        )
        assert abs(cal[ch]["lag_s"]) < 1e-6
    assert cal["pitch"]["n_valid_truth"] == int(np.isfinite(y).sum())


def test_offset_and_drift_do_not_bias_gain(model, nominal, nominal_cal):
    run = dict(nominal)
    t = run["time_s"]
    run["stroke_sensor_v"] = run["stroke_sensor_v"] + 0.03 + 0.02 * t  # V_HREF error + slow drift
    cal = calibrate(run, model.sensors.reference_voltage_v, **BAND)
    assert cal["stroke"]["gain_deg_per_v"] == pytest.approx(
        nominal_cal["stroke"]["gain_deg_per_v"], rel=1e-4
    )
    assert cal["stroke"]["offset_v"] == pytest.approx(0.03 + 0.02 * t.mean(), abs=1e-4)
    assert cal["stroke"]["drift_v_per_s"] == pytest.approx(0.02, rel=1e-3)


def test_charge_amp_highpass_does_not_bias_gain(model, drive, nominal_cal):
    """A drift-removing high-pass (2 Hz) in the sensor chain leaves the 20-200 Hz gain alone."""
    hp = with_effects(model, {"charge_amp_highpass": {"corner_hz": 2.0}})
    cal = calibrate(_run(hp, drive), model.sensors.reference_voltage_v, **BAND)
    for ch in ("stroke", "pitch"):
        assert cal[ch]["gain_deg_per_v"] == pytest.approx(
            nominal_cal[ch]["gain_deg_per_v"], rel=1e-3
        )
        # Its phase lead shows as a small negative lag (tens of microseconds), not as gain.
        assert -1e-4 < cal[ch]["lag_s"] < 0.0


def test_noisy_measured_run(model, drive):
    run = synthesize_measured_run(drive, FS, model, np.random.default_rng(11))
    cal = calibrate(run, model.sensors.reference_voltage_v, **BAND)
    assert cal["stroke"]["gain_deg_per_v"] == pytest.approx(model.stroke_gain_deg_per_v, rel=0.01)
    assert cal["pitch"]["gain_deg_per_v"] == pytest.approx(model.pitch_gain_deg_per_v, rel=0.01)
    assert abs(cal["stroke"]["lag_s"]) < 5e-6 and abs(cal["pitch"]["lag_s"]) < 5e-6


def test_calibration_feeds_front_end(model, drive):
    """Calibrate a delayed sensor, then the front end with lead compensation tracks the truth."""
    delay = 3e-4
    run = _run(with_effects(model, {"sensor_delay": {"delay_s": delay}}), drive)
    cal = calibrate(run, model.sensors.reference_voltage_v, **BAND)
    p = frontend_params.params_from_calibration(cal, FS, **FRONTEND_TUNING)
    assert p.stroke_volts_per_rad == pytest.approx(model.stroke_volts_per_rad, rel=0.01)
    est = fe.estimate(run["stroke_sensor_v"], run["pitch_sensor_v"], p)
    raw = fe.estimate(
        run["stroke_sensor_v"],
        run["pitch_sensor_v"],
        frontend_params.with_overrides(p, compensate_lag=False),
    )
    band = slice(int(0.3 * FS), int(0.9 * FS))  # 74-182 Hz of the sweep
    truth = np.radians(run["stroke_deg"][band])
    err_comp = np.sqrt(np.mean((est.stroke_rad[band] - truth) ** 2))
    err_raw = np.sqrt(np.mean((raw.stroke_rad[band] - truth) ** 2))
    assert err_comp < 0.25 * err_raw


def _errors(run, ref=1.25, **kw):
    with pytest.raises(CalibrationError) as info:
        calibrate(run, ref, **kw, **BAND)
    return str(info.value)


def test_clear_errors(nominal):
    run = dict(nominal)
    few = run["stroke_deg"].copy()
    few[100:] = np.nan
    assert "stroke_deg" in _errors({**run, "stroke_deg": few}) and "too few" in _errors(
        {**run, "stroke_deg": few}
    )
    bad = run["pitch_sensor_v"].copy()
    bad[123] = np.nan
    msg = _errors({**run, "pitch_sensor_v": bad})
    assert "pitch_sensor_v" in msg and "non-finite" in msg and "123" in msg
    clipped = np.clip(run["stroke_sensor_v"], 0.0, 2.5)
    msg = _errors({**run, "stroke_sensor_v": clipped})
    assert "stroke_sensor_v" in msg and "saturated" in msg
    msg = _errors(run, rails_v=(-0.2, 2.7))
    assert "saturated" in msg and "rails" in msg
    assert "pitch_deg" in _errors({k: v for k, v in run.items() if k != "pitch_deg"})
    assert "time_s" in _errors({**run, "time_s": run["time_s"][::-1]})
    flat = np.full(run["pitch_deg"].size, 3.0)
    assert "does not move" in _errors({**run, "pitch_deg": flat})
    assert "constant" in _errors({**run, "pitch_sensor_v": np.full(flat.size, 1.25)})
    assert issubclass(CalibrationError, ValueError)
