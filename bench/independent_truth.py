"""A robot simulated by code that shares nothing with FLAAIR's model: the truth a discovery
benchmark can trust (issue "Discovery over everything a robot couples", item 3).

Its own formulation of the equations of ../shared/model-spec.md (written here from the spec, not
from `flaair_model` or `flaair_sim`), its own integrator (DOP853 at tight tolerances, restarted
at each sample of the zero-order-held drive: Hairer's code through `scipy.integrate.ode`, or
`scipy.integrate.solve_ivp` with a contact as an event that restarts the step at the kink), its
own sensor chain (the films' charge per metre from Table 1's
constants). Imports nothing of FLAAIR.

Physics beyond the nominal robot, each off by default. Inside the discovery's grammar, written
here in this module's own terms:
- `cubic_nm_per_rad3`: a flexure stiffening, a torque -k3 phi^3 on the stroke;
- `hinge_drag_nm_s2`: a quadratic drag on the pitch, -d psi' |psi'|;
- `crosstalk`: the pitch amplifier picking up that fraction of the stroke amplifier's output;
- `drive_leak_v_per_v`: the drive leaking into the pitch amplifier's output;
- `relaxation_nm_per_rad`, `relaxation_hz`: a viscoelastic flexure, a spring in series with a
  dashpot beside the stroke's (a Maxwell arm): a torque -k_r (phi - z), z relaxing towards phi
  at the corner, z' = 2 pi f_r (phi - z) (a state of its own).
In the vocabulary:
- `hysteresis_alpha`, `hysteresis_beta_per_v`, `hysteresis_gamma_per_v`: the piezo's hysteresis,
  the textbook Bouc-Wen operator (n = 1) on the drive, dh/dt = alpha V' - beta |V'| h -
  gamma V' |h|, the actuator's torque G_a (V - h); each jump of the held drive integrated by
  DOP853 in the drive's own variable (the law is rate-independent).
Outside the grammar or the model:
- `stop_rad`, `stop_stiffness_nm_per_rad`: a one-sided stop on the stroke (contact as an event);
- `quartic_nm_per_rad4`: a torque of degree four in the stroke angle (the grammar stops at three);
- `stiffness_drift_per_s`: the stroke stiffness drifting in time, K (1 + drift t);
- `stiffness_step`: the stroke stiffness stepping to K (1 + step) at `stiffness_step_s` (a
  sample boundary) and staying there;
- `film_lag_s`: the hinge film reading the pitch through a first-order lag (a state the model
  does not have).

  python bench/independent_truth.py      # the nominal robot's gains and a chirp's peak stroke
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import ode, solve_ivp

__all__ = ["EPSILON_0", "Robot", "film_charge_per_m", "hysteretic_voltage", "simulate"]

EPSILON_0 = 8.854187817e-12  # F/m
_RTOL, _ATOL = 1e-10, 1e-14


def film_charge_per_m(
    area_m2: float, backing_thickness_m: float, length_m: float, backing_modulus_pa: float
) -> float:
    """S of a PVDF film (Table 1's PVDF) on a backing beam: charge per metre of tip deflection."""
    g31, eps_r, e_p, t_p = 0.216, 13.0, 2.8e9, 12e-6
    e_b, t_b = backing_modulus_pa, backing_thickness_m
    return (
        g31 * EPSILON_0 * eps_r * e_p * area_m2 * e_b * t_b * (t_b + t_p)
        / ((e_b * t_b + e_p * t_p) * length_m**2)
    )  # fmt: skip


@dataclass(frozen=True)
class Robot:
    """The robot's physics in SI units (model-spec.md's nominal values by default)."""

    stroke_inertia: float = 6.5e-11
    stroke_hz: float = 140.0
    aero_damping: float = 4.0e-11
    actuator_gain: float = 1.67e-7
    pitch_inertia: float = 2.0e-12
    pitch_hz: float = 190.0
    hinge_damping: float = 1.43e-9
    inertial_coupling: float = 2.0e-12
    aero_coupling: float = 1.5e-12
    transmission_rad_per_m: float = 3000.0
    stroke_film_c_per_m: float = film_charge_per_m(24.1e-6, 305e-6, 11.2e-3, 50e9)
    pitch_film_c_per_m: float = film_charge_per_m(1.2e-6, 5e-6, 0.3e-3, 9e9)
    hinge_length_m: float = 0.3e-3
    stroke_amp_per_f: float = 1.6e9
    pitch_amp_per_f: float = 1.7e9
    reference_v: float = 1.25
    stop_rad: float | None = None
    stop_stiffness_nm_per_rad: float = 0.0
    quartic_nm_per_rad4: float = 0.0
    stiffness_drift_per_s: float = 0.0
    stiffness_step: float = 0.0
    stiffness_step_s: float = 0.5
    film_lag_s: float = 0.0
    cubic_nm_per_rad3: float = 0.0
    hinge_drag_nm_s2: float = 0.0
    crosstalk: float = 0.0
    drive_leak_v_per_v: float = 0.0
    hysteresis_alpha: float = 0.0
    hysteresis_beta_per_v: float = 0.0
    hysteresis_gamma_per_v: float = 0.0
    relaxation_nm_per_rad: float = 0.0
    relaxation_hz: float = 100.0

    @property
    def stroke_stiffness(self) -> float:
        """K = I (2 pi f)^2."""
        return self.stroke_inertia * (2.0 * math.pi * self.stroke_hz) ** 2

    @property
    def hinge_stiffness(self) -> float:
        """k_h = I_p (2 pi f_p)^2."""
        return self.pitch_inertia * (2.0 * math.pi * self.pitch_hz) ** 2


def _derivatives(
    t: float, y: np.ndarray, robot: Robot, volts: float, in_contact: bool
) -> list[float]:
    """The vector field of [phi, phi', psi, psi', psi seen by the film, the Maxwell arm's
    dashpot z] at a held drive.
    """
    phi, dphi, psi, dpsi, seen, relaxed = y
    torque = robot.actuator_gain * volts - robot.aero_damping * abs(dphi) * dphi
    stepped = robot.stiffness_step if t >= robot.stiffness_step_s else 0.0
    torque -= robot.stroke_stiffness * (1.0 + robot.stiffness_drift_per_s * t + stepped) * phi
    torque -= robot.quartic_nm_per_rad4 * phi**4
    torque -= robot.cubic_nm_per_rad3 * phi**3
    torque -= robot.relaxation_nm_per_rad * (phi - relaxed)
    if in_contact:
        torque -= robot.stop_stiffness_nm_per_rad * (phi - robot.stop_rad)
    ddphi = torque / robot.stroke_inertia
    ddpsi = (
        -robot.inertial_coupling * ddphi
        - robot.aero_coupling * abs(dphi) * dphi
        - robot.hinge_damping * dpsi
        - robot.hinge_drag_nm_s2 * abs(dpsi) * dpsi
        - robot.hinge_stiffness * psi
    ) / robot.pitch_inertia
    dseen = (psi - seen) / robot.film_lag_s if robot.film_lag_s > 0 else dpsi
    drelaxed = 2.0 * math.pi * robot.relaxation_hz * (phi - relaxed)
    return [dphi, ddphi, dpsi, ddpsi, dseen, drelaxed]


def _field(robot: Robot, volts: float, in_contact: bool):  # type: ignore[no-untyped-def]
    """`_derivatives` at a held drive, as solve_ivp calls it."""

    def f(t: float, y: np.ndarray) -> list[float]:
        return _derivatives(t, y, robot, volts, in_contact)

    return f


def _stop_event(robot: Robot):  # type: ignore[no-untyped-def]
    def crossing(t: float, y: np.ndarray) -> float:
        return float(y[0] - robot.stop_rad)

    crossing.terminal = True  # type: ignore[attr-defined]
    return crossing


def _step(robot: Robot, y: np.ndarray, t0: float, t1: float, volts: float) -> np.ndarray:
    """The state at t1 from y at t0 under a held drive, restarting at every contact change."""
    has_stop = robot.stop_rad is not None and robot.stop_stiffness_nm_per_rad > 0.0
    while True:
        in_contact = has_stop and y[0] > robot.stop_rad  # type: ignore[operator]
        sol = solve_ivp(
            _field(robot, volts, in_contact), (t0, t1), y, method="DOP853",
            rtol=_RTOL, atol=_ATOL, events=_stop_event(robot) if has_stop else None,
        )  # fmt: skip
        if sol.status != 1:  # reached t1
            return np.asarray(sol.y[:, -1])
        t_event = float(sol.t_events[0][0])
        y = np.asarray(sol.y_events[0][0], dtype=float)
        # step just past the kink so the next call starts on the other side of it
        y[0] += math.copysign(1e-15, y[1])
        if t_event >= t1:
            return y
        t0 = t_event


def _bouc_wen_rate(s: float, h: np.ndarray, robot: Robot, direction: float) -> list[float]:
    """dh/ds along a jump of the drive, s = |V - V_before| (V = V_before + direction s)."""
    return [
        direction * robot.hysteresis_alpha
        - robot.hysteresis_beta_per_v * h[0]
        - direction * robot.hysteresis_gamma_per_v * abs(h[0])
    ]


def hysteretic_voltage(robot: Robot, drive_v: np.ndarray) -> np.ndarray:
    """H after each sample's jump of the held drive, from rest (V)."""
    drive = np.asarray(drive_v, dtype=float)
    out = np.zeros(drive.size)
    if robot.hysteresis_alpha == 0.0:
        return out
    solver = ode(_bouc_wen_rate).set_integrator("dop853", rtol=_RTOL, atol=1e-12, nsteps=10_000)
    h, before = 0.0, 0.0
    for k, volts in enumerate(drive):
        jump = float(volts) - before
        if jump != 0.0:
            solver.set_initial_value([h], 0.0).set_f_params(robot, math.copysign(1.0, jump))
            h = float(solver.integrate(abs(jump))[0])
        out[k] = h
        before = float(volts)
    return out


def simulate(robot: Robot, drive_v: np.ndarray, fs_hz: float) -> dict[str, np.ndarray]:
    """Noise-free measured-run columns of `robot` driven by `drive_v` (held per sample) from
    rest: sample k is the state at k / fs, the drive of sample k acting over [k, k + 1) / fs.

    Each held sample is one restarted DOP853 integration (Hairer's code through
    `scipy.integrate.ode`: solve_ivp's per-call set-up costs four times the integration here);
    a robot with a stop integrates each sample with solve_ivp and the contact as an event, and
    so does a sample Hairer's stiffness test interrupts.
    """
    drive = np.asarray(drive_v, dtype=float)
    n = drive.size
    acting = drive - hysteretic_voltage(robot, drive)  # what the actuator turns into torque
    states = np.zeros((n, 6))
    y = np.zeros(6)
    has_stop = robot.stop_rad is not None and robot.stop_stiffness_nm_per_rad > 0.0
    solver = ode(_derivatives).set_integrator(
        "dop853", rtol=_RTOL, atol=_ATOL, nsteps=100_000, verbosity=-1
    )
    for k in range(n):
        states[k] = y
        if k + 1 >= n:
            break
        t0, t1 = k / fs_hz, (k + 1) / fs_hz
        if has_stop:
            y = _step(robot, y, t0, t1, float(acting[k]))
            continue
        solver.set_initial_value(y, t0).set_f_params(robot, float(acting[k]), False)
        y_next = solver.integrate(t1)
        # DOP853's stiffness test may stop a hard-driven sample: solve_ivp has none
        y = y_next if solver.successful() else _step(robot, y, t0, t1, float(acting[k]))
    phi, psi, seen = states[:, 0], states[:, 2], states[:, 4]
    stroke_q = -robot.stroke_film_c_per_m * phi / robot.transmission_rad_per_m
    pitch_q = -robot.pitch_film_c_per_m * seen * robot.hinge_length_m / 2.0
    stroke_out = robot.stroke_amp_per_f * stroke_q
    pitch_out = (
        robot.pitch_amp_per_f * pitch_q + robot.crosstalk * stroke_out
        + robot.drive_leak_v_per_v * drive
    )  # fmt: skip
    return {
        "time_s": np.arange(n) / fs_hz,
        "drive_v": drive.copy(),
        "stroke_sensor_v": stroke_out + robot.reference_v,
        "pitch_sensor_v": pitch_out + robot.reference_v,
        "stroke_deg": np.degrees(phi),
        "pitch_deg": np.degrees(psi),
    }


def main() -> int:
    robot = Robot()
    stroke_gain = robot.transmission_rad_per_m / (
        robot.stroke_amp_per_f * robot.stroke_film_c_per_m
    )
    pitch_gain = 2.0 / (robot.pitch_amp_per_f * robot.pitch_film_c_per_m * robot.hinge_length_m)
    print(f"angle per volt: stroke {math.degrees(stroke_gain):.2f} deg/V, "
          f"pitch {math.degrees(pitch_gain):.2f} deg/V (model-spec.md: 25.39, 24.87)")  # fmt: skip
    t = np.arange(2000) / 20000.0
    out = simulate(robot, 60.0 * np.sin(2.0 * math.pi * 140.0 * t), 20000.0)
    print(f"60 V at 140 Hz for 0.1 s: peak stroke {np.abs(out['stroke_deg']).max():.2f} deg")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
