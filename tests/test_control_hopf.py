"""Hopf theory of the dSA loop (flaair_control.core.hopf)
against polynomial roots and the simulator.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.signal import hilbert

from flaair_control.core import dsa, hopf

FS = 20000.0
BLOCK = 10
I_NOM = 6.5e-11
PLANT = hopf.LinearStrokePlant.from_natural_frequency(I_NOM, 140.0)


# --------------------------------------------------------------------------- pure theory


@pytest.mark.parametrize("kappa", [0.2, 0.5, 1.0, 3.0])
@pytest.mark.parametrize("onset_hz", [145.0, 150.0, 200.0])
@pytest.mark.parametrize("damping", [0.0, 1e-9, 5e-9])
def test_closed_form_onset_is_where_the_poles_cross(kappa, onset_hz, damping):
    plant = replace(PLANT, damping_nm_s_per_rad=damping)
    r3 = hopf.r3_for_onset_frequency(kappa, onset_hz)
    on = hopf.hopf_onset(plant, r3, kappa)
    assert on.mu_nm_s_per_rad > 0
    below = hopf.closed_loop_poles(plant, r3, kappa, 0.98 * on.mu_nm_s_per_rad)
    above = hopf.closed_loop_poles(plant, r3, kappa, 1.02 * on.mu_nm_s_per_rad)
    at = hopf.closed_loop_poles(plant, r3, kappa, on.mu_nm_s_per_rad)
    assert below.real.max() < 0
    assert above.real.max() > 0
    crossing = at[np.argmax(at.real)]
    assert abs(crossing.real) < 1e-6 * on.omega_rad_s
    assert abs(abs(crossing.imag) - on.omega_rad_s) < 1e-6 * on.omega_rad_s
    # Third Hurwitz determinant vanishes at the onset.
    a4, a3, a2, a1, a0 = hopf.characteristic_polynomial(plant, r3, kappa, on.mu_nm_s_per_rad)
    hurwitz = a3 * a2 * a1 - a3**2 * a0 - a4 * a1**2
    assert abs(hurwitz) < 1e-9 * a3 * a2 * a1


@pytest.mark.parametrize("kappa", [0.3, 0.5, 1.0, 2.0])
def test_undamped_onset_frequency_is_exactly_sqrt_kappa_r3(kappa):
    r3 = hopf.r3_for_onset_frequency(kappa, 160.0)
    on = hopf.hopf_onset(PLANT, r3, kappa)
    assert on.omega_rad_s == pytest.approx(math.sqrt(kappa) * r3, rel=1e-12)
    assert on.frequency_hz == pytest.approx(160.0, rel=1e-12)
    k = PLANT.stiffness_nm_per_rad
    expected = (1 + kappa) * (I_NOM * kappa * r3**2 - k) / (kappa * r3)
    assert on.mu_nm_s_per_rad == pytest.approx(expected, rel=1e-12)


def test_filter_below_resonance_destabilises_the_undamped_plant_at_once():
    kappa = 0.5
    r3 = hopf.r3_for_onset_frequency(kappa, 120.0)  # sqrt(kappa) r3 below the 140 Hz resonance
    on = hopf.hopf_onset(PLANT, r3, kappa)
    assert on.mu_nm_s_per_rad == 0.0
    assert on.frequency_hz == pytest.approx(140.0, rel=1e-9)
    poles = hopf.closed_loop_poles(PLANT, r3, kappa, 1e-12)
    assert poles.real.max() > 0


def test_damping_moves_the_onset_above_sqrt_kappa_r3_and_vanishes_continuously():
    kappa, r3 = 0.5, hopf.r3_for_onset_frequency(0.5, 150.0)
    freqs = [
        hopf.hopf_onset(replace(PLANT, damping_nm_s_per_rad=c), r3, kappa).frequency_hz
        for c in (1e-8, 1e-10, 1e-12, 1e-14)
    ]
    assert all(f > 150.0 for f in freqs)
    assert freqs == sorted(freqs, reverse=True)
    # For small c_s the shift of w*^2 is linear in c_s: c_s a b / (I b - K).
    assert (freqs[2] - 150.0) / (freqs[3] - 150.0) == pytest.approx(100.0, rel=0.01)
    assert freqs[-1] == pytest.approx(150.0, rel=2e-6)


def test_delay_theory_reduces_to_closed_form_and_compensation_restores_it():
    kappa, r3 = 0.5, hopf.r3_for_onset_frequency(0.5, 150.0)
    exact = hopf.hopf_onset(PLANT, r3, kappa)
    no_delay = hopf.onset_with_delay(PLANT, r3, kappa, 0.0)
    assert no_delay.mu_nm_s_per_rad == pytest.approx(exact.mu_nm_s_per_rad, rel=1e-8)
    assert no_delay.omega_rad_s == pytest.approx(exact.omega_rad_s, rel=1e-9)
    t = dsa.loop_delay_s(BLOCK, FS)
    compensated = hopf.onset_with_delay(PLANT, r3, kappa, t, advance_s=t)
    assert compensated.mu_nm_s_per_rad == pytest.approx(exact.mu_nm_s_per_rad, rel=1e-8)
    assert compensated.omega_rad_s == pytest.approx(exact.omega_rad_s, rel=1e-9)
    # Uncompensated: 0.55 ms costs ~30 deg at 150 Hz, the filter already pumps at 140 Hz.
    raw = hopf.onset_with_delay(PLANT, r3, kappa, t)
    assert raw.mu_nm_s_per_rad == 0.0
    assert raw.frequency_hz == pytest.approx(140.0, rel=1e-9)


def test_bad_parameters_are_named():
    with pytest.raises(ValueError, match="kappa"):
        hopf.hopf_onset(PLANT, 1000.0, -1.0)
    with pytest.raises(ValueError, match="r3_rad_s"):
        hopf.hopf_onset(PLANT, 0.0, 0.5)
    with pytest.raises(ValueError, match="inertia_kg_m2"):
        hopf.LinearStrokePlant(0.0, 1.0)


# --------------------------------------------------------------------------- simulated loop

import flaair_model.model_io as sim_model_io
import flaair_sim.core.plant as plant_mod


@pytest.fixture(scope="module")
def model():
    return sim_model_io.load_model()


@pytest.fixture(scope="module")
def undamped(model):
    return replace(model, plant=replace(model.plant, aero_damping_nm_s2=0.0))


def _lin_plant(model) -> hopf.LinearStrokePlant:
    return hopf.LinearStrokePlant(
        model.plant.stroke_inertia_kg_m2, model.plant.stroke_stiffness_nm_per_rad
    )


def closed_loop(model, params: dsa.DsaParams, duration_s: float, kick_v: float = 5.0) -> np.ndarray:
    """Block loop: plant block k -> ideal stroke ->
    backward-difference velocity -> dSA -> block k+1.
    """
    n_blocks = round(duration_s * FS / BLOCK)
    state = plant_mod.initial_state(plant_mod.PlantStepParams(model, FS))
    ctrl = dsa.initial_state(params)
    drive = np.zeros(BLOCK)
    drive[:5] = kick_v
    prev = 0.0
    out = []
    for k in range(n_blocks):
        state, sim = plant_mod.step(
            state, plant_mod.PlantInputs(drive), plant_mod.PlantStepParams(model, FS)
        )
        phi = sim.stroke_rad
        vel = np.diff(np.concatenate([[prev], phi])) * FS
        prev = phi[-1]
        ctrl, (drive, _) = dsa.step(ctrl, dsa.DsaInputs(vel, (k + 1) * BLOCK / FS), params)
        out.append(phi)
    return np.concatenate(out)


def growth_and_frequency(phi: np.ndarray, skip_s: float = 0.05) -> tuple[float, float]:
    """Exponential growth rate (1/s) of the envelope and zero-crossing frequency (Hz)."""
    x = phi[int(skip_s * FS) :]
    env = np.abs(hilbert(x))
    t = np.arange(x.size) / FS
    sl = slice(x.size // 10, -x.size // 10)
    rate = np.polyfit(t[sl], np.log(env[sl]), 1)[0]
    up = np.nonzero((x[:-1] < 0) & (x[1:] >= 0))[0]
    return float(rate), float(FS / np.mean(np.diff(up[-20:])))


def bisect_onset(model, make_params, mu_lo: float, mu_hi: float, iterations: int = 8) -> float:
    """Mu where the simulated loop turns from decay to growth."""

    def grows(mu):
        return growth_and_frequency(closed_loop(model, make_params(mu), 0.4))[0] > 0

    assert not grows(mu_lo) and grows(mu_hi)
    for _ in range(iterations):
        mid = 0.5 * (mu_lo + mu_hi)
        if grows(mid):
            mu_hi = mid
        else:
            mu_lo = mid
    return 0.5 * (mu_lo + mu_hi)


def _params(model, r3, kappa, mu, compensate: bool) -> dsa.DsaParams:
    return dsa.DsaParams(
        r3_rad_s=r3,
        kappa=kappa,
        mu_nm_s_per_rad=mu,
        actuator_gain_nm_per_v=model.plant.actuator_gain_nm_per_v,
        sample_rate_hz=FS,
        drive_limit_v=1e6,
        loop_delay_s=dsa.loop_delay_s(BLOCK, FS) if compensate else 0.0,
        sync_amplitude_v=0.0,
        sync_frequency_hz=100.0,
        sync_phase_rad=0.0,
        kr_schedule=dsa.KrSchedule(0.0, 0.0, 0.0, 0.0),
        compensation_frequency_hz=None,
    )


def test_compensated_simulated_loop_starts_at_the_predicted_onset(undamped):
    kappa = 0.5
    r3 = hopf.r3_for_onset_frequency(kappa, 150.0)
    theory = hopf.hopf_onset(_lin_plant(undamped), r3, kappa)
    mu_sim = bisect_onset(
        undamped,
        lambda mu: _params(undamped, r3, kappa, mu, True),
        0.5 * theory.mu_nm_s_per_rad,
        1.5 * theory.mu_nm_s_per_rad,
    )
    assert mu_sim == pytest.approx(theory.mu_nm_s_per_rad, rel=0.05)
    _, f_sim = growth_and_frequency(
        closed_loop(undamped, _params(undamped, r3, kappa, 1.01 * mu_sim, True), 0.4)
    )
    assert f_sim == pytest.approx(theory.frequency_hz, rel=0.03)
    assert f_sim == pytest.approx(math.sqrt(kappa) * r3 / (2 * math.pi), rel=0.03)


def test_uncompensated_loop_follows_the_delayed_theory_not_the_ideal_one(undamped):
    kappa = 0.5
    r3 = hopf.r3_for_onset_frequency(kappa, 300.0)
    ideal = hopf.hopf_onset(_lin_plant(undamped), r3, kappa)
    delayed = hopf.onset_with_delay(_lin_plant(undamped), r3, kappa, dsa.loop_delay_s(BLOCK, FS))
    assert delayed.mu_nm_s_per_rad < 0.2 * ideal.mu_nm_s_per_rad  # the delay matters a lot
    mu_sim = bisect_onset(
        undamped,
        lambda mu: _params(undamped, r3, kappa, mu, False),
        0.5 * delayed.mu_nm_s_per_rad,
        1.5 * delayed.mu_nm_s_per_rad,
    )
    assert mu_sim == pytest.approx(delayed.mu_nm_s_per_rad, rel=0.05)
    _, f_sim = growth_and_frequency(
        closed_loop(undamped, _params(undamped, r3, kappa, 1.01 * mu_sim, False), 0.4)
    )
    assert f_sim == pytest.approx(delayed.frequency_hz, rel=0.03)
    assert f_sim < 0.6 * ideal.frequency_hz  # 161 Hz instead of the designed 300 Hz


def test_aero_damping_gives_a_stable_limit_cycle_slightly_above_resonance(model):
    kappa = 0.5
    r3 = hopf.r3_for_onset_frequency(kappa, 142.0)
    mu = 10.0 * hopf.hopf_onset(_lin_plant(model), r3, kappa).mu_nm_s_per_rad
    params = _params(model, r3, kappa, mu, True)
    phi = np.degrees(closed_loop(model, params, 1.2))
    amps = [np.ptp(phi[int(a * FS) : int((a + 0.1) * FS)]) / 2 for a in (0.7, 0.9, 1.1)]
    assert amps[-1] > 1.0  # it does flap
    assert max(amps) - min(amps) < 0.005 * amps[-1]  # settled: a limit cycle
    x = phi[int(1.0 * FS) :]
    up = np.nonzero((x[:-1] < 0) & (x[1:] >= 0))[0]
    f_sim = FS / np.mean(np.diff(up))
    fn = model.plant.stroke_natural_frequency_hz
    assert fn < f_sim < 1.15 * fn  # above the stroke resonance
    t = dsa.loop_delay_s(BLOCK, FS)
    df = hopf.limit_cycle(_lin_plant(model), model.plant.aero_damping_nm_s2, r3, kappa, mu, t, t)
    assert f_sim == pytest.approx(df.frequency_hz, rel=0.01)
    assert amps[-1] == pytest.approx(math.degrees(df.amplitude_rad), rel=0.03)
