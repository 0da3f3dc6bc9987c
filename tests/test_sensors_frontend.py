"""Front end (inverse sensor model): closed-form checks on synthetic sinusoids and the plant."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from flaair_model.model_io import load_model
from flaair_sensors.core import frontend as fe
from flaair_sensors.core import frontend_params
from flaair_sensors.core.bode import sine_phasor
from flaair_sim.core.plant import simulate
from tuning import FRONTEND_TUNING

FS = 20000.0


@pytest.fixture(scope="module")
def model():
    return load_model()


@pytest.fixture(scope="module")
def params(model):
    return frontend_params.params_from_model(model, FS, **FRONTEND_TUNING)


def _sine_volts(params, amp_rad, f_hz, n, lag_s=0.0, offset_v=0.0, channel="stroke"):
    t = np.arange(n) / FS
    vpr = params.stroke_volts_per_rad if channel == "stroke" else params.pitch_volts_per_rad
    theta = amp_rad * np.sin(2 * np.pi * f_hz * t)
    v = (
        params.reference_voltage_v
        + offset_v
        + vpr * amp_rad * np.sin(2 * np.pi * f_hz * (t - lag_s))
    )
    return t, theta, v


def _phasor(x, t, f_hz, sl):
    return sine_phasor(x[sl], 2 * np.pi * f_hz * t[sl])


def test_params_from_model_matches_model_gains(model, params):
    # Spec values (shared/model-spec.md): 25.39 deg/V stroke, 24.87 deg/V pitch, polarity -1.
    assert math.degrees(1 / abs(params.stroke_volts_per_rad)) == pytest.approx(
        model.stroke_gain_deg_per_v, rel=1e-12
    )
    assert math.degrees(1 / abs(params.pitch_volts_per_rad)) == pytest.approx(
        model.pitch_gain_deg_per_v, rel=1e-12
    )
    assert math.degrees(1 / abs(params.stroke_volts_per_rad)) == pytest.approx(25.39, rel=1e-3)
    assert math.degrees(1 / abs(params.pitch_volts_per_rad)) == pytest.approx(24.87, rel=1e-3)
    assert params.stroke_volts_per_rad < 0 and params.pitch_volts_per_rad < 0
    assert params.reference_voltage_v == model.sensors.reference_voltage_v


def test_plant_angles_recovered(model, params):
    """Nominal plant, noise off: the inverse model returns
    the simulated angles (drift removal aside).
    """
    n = 8000
    t = np.arange(n) / FS
    drive = 100.0 * np.sin(2 * np.pi * 140.0 * t)
    out = simulate(drive, FS, model)
    exact = fe.estimate(
        out.stroke_sensor_v,
        out.pitch_sensor_v,
        frontend_params.with_overrides(params, drift_corner_hz=0.0),
    )
    np.testing.assert_allclose(exact.stroke_rad, out.stroke_rad, atol=1e-12)
    np.testing.assert_allclose(exact.pitch_rad, out.pitch_rad, atol=1e-12)
    est = fe.estimate(out.stroke_sensor_v, out.pitch_sensor_v, params)
    amp = np.max(np.abs(out.stroke_rad))
    assert np.max(np.abs(est.stroke_rad - out.stroke_rad)) < 0.01 * amp
    assert est.stroke_valid.all() and est.pitch_valid.all()


def test_drift_removal_phase_is_documented(params):
    """Steady-state response to a sine equals the documented drift-removal response exactly."""
    for f in (20.0, 60.0, 140.0):
        t, theta, v = _sine_volts(params, 0.5, f, 60000)
        est = fe.estimate(v, v, params)
        sl = slice(40000, 60000)  # > 6 time constants of the 0.5 Hz tracker
        ratio = _phasor(est.stroke_rad, t, f, sl) / _phasor(theta, t, f, sl)
        expected = fe.drift_removal_response(params, f)[0]
        assert abs(ratio / expected - 1) < 1e-4
    # Docstring: 0.48 deg lead at 60 Hz for the 0.5 Hz default corner, gain error < 0.004 %.
    h60 = fe.drift_removal_response(params, 60.0)[0]
    assert math.degrees(np.angle(h60)) == pytest.approx(
        math.degrees(math.atan(params.drift_corner_hz / 60.0)), abs=0.01
    )
    assert abs(abs(fe.drift_removal_response(params, [20.0, 200.0])) - 1).max() < 4e-4


def test_drift_removal_tracks_offset_and_ramp(params):
    n = int(3 * FS)
    t, theta, v = _sine_volts(params, 0.3, 140.0, n)
    v = v + 0.05 + 0.01 * t  # V_HREF error of 50 mV and a 10 mV/s drift
    est = fe.estimate(v, v, params)
    late = slice(int(2 * FS), n)
    err_deg = np.degrees(np.abs(est.stroke_rad[late] - theta[late]))
    assert err_deg.max() < 0.25
    no_drift = fe.estimate(v, v, frontend_params.with_overrides(params, drift_corner_hz=0.0))
    assert np.degrees(np.abs(no_drift.stroke_rad[late] - theta[late])).max() > 1.0


def test_initial_state_at_rest_voltage_removes_startup_offset(params):
    _t, theta, v = _sine_volts(params, 0.3, 140.0, 4000, offset_v=0.04)
    v[:400] = params.reference_voltage_v + 0.04  # wing at rest first
    theta[:400] = 0.0
    est = fe.estimate(
        v, v, params, fe.initial_state(params, first_stroke_v=v[0], first_pitch_v=v[0])
    )
    assert np.degrees(np.abs(est.stroke_rad - theta)).max() < 0.2
    cold = fe.estimate(v, v, params)
    assert np.degrees(np.abs(cold.stroke_rad - theta)).max() > 0.5


def test_block_stepping_equals_whole_record(params):
    rng = np.random.default_rng(3)
    p = frontend_params.with_overrides(
        params,
        stroke_lag_s=2e-4,
        pitch_lag_s=-1e-4,
        rail_low_v=0.0,
        rail_high_v=2.5,
        rail_margin_v=0.01,
    )
    _t, _, sv = _sine_volts(p, 0.6, 130.0, 6003)
    _, _, pv = _sine_volts(p, 0.4, 130.0, 6003, lag_s=1e-3, channel="pitch")
    sv = sv + 1e-3 * rng.standard_normal(sv.size)
    sv[rng.integers(0, sv.size, 30)] = np.nan
    pv[rng.integers(0, pv.size, 10)] = np.inf
    state0 = fe.initial_state(p, first_stroke_v=1.25, first_pitch_v=1.26)
    whole = fe.step(state0, fe.FrontendInputs(sv, pv), p)[1]
    for sizes in (np.full(601, 10), rng.integers(0, 25, 2000)):
        state, parts, start = state0, [], 0
        for size in sizes:
            stop = min(start + int(size), sv.size)
            state, out = fe.step(state, fe.FrontendInputs(sv[start:stop], pv[start:stop]), p)
            parts.append(out)
            start = stop
        state, out = fe.step(state, fe.FrontendInputs(sv[start:], pv[start:]), p)
        parts.append(out)
        for i, name in enumerate(fe.WingEstimate._fields):
            np.testing.assert_array_equal(
                np.concatenate([q[i] for q in parts]), whole[i], err_msg=name
            )
    np.testing.assert_array_equal(fe.estimate(sv, pv, p, state0).stroke_rad, whole.stroke_rad)


@settings(max_examples=25, deadline=None)
@given(
    sizes=st.lists(st.integers(0, 40), min_size=1, max_size=60),
    bad=st.lists(st.integers(0, 599), max_size=20),
    lag=st.floats(-3e-4, 5e-4),
)
def test_block_partition_property(params, sizes, bad, lag):
    """Any partition of any record (with unusable samples) gives the whole-record result."""
    p = frontend_params.with_overrides(params, stroke_lag_s=lag, rail_low_v=0.2, rail_high_v=2.3)
    _t, _, sv = _sine_volts(p, 0.55, 150.0, 600)
    pv = sv[::-1].copy()
    sv[bad] = np.nan
    state0 = fe.initial_state(p, first_stroke_v=1.25, first_pitch_v=1.25)
    whole = fe.estimate(sv, pv, p, state0)
    state, parts, start = state0, [], 0
    for size in [*sizes, sv.size]:
        stop = min(start + size, sv.size)
        state, out = fe.step(state, fe.FrontendInputs(sv[start:stop], pv[start:stop]), p)
        parts.append(out)
        start = stop
    for i, name in enumerate(fe.WingEstimate._fields):
        np.testing.assert_array_equal(np.concatenate([q[i] for q in parts]), whole[i], err_msg=name)
    assert not whole.stroke_valid[bad].any()


def test_nan_and_inf_never_valid_never_in_state(params):
    rng = np.random.default_rng(5)
    _t, _theta, v = _sine_volts(params, 0.5, 140.0, 20000)
    clean = fe.estimate(v, v, params)
    bad = v.copy()
    idx = rng.choice(np.arange(2000, 19000), 40, replace=False)
    bad[idx] = np.nan
    bad[idx[:10]] = np.inf
    bad[idx[10:15]] = -np.inf
    bad[5000:5100] = np.nan  # a long gap
    state, est = fe.step(fe.initial_state(params), fe.FrontendInputs(bad, bad), params)
    unusable = ~np.isfinite(bad)
    assert not est.stroke_valid[unusable].any() and not est.pitch_valid[unusable].any()
    assert (
        np.isnan(est.stroke_rad[unusable]).all()
        and np.isnan(est.stroke_velocity_rad_s[unusable]).all()
    )
    for arr in (est.stroke_rad, est.pitch_rad, est.stroke_velocity_rad_s):
        assert np.isfinite(arr[est.stroke_valid]).all()
    assert np.isfinite(state.filter_zi).all()  # every filter's state
    # Hold-off: the samples right after each unusable one are invalid, later ones valid again.
    h = params.holdoff_samples
    assert h >= 1
    assert not est.stroke_valid[5100 : 5100 + h].any()
    assert est.stroke_valid[5100 + h + 1]
    # Valid samples are honest: angles within 1 % of amplitude (the drift tracker misses the gap's
    # share of the signal ripple), velocity within 2 % of its amplitude.
    ok = est.stroke_valid
    assert np.abs(est.stroke_rad[ok] - clean.stroke_rad[ok]).max() < 0.01 * 0.5
    vel_amp = 2 * np.pi * 140.0 * 0.5
    assert (
        np.abs(est.stroke_velocity_rad_s[ok] - clean.stroke_velocity_rad_s[ok]).max()
        < 0.02 * vel_amp
    )


def test_saturation_marks_samples_invalid(params):
    p = frontend_params.with_overrides(params, rail_low_v=0.0, rail_high_v=2.5, rail_margin_v=0.02)
    # 0.6 rad * 2.26 V/rad = 1.35 V: clips at both rails
    _t, theta, v = _sine_volts(p, 0.6, 140.0, 4000)
    v = np.clip(v, 0.0, 2.5)
    est = fe.estimate(v, v, p)
    near_rail = (v <= 0.02) | (v >= 2.48)
    assert near_rail.sum() > 100
    assert not est.stroke_valid[near_rail].any() and not est.pitch_valid[near_rail].any()
    assert np.isnan(est.stroke_rad[near_rail]).all()
    # Hold-off after leaving saturation, then valid.
    h = p.holdoff_samples
    leave = np.flatnonzero(near_rail[:-1] & ~near_rail[1:]) + 1
    for i in leave[:-1]:
        assert not est.stroke_valid[i : i + h].any()
    # Between clips, samples past the hold-off are valid and honest.
    ok = est.stroke_valid
    assert ok.mean() > 0.2
    assert np.abs(est.stroke_rad[ok] - theta[ok]).max() < 0.01 * 0.6
    # Without rails the same record is all valid (detection is what marks it).
    assert fe.estimate(v, v, params).stroke_valid.all()


def test_velocity_of_pure_sine_at_140hz(params):
    f, amp = 140.0, 0.4
    t, theta, v = _sine_volts(params, amp, f, 20000)
    est = fe.estimate(v, v, params)
    sl = slice(10000, 20000)
    pv = _phasor(est.stroke_velocity_rad_s, t, f, sl)
    ideal = 2j * np.pi * f * _phasor(theta, t, f, sl)  # analytic derivative
    assert abs(pv) / abs(ideal) == pytest.approx(1.0, abs=0.02)
    gain, lag_deg, gd = fe.velocity_response(params, f)
    measured_lag_deg = -math.degrees(np.angle(pv / ideal))
    drift_lead_deg = math.degrees(np.angle(fe.drift_removal_response(params, f)[0]))
    assert measured_lag_deg == pytest.approx(lag_deg - drift_lead_deg, abs=0.02)
    assert fe.velocity_phase_lag_deg(params, f) == lag_deg
    # Documented figures for the default 1 kHz cutoff at 20 kHz: 11.42 deg, 0.230 ms group delay.
    assert lag_deg == pytest.approx(11.42, abs=0.01)
    assert gd == pytest.approx(0.230e-3, abs=2e-6)
    assert gain == pytest.approx(1.0, abs=1e-3)


def test_lag_compensation_phase_lead(params):
    lag = 3e-4
    p = frontend_params.with_overrides(params, stroke_lag_s=lag, pitch_lag_s=lag)
    for f in (60.0, 140.0, 200.0):
        t, theta, v = _sine_volts(p, 0.5, f, 40000, lag_s=lag)
        sl = slice(30000, 40000)
        comp = fe.estimate(v, v, p)
        raw = fe.estimate(v, v, frontend_params.with_overrides(p, compensate_lag=False))
        r_comp = _phasor(comp.stroke_rad, t, f, sl) / _phasor(theta, t, f, sl)
        r_raw = _phasor(raw.stroke_rad, t, f, sl) / _phasor(theta, t, f, sl)
        expected = fe.lag_compensation_response(p, f)[0] * fe.drift_removal_response(p, f)[0]
        assert abs(r_comp / expected - 1) < 1e-4
        assert abs(r_comp - 1) < 0.2 * abs(r_raw - 1)  # compensation removes >80 % of the lag error
    # Documented residual for 0.3 ms at the default 1 kHz roll-off: 0.9 deg / 0.8 % at 140 Hz.
    r = fe.lag_compensation_response(p, 140.0)[0]
    assert math.degrees(np.angle(r)) == pytest.approx(0.9, abs=0.05)
    assert abs(r) - 1 == pytest.approx(0.008, abs=0.001)
    assert fe.lag_compensation_noise_gain(p) == pytest.approx(5.9, abs=0.1)
    assert abs(fe.estimate_delay_s(p, 140.0)["stroke_s"]) < 0.1 * lag
    assert fe.estimate_delay_s(frontend_params.with_overrides(p, compensate_lag=False), 140.0)[
        "stroke_s"
    ] == pytest.approx(lag, rel=0.05)


def test_params_from_calibration_roundtrip(params):
    cal = {
        "reference_voltage_v": 1.25,
        "stroke": {"gain_deg_per_v": 25.0, "polarity": -1, "offset_v": 0.01, "lag_s": 1e-4},
        "pitch": {"gain_deg_per_v": 108.0, "polarity": 1, "offset_v": -0.02, "lag_s": 2e-4},
    }
    p = frontend_params.params_from_calibration(
        cal, FS, **{**FRONTEND_TUNING, "drift_corner_hz": 0.0, "compensate_lag": False}
    )
    v = np.array([1.25 + 0.01 + 0.1])
    est = fe.estimate(v, np.array([1.25 - 0.02 + 0.1]), p)
    assert math.degrees(est.stroke_rad[0]) == pytest.approx(-25.0 * 0.1)
    assert math.degrees(est.pitch_rad[0]) == pytest.approx(108.0 * 0.1)
    assert p.stroke_lag_s == 1e-4 and p.pitch_lag_s == 2e-4
    with pytest.raises(ValueError, match="polarity"):
        frontend_params.params_from_calibration(
            {**cal, "pitch": {**cal["pitch"], "polarity": 0}}, FS, **FRONTEND_TUNING
        )
    with pytest.raises(ValueError, match="gain_deg_per_v"):
        frontend_params.params_from_calibration(
            {**cal, "stroke": {"polarity": 1, "offset_v": 0, "lag_s": 0}}, FS, **FRONTEND_TUNING
        )


def test_bad_parameters_and_inputs_raise(params):
    with pytest.raises(ValueError, match="velocity_cutoff_hz"):
        frontend_params.with_overrides(params, velocity_cutoff_hz=20000.0)
    with pytest.raises(ValueError, match="stroke_volts_per_rad"):
        frontend_params.with_overrides(params, stroke_volts_per_rad=0.0)
    with pytest.raises(ValueError, match="rail_low_v"):
        frontend_params.with_overrides(params, rail_low_v=3.0, rail_high_v=1.0)
    with pytest.raises(ValueError, match="same length"):
        fe.step(fe.initial_state(params), fe.FrontendInputs(np.zeros(3), np.zeros(4)), params)
