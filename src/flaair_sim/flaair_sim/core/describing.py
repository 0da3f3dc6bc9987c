"""The plant's torques at the fundamental of a harmonic motion (describing functions).

An estimator that reads the plant at its wingbeat frequency (the health monitor's regression,
the harmonic-balance start of a frequency-response table) needs every stroke torque but the
drive's and the inertia's as one complex dynamic stiffness N = K_eq + j w c_eq at the motion's
amplitude. It is computed here from the RK4 kernel's own accelerations (`plant_kernel`) along
phi = A cos(w t), projected on the fundamental: a force the kernel computes (a nominal term, an
effect's, a discovered term) reaches every estimator built on this, with no formula copied.
The quadratic aerodynamic damping comes out as its describing function (8 / 3 pi) Gamma w A to
within 1e-6 of it at the default 128 points a period. The pitch the hinge makes of a stroke
(`pitch_response`) is solved from the kernel's pitch torques the same way.
"""

from __future__ import annotations

import numpy as np

from flaair_sim.core.plant_kernel import pitch_responses, stroke_fundamentals
from flaair_sim.core.plant_params import P_I

__all__ = ["N_POINTS", "pitch_response", "stroke_dynamic_stiffness"]

N_POINTS = 128  # samples of a period: the projection's error on |x'| x' is ~1 / N_POINTS^3
# Below this amplitude (rad) the motion is probed at _PROBE_RAD: the linear part, its limit.
_SMALL_RAD, _PROBE_RAD = 1e-12, 1e-9


def stroke_dynamic_stiffness(
    params: np.ndarray,
    omega_rad_s: np.ndarray | float,
    stroke_amplitude_rad: np.ndarray | float,
    pitch_phasor_rad: np.ndarray | complex = 0j,
) -> np.ndarray:
    """N = K_eq + j w c_eq (N m/rad) of the model's parameter vector `params` (`prepare`).

    Parameters
    ----------
    params
        The kernels' parameter vector of the model (`plant_params.prepare(model, fs).params`).
    omega_rad_s, stroke_amplitude_rad
        The motion phi = A cos(w t) (broadcast together).
    pitch_phasor_rad
        The pitch along it, Re(P e^(j w t)) (for torques that depend on it).

    Returns
    -------
    np.ndarray
        Complex, the broadcast shape: the fundamental of the stroke torques but the drive's and
        the inertia's, per radian of stroke amplitude. At A = 0, the linear part. A complex
        scalar for scalar arguments (an estimator's one motion a wingbeat, without numpy's
        broadcasting around a kernel call that costs a few microseconds).
    """
    if (
        isinstance(omega_rad_s, float)
        and isinstance(stroke_amplitude_rad, float)
        and isinstance(pitch_phasor_rad, complex)
    ):
        return _one(params, omega_rad_s, stroke_amplitude_rad, pitch_phasor_rad)
    w, a, pitch = np.broadcast_arrays(
        np.asarray(omega_rad_s, dtype=float),
        np.asarray(stroke_amplitude_rad, dtype=float),
        np.asarray(pitch_phasor_rad, dtype=complex),
    )
    shape = w.shape
    # copies: numba warns on the views broadcast_arrays returns (their writeable flag is going)
    w, a, pitch = np.array(w).ravel(), np.array(a).ravel(), np.array(pitch).ravel()
    probe = np.where(np.abs(a) < _SMALL_RAD, _PROBE_RAD, a)
    out = np.empty(w.size, dtype=complex)
    stroke_fundamentals(
        params,
        w,
        probe,
        np.ascontiguousarray(pitch.real),
        np.ascontiguousarray(pitch.imag),
        N_POINTS,
        out,
    )
    stiffness: np.ndarray = (-params[P_I] * out / probe).reshape(shape)
    return stiffness


def _one(params: np.ndarray, omega: float, amplitude: float, pitch: complex) -> np.ndarray:
    """`stroke_dynamic_stiffness` of one motion (the same kernel, the same arithmetic)."""
    probe = np.array([_PROBE_RAD if abs(amplitude) < _SMALL_RAD else amplitude])
    out = np.empty(1, dtype=complex)
    stroke_fundamentals(
        params,
        np.array([omega]),
        probe,
        np.array([pitch.real]),
        np.array([pitch.imag]),
        N_POINTS,
        out,
    )
    one: np.ndarray = (-params[P_I] * out / probe)[0]
    return one


# Fixed-point passes for the pitch, at most, until a pass moves it by less than _PITCH_TOL of
# itself (a linear hinge stops at the second, which repeats the first); the first pass reads the
# hinge at _PITCH_PROBE_RAD, small against any stiffening, large against rounding.
_PITCH_PASSES, _PITCH_TOL, _PITCH_PROBE_RAD = 60, 1e-9, 1e-4


def pitch_response(
    params: np.ndarray,
    omega_rad_s: np.ndarray | float,
    stroke_amplitude_rad: np.ndarray | float,
    growth_per_s: np.ndarray | float = 0.0,
    pitch_inertia_ratio: np.ndarray | float = 1.0,
    start: np.ndarray | complex = 0j,
) -> np.ndarray:
    """The pitch phasor per radian of stroke, P / A, the hinge makes of the stroke Re(A e^(s t)).

    The pitch torques at the fundamental come from the kernel (`plant_kernel.pitch_responses`:
    the hinge's nominal terms, its effects, discovered pitch terms, the coupling to the stroke),
    and the pitch solves r I_p s^2 P = T(P), the hinge taken as its describing function at the
    pitch. For a linear hinge this is -(J_c s^2 + c_d s) / (k_h + r I_p s^2 + c_p s), with the
    aerodynamic coupling c_d = (8 / 3 pi) D_p |s| A.

    Parameters
    ----------
    params
        The kernels' parameter vector of the model (`plant_params.prepare(model, fs).params`).
    omega_rad_s, stroke_amplitude_rad
        The stroke's angular frequency and amplitude A (phase 0).
    growth_per_s
        The motion's logarithmic rate (s = growth + j w): a growing or decaying stroke.
    pitch_inertia_ratio
        r: the pitch inertia against the model's.
    start
        A guess of P / A (a last solution: an iteration around it stops in a few passes).

    Returns
    -------
    np.ndarray
        Complex, the broadcast shape (a complex scalar for float arguments).
    """
    if (
        isinstance(omega_rad_s, float)
        and isinstance(stroke_amplitude_rad, float)
        and isinstance(growth_per_s, float)
        and isinstance(pitch_inertia_ratio, float)
        and isinstance(start, complex)
    ):
        # one motion a wingbeat (the health monitor): no broadcasting around the kernel call
        one = _PROBE_RAD if abs(stroke_amplitude_rad) < _SMALL_RAD else stroke_amplitude_rad
        rate = complex(growth_per_s, omega_rad_s)
        inertial = np.array([pitch_inertia_ratio * rate * rate])
        stroke = np.array([one + 0j])
        guess = np.array([start * one])
        single: np.ndarray = _pitch(params, stroke, np.array([rate]), inertial, guess)[0]
        return single
    w, a, lam, r, guess = np.broadcast_arrays(
        np.asarray(omega_rad_s, dtype=float),
        np.asarray(stroke_amplitude_rad, dtype=float),
        np.asarray(growth_per_s, dtype=float),
        np.asarray(pitch_inertia_ratio, dtype=float),
        np.asarray(start, dtype=complex),
    )
    s = (lam + 1j * w).ravel()
    stroke = np.where(np.abs(a) < _SMALL_RAD, _PROBE_RAD, a).ravel().astype(complex)
    inertial = r.ravel() * s * s
    response = _pitch(params, stroke, s, inertial, guess.ravel() * stroke).reshape(w.shape)
    return response


def _pitch(
    params: np.ndarray, stroke: np.ndarray, s: np.ndarray, inertial: np.ndarray, start: np.ndarray
) -> np.ndarray:
    """P / A of each row (`pitch_response`; `inertial` is r s^2, `start` a guess of P)."""
    out = np.empty(s.size, dtype=complex)
    pitch_responses(
        params,
        stroke,
        s,
        inertial.astype(complex),
        np.ascontiguousarray(start, dtype=complex),
        N_POINTS,
        _PITCH_PASSES,
        _PITCH_TOL,
        _PITCH_PROBE_RAD,
        out,
    )
    per_stroke: np.ndarray = out / stroke
    return per_stroke
