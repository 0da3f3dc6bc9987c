"""flaair_sim.core.torque_response: the plant's response to small added torques, linearised
about its own motion, against a closed form and against the nonlinear simulation it stands for.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from flaair_model.model_io import load_model
from flaair_model.terms import DiscoveredTerm, TermSignals, primitive_values
from flaair_sim.core.drive import chirp
from flaair_sim.core.plant import simulate_batch_from
from flaair_sim.core.torque_response import torque_responses

FS_HZ = 20_000.0


@pytest.fixture(scope="module")
def model():
    return load_model()


def test_a_constant_torque_on_the_plant_at_rest_is_the_linear_oscillators_step_response(
    model,
) -> None:
    """With no drive the plant rests at zero, where its drag has no slope: the linearised stroke
    is the undamped oscillator I phi'' + K phi = tau (the nominal plant's damping is its drag),
    whose step response is tau / K (1 - cos(w t)), w = sqrt(K / I); the pitch, damped by c_p,
    settles at tau / k_h.
    """
    n = int(0.5 * FS_HZ)
    tau_nm = 1e-7
    torque = np.full((n, 1), tau_nm)
    stroke = torque_responses(model, np.zeros(n), FS_HZ, np.zeros(4), "stroke", torque, "stroke")
    k, inertia = model.plant.stroke_stiffness_nm_per_rad, model.plant.stroke_inertia_kg_m2
    t = np.arange(n) / FS_HZ
    closed = tau_nm / k * (1.0 - np.cos(math.sqrt(k / inertia) * t))
    assert stroke[0, 0] == 0.0  # sample 0 is the state before the first step
    assert np.max(np.abs(stroke[:, 0] - closed)) < 1e-4 * tau_nm / k
    pitch = torque_responses(model, np.zeros(n), FS_HZ, np.zeros(4), "pitch", torque, "pitch")
    assert pitch[-1, 0] == pytest.approx(tau_nm / model.plant.hinge_stiffness_nm_per_rad, rel=1e-6)


def _form_torque(term: DiscoveredTerm, phi, psi, drive_v) -> np.ndarray:
    """The form's torque at each sample period's midpoint (drive and time held)."""

    def mid(x):
        return np.append(0.5 * (x[:-1] + x[1:]), x[-1:])

    sig = TermSignals.of_block(FS_HZ, drive_v, phi=phi, psi=psi)
    dphi, dpsi = np.gradient(phi) * FS_HZ, np.gradient(psi) * FS_HZ
    prims = primitive_values(mid(phi), mid(dphi), mid(psi), mid(dpsi), drive_v, sig.t, sig.ddrive_v)
    out = np.ones_like(phi)
    for x, e in zip(prims, term.monomial, strict=True):
        out = out * x**e
    return term.coefficient * out


@pytest.mark.parametrize(
    ("form", "site", "smooth"),
    [
        ("phi**3", "stroke_dynamics", True),
        ("dphi**3", "stroke_dynamics", True),
        ("drive_v*t", "stroke_dynamics", True),
        ("psi**3", "pitch_dynamics", True),
        ("dphi*abs(dpsi)", "pitch_dynamics", False),
        ("sign(dphi)", "stroke_dynamics", False),
    ],
)
def test_the_linearised_response_is_the_simulated_change_of_a_small_term(
    model, form: str, site: str, smooth: bool
) -> None:
    """A form at a coefficient that moves the stroke by ~1e-4 of its amplitude: the simulated
    change and the linearised response agree to 0.5 % for a smooth form, to 5 % for one with a
    sign() (its jumps fall inside sample periods, where the kernel meets them at its stages).
    """
    drive = chirp(np.arange(int(0.3 * FS_HZ)) / FS_HZ, 60.0, 60.0, 200.0, 0.3)
    base = simulate_batch_from(drive, FS_HZ, [model], np.zeros(4))
    phi, psi = base.stroke_rad[0], base.pitch_rad[0]
    unit = DiscoveredTerm(form, site, 1.0)
    size = float(np.sqrt(np.mean(_form_torque(unit, phi, psi, drive) ** 2)))
    equation, angle = ("stroke", "stroke") if site == "stroke_dynamics" else ("pitch", "pitch")
    spring = (
        model.plant.stroke_stiffness_nm_per_rad
        if equation == "stroke"
        else model.plant.hinge_stiffness_nm_per_rad
    )
    amplitude = float(np.max(np.abs(phi if angle == "stroke" else psi)))
    term = DiscoveredTerm(form, site, 1e-4 * spring * amplitude / size)
    probe = dataclasses.replace(model, discovered=(term,))
    moved = simulate_batch_from(drive, FS_HZ, [probe], np.zeros(4))
    simulated = (moved.stroke_rad if angle == "stroke" else moved.pitch_rad)[0] - (
        phi if angle == "stroke" else psi
    )
    torque = _form_torque(term, phi, psi, drive)[:, None]
    linear = torque_responses(model, drive, FS_HZ, np.zeros(4), equation, torque, angle)[:, 0]
    error = np.linalg.norm(linear - simulated) / np.linalg.norm(simulated)
    assert error < (5e-3 if smooth else 5e-2), error
    assert math.isfinite(error) and np.linalg.norm(simulated) > 0.0


def test_a_torque_of_the_wrong_length_is_refused_by_name(model) -> None:
    with pytest.raises(ValueError, match="torque_nm is"):
        torque_responses(model, np.zeros(100), FS_HZ, np.zeros(4), "stroke", np.zeros(99), "stroke")
