"""dSA controller core (flaair_control.core.dsa):
discretization, blend, limits, sync->async transition.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from flaair_control.core import dsa, hopf

FS = 20000.0
BLOCK = 10
G_A = 1.67e-7
KAPPA = 0.5
R3 = hopf.r3_for_onset_frequency(KAPPA, 150.0)
MU = 2.0e-8


def make(**kw) -> dsa.DsaParams:
    base = dict(
        r3_rad_s=R3,
        kappa=KAPPA,
        mu_nm_s_per_rad=MU,
        actuator_gain_nm_per_v=G_A,
        sample_rate_hz=FS,
        drive_limit_v=100.0,
        sync_amplitude_v=0.0,
        sync_frequency_hz=100.0,
        sync_phase_rad=0.0,
        kr_schedule=dsa.KrSchedule(0.0, 0.0, 0.0, 0.0),
        loop_delay_s=0.0,
        compensation_frequency_hz=None,
    )
    base.update(kw)
    return dsa.DsaParams(**base)


def test_coefficients_follow_the_paper():
    p = make()
    assert p.a == pytest.approx(R3 * (1 + KAPPA))
    assert p.b == pytest.approx(KAPPA * R3**2)
    assert p.c == pytest.approx(MU * KAPPA * R3**2)


@pytest.mark.parametrize("advanced", [False, True])
def test_discrete_response_matches_continuous_filter(advanced):
    p = make(loop_delay_s=dsa.loop_delay_s(BLOCK, FS))
    f = np.linspace(20.0, 250.0, 60)  # Tustin warp (w T)^2/12 keeps this band within 1e-3
    ratio = dsa.frequency_response(p, f, advanced) / dsa.continuous_response(p, f, advanced)
    assert np.max(np.abs(np.abs(ratio) - 1)) < 1e-3
    assert np.max(np.abs(np.degrees(np.angle(ratio)))) < 0.05
    # exact at the pre-warp frequency
    fc = p.design_omega_rad_s / (2 * math.pi)
    r_c = (
        dsa.frequency_response(p, [fc], advanced)[0] / dsa.continuous_response(p, [fc], advanced)[0]
    )
    assert abs(r_c - 1) < 1e-7


def test_phase_advance_cancels_the_loop_delay_at_the_design_frequency():
    t = dsa.loop_delay_s(BLOCK, FS)
    p = make(loop_delay_s=t)
    wc = p.design_omega_rad_s
    fc = wc / (2 * math.pi)
    adv = dsa.frequency_response(p, [fc], True)[0] / dsa.frequency_response(p, [fc], False)[0]
    assert adv == pytest.approx(np.exp(1j * wc * t), abs=1e-7)
    # away from w_c it is only approximate: 140 Hz differs from a pure advance
    f = 140.0
    adv140 = dsa.frequency_response(p, [f], True)[0] / dsa.frequency_response(p, [f], False)[0]
    assert abs(np.angle(adv140) - 2 * math.pi * f * t) > 1e-3


def test_loop_delay_and_its_phase_at_140_hz():
    t = dsa.loop_delay_s(BLOCK, FS)
    assert t == pytest.approx(0.55e-3)
    assert math.degrees(2 * math.pi * 140.0 * t) == pytest.approx(27.72, abs=0.01)
    assert math.degrees(2 * math.pi * 140.0 * BLOCK / FS) == pytest.approx(25.2, abs=0.01)


def test_velocity_step_response_matches_the_analytic_solution():
    p = make()  # no advance: torque_raw == torque
    n = 4000
    _state, (_, sig) = dsa.step(dsa.initial_state(p), dsa.DsaInputs(np.ones(n), 0.0), p)
    # Tustin sees the sampled step as a ramp over the first sample: half a sample late.
    t = (np.arange(n) + 0.5) / FS
    p1, p2 = R3, KAPPA * R3
    analytic = -p.c * (
        1 / (p1 * p2) + np.exp(-p1 * t) / (p1 * (p1 - p2)) + np.exp(-p2 * t) / (p2 * (p2 - p1))
    )
    assert np.max(np.abs(sig.torque_nm - analytic)) < 1e-3 * MU
    assert sig.torque_nm[-1] == pytest.approx(-MU, rel=1e-6)  # DC: tau = -mu phi'
    np.testing.assert_array_equal(sig.torque_nm, sig.torque_raw_nm)


def test_block_splitting_changes_nothing():
    p = make(
        loop_delay_s=0.55e-3,
        sync_amplitude_v=40.0,
        sync_frequency_hz=60.0,
        kr_schedule=dsa.KrSchedule(1.0, 0.0, 0.01, 0.02),
    )
    rng = np.random.default_rng(3)
    v = rng.standard_normal(1000) * 100.0
    _, (whole, _sig_w) = dsa.step(dsa.initial_state(p), dsa.DsaInputs(v, 0.0), p)
    state = dsa.initial_state(p)
    parts = []
    i = 0
    for size in rng.integers(1, 37, 200):
        if i >= v.size:
            break
        state, (d, _) = dsa.step(state, dsa.DsaInputs(v[i : i + size], i / FS), p)
        parts.append(d)
        i += size
    np.testing.assert_allclose(np.concatenate(parts), whole, rtol=0, atol=1e-12)


def test_kr_schedule_and_blend():
    sched = dsa.KrSchedule(start_value=1.0, end_value=0.0, start_time_s=0.1, duration_s=0.2)
    np.testing.assert_allclose(
        sched.value(np.array([0.0, 0.1, 0.2, 0.3, 0.5])), [1, 1, 0.5, 0, 0], atol=1e-12
    )
    p = make(sync_amplitude_v=30.0, sync_frequency_hz=50.0, kr_schedule=sched, drive_limit_v=1e6)
    v = np.sin(np.arange(8000) / FS * 2 * np.pi * 150.0) * 500.0
    _, (drive, sig) = dsa.step(dsa.initial_state(p), dsa.DsaInputs(v, 0.0), p)
    t = np.arange(8000) / FS
    sync = 30.0 * np.sin(2 * np.pi * 50.0 * t)
    np.testing.assert_allclose(sig.sync_v, sync, atol=1e-9)
    first = t < 0.1
    np.testing.assert_allclose(drive[first], sync[first], atol=1e-9)  # fully synchronous
    last = t >= 0.3
    np.testing.assert_allclose(drive[last], sig.async_v[last], atol=1e-9)  # fully asynchronous
    mid = np.argmin(np.abs(t - 0.2))
    assert drive[mid] == pytest.approx(0.5 * sync[mid] + 0.5 * sig.async_v[mid], abs=1e-9)
    np.testing.assert_allclose(sig.async_v, sig.torque_nm / G_A)


def test_drive_limit_and_non_finite_velocity():
    p = make(drive_limit_v=50.0)
    v = np.full(200, 1e4)
    v[50:60] = np.nan
    v[70] = np.inf
    state, (drive, sig) = dsa.step(dsa.initial_state(p), dsa.DsaInputs(v, 0.0), p)
    assert np.all(np.isfinite(drive)) and np.max(np.abs(drive)) <= 50.0
    assert np.max(np.abs(sig.drive_unclipped_v)) > 50.0  # the limit did act
    assert not sig.velocity_valid[55] and not sig.velocity_valid[70] and sig.velocity_valid[0]
    assert np.all(np.isfinite(state.zi_advanced)) and np.all(np.isfinite(state.zi_raw))
    _, (drive2, _) = dsa.step(state, dsa.DsaInputs(np.zeros(10), 0.01), p)
    assert np.all(np.isfinite(drive2))


@pytest.mark.parametrize(
    "field,value",
    [
        ("r3_rad_s", 0.0),
        ("kappa", -1.0),
        ("actuator_gain_nm_per_v", 0.0),
        ("sample_rate_hz", math.nan),
        ("loop_delay_s", -1e-3),
        ("mu_nm_s_per_rad", math.inf),
    ],
)
def test_bad_parameters_are_named(field, value):
    with pytest.raises(ValueError, match=field):
        make(**{field: value})


def test_bad_schedule_is_named():
    with pytest.raises(ValueError, match="end_value"):
        dsa.KrSchedule(1.0, 1.5, 0.0, 0.0)


# --------------------------------------------------------------------------- on the simulated robot

import flaair_model.model_io as sim_model_io
import flaair_sim.core.plant as plant_mod


def test_sync_to_async_transition_on_the_simulated_robot():
    """Paper Fig. asynch: sync far below resonance, K_r 1 -> 0, self-excited above resonance."""
    model = sim_model_io.load_model()
    vpr = model.stroke_volts_per_rad
    vref = model.sensors.reference_voltage_v
    lin = hopf.LinearStrokePlant(
        model.plant.stroke_inertia_kg_m2, model.plant.stroke_stiffness_nm_per_rad
    )
    r3 = hopf.r3_for_onset_frequency(KAPPA, 142.0)
    mu = 10.0 * hopf.hopf_onset(lin, r3, KAPPA).mu_nm_s_per_rad
    delay = dsa.loop_delay_s(BLOCK, FS)
    p = dsa.DsaParams(
        r3_rad_s=r3,
        kappa=KAPPA,
        mu_nm_s_per_rad=mu,
        actuator_gain_nm_per_v=model.plant.actuator_gain_nm_per_v,
        sample_rate_hz=FS,
        drive_limit_v=100.0,
        sync_amplitude_v=20.0,
        sync_frequency_hz=60.0,
        kr_schedule=dsa.KrSchedule(1.0, 0.0, 0.3, 0.3),
        loop_delay_s=delay,
        sync_phase_rad=0.0,
        compensation_frequency_hz=None,
    )
    rng = np.random.default_rng(7)
    state = plant_mod.initial_state(plant_mod.PlantStepParams(model, FS))
    ctrl = dsa.initial_state(p)
    drive = np.zeros(BLOCK)
    prev = 0.0
    stroke = []
    for k in range(int(1.6 * FS / BLOCK)):
        state, out = plant_mod.step(
            state, plant_mod.PlantInputs(drive, rng), plant_mod.PlantStepParams(model, FS)
        )  # sensor noise on
        # sensor-derived stroke
        phi = (out.stroke_sensor_v - vref) / vpr
        vel = np.diff(np.concatenate([[prev], phi])) * FS
        prev = phi[-1]
        ctrl, (drive, _) = dsa.step(ctrl, dsa.DsaInputs(vel, (k + 1) * BLOCK / FS), p)
        stroke.append(phi)
    x = np.degrees(np.concatenate(stroke))

    def freq(a, b):
        seg = x[int(a * FS) : int(b * FS)]
        seg = seg - seg.mean()
        up = np.nonzero((seg[:-1] < -0.5) & (seg[1:] >= -0.5))[0]
        up = up[np.concatenate([[True], np.diff(up) > 20])]
        return FS / np.mean(np.diff(up))

    f_sync, f_async = freq(0.1, 0.3), freq(1.2, 1.6)
    assert f_sync == pytest.approx(60.0, rel=0.01)
    amp_sync = np.ptp(x[int(0.1 * FS) : int(0.3 * FS)]) / 2
    fn = model.plant.stroke_natural_frequency_hz
    assert fn < f_async < 1.15 * fn
    lc = hopf.limit_cycle(lin, model.plant.aero_damping_nm_s2, r3, KAPPA, mu, delay, delay)
    assert f_async == pytest.approx(lc.frequency_hz, rel=0.02)
    amp_async = np.ptp(x[int(1.2 * FS) : int(1.6 * FS)]) / 2
    assert amp_async == pytest.approx(math.degrees(lc.amplitude_rad), rel=0.1)
    assert amp_sync > 0.5 and amp_async > 1.0


def test_dsa_params_builds_from_values_and_applies_the_delay_only_when_compensating() -> None:
    values = {
        "r3_rad_s": R3,
        "kappa": KAPPA,
        "mu_nm_s_per_rad": MU,
        "drive_limit_v": 100.0,
        "sync_amplitude_v": 0.0,
        "sync_frequency_hz": 100.0,
        "sync_phase_rad": 0.0,
        "compensate_delay": True,
        "compensation_frequency_hz": None,
        "unrelated_key": "ignored",
    }
    kr = dsa.KrSchedule(0.0, 0.0, 0.0, 0.0)
    built = dsa.dsa_params(
        values, actuator_gain_nm_per_v=G_A, sample_rate_hz=FS, loop_delay_s=5.5e-4, kr_schedule=kr
    )
    assert built == make(loop_delay_s=5.5e-4)
    off = dsa.dsa_params(
        {**values, "compensate_delay": False},
        actuator_gain_nm_per_v=G_A,
        sample_rate_hz=FS,
        loop_delay_s=5.5e-4,
        kr_schedule=kr,
    )
    assert off.loop_delay_s == 0.0
    del values["kappa"]
    with pytest.raises(dsa.DsaParameterError, match="lack kappa"):
        dsa.dsa_params(
            values, actuator_gain_nm_per_v=G_A, sample_rate_hz=FS, loop_delay_s=0.0, kr_schedule=kr
        )
