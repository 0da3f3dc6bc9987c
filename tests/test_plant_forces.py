"""One source of the plant's forces: the RK4 kernel's accelerations, read at the fundamental
(`flaair_sim.core.describing`: the stroke's dynamic stiffness, the pitch the hinge makes of a
stroke) by the health monitor's regression and the harmonic-balance start of a table. A stroke
torque and a pitch torque added to the model reach all three.
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
from flaair_sim.core.describing import pitch_response, stroke_dynamic_stiffness
from flaair_sim.core.plant import simulate
from flaair_sim.core.plant_params import (
    P_CP,
    P_CSTRUCT,
    P_DP,
    P_GAMMA,
    P_IP,
    P_JC,
    P_K,
    P_KH,
    prepare,
)

FS = 20000.0
DRIVE_V, DRIVE_HZ = 40.0, 140.0
# A stiffening flexure: -kappa phi^3 (N m / rad^3). At the run's ~0.7 rad its describing
# function, 3/4 kappa A^2, is ~35 % of the linear stiffness: no estimator can miss it.
KAPPA_NM_PER_RAD3 = 4e-5
# A stiffening hinge: -kappa_p psi^3. At the run's ~0.45 rad pitch, 3/4 kappa_p P^2 is ~25 % of
# the hinge's linear stiffness.
PITCH_KAPPA_NM_PER_RAD3 = 5e-6


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
def stiff_hinge(nominal):
    term = DiscoveredTerm("cube_angle", "pitch_dynamics", -PITCH_KAPPA_NM_PER_RAD3)
    return replace(nominal, discovered=(term,))


@pytest.mark.timeout(120)
def test_the_pitch_response_is_the_closed_form_of_a_linear_hinge(nominal, stiff_hinge) -> None:
    w = 2 * math.pi * np.array([100.0, 140.0, 180.0])
    amp = np.array([0.3, 0.5, 0.7])
    growth = np.array([0.0, 20.0, -30.0])  # a growing and a decaying stroke
    ratio = np.array([1.0, 0.95, 1.05])
    p = prepare(nominal, FS).params
    s = growth + 1j * w
    c_d = 8 / (3 * math.pi) * p[P_DP] * np.abs(s) * amp
    closed = -(p[P_JC] * s * s + c_d * s) / (p[P_KH] + ratio * p[P_IP] * s * s + p[P_CP] * s)
    np.testing.assert_allclose(pitch_response(p, w, amp, growth, ratio), closed, rtol=1e-6)
    # the stiffening hinge at the fundamental: k_h + 3/4 kappa_p |P|^2 at its own pitch
    q = prepare(stiff_hinge, FS).params
    pitch = pitch_response(q, w, amp) * amp
    kh = p[P_KH] + 0.75 * PITCH_KAPPA_NM_PER_RAD3 * np.abs(pitch) ** 2
    force = p[P_JC] * w**2 - 1j * w * 8 / (3 * math.pi) * p[P_DP] * w * amp
    stiffened = force * amp / (kh - p[P_IP] * w**2 + 1j * w * p[P_CP])
    np.testing.assert_allclose(pitch, stiffened, rtol=1e-6)
    assert np.all(np.abs(pitch) < np.abs(pitch_response(p, w, amp) * amp))


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


def _settled_estimate(model, run, column: int) -> float:
    """The health monitor's mean estimate `column` (`health.PARAMETERS`) of a run's settled
    wingbeats (after 0.4 s), read against `model`.
    """
    params = replace(health_params_from_config(model=model), sample_rate_hz=FS)
    _, out = H.step(H.initial_state(params), H.HealthInputs(*run), params)
    est = np.array([b.estimate for b in out.wingbeats if b.valid and b.time_s > 0.4])
    return float(est[:, column].mean())


def _tail_amplitude(x: np.ndarray, window: int) -> float:
    tail = x[-window:]
    return 0.5 * float(tail.max() - tail.min())


@pytest.mark.timeout(180)
def test_a_pitch_torque_added_to_the_model_reaches_the_kernel_and_harmonic_balance(
    nominal, stiff_hinge
) -> None:
    f, a, b = np.array([DRIVE_HZ]), np.array([DRIVE_V]), np.array([0.0])
    t = np.arange(int(0.5 * FS)) / FS
    drive = DRIVE_V * np.sin(2 * math.pi * DRIVE_HZ * t)
    window = round(5 * FS / DRIVE_HZ)
    pitch = {
        name: _tail_amplitude(simulate(drive, FS, model).pitch_rad, window)
        for name, model in (("nominal", nominal), ("stiff", stiff_hinge))
    }
    # the kernel: the stiffer hinge pitches the wing less
    assert pitch["stiff"] / pitch["nominal"] < 0.9
    # harmonic balance: each model's start pitch is within 3 % of its own simulated pitch
    w = 2 * math.pi * DRIVE_HZ
    for name, model in (("nominal", nominal), ("stiff", stiff_hinge)):
        x0 = harmonic_balance_start(model, f, a, b, FS)[0]
        assert math.hypot(x0[2], x0[3] / w) == pytest.approx(pitch[name], rel=0.03), name


@pytest.mark.timeout(180)
def test_a_stroke_torque_from_the_pitch_reaches_harmonic_balance(nominal) -> None:
    """A torque on the stroke that the pitch makes (+0.2 K psi): the start solves the stroke and
    the pitch together (the stroke moves 0.373 rad against the nominal 0.505).
    """
    k = prepare(nominal, FS).params[P_K]
    coupled = replace(
        nominal, discovered=(DiscoveredTerm("cross_angle", "stroke_dynamics", 0.2 * k),)
    )
    t = np.arange(int(0.5 * FS)) / FS
    drive = DRIVE_V * np.sin(2 * math.pi * DRIVE_HZ * t)
    run = simulate(drive, FS, coupled)
    window = round(5 * FS / DRIVE_HZ)
    stroke = _tail_amplitude(run.stroke_rad, window)
    assert stroke < 0.8 * _tail_amplitude(simulate(drive, FS, nominal).stroke_rad, window)
    x0 = harmonic_balance_start(
        coupled, np.array([DRIVE_HZ]), np.array([DRIVE_V]), np.array([0.0]), FS
    )[0]
    w = 2 * math.pi * DRIVE_HZ
    assert math.hypot(x0[0], x0[1] / w) == pytest.approx(stroke, rel=0.01)
    assert math.hypot(x0[2], x0[3] / w) == pytest.approx(
        _tail_amplitude(run.pitch_rad, window), rel=0.01
    )


@pytest.mark.timeout(180)
def test_a_pitch_torque_added_to_the_model_reaches_the_health_regression(
    nominal, stiff_hinge
) -> None:
    run = hs.run(stiff_hinge, 0.6, sine=(DRIVE_V, DRIVE_HZ))
    # read against the model that carries the torque, the pitch film is unchanged
    assert _settled_estimate(stiff_hinge, run, 2) == pytest.approx(1.0, abs=0.01)
    # against the nominal model the stiffer hinge reads as a weaker pitch film
    assert _settled_estimate(nominal, run, 2) < 0.9


@pytest.mark.timeout(180)
def test_a_torque_added_to_the_model_reaches_the_health_regression(
    nominal, stiffened, stiffened_run
) -> None:
    # read against the model that carries the torque, the robot is unchanged
    assert _settled_estimate(stiffened, stiffened_run, 0) == pytest.approx(1.0, abs=0.01)
    # against the nominal model the stiffer flexure reads as a lighter wing (K / r)
    assert _settled_estimate(nominal, stiffened_run, 0) < 0.9
