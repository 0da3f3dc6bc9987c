"""The plant's numba kernels: RK4 with the collision stop, the sensor deviations, one model or a
batch (the dynamics and sample convention: `flaair_sim.core.plant`'s docstring).

Kernels are compiled with fused multiply-add allowed but no reassociation, so results are
deterministic: block stepping, whole records and batches agree bit for bit. The mechanical
constants travel as a tuple `c` (`term_kernel.mechanical_constants`, order
`plant_params.C_*`).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from flaair_sim.core import plant_params as pp
from flaair_sim.core.hysteresis_kernel import hysteretic_voltage
from flaair_sim.core.plant_params import N_CONSTANTS
from flaair_sim.core.sensor_kernel import sensor_channel_kernel
from flaair_sim.core.term_kernel import (
    constants_with_terms,
    dynamics_terms,
    lowpass_rates,
    mechanical_constants,
)

__all__ = [
    "linear_responses",
    "pitch_responses",
    "rk4_step",
    "run_batch",
    "run_model",
    "stroke_fundamentals",
]

# Fused multiply-add only (no reassociation): deterministic, shortens RK4's dependency chain.
_FMA = {"contract"}
# Where the parameter vector carries each term slot's low-pass corner (0: no low-pass).
_LOWPASS_0 = pp.P_TERMS + pp.TERM_LOWPASS
_LOWPASS_1 = pp.P_TERMS + pp.TERM_SLOT + pp.TERM_LOWPASS


# The mechanical constants travel as a tuple `c` (immutable, so the compiler can keep them in
# registers across the stores to the output arrays); see mechanical_constants for the order.


@njit(cache=True, fastmath=_FMA)
def _accelerations(phi, dphi, psi, dpsi, v, c, contact, t, dv, z0, z1):
    """Stroke and pitch accelerations; contact 0: stop ignored, 1: stop acts past the limit,
    2: stop acts (just after an impact, where phi may be a rounding error below the limit); `t`
    the sample's time from the run's start and `dv` the drive's rate there (for a discovered
    term with such a factor), `z0`, `z1` the low-pass terms' filter states.
    """
    ga, gamma, k, cstruct = c[pp.C_GA], c[pp.C_GAMMA], c[pp.C_K], c[pp.C_CSTRUCT]
    limit, kc, cc = c[pp.C_PHI_LIM], c[pp.C_KC], c[pp.C_CC]
    drag = abs(dphi) * dphi
    ddphi = ga * v - k * phi - cstruct * dphi - gamma * drag
    stroke_terms, pitch_terms = dynamics_terms(c, phi, dphi, psi, dpsi, v, t, dv, z0, z1)
    if len(c) > N_CONSTANTS:  # a compile-time constant: the nominal kernels add no term
        ddphi += stroke_terms
    if contact == 2 or (contact == 1 and phi > limit):
        push = kc * (phi - limit) + cc * dphi
        if push > 0.0:  # a contact only pushes
            ddphi -= push
    return ddphi, _pitch_acceleration(psi, dpsi, ddphi, drag, c, pitch_terms)


@njit(cache=True, fastmath=_FMA, inline="always")
def _pitch_acceleration(psi, dpsi, ddphi, drag, c, pitch_terms):
    """The pitch's acceleration given the stroke's (`ddphi`), its drag |dphi| dphi and the
    discovered terms' sum on the pitch equation (`pitch_terms`).
    """
    kh, hcubic, cp, jc, dp = c[pp.C_KH], c[pp.C_HCUBIC], c[pp.C_CP], c[pp.C_JC], c[pp.C_DP]
    # Summed in the order the inputs become ready within an RK4 stage (the stroke's drag and
    # acceleration first, the pitch's own state last): the pitch rate's recursion then waits on
    # one fused multiply-add per stage instead of four, and the stroke's chain sets the pace
    # (-27 % per step; results move by rounding only, <= 5e-16 of the amplitude).
    ddpsi = -dp * drag - jc * ddphi - kh * (psi + hcubic * psi * psi * psi) - cp * dpsi
    if len(c) > N_CONSTANTS:
        ddpsi += pitch_terms
    return ddpsi


# Inlined where it is called (numba IR): left to LLVM it stays a call returning a 5-tuple
# through memory, which costs ~4.5 ns of a ~19 ns step.
@njit(cache=True, fastmath=_FMA, inline="always")
def rk4_step(phi, dphi, psi, dpsi, v, c, hs, contact, t, dv, held, lowpass):
    """One RK4 step of length hs at the sample time `t` (held over the sample, like the drive
    `v` and its rate `dv`); also reports whether any stage was past the stop. A model with
    low-pass terms (`lowpass`) integrates their filter states with the mechanics and updates
    them in `held` (`plant_params.HELD_LOWPASS`).
    """
    z0 = z1 = r0 = r1 = s0 = s1 = 0.0
    lowpass = lowpass and len(c) > N_CONSTANTS  # the nominal kernels carry no filter code
    if lowpass:
        z0, z1 = held[pp.HELD_LOWPASS], held[pp.HELD_LOWPASS + 1]
        r0, r1 = lowpass_rates(c, phi, dphi, psi, dpsi, v, t, dv, z0, z1)
    a1, b1 = _accelerations(phi, dphi, psi, dpsi, v, c, contact, t, dv, z0, z1)
    phi2 = phi + 0.5 * hs * dphi
    dphi2 = dphi + 0.5 * hs * a1
    dpsi2 = dpsi + 0.5 * hs * b1
    psi2 = psi + 0.5 * hs * dpsi
    z0_2, z1_2 = z0 + 0.5 * hs * r0, z1 + 0.5 * hs * r1
    if lowpass:
        s0, s1 = r0, r1
        r0, r1 = lowpass_rates(c, phi2, dphi2, psi2, dpsi2, v, t, dv, z0_2, z1_2)
    a2, b2 = _accelerations(phi2, dphi2, psi2, dpsi2, v, c, contact, t, dv, z0_2, z1_2)
    phi3 = phi + 0.5 * hs * dphi2
    dphi3 = dphi + 0.5 * hs * a2
    dpsi3 = dpsi + 0.5 * hs * b2
    psi3 = psi + 0.5 * hs * dpsi2
    z0_3, z1_3 = z0 + 0.5 * hs * r0, z1 + 0.5 * hs * r1
    if lowpass:
        s0, s1 = s0 + 2.0 * r0, s1 + 2.0 * r1
        r0, r1 = lowpass_rates(c, phi3, dphi3, psi3, dpsi3, v, t, dv, z0_3, z1_3)
    a3, b3 = _accelerations(phi3, dphi3, psi3, dpsi3, v, c, contact, t, dv, z0_3, z1_3)
    phi4 = phi + hs * dphi3
    dphi4 = dphi + hs * a3
    dpsi4 = dpsi + hs * b3
    psi4 = psi + hs * dpsi3
    z0_4, z1_4 = z0 + hs * r0, z1 + hs * r1
    if lowpass:
        s0, s1 = s0 + 2.0 * r0, s1 + 2.0 * r1
        r0, r1 = lowpass_rates(c, phi4, dphi4, psi4, dpsi4, v, t, dv, z0_4, z1_4)
        held[pp.HELD_LOWPASS] = z0 + hs / 6.0 * (s0 + r0)
        held[pp.HELD_LOWPASS + 1] = z1 + hs / 6.0 * (s1 + r1)
    a4, b4 = _accelerations(phi4, dphi4, psi4, dpsi4, v, c, contact, t, dv, z0_4, z1_4)
    limit = c[pp.C_PHI_LIM]
    touched = phi > limit or phi2 > limit or phi3 > limit or phi4 > limit
    return (
        phi + hs / 6.0 * (dphi + 2.0 * dphi2 + 2.0 * dphi3 + dphi4),
        dphi + hs / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4),
        psi + hs / 6.0 * (dpsi + 2.0 * dpsi2 + 2.0 * dpsi3 + dpsi4),
        dpsi + hs / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4),
        touched,
    )


@njit(cache=True)
def _crossing_fraction(phi0, dphi0, phi1, dphi1, hs, limit):
    """Fraction of a step at which the cubic Hermite interpolant of phi reaches `limit`."""
    lo, hi = 0.0, 1.0
    for _ in range(40):
        s = 0.5 * (lo + hi)
        s2 = s * s
        s3 = s2 * s
        value = (
            (2 * s3 - 3 * s2 + 1) * phi0
            + (s3 - 2 * s2 + s) * hs * dphi0
            + (-2 * s3 + 3 * s2) * phi1
            + (s3 - s2) * hs * dphi1
        )
        if value > limit:
            hi = s
        else:
            lo = s
    return 0.5 * (lo + hi)


@njit(cache=True, fastmath=_FMA)
def _contact_sample(phi, dphi, psi, dpsi, v, c, h, nsub, t, dv, held, lowpass):
    """One sample period touching the stop, `nsub` substeps.

    The damper makes the contact force jump at impact, which would cut RK4 to first order;
    a substep that enters the contact is split at the impact time (Hermite interpolation).
    """
    hs = h / nsub
    limit = c[pp.C_PHI_LIM]
    for _ in range(nsub):
        if phi <= limit:
            z0, z1 = held[pp.HELD_LOWPASS], held[pp.HELD_LOWPASS + 1]  # the trial moves them
            f_phi, f_dphi, f_psi, f_dpsi, _hit = rk4_step(
                phi, dphi, psi, dpsi, v, c, hs, 0, t, dv, held, lowpass
            )
            if f_phi <= limit:
                phi, dphi, psi, dpsi = f_phi, f_dphi, f_psi, f_dpsi
                continue
            held[pp.HELD_LOWPASS], held[pp.HELD_LOWPASS + 1] = z0, z1
            theta = _crossing_fraction(phi, dphi, f_phi, f_dphi, hs, limit)
            phi, dphi, psi, dpsi, _hit = rk4_step(
                phi, dphi, psi, dpsi, v, c, theta * hs, 0, t, dv, held, lowpass
            )
            phi, dphi, psi, dpsi, _hit = rk4_step(
                phi, dphi, psi, dpsi, v, c, (1.0 - theta) * hs, 2, t, dv, held, lowpass
            )
        else:
            phi, dphi, psi, dpsi, _hit = rk4_step(
                phi, dphi, psi, dpsi, v, c, hs, 1, t, dv, held, lowpass
            )
    return phi, dphi, psi, dpsi


@njit(cache=True, fastmath=_FMA)
def _mechanics(
    x, drive, commanded, last, held, h, nsub, nsub_contact, p, phi_out, psi_out, dev_s_out,
    dev_p_out, n0,
):  # fmt: skip
    """`_mechanics_with` the model's constants (with its discovered terms' slots if it has any)."""
    if p[pp.P_NTERMS] > 0.0:
        _mechanics_with(
            x, drive, commanded, last, held, h, nsub, nsub_contact, p, constants_with_terms(p),
            phi_out, psi_out, dev_s_out, dev_p_out, n0,
        )  # fmt: skip
    else:
        _mechanics_with(
            x, drive, commanded, last, held, h, nsub, nsub_contact, p, mechanical_constants(p),
            phi_out, psi_out, dev_s_out, dev_p_out, n0,
        )  # fmt: skip


@njit(cache=True, fastmath=_FMA)
def _mechanics_with(
    x, drive, commanded, last, held, h, nsub, nsub_contact, p, c, phi_out, psi_out, dev_s_out,
    dev_p_out, n0,
):  # fmt: skip
    """Stroke, pitch and the sensor deviations (before high-pass and delay) at each sample time;
    the block's first sample is the run's `n0`-th (the k-th sample's time from the run's start is
    exactly (n0 + k) h, however the run is cut into blocks). `drive` is what the actuator sees;
    `commanded` is the drive it is given (before its hysteresis) and `last` that drive's sample
    before the block (their backward difference: a discovered term's drive rate). `held` is the
    state held between samples (`plant_params.HELD_LEN`): the low-pass terms' filter states,
    which each RK4 step moves.

    x (the state after the block) is updated in place. The transduction is computed here
    because the RK4 recursion is latency-bound: the extra arithmetic comes almost free.
    A sample period in which the collision stop is touched is integrated again by
    `_contact_sample`, so before the first contact the trajectory is bit-identical to the
    model without the collision effect.
    """
    contact = 1 if p[pp.P_CONTACT_ON] != 0.0 else 0
    lowpass = p[_LOWPASS_0] != 0.0 or p[_LOWPASS_1] != 0.0  # a low-pass term in a slot
    gs, gp, cubic, feed = p[pp.P_GS], p[pp.P_GP], p[pp.P_TCUBIC], p[pp.P_FT]
    phi, dphi, psi, dpsi = x[0], x[1], x[2], x[3]
    hs, fs = h / nsub, 1.0 / h
    if contact == 0 and nsub == 1:
        # the common case, kept free of branches (the same arithmetic as the general loop; a
        # model without terms never reads dv, and the compiler drops it)
        for k in range(drive.shape[0]):
            v = drive[k]
            dv = (commanded[k] - last) * fs
            last = commanded[k]
            phi_out[k] = phi
            psi_out[k] = psi
            dev_s_out[k] = gs * (phi + cubic * phi * phi * phi) + feed * v
            dev_p_out[k] = gp * psi
            t = (n0 + k) * h
            phi, dphi, psi, dpsi, _hit = rk4_step(
                phi, dphi, psi, dpsi, v, c, hs, 0, t, dv, held, lowpass
            )
        x[0], x[1], x[2], x[3] = phi, dphi, psi, dpsi
        return
    for k in range(drive.shape[0]):
        v = drive[k]
        dv = (commanded[k] - last) * fs
        last = commanded[k]
        phi_out[k] = phi
        psi_out[k] = psi
        dev_s_out[k] = gs * (phi + cubic * phi * phi * phi) + feed * v
        dev_p_out[k] = gp * psi
        phi0, dphi0, psi0, dpsi0 = phi, dphi, psi, dpsi
        z0, z1 = held[pp.HELD_LOWPASS], held[pp.HELD_LOWPASS + 1]
        t = (n0 + k) * h
        touched = False
        for _ in range(nsub):
            phi, dphi, psi, dpsi, hit = rk4_step(
                phi, dphi, psi, dpsi, v, c, hs, contact, t, dv, held, lowpass
            )
            touched = touched or hit
        if contact == 1 and (touched or phi > c[pp.C_PHI_LIM]):
            held[pp.HELD_LOWPASS], held[pp.HELD_LOWPASS + 1] = z0, z1  # the sample again
            phi, dphi, psi, dpsi = _contact_sample(
                phi0, dphi0, psi0, dpsi0, v, c, h, nsub_contact, t, dv, held, lowpass
            )
    x[0], x[1], x[2], x[3] = phi, dphi, psi, dpsi


@njit(cache=True)
def run_model(
    x,
    actuator,
    zi,
    hist_s,
    hist_p,
    drive,
    h,
    nsub,
    nsub_contact,
    p,
    delay_s,
    delay_p,
    phi_out,
    psi_out,
    vs_out,
    vp_out,
    n0,
):
    """Simulate one model over `drive`, its first sample the run's `n0`-th (a float: a
    discovered term's time is (n0 + k) h); x, actuator, zi, hist_s, hist_p are updated in place.

    `actuator` is the state held between samples (`plant_params.HELD_LEN`): the hysteretic
    voltage, the last drive sample, the low-pass terms' filters. With the actuator's hysteresis
    on, the mechanics see the drive less that voltage; the feedthrough sees the drive.
    """
    fraction = p[pp.P_HYST_FRAC]
    last = actuator[1]  # the commanded drive's sample before the block (its rate's start)
    if fraction > 0.0:
        lag = np.empty(drive.shape[0])
        hysteretic_voltage(drive, fraction, p[pp.P_HYST_SAT], actuator, lag)
        _mechanics(
            x, drive - lag, drive, last, actuator, h, nsub, nsub_contact, p, phi_out, psi_out,
            vs_out, vp_out, n0,
        )  # fmt: skip
        feed = p[pp.P_FT]
        if feed != 0.0:
            for k in range(drive.shape[0]):
                vs_out[k] += feed * lag[k]
    else:
        _mechanics(
            x, drive, drive, last, actuator, h, nsub, nsub_contact, p, phi_out, psi_out, vs_out,
            vp_out, n0,
        )  # fmt: skip
        if drive.shape[0] > 0:
            actuator[1] = drive[drive.shape[0] - 1]
    zi[0] = sensor_channel_kernel(
        vs_out,
        p[pp.P_HPS_ON],
        p[pp.P_HPS_B0],
        p[pp.P_HPS_B1],
        p[pp.P_HPS_A1],
        zi[0],
        hist_s,
        delay_s,
        p[pp.P_DS_FRAC],
        p[pp.P_VREF],
    )
    zi[1] = sensor_channel_kernel(
        vp_out,
        p[pp.P_HPP_ON],
        p[pp.P_HPP_B0],
        p[pp.P_HPP_B1],
        p[pp.P_HPP_A1],
        zi[1],
        hist_p,
        delay_p,
        p[pp.P_DP_FRAC],
        p[pp.P_VREF],
    )


@njit(cache=True, parallel=True)
def run_batch(drive, h, nsubs, params, delays, hist_len, x0, phi_out, psi_out, vs_out, vp_out):
    """Each model from its own mechanical state x0[i] (zeros: from rest; the actuator and the
    sensor chain at rest) over a shared (1, n) or per-model (m, n) drive.
    """
    shared = drive.shape[0] == 1
    for i in prange(params.shape[0]):
        row = np.int64(0) if shared else np.int64(i)
        x = x0[i].copy()
        actuator = np.zeros(pp.HELD_LEN)
        zi = np.zeros(2)
        hist_s = np.zeros(hist_len[i, 0])
        hist_p = np.zeros(hist_len[i, 1])
        run_model(
            x,
            actuator,
            zi,
            hist_s,
            hist_p,
            drive[row],
            h,
            nsubs[i, 0],
            nsubs[i, 1],
            params[i],
            delays[i, 0],
            delays[i, 1],
            phi_out[i],
            psi_out[i],
            vs_out[i],
            vp_out[i],
            0.0,  # every run's time starts at its first sample
        )


# Central-difference step of a state in the linearised responses: this fraction of (|x| + the
# state's own scale: rad, rad/s, rad, rad/s).
_REL_STEP = 1e-6
_SCALE = (1.0, 100.0, 1.0, 100.0)


@njit(cache=True, fastmath=_FMA, inline="always")
def _moved(x, i, step):
    """The state `x` (4,) with component i moved by `step`, as four scalars."""
    return (
        x[0] + step if i == 0 else x[0],
        x[1] + step if i == 1 else x[1],
        x[2] + step if i == 2 else x[2],
        x[3] + step if i == 3 else x[3],
    )


@njit(cache=True, fastmath=_FMA)
def _jacobian(x, v, c, contact, t, dv, z0, z1, equation, out_a, out_b):
    """Rows of A (the accelerations' derivatives in phi, dphi, psi, dpsi) into `out_a`
    (stroke) and `out_b` (pitch), and B (the accelerations' change per unit of forcing on
    `equation`) as the returned pair.
    """
    for i in range(4):
        step = _REL_STEP * (abs(x[i]) + _SCALE[i])
        p0, p1, p2, p3 = _moved(x, i, step)
        a_up, b_up = _accelerations(p0, p1, p2, p3, v, c, contact, t, dv, z0, z1)
        p0, p1, p2, p3 = _moved(x, i, -step)
        a_dn, b_dn = _accelerations(p0, p1, p2, p3, v, c, contact, t, dv, z0, z1)
        out_a[i] = (a_up - a_dn) / (2.0 * step)
        out_b[i] = (b_up - b_dn) / (2.0 * step)
    if equation == 2:
        return 0.0, 1.0
    # a stroke forcing reaches the pitch through the stroke's acceleration
    a, _b = _accelerations(x[0], x[1], x[2], x[3], v, c, contact, t, dv, z0, z1)
    drag = abs(x[1]) * x[1]
    step = _REL_STEP * (abs(a) + 1.0)
    _stroke, pitch_terms = dynamics_terms(c, x[0], x[1], x[2], x[3], v, t, dv, z0, z1)
    b_up = _pitch_acceleration(x[2], x[3], a + step, drag, c, pitch_terms)
    b_dn = _pitch_acceleration(x[2], x[3], a - step, drag, c, pitch_terms)
    return 1.0, (b_up - b_dn) / (2.0 * step)


@njit(cache=True, fastmath=_FMA)
def _product4(x, y, out):
    """The 4x4 product x @ y into `out` (written out: BLAS costs more than the product here)."""
    for r in range(4):
        for k in range(4):
            acc = 0.0
            for j in range(4):
                acc += x[r, j] * y[j, k]
            out[r, k] = acc


@njit(cache=True, fastmath=_FMA)
def _transition(row_a, row_b, b_phi, b_psi, hs, nsub, phi_m, gamma, work):
    """The sample's transition of the linear system d' = A d + B u (u held): RK4's for a
    constant A (its Taylor series to fourth order) over `nsub` substeps of `hs`, into the 4x4
    `phi_m` and the 4-vector `gamma`; `work` (5, 4, 4) is scratch.
    """
    ha, term, series, forcing, scratch = work[0], work[1], work[2], work[3], work[4]
    ha[:, :] = 0.0
    ha[0, 1] = hs
    ha[2, 3] = hs
    for j in range(4):
        ha[1, j] = hs * row_a[j]
        ha[3, j] = hs * row_b[j]
    # series = I + hA + (hA)^2/2 + (hA)^3/6 + (hA)^4/24; forcing = I + hA/2 + (hA)^2/6 + ...
    term[:, :] = 0.0
    for j in range(4):
        term[j, j] = 1.0
    series[:, :] = term
    forcing[:, :] = term
    for k in range(1, 5):
        _product4(term, ha, scratch)
        for r in range(4):
            for j in range(4):
                term[r, j] = scratch[r, j] / k
                series[r, j] += term[r, j]
                if k < 4:
                    forcing[r, j] += term[r, j] / (k + 1)
    # a substep's forcing hs F B, B = (0, b_phi, 0, b_psi)
    g0 = hs * (forcing[0, 1] * b_phi + forcing[0, 3] * b_psi)
    g1 = hs * (forcing[1, 1] * b_phi + forcing[1, 3] * b_psi)
    g2 = hs * (forcing[2, 1] * b_phi + forcing[2, 3] * b_psi)
    g3 = hs * (forcing[3, 1] * b_phi + forcing[3, 3] * b_psi)
    phi_m[:, :] = 0.0
    for j in range(4):
        phi_m[j, j] = 1.0
    gamma[:] = 0.0
    for _ in range(nsub):
        s0, s1, s2, s3 = gamma[0], gamma[1], gamma[2], gamma[3]
        for r in range(4):
            gamma[r] = series[r, 0] * s0 + series[r, 1] * s1 + series[r, 2] * s2 + series[r, 3] * s3
        gamma[0] += g0
        gamma[1] += g1
        gamma[2] += g2
        gamma[3] += g3
        _product4(series, phi_m, scratch)
        phi_m[:, :] = scratch


@njit(cache=True, fastmath=_FMA)
def _linear_responses_with(
    x, drive, commanded, last, held, h, nsub, nsub_contact, p, c, equation, torque, inertia, angle,
    out,
):  # fmt: skip
    """March the motion sample by sample with the kernel's own step, and every torque column's
    deviation with the linearised transition (its forcing the torque over `inertia`); `out[k, j]`
    is column j's deviation of the judged angle (0 stroke, 2 pitch) at sample k (before the
    sample's step, like the kernel's output).
    """
    n, m = torque.shape
    d = np.zeros((4, m))
    row_a, row_b = np.zeros(4), np.zeros(4)
    phi_m, gamma, work = np.zeros((4, 4)), np.zeros(4), np.zeros((5, 4, 4))
    scratch = np.zeros((4, 1))
    contact = 1 if p[pp.P_CONTACT_ON] != 0.0 else 0
    fs = 1.0 / h
    hs = h / nsub
    start, mid = np.zeros(4), np.zeros(4)
    for k in range(n):
        for j in range(m):
            out[k, j] = d[angle, j]
        v = drive[k]
        dv = (commanded[k] - last) * fs
        z0, z1 = held[pp.HELD_LOWPASS], held[pp.HELD_LOWPASS + 1]
        start[:] = x
        # the motion's own step: the kernel's, one sample at a time (bit for bit its output)
        _mechanics_with(
            x, drive[k : k + 1], commanded[k : k + 1], last, held, h, nsub, nsub_contact, p, c,
            scratch[0], scratch[1], scratch[2], scratch[3], float(k),
        )  # fmt: skip
        last = commanded[k]
        # A at the sample's midpoint: the transition then errs at second order in h
        for i in range(4):
            mid[i] = 0.5 * (start[i] + x[i])
        b_phi, b_psi = _jacobian(mid, v, c, contact, k * h, dv, z0, z1, equation, row_a, row_b)
        _transition(row_a, row_b, b_phi, b_psi, hs, nsub, phi_m, gamma, work)
        for j in range(m):
            u = torque[k, j] / inertia
            d0 = phi_m[0, 0] * d[0, j] + phi_m[0, 1] * d[1, j] + phi_m[0, 2] * d[2, j]
            d1 = phi_m[1, 0] * d[0, j] + phi_m[1, 1] * d[1, j] + phi_m[1, 2] * d[2, j]
            d2 = phi_m[2, 0] * d[0, j] + phi_m[2, 1] * d[1, j] + phi_m[2, 2] * d[2, j]
            d3 = phi_m[3, 0] * d[0, j] + phi_m[3, 1] * d[1, j] + phi_m[3, 2] * d[2, j]
            d[0, j] = d0 + phi_m[0, 3] * d[3, j] + gamma[0] * u
            d[1, j] = d1 + phi_m[1, 3] * d[3, j] + gamma[1] * u
            d[2, j] = d2 + phi_m[2, 3] * d[3, j] + gamma[2] * u
            d[3, j] = d3 + phi_m[3, 3] * d[3, j] + gamma[3] * u


@njit(cache=True)
def linear_responses(x, drive, h, nsub, nsub_contact, p, equation, torque, inertia, angle, out):
    """The plant's response to small added torques on `equation` (1 stroke, 2 pitch; its
    `inertia` turns them into accelerations), linearised about its motion from the state `x`
    (the actuator and the low-pass terms at rest) over `drive`: `out[k, j]` is the change of
    the angle `angle` (0 stroke, 2 pitch) at sample k made by the torque column `torque[:, j]`
    (N m, held over each sample), divided by `inertia` as the kernel reads it.

    The motion is marched sample by sample with the kernel's own step (bit for bit its output;
    the actuator's hysteresis taken off the drive as `run_model` does), and each column's
    deviation with the linear system's transition at the sample (`_transition`).
    """
    held = np.zeros(pp.HELD_LEN)
    seen = drive
    if p[pp.P_HYST_FRAC] > 0.0:
        lag = np.empty(drive.shape[0])
        hysteretic_voltage(drive, p[pp.P_HYST_FRAC], p[pp.P_HYST_SAT], held, lag)
        seen = drive - lag
    if p[pp.P_NTERMS] > 0.0:
        _linear_responses_with(
            x, seen, drive, 0.0, held, h, nsub, nsub_contact, p, constants_with_terms(p),
            equation, torque, inertia, angle, out,
        )  # fmt: skip
    else:
        _linear_responses_with(
            x, seen, drive, 0.0, held, h, nsub, nsub_contact, p, mechanical_constants(p),
            equation, torque, inertia, angle, out,
        )  # fmt: skip


@njit(cache=True, fastmath=_FMA)
def _stroke_fundamentals_with(c, omega, amplitudes, pitch_re, pitch_im, n_points, out):
    """`stroke_fundamentals` with the constants tuple `c`."""
    step = 2.0 * np.pi / n_points
    for i in range(amplitudes.shape[0]):
        a = amplitudes[i]
        w = omega[i]
        acc_re, acc_im = 0.0, 0.0
        for k in range(n_points):
            theta = k * step
            ct, st = np.cos(theta), np.sin(theta)
            phi, dphi = a * ct, -a * w * st
            psi = pitch_re[i] * ct - pitch_im[i] * st
            dpsi = -w * (pitch_re[i] * st + pitch_im[i] * ct)
            ddphi, _ddpsi = _accelerations(phi, dphi, psi, dpsi, 0.0, c, 0, 0.0, 0.0, 0.0, 0.0)
            acc_re += ddphi * ct
            acc_im -= ddphi * st
        out[i] = complex(acc_re, acc_im) * (2.0 / n_points)


@njit(cache=True, fastmath=_FMA)
def _pitch_fundamental(c, stroke, pitch, s, n_points):
    """Fundamental of the pitch acceleration (but the pitch inertia's) along the stroke and the
    pitch phasors `stroke`, `pitch` of the motion e^(s t): rates s X, the stroke's acceleration
    s^2 S, the motion's own.
    """
    step = 2.0 * np.pi / n_points
    turn = complex(np.cos(step), np.sin(step))
    da, dda, db = s * stroke, s * s * stroke, s * pitch
    acc = 0.0 + 0.0j
    e = 1.0 + 0.0j  # e^(j k step) by rotation: a period's rounding stays ~1e-14
    for _ in range(n_points):
        phi, dphi = (stroke * e).real, (da * e).real
        psi, dpsi = (pitch * e).real, (db * e).real
        # the drive off (and its rate), the time at 0 and the low-pass terms' states at rest, as
        # the stroke's describing function
        _stroke, pitch_terms = dynamics_terms(c, phi, dphi, psi, dpsi, 0.0, 0.0, 0.0, 0.0, 0.0)
        ddpsi = _pitch_acceleration(psi, dpsi, (dda * e).real, abs(dphi) * dphi, c, pitch_terms)
        acc += ddpsi * e.conjugate()
        e *= turn
    return acc * (2.0 / n_points)


@njit(cache=True, fastmath=_FMA)
def _pitch_responses_with(c, stroke, s, inertial, start, n_points, passes, tol, probe_rad, out):
    """`pitch_responses` with the constants tuple `c`."""
    for i in range(stroke.shape[0]):
        forced = _pitch_fundamental(c, stroke[i], 0.0j, s[i], n_points)
        pitch = start[i]
        probe = pitch if abs(pitch) > probe_rad else complex(probe_rad, 0.0)
        for k in range(passes):
            hinge = (_pitch_fundamental(c, stroke[i], probe, s[i], n_points) - forced) / probe
            new = forced / (inertial[i] - hinge)
            done = abs(new - pitch) <= tol * abs(new)
            # the first pass whole (from the start, or the hinge's linear part); later ones
            # halved (a stiffening hinge near its resonance overshoots: a plain iteration
            # there oscillates)
            pitch = new if k == 0 or done else 0.5 * (pitch + new)
            if done:
                break
            probe = pitch if abs(pitch) > probe_rad else complex(probe_rad, 0.0)
        out[i] = pitch


@njit(cache=True)
def pitch_responses(p, stroke, s, inertial, start, n_points, passes, tol, probe_rad, out):
    """The pitch phasor P the hinge makes of each stroke phasor `stroke` (motion e^(s t)):
    r I_p s^2 P = T(P) with the kernel's own pitch torques T at the fundamental (`inertial` is
    r s^2), the hinge taken as its describing function at the pitch of the last pass, from a
    first pass at `start` (or at `probe_rad` where smaller), until a pass moves it by less than
    `tol` of itself (at most `passes`); into `out`.
    """
    if p[pp.P_NTERMS] > 0.0:
        c = constants_with_terms(p)
        _pitch_responses_with(c, stroke, s, inertial, start, n_points, passes, tol, probe_rad, out)
    else:
        c = mechanical_constants(p)
        _pitch_responses_with(c, stroke, s, inertial, start, n_points, passes, tol, probe_rad, out)


@njit(cache=True)
def stroke_fundamentals(p, omega, amplitudes, pitch_re, pitch_im, n_points, out):
    """Fundamental (complex amplitude, rad/s^2) of the stroke acceleration the kernel's own
    `_accelerations` gives, drive off and the stop ignored, along phi = a cos(w t) with the
    pitch Re(P e^(j w t)); one per row of `omega`, `amplitudes`, `pitch_re`, `pitch_im` into
    `out` (complex), from `n_points` samples of a period.
    """
    if p[pp.P_NTERMS] > 0.0:
        _stroke_fundamentals_with(
            constants_with_terms(p), omega, amplitudes, pitch_re, pitch_im, n_points, out
        )
    else:
        _stroke_fundamentals_with(
            mechanical_constants(p), omega, amplitudes, pitch_re, pitch_im, n_points, out
        )
