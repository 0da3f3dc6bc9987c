"""flaair_sim.core.plant: dynamics against closed forms
and solve_ivp, sensor chain, effects, step/batch.
"""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from flaair_model.model import Model, with_effects
from flaair_model.model_io import load_model
from flaair_model.validation import ModelError
from flaair_sim.core.drive import chirp, sine, stepped_sine
from flaair_sim.core.measured_run import synthesize_measured_run
from flaair_sim.core.plant import (
    PlantInputs,
    PlantState,
    PlantStepParams,
    SimOutput,
    initial_state,
    n_substeps,
    simulate,
    simulate_batch,
    step,
)

FS_HZ = 20_000.0

ALL_EFFECTS = {
    "sensor_delay": {"delay_s": 2.3e-4, "channel": "both"},
    "charge_amp_highpass": {"corner_hz": 3.0, "channel": "both"},
    "feedthrough": {"gain_v_per_v": 2e-3},
    "transmission_nonlinearity": {"cubic_per_rad2": 0.2},
    "hinge_stiffening": {"cubic_per_rad2": 1.5},
    "structural_damping": {"damping_ratio": 0.03},
    "strain_transfer_loss": {"efficiency": 0.23, "channel": "pitch"},
    "collision": {"stroke_limit_deg": 30.0},
    "wing_damage": {"inertia_factor": 0.85},
}


@pytest.fixture(scope="module")
def model() -> Model:
    return load_model()


def t_s(n: int) -> np.ndarray:
    return np.arange(n) / FS_HZ


def fundamental(y: np.ndarray, frequency_hz: float, window: int) -> complex:
    """Complex amplitude C of y ~ Re(C exp(j w t)) over the last `window` samples."""
    t = t_s(len(y))[-window:]
    w = 2 * np.pi * frequency_hz
    basis = np.column_stack([np.cos(w * t), np.sin(w * t), np.ones_like(t)])
    (a, b, _), *_ = np.linalg.lstsq(basis, y[-window:], rcond=None)
    return complex(a, -b)


def ideal(model: Model) -> Model:
    """Linear version of the model: no quadratic aerodynamic terms."""
    plant = dataclasses.replace(model.plant, aero_damping_nm_s2=0.0, aero_coupling_nm_s2=0.0)
    return dataclasses.replace(model, plant=plant)


# --------------------------------------------------------------------------- dynamics


@pytest.mark.slow  # the reference solution by solve_ivp at tight tolerances
def test_nominal_agrees_with_solve_ivp(model):
    """1 s chirp 20-200 Hz at 100 V: RK4 vs DOP853 (rtol 1e-10) with the same ZOH input."""
    n = int(FS_HZ)
    drive = chirp(t_s(n), 100.0, 20.0, 200.0, 1.0)
    out = simulate(drive, FS_HZ, model)
    pl = model.plant
    inertia, gamma, k, ga = (
        pl.stroke_inertia_kg_m2,
        pl.aero_damping_nm_s2,
        pl.stroke_stiffness_nm_per_rad,
        pl.actuator_gain_nm_per_v,
    )
    ip, cp, kh, jc, dp = (
        pl.pitch_inertia_kg_m2,
        pl.hinge_damping_nm_s_per_rad,
        pl.hinge_stiffness_nm_per_rad,
        pl.inertial_coupling_kg_m2,
        pl.aero_coupling_nm_s2,
    )

    def rhs(_t, y, v):
        phi, dphi, psi, dpsi = y
        ddphi = (ga * v - gamma * abs(dphi) * dphi - k * phi) / inertia
        return [
            dphi,
            ddphi,
            dpsi,
            (-cp * dpsi - kh * psi - jc * ddphi - dp * abs(dphi) * dphi) / ip,
        ]

    h = 1.0 / FS_HZ
    y = np.zeros(4)
    ref = np.empty((n, 4))
    for i in range(n):
        ref[i] = y
        sol = solve_ivp(
            rhs,
            (0.0, h),
            y,
            method="DOP853",
            rtol=1e-10,
            atol=1e-13,
            args=(drive[i],),
            first_step=h,
        )
        y = sol.y[:, -1]
    assert np.degrees(np.max(np.abs(ref[:, 0]))) > 20  # the test exercises large strokes
    assert np.degrees(np.max(np.abs(out.stroke_rad - ref[:, 0]))) < 0.05
    assert np.degrees(np.max(np.abs(out.pitch_rad - ref[:, 2]))) < 0.05


@pytest.mark.parametrize("damage", [None, 0.7])
@pytest.mark.parametrize("frequency_hz", [60.0, 140.0, 230.0])
def test_linear_response_matches_transfer_function(model, frequency_hz, damage):
    """With the quadratic terms off: stroke = G_a/(K - I w^2 + j
    w c) V, pitch = J_c w^2/(k_h - I_p w^2 + j w c_p) stroke.
    """
    zeta = 0.05
    effects = {"structural_damping": {"damping_ratio": zeta}}
    if damage is not None:
        effects["wing_damage"] = {"inertia_factor": damage}
    m = with_effects(ideal(model), effects)
    n = int(0.5 * FS_HZ)
    amplitude_v = 10.0
    out = simulate(sine(t_s(n), amplitude_v, frequency_hz), FS_HZ, m)

    pl = model.plant
    factor = 1.0 if damage is None else damage
    w = 2 * np.pi * frequency_hz
    h = 1.0 / FS_HZ
    k = pl.stroke_stiffness_nm_per_rad
    c = 2 * zeta * math.sqrt(k * pl.stroke_inertia_kg_m2)
    # zero-order hold of a sampled sine: fundamental scaled by sinc and delayed half a sample
    zoh = np.sinc(w * h / (2 * np.pi)) * np.exp(-0.5j * w * h)
    # the drive A sin(w t) is Re(-j A exp(j w t))
    stroke = (
        -1j
        * amplitude_v
        * zoh
        * pl.actuator_gain_nm_per_v
        / (k - factor * pl.stroke_inertia_kg_m2 * w**2 + 1j * w * c)
    )
    pitch = (
        stroke
        * pl.inertial_coupling_kg_m2
        * w**2
        / (
            pl.hinge_stiffness_nm_per_rad
            - factor * pl.pitch_inertia_kg_m2 * w**2
            + 1j * w * pl.hinge_damping_nm_s_per_rad
        )
    )
    window = int(0.1 * FS_HZ)
    got_stroke = fundamental(out.stroke_rad, frequency_hz, window)
    got_pitch = fundamental(out.pitch_rad, frequency_hz, window)
    assert abs(got_stroke - stroke) < 1e-5 * abs(stroke)
    assert abs(got_pitch - pitch) < 1e-5 * abs(pitch)
    got_vs = fundamental(out.stroke_sensor_v, frequency_hz, window)
    assert abs(got_vs - m.stroke_volts_per_rad * stroke) < 1e-5 * abs(
        m.stroke_volts_per_rad * stroke
    )


def test_stroke_resonance_peak_at_200_vpp(model):
    frequencies = np.arange(100.0, 181.0, 5.0)
    dwell_s = 0.15
    drive, freq = stepped_sine(FS_HZ, 100.0, frequencies, dwell_s)
    out = simulate(drive, FS_HZ, model)
    dwell = round(dwell_s * FS_HZ)
    stroke = np.degrees(out.stroke_rad).reshape(len(frequencies), dwell)[:, dwell // 2 :]
    amplitude = 0.5 * (stroke.max(axis=1) - stroke.min(axis=1))
    peak_hz = frequencies[np.argmax(amplitude)]
    assert 120.0 <= peak_hz <= 150.0
    assert amplitude.max() > 1.2 * max(amplitude[0], amplitude[-1])
    assert np.all(freq.reshape(len(frequencies), dwell)[:, 0] == frequencies)


def test_rest_and_sample_convention(model):
    out = simulate(np.full(50, 100.0), FS_HZ, model)
    assert out.stroke_rad[0] == 0.0 and out.pitch_rad[0] == 0.0
    assert out.stroke_sensor_v[0] == model.sensors.reference_voltage_v
    assert out.stroke_rad[1] > 0  # positive drive -> positive stroke, sensor goes below V_HREF
    assert out.stroke_sensor_v[1] < model.sensors.reference_voltage_v
    # nominal sensors are the spec's linear maps of the angles
    vref = model.sensors.reference_voltage_v
    np.testing.assert_allclose(
        out.stroke_sensor_v - vref, model.stroke_volts_per_rad * out.stroke_rad, rtol=1e-12, atol=0
    )
    np.testing.assert_allclose(
        out.pitch_sensor_v - vref, model.pitch_volts_per_rad * out.pitch_rad, rtol=1e-12, atol=0
    )


# --------------------------------------------------------------------------- effects

DRIVE_N = 4000


@pytest.fixture(scope="module")
def drive() -> np.ndarray:
    return chirp(t_s(DRIVE_N), 100.0, 100.0, 180.0, DRIVE_N / FS_HZ)


@pytest.fixture(scope="module")
def nominal(model, drive) -> SimOutput:
    return simulate(drive, FS_HZ, model)


def deviation(v: np.ndarray, model: Model) -> np.ndarray:
    return v - model.sensors.reference_voltage_v


def assert_same_angles(a: SimOutput, b: SimOutput) -> None:
    assert np.array_equal(a.stroke_rad, b.stroke_rad)
    assert np.array_equal(a.pitch_rad, b.pitch_rad)


def test_sensor_delay_integer_shift(model, drive, nominal):
    shift = 7
    out = simulate(drive, FS_HZ, with_effects(model, {"sensor_delay": {"delay_s": shift / FS_HZ}}))
    assert_same_angles(out, nominal)
    vref = model.sensors.reference_voltage_v
    for got, ref in (
        (out.stroke_sensor_v, nominal.stroke_sensor_v),
        (out.pitch_sensor_v, nominal.pitch_sensor_v),
    ):
        assert np.array_equal(got[shift:], ref[:-shift])
        assert np.all(got[:shift] == vref)
    only = simulate(
        drive,
        FS_HZ,
        with_effects(model, {"sensor_delay": {"delay_s": shift / FS_HZ, "channel": "stroke"}}),
    )
    assert np.array_equal(only.pitch_sensor_v, nominal.pitch_sensor_v)
    assert np.array_equal(only.stroke_sensor_v[shift:], nominal.stroke_sensor_v[:-shift])


def test_sensor_delay_fractional_is_linear_interpolation(model, drive, nominal):
    delay_s = 2.25 / FS_HZ
    out = simulate(
        drive,
        FS_HZ,
        with_effects(model, {"sensor_delay": {"delay_s": delay_s, "channel": "pitch"}}),
    )
    t = t_s(DRIVE_N)
    expected = np.interp(
        t - delay_s, t, nominal.pitch_sensor_v, left=model.sensors.reference_voltage_v
    )
    np.testing.assert_allclose(out.pitch_sensor_v, expected, rtol=0, atol=1e-12)
    assert np.array_equal(out.stroke_sensor_v, nominal.stroke_sensor_v)


def test_charge_amp_highpass_corner(model):
    """At its corner a first-order high-pass passes 1/sqrt(2) of the signal, 45 degrees ahead."""
    corner_hz = 80.0
    base = with_effects(model, {"structural_damping": {"damping_ratio": 0.3}})  # quick settling
    n = int(0.4 * FS_HZ)
    drive = sine(t_s(n), 50.0, corner_hz)
    ref = simulate(drive, FS_HZ, base)
    out = simulate(
        drive,
        FS_HZ,
        with_effects(base, {"charge_amp_highpass": {"corner_hz": corner_hz, "channel": "stroke"}}),
    )
    assert_same_angles(out, ref)
    assert np.array_equal(out.pitch_sensor_v, ref.pitch_sensor_v)
    window = int(0.1 * FS_HZ)
    ratio = fundamental(deviation(out.stroke_sensor_v, model), corner_hz, window) / fundamental(
        deviation(ref.stroke_sensor_v, model), corner_hz, window
    )
    assert abs(ratio) == pytest.approx(1 / math.sqrt(2), rel=1e-6)
    assert np.angle(ratio) == pytest.approx(math.pi / 4, abs=1e-6)
    # DC is removed: a held drive decays back to V_HREF
    held = simulate(
        np.full(n, 50.0), FS_HZ, with_effects(base, {"charge_amp_highpass": {"corner_hz": 20.0}})
    )
    assert abs(deviation(held.stroke_sensor_v, model)[-1]) < 1e-6
    assert abs(deviation(held.stroke_sensor_v, model)).max() > 0.05


def test_charge_amp_highpass_above_nyquist_refused(model):
    with pytest.raises(ModelError, match="corner_hz"):
        simulate(
            np.zeros(10), 100.0, with_effects(model, {"charge_amp_highpass": {"corner_hz": 60.0}})
        )


def test_feedthrough_adds_gain_times_drive(model, drive, nominal):
    gain = 3e-3
    out = simulate(drive, FS_HZ, with_effects(model, {"feedthrough": {"gain_v_per_v": gain}}))
    assert_same_angles(out, nominal)
    assert np.array_equal(out.pitch_sensor_v, nominal.pitch_sensor_v)
    np.testing.assert_allclose(
        out.stroke_sensor_v - nominal.stroke_sensor_v, gain * drive, rtol=0, atol=1e-12
    )


def test_transmission_nonlinearity_changes_only_the_stroke_sensor(model, drive, nominal):
    cubic = 0.4
    out = simulate(
        drive, FS_HZ, with_effects(model, {"transmission_nonlinearity": {"cubic_per_rad2": cubic}})
    )
    assert_same_angles(out, nominal)
    assert np.array_equal(out.pitch_sensor_v, nominal.pitch_sensor_v)
    phi = nominal.stroke_rad
    np.testing.assert_allclose(
        deviation(out.stroke_sensor_v, model),
        model.stroke_volts_per_rad * (phi + cubic * phi**3),
        rtol=1e-12,
        atol=1e-15,
    )
    assert np.max(np.abs(out.stroke_sensor_v - nominal.stroke_sensor_v)) > 0.01


def test_strain_transfer_loss_scales_deviation(model, drive, nominal):
    out = simulate(
        drive, FS_HZ, with_effects(model, {"strain_transfer_loss": {"efficiency": 0.23}})
    )
    assert_same_angles(out, nominal)
    assert np.array_equal(out.stroke_sensor_v, nominal.stroke_sensor_v)
    np.testing.assert_allclose(
        deviation(out.pitch_sensor_v, model),
        0.23 * deviation(nominal.pitch_sensor_v, model),
        rtol=1e-12,
        atol=1e-15,
    )
    both = simulate(
        drive,
        FS_HZ,
        with_effects(model, {"strain_transfer_loss": {"efficiency": 0.5, "channel": "both"}}),
    )
    np.testing.assert_allclose(
        deviation(both.stroke_sensor_v, model),
        0.5 * deviation(nominal.stroke_sensor_v, model),
        rtol=1e-12,
        atol=1e-15,
    )


def test_hinge_stiffening_changes_only_pitch(model, drive, nominal):
    out = simulate(drive, FS_HZ, with_effects(model, {"hinge_stiffening": {"cubic_per_rad2": 2.0}}))
    assert np.array_equal(out.stroke_rad, nominal.stroke_rad)
    assert np.array_equal(out.stroke_sensor_v, nominal.stroke_sensor_v)
    assert np.max(np.abs(np.degrees(out.pitch_rad - nominal.pitch_rad))) > 1.0
    # stiffening bounds the large pitch excursions
    assert np.max(np.abs(out.pitch_rad)) < np.max(np.abs(nominal.pitch_rad))
    # and vanishes at small deflection (cubic term)
    small = drive * 1e-3
    a = simulate(small, FS_HZ, model)
    b = simulate(small, FS_HZ, with_effects(model, {"hinge_stiffening": {"cubic_per_rad2": 2.0}}))
    # relative change ~ c psi^2 with psi ~ 5 mrad here
    np.testing.assert_allclose(
        b.pitch_rad, a.pitch_rad, rtol=0, atol=1e-3 * np.max(np.abs(a.pitch_rad))
    )


def test_structural_damping_lowers_the_resonant_stroke(model):
    n = int(0.3 * FS_HZ)
    drive = sine(t_s(n), 100.0, model.plant.stroke_natural_frequency_hz)
    a = simulate(drive, FS_HZ, model)
    b = simulate(drive, FS_HZ, with_effects(model, {"structural_damping": {"damping_ratio": 0.1}}))
    tail = slice(n // 2, None)
    assert np.ptp(b.stroke_rad[tail]) < 0.8 * np.ptp(a.stroke_rad[tail])


def test_collision_stops_the_stroke_and_excites_pitch(model, drive, nominal):
    limit_deg = 25.0
    m = with_effects(model, {"collision": {"stroke_limit_deg": limit_deg}})
    out = simulate(drive, FS_HZ, m)
    stroke_deg = np.degrees(out.stroke_rad)
    nominal_deg = np.degrees(nominal.stroke_rad)
    assert nominal_deg.max() > limit_deg + 10
    first = int(np.argmax(nominal_deg > limit_deg))
    # bit-identical until the sample period in which the wing first reaches the obstacle
    assert np.array_equal(out.stroke_rad[:first], nominal.stroke_rad[:first])
    assert np.array_equal(out.pitch_rad[:first], nominal.pitch_rad[:first])
    assert out.stroke_rad[first] < nominal.stroke_rad[first]
    # the stop holds: penetration is a small fraction of the free overshoot
    assert stroke_deg.max() - limit_deg < 0.25 * (nominal_deg.max() - limit_deg)
    # one-sided: the other side of the stroke still swings past -limit
    assert stroke_deg.min() < -limit_deg
    # the impact kicks the pitch through J_c phi''
    assert np.max(np.abs(np.degrees(out.pitch_rad - nominal.pitch_rad))) > 5.0
    assert n_substeps(m, FS_HZ)[1] > n_substeps(m, FS_HZ)[0] == n_substeps(model, FS_HZ)[0]


def test_wing_damage_raises_the_natural_frequency(model):
    """Free decay after a held step: the ringing frequency is f_n / sqrt(inertia_factor)."""
    factor = 0.6
    m = with_effects(ideal(model), {"wing_damage": {"inertia_factor": factor}})
    n = int(0.2 * FS_HZ)
    out = simulate(np.full(n, 10.0), FS_HZ, m)
    centred = out.stroke_rad - out.stroke_rad.mean()
    crossings = np.flatnonzero(np.diff(np.signbit(centred)))
    measured_hz = (len(crossings) - 1) / 2 / ((crossings[-1] - crossings[0]) / FS_HZ)
    expected_hz = model.plant.stroke_natural_frequency_hz / math.sqrt(factor)
    assert measured_hz == pytest.approx(expected_hz, rel=2e-3)
    # the static deflection (stiffness) is unchanged: mean stroke = G_a V / K
    static = model.plant.actuator_gain_nm_per_v * 10.0 / model.plant.stroke_stiffness_nm_per_rad
    assert out.stroke_rad.mean() == pytest.approx(static, rel=1e-2)


def test_effects_compose(model, drive, nominal):
    shift, efficiency, gain = 5, 0.4, 1e-3
    m = with_effects(
        model,
        {
            "sensor_delay": {"delay_s": shift / FS_HZ},
            "strain_transfer_loss": {"efficiency": efficiency, "channel": "both"},
            "feedthrough": {"gain_v_per_v": gain},
        },
    )
    out = simulate(drive, FS_HZ, m)
    assert_same_angles(out, nominal)
    expected_s = efficiency * deviation(nominal.stroke_sensor_v, model) + gain * drive
    expected_p = efficiency * deviation(nominal.pitch_sensor_v, model)
    np.testing.assert_allclose(
        deviation(out.stroke_sensor_v, model)[shift:], expected_s[:-shift], rtol=0, atol=1e-12
    )
    np.testing.assert_allclose(
        deviation(out.pitch_sensor_v, model)[shift:], expected_p[:-shift], rtol=0, atol=1e-12
    )
    everything = simulate(drive, FS_HZ, with_effects(model, ALL_EFFECTS))
    assert all(np.all(np.isfinite(a)) for a in everything)


# --------------------------------------------------------------------------- step, batch, noise


def test_block_stepping_equals_whole_record(model, drive):
    m = with_effects(model, ALL_EFFECTS)
    whole = simulate(drive, FS_HZ, m, noise=True, rng=np.random.default_rng(7))
    rng_blocks = np.random.default_rng(3)
    noise_rng = np.random.default_rng(7)
    state = initial_state(PlantStepParams(m, FS_HZ))
    parts = []
    start = 0
    while start < DRIVE_N:
        size = int(rng_blocks.choice([0, 1, 2, 17, 100, 333]))
        state, out = step(
            state, PlantInputs(drive[start : start + size], noise_rng), PlantStepParams(m, FS_HZ)
        )
        parts.append(out)
        start += size
    assert state.sample_index == DRIVE_N
    for i, name in enumerate(SimOutput._fields):
        assert np.array_equal(np.concatenate([p[i] for p in parts]), whole[i]), name


def test_state_is_immutable_and_checked(model):
    state = initial_state(PlantStepParams(model, FS_HZ))
    assert isinstance(state, PlantState)
    new_state, _ = step(state, PlantInputs(np.full(10, 50.0)), PlantStepParams(model, FS_HZ))
    assert np.all(state.mechanical == 0) and np.any(new_state.mechanical != 0)
    with pytest.raises(ValueError):
        new_state.mechanical[0] = 1.0
    with pytest.raises(ValueError, match="fs_hz"):
        step(state, PlantInputs(np.zeros(4)), PlantStepParams(model, 10_000.0))
    with pytest.raises(ValueError, match="drive_v"):
        step(state, PlantInputs(np.array([0.0, np.nan])), PlantStepParams(model, FS_HZ))


def test_model_may_change_between_blocks(model, drive):
    delayed = with_effects(model, {"sensor_delay": {"delay_s": 4 / FS_HZ}})
    state, _first = step(
        initial_state(PlantStepParams(model, FS_HZ)),
        PlantInputs(drive[:1000]),
        PlantStepParams(model, FS_HZ),
    )
    state, second = step(state, PlantInputs(drive[1000:2000]), PlantStepParams(delayed, FS_HZ))
    whole = simulate(drive[:2000], FS_HZ, model)
    assert np.array_equal(second.stroke_rad, whole.stroke_rad[1000:])
    # the new delay line starts from the recent history at rest level (zeros)
    assert np.array_equal(second.stroke_sensor_v[4:], whole.stroke_sensor_v[1000:1996])


def test_batch_equals_single(model, drive):
    models = [
        model,
        with_effects(model, ALL_EFFECTS),
        with_effects(
            model, {"collision": {"stroke_limit_deg": 20.0}, "sensor_delay": {"delay_s": 1.7e-4}}
        ),
        with_effects(
            model,
            {
                "wing_damage": {"inertia_factor": 0.5},
                "charge_amp_highpass": {"corner_hz": 10.0, "channel": "pitch"},
            },
        ),
    ]
    batch = simulate_batch(drive, FS_HZ, models)
    assert batch.stroke_rad.shape == (len(models), DRIVE_N)
    for i, m in enumerate(models):
        single = simulate(drive, FS_HZ, m)
        for j, name in enumerate(SimOutput._fields):
            assert np.array_equal(batch[j][i], single[j]), (i, name)
    drives = np.stack([drive, 0.5 * drive, -drive, drive[::-1]])
    per_model = simulate_batch(drives, FS_HZ, models)
    for i, m in enumerate(models):
        assert np.array_equal(
            per_model.pitch_sensor_v[i], simulate(drives[i], FS_HZ, m).pitch_sensor_v
        )
    with pytest.raises(ValueError, match="drive_v"):
        simulate_batch(drives[:2], FS_HZ, models)


def test_noise_level_and_reproducibility(model, drive, nominal):
    a = simulate(drive, FS_HZ, model, noise=True, rng=np.random.default_rng(1))
    b = simulate(drive, FS_HZ, model, noise=True, rng=np.random.default_rng(1))
    assert np.array_equal(a.stroke_sensor_v, b.stroke_sensor_v)
    assert_same_angles(a, nominal)
    sigma = model.noise.sensor_noise_v_rms
    for got, ref in (
        (a.stroke_sensor_v, nominal.stroke_sensor_v),
        (a.pitch_sensor_v, nominal.pitch_sensor_v),
    ):
        assert np.std(got - ref) == pytest.approx(sigma, rel=0.05)
    assert not np.allclose(
        a.stroke_sensor_v - nominal.stroke_sensor_v, a.pitch_sensor_v - nominal.pitch_sensor_v
    )


def test_synthesize_measured_run_columns_and_units(model, drive, nominal):
    run = synthesize_measured_run(drive, FS_HZ, model, np.random.default_rng(5))
    assert list(run) == [
        "time_s",
        "drive_v",
        "stroke_sensor_v",
        "pitch_sensor_v",
        "stroke_deg",
        "pitch_deg",
    ]
    assert all(len(col) == DRIVE_N for col in run.values())
    assert run["time_s"][1] == pytest.approx(1 / FS_HZ)
    assert np.array_equal(run["drive_v"], drive)
    tracking = run["stroke_deg"] - np.degrees(nominal.stroke_rad)
    assert np.std(tracking) == pytest.approx(model.noise.tracking_noise_deg_rms, rel=0.05)
    assert np.std(run["pitch_sensor_v"] - nominal.pitch_sensor_v) == pytest.approx(
        model.noise.sensor_noise_v_rms, rel=0.05
    )


def test_collision_matches_refined_step(model):
    """The stiff contact at 20 kHz agrees with the same ZOH drive simulated at 10x the rate."""
    m = with_effects(model, {"collision": {"stroke_limit_deg": 20.0}})
    n, up = 4000, 10
    drive = chirp(t_s(n), 100.0, 100.0, 180.0, n / FS_HZ)
    coarse = simulate(drive, FS_HZ, m)
    fine = simulate(np.repeat(drive, up), up * FS_HZ, m)
    assert np.degrees(coarse.stroke_rad).max() < 25.0 and np.degrees(coarse.stroke_rad).max() > 20.0
    assert np.degrees(np.max(np.abs(coarse.stroke_rad - fine.stroke_rad[::up]))) < 0.05
    assert np.degrees(np.max(np.abs(coarse.pitch_rad - fine.pitch_rad[::up]))) < 0.05


def test_batch_into_preallocated_output(model, drive):
    models = [model, with_effects(model, {"feedthrough": {"gain_v_per_v": 1e-3}})]
    out = SimOutput(*(np.full((2, DRIVE_N), np.nan) for _ in range(4)))
    got = simulate_batch(drive, FS_HZ, models, out=out)
    assert all(g is o for g, o in zip(got, out, strict=True))
    fresh = simulate_batch(drive, FS_HZ, models)
    assert all(np.array_equal(g, f) for g, f in zip(got, fresh, strict=True))
    with pytest.raises(ValueError, match=re.escape("out.stroke_rad")):
        simulate_batch(
            drive, FS_HZ, models, out=SimOutput(*(np.empty((3, DRIVE_N)) for _ in range(4)))
        )


def test_batch_of_one_and_of_none(model, drive):
    one = simulate_batch(drive, FS_HZ, [model])
    assert np.array_equal(one.pitch_sensor_v[0], simulate(drive, FS_HZ, model).pitch_sensor_v)
    none = simulate_batch(drive, FS_HZ, [])
    assert none.stroke_rad.shape == (0, DRIVE_N)
