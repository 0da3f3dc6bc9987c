"""Characterization (paper Sensor Performance section): Bode data and figures vs closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from flaair_model.model import with_effects
from flaair_model.model_io import load_model
from flaair_sensors.core import bode, frontend_params
from flaair_sensors.core import characterization as ch
from flaair_sensors.core import frontend as fe
from flaair_sim.core.drive import chirp as chirp_drive
from flaair_sim.core.drive import stepped_sine
from flaair_sim.core.plant import simulate
from tuning import FRONTEND_TUNING

FS = 20000.0
AMP_V = 100.0  # Vpp = 200 V (paper)
BANDS = {"amplitude_band_hz": (110.0, 190.0), "time_band_hz": (100.0, 190.0)}  # the paper's bands


def _stepped(freqs, dwell_s=0.2):
    drive, track = stepped_sine(FS, AMP_V, list(freqs), dwell_s)
    return np.asarray(drive, float), np.asarray(track, float)


def _chirp():
    """Paper chirp: 20-200 Hz over 1 s; the drive generator's frequency track is linear."""
    t = np.arange(int(FS)) / FS
    return np.asarray(chirp_drive(t, AMP_V, 20.0, 200.0, 1.0), float), 20.0 + 180.0 * t


def _run(model, drive):
    out = simulate(drive, FS, model)
    return out, {
        "time_s": np.arange(drive.size) / FS,
        "drive_v": drive,
        "stroke_sensor_v": out.stroke_sensor_v,
        "pitch_sensor_v": out.pitch_sensor_v,
        "stroke_deg": np.degrees(out.stroke_rad),
        "pitch_deg": np.degrees(out.pitch_rad),
    }


@pytest.fixture(scope="module")
def model():
    return load_model()


@pytest.fixture(scope="module")
def params(model):
    return frontend_params.params_from_model(model, FS, **FRONTEND_TUNING)


@pytest.fixture(scope="module")
def stepped(model, params):
    freqs = np.arange(60.0, 201.0, 10.0)
    drive, track = _stepped(freqs)
    out, run = _run(model, drive)
    return freqs, track, out, run, ch.characterize_run(run, params, "stepped", track, **BANDS)


@pytest.fixture(scope="module")
def chirp(model, params):
    drive, track = _chirp()
    out, run = _run(model, drive)
    return track, out, run, ch.characterize_run(run, params, "chirp", track, **BANDS)


def _describing_function(model, f_hz):
    """Harmonic-balance stroke and pitch phasors (rad) of the nominal plant at drive AMP_V."""
    p = model.plant
    w = 2 * np.pi * f_hz
    i, k, g, ga = (
        p.stroke_inertia_kg_m2,
        p.stroke_stiffness_nm_per_rad,
        p.aero_damping_nm_s2,
        p.actuator_gain_nm_per_v,
    )
    c = 8.0 / (3.0 * np.pi)  # fundamental of |x|x for a sine
    amp = brentq(lambda a: abs(k - i * w * w + 1j * c * g * w * w * a) * a - ga * AMP_V, 1e-9, 10.0)
    stroke = ga * AMP_V / (k - i * w * w + 1j * c * g * w * w * amp)
    forcing = (
        p.inertial_coupling_kg_m2 * w * w - 1j * c * p.aero_coupling_nm_s2 * w * w * abs(stroke)
    ) * stroke
    pitch = forcing / (
        p.hinge_stiffness_nm_per_rad
        - p.pitch_inertia_kg_m2 * w * w
        + 1j * p.hinge_damping_nm_s_per_rad * w
    )
    return stroke, pitch


def test_stepped_bode_recovers_simulated_amplitudes(model, stepped):
    freqs, _track, _out, _run, result = stepped
    b = result.bode
    np.testing.assert_allclose(b.stroke.frequency_hz, freqs)
    # Sensor curves equal the truth curves (nominal gains) within 1 %.
    np.testing.assert_allclose(
        b.stroke.sensor_amplitude_deg, b.stroke.truth_amplitude_deg, rtol=0.01
    )
    np.testing.assert_allclose(b.pitch.sensor_amplitude_deg, b.pitch.truth_amplitude_deg, rtol=0.01)
    # Truth curve equals the steady state of a long simulation at the same frequency within 1 %.
    for f in (60.0, 140.0, 200.0):
        t = np.arange(int(0.6 * FS)) / FS
        o = simulate(AMP_V * np.sin(2 * np.pi * f * t), FS, model)
        sl = slice(-4000, None)
        ref_s = math.degrees(abs(bode.sine_phasor(o.stroke_rad[sl], 2 * np.pi * f * t[sl])))
        ref_p = math.degrees(abs(bode.sine_phasor(o.pitch_rad[sl], 2 * np.pi * f * t[sl])))
        i = int(np.flatnonzero(freqs == f)[0])
        assert b.stroke.truth_amplitude_deg[i] == pytest.approx(ref_s, rel=0.01)
        assert b.pitch.truth_amplitude_deg[i] == pytest.approx(ref_p, rel=0.01)


def test_stepped_bode_matches_harmonic_balance(model, stepped):
    freqs, _track, _out, _run, result = stepped
    b = result.bode
    for i, f in enumerate(freqs):
        s, p = _describing_function(model, f)
        assert b.stroke.truth_amplitude_deg[i] == pytest.approx(math.degrees(abs(s)), rel=0.015)
        assert b.pitch.truth_amplitude_deg[i] == pytest.approx(math.degrees(abs(p)), rel=0.025)
        # Phases: within the zero-order-hold half-sample delay plus harmonic-balance error.
        assert b.stroke.truth_phase_deg[i] == pytest.approx(math.degrees(np.angle(s)), abs=3.0)
        assert b.pitch.truth_phase_deg[i] == pytest.approx(math.degrees(np.angle(p / s)), abs=1.0)
    # At the 140 Hz natural frequency the stroke lags the drive by 90 deg (K = I w^2).
    assert b.stroke.truth_phase_deg[freqs == 140.0][0] == pytest.approx(-90.0, abs=3.0)


def test_stroke_peak_between_120_and_150_hz(stepped, chirp):
    for b in (stepped[-1].bode, chirp[-1].bode):
        for curve in (b.stroke.truth_amplitude_deg, b.stroke.sensor_amplitude_deg):
            peak = b.stroke.frequency_hz[int(np.nanargmax(curve))]
            assert 120.0 <= peak <= 150.0


def test_nominal_figures_small(stepped, chirp):
    for result in (stepped[-1], chirp[-1]):
        for m in (result.stroke, result.pitch):
            assert m.amplitude_rmse_deg < 0.02
            assert m.amplitude_rmse_band_deg < 0.02
            assert m.phase_rmse_deg < 0.5  # only the drift removal's lead (<0.5 deg above 60 Hz)
            assert abs(m.lag_s) < 2e-5
            assert m.time_rmse_lag_corrected_band_deg < 0.2
    assert chirp[-1].bode.method == "chirp" and stepped[-1].bode.method == "stepped"
    d = chirp[-1].as_dict()
    assert d["stroke"]["amplitude_band_hz"] == (110.0, 190.0)


def test_chirp_bode_agrees_with_stepped(stepped, chirp):
    """The sweep's sliding fits track the stepped-sine steady state away from the resonance peak."""
    freqs, _, _, _, st = stepped
    cb = chirp[-1].bode
    for f in (60.0, 80.0, 180.0, 190.0):
        a_chirp = cb.stroke.truth_amplitude_deg[cb.stroke.frequency_hz == f][0]
        a_step = st.bode.stroke.truth_amplitude_deg[freqs == f][0]
        assert a_chirp == pytest.approx(a_step, rel=0.02)


def test_delay_shows_in_phase_and_time_figures(model, params):
    """A pure sensor delay tau: phase error 360 f tau at
    every point, lag recovered, lag-corrected RMSE small.
    """
    tau = 3e-4
    freqs = np.arange(60.0, 201.0, 20.0)
    drive, track = _stepped(freqs)
    _out, run = _run(with_effects(model, {"sensor_delay": {"delay_s": tau}}), drive)
    res = ch.characterize_run(run, params, "stepped", track, **BANDS)
    drift_lead = np.degrees(np.angle(fe.drift_removal_response(params, freqs)))
    expected = -360.0 * freqs * tau + drift_lead
    for cb in (res.bode.stroke, res.bode.pitch):
        np.testing.assert_allclose(
            bode.wrap_deg(cb.sensor_phase_deg - cb.truth_phase_deg), expected, atol=0.1
        )
    assert res.stroke.phase_rmse_deg == pytest.approx(
        float(np.sqrt(np.mean(expected**2))), rel=0.01
    )
    for m in (res.stroke, res.pitch):
        assert m.lag_s == pytest.approx(tau, rel=0.05)
        assert m.time_rmse_deg > 5 * m.time_rmse_lag_corrected_deg
    # Pitch phase relative to each curve's own stroke: equal delays cancel.
    same = ch.characterize_run(
        run, params, "stepped", track, pitch_phase_reference="sensor", **BANDS
    )
    assert same.pitch.phase_rmse_deg < 0.5 < res.pitch.phase_rmse_deg
    assert same.stroke.phase_rmse_deg == pytest.approx(res.stroke.phase_rmse_deg)


def test_truth_gaps_tolerated(stepped, params):
    _freqs, track, _out, run, result = stepped
    gappy = dict(run)
    y = run["pitch_deg"].copy()
    y[np.arange(y.size) % 3 != 0] = np.nan
    y[20000:21000] = np.nan
    gappy["pitch_deg"] = y
    res = ch.characterize_run(gappy, params, "stepped", track, **BANDS)
    np.testing.assert_allclose(
        res.bode.pitch.truth_amplitude_deg, result.bode.pitch.truth_amplitude_deg, rtol=1e-3
    )
    assert res.pitch.n_truth_samples == int(np.isfinite(y).sum())


def test_rmse_closed_form():
    f = np.array([60.0, 110.0, 150.0, 190.0, 200.0])
    cb = bode.ChannelBode(
        frequency_hz=f,
        sensor_amplitude_deg=np.array([10.0, 21.0, 29.0, 42.0, 50.0]),
        truth_amplitude_deg=np.array([10.0, 20.0, 30.0, 40.0, 53.0]),
        sensor_phase_deg=np.array([0.0, -10.0, 170.0, 20.0, 0.0]),
        truth_phase_deg=np.array([0.0, 0.0, -170.0, 0.0, 0.0]),
        phase_reference="drive",
    )
    amp, ph = bode.amplitude_phase_rmse(cb)
    assert amp == pytest.approx(math.sqrt((0 + 1 + 1 + 4 + 9) / 5))
    # 170 vs -170: 20 deg, wrapped
    assert ph == pytest.approx(math.sqrt((0 + 100 + 400 + 400 + 0) / 5))
    amp_b, ph_b = bode.amplitude_phase_rmse(cb, (110.0, 190.0))
    assert amp_b == pytest.approx(math.sqrt(6 / 3)) and ph_b == pytest.approx(math.sqrt(900 / 3))


def test_bad_inputs_raise(stepped, params):
    _freqs, track, _out, run, _ = stepped
    with pytest.raises(ValueError, match="method"):
        ch.characterize_run(run, params, "sweep", track, **BANDS)
    with pytest.raises(ValueError, match="frequency_hz_per_sample"):
        ch.characterize_run(run, params, "stepped", **BANDS)
    with pytest.raises(ValueError, match="stroke_deg"):
        ch.characterize_run(
            {k: v for k, v in run.items() if k != "stroke_deg"}, params, "stepped", track, **BANDS
        )
    with pytest.raises(ValueError, match="pitch_phase_reference"):
        ch.characterize_run(run, params, "stepped", track, pitch_phase_reference="drive", **BANDS)


def test_bode_figure_png(stepped, chirp, tmp_path):
    from flaair_sensors.figures import save_bode_figure

    path = save_bode_figure(
        tmp_path / "bode.png", chirp[-1].bode, stepped[-1].bode, title="nominal model"
    )
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10000
