"""The compiled per-block kernels against scipy/numpy written out the plain way.

flaair_model.lfilter must be scipy.signal.lfilter (same samples, same final state), and the
dSA controller, safety and front-end cores that now run on it must give what the plain
numpy/scipy chains give, block by block, including non-finite and out-of-rail samples.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from flaair_control.core import dsa, safety
from flaair_model.lfilter import float_block, lfilter, normalized_ba
from flaair_sensors.core import frontend as fe
from flaair_sensors.core import frontend_params

FS = 20000.0


@settings(max_examples=60, deadline=None)
@given(
    order=st.integers(1, 4),
    a0=st.floats(0.25, 4.0),
    seed=st.integers(0, 2**31 - 1),
    n=st.integers(1, 64),
)
def test_lfilter_is_scipy_bit_for_bit(order: int, a0: float, seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    b, a = signal.butter(order, rng.uniform(0.05, 0.4))
    b, a = b * rng.uniform(0.5, 3.0) * a0, a * a0  # a[0] != 1: lfilter normalizes
    x = rng.standard_normal(n) * 100.0
    zi = rng.standard_normal(order)
    y_ref, z_ref = signal.lfilter(b, a, x, zi=zi)
    y, z = lfilter(*normalized_ba(b, a), x, zi)
    np.testing.assert_array_equal(y, y_ref)
    np.testing.assert_array_equal(z, z_ref)
    # an empty block leaves the state as it was (scipy returns zeros there)
    np.testing.assert_array_equal(lfilter(*normalized_ba(b, a), x[:0], zi)[1], zi)


def test_float_block_copies_only_what_the_kernels_cannot_take() -> None:
    x = np.arange(10.0)
    assert np.shares_memory(float_block(x), x)  # already fit: no copy
    view = np.frombuffer(x.tobytes(), dtype=np.float64)  # read-only, as a CDR view
    out = float_block(view)
    assert out.flags.writeable and out is not view
    np.testing.assert_array_equal(out, x)
    np.testing.assert_array_equal(float_block(np.arange(10, dtype=np.float32)), x)
    np.testing.assert_array_equal(float_block(x[::2]), x[::2])


def _dsa_reference(state: dsa.DsaState, v: np.ndarray, t_start_s: float, p: dsa.DsaParams):
    """The dSA block as plain numpy/scipy: two lfilter calls, K_r, sine, blend, clip."""
    valid = np.isfinite(v)
    v = np.where(valid, v, 0.0)
    torque, zi_adv = signal.lfilter(*dsa.filter_coefficients(p, True), v, zi=state.zi_advanced)
    torque_raw, zi_raw = signal.lfilter(*dsa.filter_coefficients(p, False), v, zi=state.zi_raw)
    t = t_start_s + np.arange(v.size) / p.sample_rate_hz
    kr = p.kr_schedule.value(t)
    sync = p.sync_amplitude_v * np.sin(2.0 * np.pi * p.sync_frequency_hz * t + p.sync_phase_rad)
    async_v = torque / p.actuator_gain_nm_per_v
    unclipped = kr * sync + (1.0 - kr) * async_v
    drive = np.clip(np.nan_to_num(unclipped, nan=0.0), -p.drive_limit_v, p.drive_limit_v)
    return (
        dsa.DsaState(zi_adv, zi_raw),
        drive,
        (torque_raw, torque, async_v, sync, kr, unclipped, valid),
    )


@pytest.mark.parametrize("ramp_s", [0.0, 0.004])
def test_dsa_step_matches_the_scipy_chain(ramp_s: float) -> None:
    p = dsa.DsaParams(
        r3_rad_s=180.0,
        kappa=0.5,
        mu_nm_s_per_rad=6e-7,
        actuator_gain_nm_per_v=1.67e-7,
        sample_rate_hz=FS,
        drive_limit_v=150.0,
        sync_amplitude_v=20.0,
        sync_frequency_hz=90.0,
        sync_phase_rad=0.3,
        kr_schedule=dsa.KrSchedule(1.0, 0.0, 0.003, ramp_s),
        loop_delay_s=dsa.loop_delay_s(10, FS),
        compensation_frequency_hz=None,
    )
    rng = np.random.default_rng(7)
    state = ref = dsa.initial_state(p)
    clipped = 0
    for k in range(400):
        v = rng.standard_normal(10) * 3e3
        v[rng.integers(0, 10)] = [np.nan, np.inf, -np.inf, 1.0][k % 4]
        state, out = dsa.step(state, dsa.DsaInputs(v, k * 10 / FS), p)
        ref, drive, signals = _dsa_reference(ref, v, k * 10 / FS, p)
        np.testing.assert_allclose(out.drive_v, drive, rtol=1e-12, atol=1e-12 * p.drive_limit_v)
        for got, want in zip(out.signals, signals, strict=True):
            np.testing.assert_allclose(
                np.asarray(got, float), np.asarray(want, float), rtol=1e-12, atol=1e-18
            )
        np.testing.assert_allclose(state.zi_advanced, ref.zi_advanced, rtol=1e-12, atol=1e-18)
        clipped += int(np.count_nonzero(np.abs(out.drive_v) == p.drive_limit_v))
    assert clipped > 0  # the clip was exercised


def _safety_reference(
    state: safety.SafetyState, x: np.ndarray, t_start_s: float, p: safety.SafetyParams
):
    """The safety stages as plain numpy (sanitize, envelope, slew, clamp)."""
    finite = np.isfinite(x)
    x = np.where(finite, x, 0.0)
    t = t_start_s + np.arange(x.size) / p.sample_rate_hz
    state = safety.check_timeout(state, t[-1], p)
    env = np.ones(x.size)
    if state.status == safety.TRIPPED:
        env = (
            np.clip(1.0 - (t - state.trip_time_s) / p.ramp_down_s, 0.0, 1.0)
            if p.ramp_down_s > 0
            else 0.0 * t
        )
        env = np.where(t < state.trip_time_s, 1.0, env)
    y, prev, step_v = (
        np.empty(x.size),
        min(max(state.last_drive_v, -p.drive_limit_v), p.drive_limit_v),
        p.slew_limit_v_per_s / p.sample_rate_hz,
    )
    for i, xi in enumerate(x * env):
        prev = min(
            max(min(max(xi, prev - step_v), prev + step_v), -p.drive_limit_v), p.drive_limit_v
        )
        y[i] = prev
    return state._replace(last_drive_v=float(y[-1])), y, env, int(x.size - finite.sum())


@pytest.mark.parametrize("ramp_down_s", [0.0, 0.003])
def test_safety_step_matches_the_numpy_stages(ramp_down_s: float) -> None:
    p = safety.SafetyParams(
        drive_limit_v=100.0,
        slew_limit_v_per_s=4e5,
        invalid_timeout_s=0.004,
        ramp_down_s=ramp_down_s,
        sample_rate_hz=FS,
    )
    rng = np.random.default_rng(11)
    state = ref = safety.initial_state(p)
    for k in range(60):
        x = rng.standard_normal(10) * 150.0
        x[rng.integers(0, 10)] = [np.nan, np.inf, -np.inf, 0.0][k % 4]
        t0 = k * 10 / FS + (0.006 if k >= 30 else 0.0)  # a silence: the watchdog trips mid-run
        if k < 20:
            state = safety.note_sensor_block(state, t0, True, p)
            ref = safety.note_sensor_block(ref, t0, True, p)
        state, out = safety.step(state, safety.SafetyInputs(x, t0), p)
        ref, y, env, nonfinite = _safety_reference(ref, x, t0, p)
        np.testing.assert_array_equal(out.drive_v, y)
        np.testing.assert_array_equal(out.envelope, env)
        assert out.nonfinite_count == nonfinite
        assert state.status == ref.status and state.last_drive_v == ref.last_drive_v
    assert state.status == safety.TRIPPED and np.all(out.drive_v == 0.0)


def _frontend_reference(
    v: np.ndarray, p: frontend_params.FrontendParams, channel: str
) -> np.ndarray:
    """One channel of the chain with scipy over the usable samples of a whole record."""
    usable = (
        np.isfinite(v)
        & (v > p.rail_low_v + p.rail_margin_v)
        & (v < p.rail_high_v - p.rail_margin_v)
    )
    e = v[usable] - (p.reference_voltage_v + getattr(p, f"{channel}_offset_v"))
    db, da = signal.butter(1, p.drift_corner_hz, btype="low", fs=p.sample_rate_hz)
    e = e - signal.lfilter(db, da, e, zi=np.zeros(1))[0]
    theta = e / getattr(p, f"{channel}_volts_per_rad")
    lead = fe.filters(p).stroke_lead if channel == "stroke" else fe.filters(p).pitch_lead
    if lead is not None:
        theta = signal.lfilter(*lead, theta, zi=np.zeros(2))[0]
    out = np.full(v.size, np.nan)
    out[usable] = theta
    return out


def test_frontend_step_matches_the_scipy_chain_bit_for_bit() -> None:
    p = frontend_params.FrontendParams(
        stroke_volts_per_rad=-2.25,
        pitch_volts_per_rad=-2.3,
        reference_voltage_v=1.25,
        sample_rate_hz=FS,
        drift_corner_hz=0.5,
        compensate_lag=True,
        lead_rolloff_hz=1000.0,
        rail_low_v=-5.0,
        rail_high_v=7.5,
        rail_margin_v=0.05,
        holdoff_s=1.5e-3,
        velocity_cutoff_hz=1000.0,
        stroke_offset_v=0.02,
        stroke_lag_s=2.5e-4,
    )
    rng = np.random.default_rng(5)
    t = np.arange(4000) / FS
    sv = 1.25 + 1.5 * np.sin(2 * math.pi * 140 * t) + 0.01 * rng.standard_normal(t.size)
    pv = 1.25 + 0.8 * np.sin(2 * math.pi * 140 * t + 1.0)
    sv[[17, 900, 901]] = [np.nan, np.inf, 9.0]  # non-finite and above the rail
    pv[[55, 3000]] = [-np.inf, -6.0]
    state, parts = fe.initial_state(p), []
    for a in range(0, t.size, 10):
        state, est = fe.step(state, fe.FrontendInputs(sv[a : a + 10], pv[a : a + 10]), p)
        parts.append(est)
    stroke = np.concatenate([e.stroke_rad for e in parts])
    np.testing.assert_array_equal(stroke, _frontend_reference(sv, p, "stroke"))
    np.testing.assert_array_equal(
        np.concatenate([e.pitch_rad for e in parts]), _frontend_reference(pv, p, "pitch")
    )
    velocity = np.full(t.size, np.nan)
    ok = np.isfinite(stroke)
    velocity[ok] = signal.lfilter(
        *fe.velocity_ba(p.velocity_cutoff_hz, FS), stroke[ok], zi=np.zeros(2)
    )[0]
    np.testing.assert_array_equal(
        np.concatenate([e.stroke_velocity_rad_s for e in parts]), velocity
    )
    valid = np.concatenate([e.stroke_valid for e in parts])
    assert (
        not valid[17 : 17 + 31].any() and valid[17 + 31] and not valid[900:932].any() and valid[932]
    )
