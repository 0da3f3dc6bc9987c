"""The model on a table: steady-state responses through the plant core, against closed forms."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from flaair_analysis.tables.steady_state import (
    harmonic_balance_start,
    point_drives,
    steady_response,
)
from flaair_model import settings
from flaair_model.model import with_effects
from flaair_model.model_io import load_model
from flaair_model.terms import DiscoveredTerm
from flaair_sim.core.describing import stroke_dynamic_stiffness
from flaair_sim.core.plant import simulate, simulate_batch_from
from flaair_sim.core.plant_params import P_GA, P_I, P_K, prepare

pytestmark = pytest.mark.timeout(120)


def _linear():
    m = load_model()
    plant = replace(m.plant, aero_damping_nm_s2=0.0, aero_coupling_nm_s2=0.0)
    return with_effects(replace(m, plant=plant), {"structural_damping": {"damping_ratio": 0.05}})


def test_the_linear_plant_gives_its_transfer_functions_magnitude_and_phase() -> None:
    s = settings.tables()
    model = _linear()
    f = np.array([60.0, 100.0, 130.0, 140.0, 150.0, 200.0, 300.0])
    r = steady_response([model], f, np.full(f.size, 20.0), np.zeros(f.size), s)
    pl = model.plant
    inertia = pl.stroke_inertia_kg_m2
    k = inertia * (2 * math.pi * pl.stroke_natural_frequency_hz) ** 2
    c = 2 * 0.05 * math.sqrt(k * inertia)
    w = 2 * math.pi * f
    h = pl.actuator_gain_nm_per_v / (k - inertia * w**2 + 1j * c * w)
    np.testing.assert_allclose(r["stroke_pp_deg"][0], np.degrees(2 * 20.0 * abs(h)), rtol=1e-3)
    np.testing.assert_allclose(r["stroke_phase_deg"][0], np.degrees(np.angle(h)), atol=0.05)
    ip = pl.pitch_inertia_kg_m2
    kh = ip * (2 * math.pi * pl.pitch_natural_frequency_hz) ** 2
    hp = (
        pl.inertial_coupling_kg_m2
        * w**2
        / (kh - ip * w**2 + 1j * pl.hinge_damping_nm_s_per_rad * w)
    )
    np.testing.assert_allclose(r["pitch_pp_deg"][0] / r["stroke_pp_deg"][0], abs(hp), rtol=1e-3)
    np.testing.assert_allclose(r["pitch_phase_deg"][0], np.degrees(np.angle(hp)), atol=0.05)
    assert r["settle_change"].max() < 1e-3


def test_every_point_is_the_simulators_own_steady_state_and_effects_act() -> None:
    s = settings.tables()
    model = load_model()
    f, a, b = np.array([120.0, 170.0]), np.array([60.0, 40.0]), np.array([0.0, 5.0])
    stop = with_effects(model, {"collision": {"stroke_limit_deg": 15.0}})
    r = steady_response([model, stop], f, a, b, s)
    drive, window = point_drives(f, a, b, s)
    x0 = harmonic_balance_start(model, f, a, b, s.sample_rate_hz)
    long, _ = point_drives(f, a, b, replace(s, settle_s=0.6))
    for j in range(2):
        one = simulate_batch_from(drive[j], s.sample_rate_hz, [model], x0[j])
        tail = np.degrees(one.stroke_rad[0, -window[j] :])
        assert r["stroke_pp_deg"][0, j] == pytest.approx(tail.max() - tail.min(), rel=1e-12)
        # the harmonic-balance start only shortens the way: from rest, settled, the same
        rest = simulate(long[j], s.sample_rate_hz, model)
        settled = np.degrees(rest.stroke_rad[-window[j] :])
        assert r["stroke_pp_deg"][0, j] == pytest.approx(np.ptp(settled), rel=2e-3)
    # the nominal model is nonlinear: the gain per volt changes with the level
    assert r["stroke_pp_deg"][0, 0] / 60.0 != pytest.approx(
        r["stroke_pp_deg"][0, 1] / 40.0, rel=0.1
    )
    # the stop caps the stroke where it reaches 15 deg (a little beyond, the contact is stiff)
    assert r["stroke_pp_deg"][1].max() < r["stroke_pp_deg"][0].max()
    assert r["settle_change"].max() < 5e-3


def test_simulate_batch_from_takes_one_drive_per_model() -> None:
    from flaair_model.terms import DiscoveredTerm
    from flaair_sim.core.plant import simulate_batch

    m = load_model()
    sat = replace(m, discovered=(DiscoveredTerm("drive_cube", "drive", -2e-5),))
    rng = np.random.default_rng(0)
    drives = 40.0 * rng.standard_normal((2, 3000))
    a = simulate_batch(drives, 20000.0, [m, sat])
    b = simulate_batch_from(drives, 20000.0, [m, sat], np.zeros(4))
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    with pytest.raises(ValueError, match="3 rows for 2 models"):
        simulate_batch_from(np.zeros((3, 10)), 20000.0, [m, sat], np.zeros(4))


def test_the_start_is_the_stroke_amplitudes_fixed_point_under_a_dry_friction() -> None:
    """The start's stroke amplitude A solves A = |G_a v / (N(A) - I w^2)| (the describing
    function N from the kernel) to 1e-10 of itself, even under a dry friction, whose damped
    iteration alone contracts slowly.
    """
    s = settings.tables()
    nominal = load_model()
    friction = DiscoveredTerm("sign_velocity", "stroke_dynamics", -1.5e-6)
    model = replace(nominal, discovered=(friction,))
    fn = nominal.plant.stroke_natural_frequency_hz
    f = np.tile(np.linspace(0.6 * fn, 1.6 * fn, 20), 3)
    v = np.repeat([20.0, 40.0, 60.0], 20)
    x0 = harmonic_balance_start(model, f, v, np.zeros(f.size), s.sample_rate_hz)
    w = 2 * math.pi * f
    amp = np.hypot(x0[:, 0], x0[:, 1] / w)  # phi = A cos(w t + theta) at t = 0
    p = prepare(model, s.sample_rate_hz).params
    n = stroke_dynamic_stiffness(p, w, amp)
    c = np.maximum(n.imag / w, 1e-3 * p[P_K] / w)
    g = np.abs(p[P_GA] * v / (n.real - p[P_I] * w**2 + 1j * c * w))
    assert np.max(np.abs(g - amp) / amp) < 1e-10
