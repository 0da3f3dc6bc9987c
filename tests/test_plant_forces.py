"""One source of the plant's forces: the RK4 kernel's accelerations, read at the fundamental
(`flaair_sim.core.stroke_dynamic_stiffness`) by the health monitor's regression and the
harmonic-balance start of a table. A torque added to the model reaches all three.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

import health_sim as hs
from flaair_analysis.tables.steady_state import harmonic_balance_start
from flaair_control.core import health as H
from flaair_control.health_io import health_params_from_config
from flaair_model.model import with_effects
from flaair_model.model_io import load_model
from flaair_model.terms import DiscoveredTerm
from flaair_sim.core.describing import stroke_dynamic_stiffness
from flaair_sim.core.plant import simulate
from flaair_sim.core.plant_params import P_CSTRUCT, P_GAMMA, P_K, prepare

FS = 20000.0
DRIVE_V, DRIVE_HZ = 40.0, 140.0
# A stiffening flexure: -kappa phi^3 (N m / rad^3). At the run's ~0.7 rad its describing
# function, 3/4 kappa A^2, is ~35 % of the linear stiffness: no estimator can miss it.
KAPPA_NM_PER_RAD3 = 4e-5


@pytest.fixture(scope="module")
def nominal():
    return load_model()


@pytest.fixture(scope="module")
def stiffened(nominal):
    term = DiscoveredTerm("cube_angle", "stroke_dynamics", -KAPPA_NM_PER_RAD3)
    return replace(nominal, discovered=(term,))


@pytest.mark.timeout(120)  # a cold numba cache compiles the projection first
def test_the_describing_function_is_the_closed_form_of_each_torque(nominal, stiffened) -> None:
    damped = with_effects(nominal, {"structural_damping": {"damping_ratio": 0.03}})
    w = 2 * math.pi * np.array([90.0, 140.0, 190.0])
    amp = np.array([0.0, 0.4, 0.9])
    p = prepare(damped, FS).params
    closed = p[P_K] + 1j * w * (p[P_CSTRUCT] + 8 / (3 * math.pi) * p[P_GAMMA] * w * amp)
    assert p[P_CSTRUCT] > 0
    np.testing.assert_allclose(stroke_dynamic_stiffness(p, w, amp), closed, rtol=1e-6)
    # a cubic stiffness at the fundamental: 3/4 kappa A^2 on the real part
    q = prepare(stiffened, FS).params
    extra = stroke_dynamic_stiffness(q, w, amp) - stroke_dynamic_stiffness(
        prepare(nominal, FS).params, w, amp
    )
    np.testing.assert_allclose(extra.real, 0.75 * KAPPA_NM_PER_RAD3 * amp**2, rtol=1e-6, atol=1e-15)
    np.testing.assert_allclose(extra.imag, 0.0, atol=1e-12)


@pytest.fixture(scope="module")
def stiffened_run(stiffened):
    return hs.run(stiffened, 0.6, sine=(DRIVE_V, DRIVE_HZ))


@pytest.mark.timeout(180)
def test_a_torque_added_to_the_model_reaches_the_kernel_and_harmonic_balance(
    nominal, stiffened
) -> None:
    f, a, b = np.array([DRIVE_HZ]), np.array([DRIVE_V]), np.array([0.0])
    t = np.arange(int(0.5 * FS)) / FS
    drive = DRIVE_V * np.sin(2 * math.pi * DRIVE_HZ * t)
    window = round(5 * FS / DRIVE_HZ)
    amplitude = {}
    for name, model in (("nominal", nominal), ("stiffened", stiffened)):
        run = simulate(drive, FS, model)
        tail = run.stroke_rad[-window:]
        amplitude[name] = 0.5 * (tail.max() - tail.min())
    # the kernel: the stiffer flexure moves the wing less (0.478 against 0.505 rad)
    assert amplitude["stiffened"] / amplitude["nominal"] < 0.96
    # harmonic balance: the start of each model is within 2 % of its own simulated amplitude
    for name, model in (("nominal", nominal), ("stiffened", stiffened)):
        x0 = harmonic_balance_start(model, f, a, b, FS)[0]
        start_amp = math.hypot(x0[0], x0[1] / (2 * math.pi * DRIVE_HZ))
        assert start_amp == pytest.approx(amplitude[name], rel=0.02), name


@pytest.mark.timeout(180)
def test_a_torque_added_to_the_model_reaches_the_health_regression(
    nominal, stiffened, stiffened_run
) -> None:
    def inertia_ratio(model) -> float:
        params = replace(health_params_from_config(model=model), sample_rate_hz=FS)
        _, out = H.step(H.initial_state(params), H.HealthInputs(*stiffened_run), params)
        est = np.array([b.estimate for b in out.wingbeats if b.valid and b.time_s > 0.4])
        return float(est[:, 0].mean())

    # read against the model that carries the torque, the robot is unchanged
    assert inertia_ratio(stiffened) == pytest.approx(1.0, abs=0.01)
    # against the nominal model the stiffer flexure reads as a lighter wing (K / r)
    assert inertia_ratio(nominal) < 0.9
