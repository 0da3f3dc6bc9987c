r"""Linear theory of the dSA loop: characteristic polynomial and Hopf onset.

Pure numpy/scipy; no state, no I/O.

Loop (paper eqs. dsa, dsaconst) with the aerodynamic damping removed (Gamma = 0) and an
optional linear structural damping ``c_s``::

    I phi'' + c_s phi' + K phi = tau                       (plant)
    tau'' + a tau' + b tau     = -c phi'                   (dSA filter)
    a = r3 (1 + kappa),  b = kappa r3^2,  c = mu kappa r3^2

``mu`` is dimensional here (N m s / rad): at DC the filter is tau = -mu phi', a plain damper
of gain mu; above sqrt(b) its phase lag exceeds 90 deg and it feeds energy in.

Derivation of the Hopf onset
----------------------------
Laplace transform: (I s^2 + c_s s + K) Phi = T and (s^2 + a s + b) T = -c s Phi, so the
closed loop has the characteristic polynomial::

    Delta(s) = (I s^2 + c_s s + K)(s^2 + a s + b) + c s
             = a4 s^4 + a3 s^3 + a2 s^2 + a1 s + a0
    a4 = I,  a3 = I a + c_s,  a2 = I b + c_s a + K,  a1 = c_s b + K a + c,  a0 = K b.

Note (s^2 + a s + b) = (s + r3)(s + kappa r3): the filter alone is stable for r3, kappa > 0.
A pair of roots crosses the imaginary axis at s = j w when Re Delta(jw) = Im Delta(jw) = 0::

    Re:  I w^4 - (I b + c_s a + K) w^2 + K b = 0
    Im:  a1 = a3 w^2            ->  c = (I a + c_s) w^2 - c_s b - K a

Equivalently the third Hurwitz determinant vanishes, a3 a2 a1 - a3^2 a0 - a4 a1^2 = 0, a
quadratic in a1 (c enters a1 only). At c = 0 the loop (damped plant x stable filter) is
stable, a1 sits between the two roots of that quadratic, and increasing c raises a1 until it
reaches the larger root. Hence, in closed form::

    w*^2 = [ a2 + sqrt(a2^2 - 4 I K b) ] / (2 I)        (the larger root of "Re")
    c*   = (I a + c_s) w*^2 - c_s b - K a
    mu*  = c* / (kappa r3^2)

Undamped plant (c_s = 0, the case asked for): "Re" factorises, (I w^2 - K)(w^2 - b) = 0.

* If kappa r3^2 > K / I (sqrt(kappa) r3 above the plant natural frequency w_n)::

      w*  = sqrt(kappa) * r3                     (exactly)
      c*  = a (I b - K)
      mu* = (1 + kappa) (I kappa r3^2 - K) / (kappa r3)
          = (1 + kappa) I (w*^2 - w_n^2) / (kappa r3)

  At w = sqrt(b) the filter's phase lag is exactly 90 deg (atan(w/r3) + atan(w/(kappa r3))
  = 90 deg iff w^2 = kappa r3^2): it acts as a pure spring tau = -(c/a) phi with no energy
  exchange, and the loop oscillates where that added spring retunes the plant to
  I w^2 = K + c/a. So the emergent frequency sits *above* the stroke resonance, as in the
  paper's transition experiment.
* If sqrt(kappa) r3 <= w_n, the filter already feeds energy in at w_n, where the undamped
  plant is marginal: mu* = 0 and the onset is at w_n (degenerate; the undamped plant alone
  sits on the stability boundary). Choosing r3 = w_n / sqrt(kappa) is the border case of
  both (mu* = 0, w* = w_n = sqrt(kappa) r3).

So with Gamma = 0 and no structural damping, w* = sqrt(kappa) r3 holds exactly whenever
sqrt(kappa) r3 > w_n; the plant sets only mu*. With structural damping c_s > 0 the onset
frequency is set jointly by plant and filter (formula above), slightly above sqrt(kappa) r3,
and reduces to sqrt(kappa) r3 as c_s -> 0.

Loop delay
----------
A pure delay T in the loop (block transport, zero-order hold, velocity estimation) multiplies
the filter by exp(-s T). At the crossing the filter must still look like a pure spring, so the
onset moves to where atan(w/r3) + atan(w/(kappa r3)) + w T = 90 deg: *lower* w, and because
mu* grows with (w*^2 - w_n^2) the threshold collapses. With the nominal numbers (T = 0.55 ms,
w/2pi ~ 150 Hz: w T ~ 30 deg) this is a first-order effect. ``onset_with_delay`` solves the
delayed loop numerically (optionally with the phase-advance compensation used by
``flaair_control.core.dsa``, which restores the undelayed onset exactly at its design frequency).

Limit cycle with aerodynamic damping
------------------------------------
``limit_cycle``: first-harmonic balance, Gamma |phi'| phi' ~ c_eq phi' with
c_eq = 8/(3 pi) Gamma w A; the limit cycle is the Hopf onset of the loop with damping c_eq.
Since mu* rises with damping, A grows with mu and so does w (the filter's added stiffness c/a):
nominal plant, kappa = 0.5, onset designed at 142 Hz, mu = 10 mu*: 2.9 deg at 159 Hz
(20 mu*: 9.2 deg at 176 Hz). The simulated block loop agrees within 0.1 %.

Checked against the simulator (tests/test_control_hopf.py): with the compensated 0.55 ms loop the
simulated onset is within 0.1 % of mu* and at 150.0 Hz for a 150 Hz design; uncompensated, a
300 Hz design starts at the delayed prediction (161 Hz, mu* ten times lower).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import brentq

__all__ = [
    "HopfOnset",
    "HopfParameterError",
    "LimitCycle",
    "LinearStrokePlant",
    "characteristic_polynomial",
    "closed_loop_poles",
    "filter_coefficients",
    "hopf_onset",
    "limit_cycle",
    "onset_with_delay",
    "phase_advance",
    "r3_for_onset_frequency",
]


class HopfParameterError(ValueError):
    """A plant or filter parameter is out of range; the message names it."""


@dataclass(frozen=True)
class LinearStrokePlant:
    """Linearised stroke plant I phi'' + c_s phi' + K phi = tau (aerodynamic damping removed)."""

    inertia_kg_m2: float
    stiffness_nm_per_rad: float
    damping_nm_s_per_rad: float = 0.0

    def __post_init__(self) -> None:
        if not self.inertia_kg_m2 > 0:
            raise HopfParameterError(f"inertia_kg_m2 must be > 0, got {self.inertia_kg_m2}")
        if not self.stiffness_nm_per_rad > 0:
            raise HopfParameterError(
                f"stiffness_nm_per_rad must be > 0, got {self.stiffness_nm_per_rad}"
            )
        if not self.damping_nm_s_per_rad >= 0:
            raise HopfParameterError(
                f"damping_nm_s_per_rad must be >= 0, got {self.damping_nm_s_per_rad}"
            )

    @property
    def natural_frequency_rad_s(self) -> float:
        """Undamped natural frequency w_n = sqrt(K / I)."""
        return math.sqrt(self.stiffness_nm_per_rad / self.inertia_kg_m2)

    @classmethod
    def from_natural_frequency(
        cls, inertia_kg_m2: float, natural_frequency_hz: float, damping_nm_s_per_rad: float = 0.0
    ) -> LinearStrokePlant:
        """Plant with K = I (2 pi f_n)^2."""
        k = inertia_kg_m2 * (2.0 * math.pi * natural_frequency_hz) ** 2
        return cls(inertia_kg_m2, k, damping_nm_s_per_rad)


@dataclass(frozen=True)
class HopfOnset:
    """Where the loop starts to oscillate: threshold gain and crossing frequency."""

    mu_nm_s_per_rad: float
    omega_rad_s: float

    @property
    def frequency_hz(self) -> float:
        """Onset frequency in Hz."""
        return self.omega_rad_s / (2.0 * math.pi)


def _check_filter(r3_rad_s: float, kappa: float) -> None:
    if not (math.isfinite(r3_rad_s) and r3_rad_s > 0):
        raise HopfParameterError(f"r3_rad_s must be finite and > 0, got {r3_rad_s}")
    if not (math.isfinite(kappa) and kappa > 0):
        raise HopfParameterError(f"kappa must be finite and > 0, got {kappa}")


def filter_coefficients(
    r3_rad_s: float, kappa: float, mu_nm_s_per_rad: float
) -> tuple[float, float, float]:
    """(a, b, c) of tau'' + a tau' + b tau = -c phi' (paper eq. dsaconst)."""
    _check_filter(r3_rad_s, kappa)
    a = r3_rad_s * (1.0 + kappa)
    b = kappa * r3_rad_s**2
    c = mu_nm_s_per_rad * kappa * r3_rad_s**2
    return a, b, c


def characteristic_polynomial(
    plant: LinearStrokePlant, r3_rad_s: float, kappa: float, mu_nm_s_per_rad: float
) -> np.ndarray:
    """Coefficients [a4, a3, a2, a1, a0] (descending powers of s) of the closed-loop Delta(s)."""
    a, b, c = filter_coefficients(r3_rad_s, kappa, mu_nm_s_per_rad)
    i, cs, k = plant.inertia_kg_m2, plant.damping_nm_s_per_rad, plant.stiffness_nm_per_rad
    p = np.polymul([i, cs, k], [1.0, a, b])
    p[-2] += c
    return p


def closed_loop_poles(
    plant: LinearStrokePlant, r3_rad_s: float, kappa: float, mu_nm_s_per_rad: float
) -> np.ndarray:
    """Roots of Delta(s) (rad/s), the four closed-loop poles of the delay-free loop."""
    return np.roots(characteristic_polynomial(plant, r3_rad_s, kappa, mu_nm_s_per_rad))


def hopf_onset(plant: LinearStrokePlant, r3_rad_s: float, kappa: float) -> HopfOnset:
    """Closed-form Hopf onset (mu*, w*) of the delay-free loop; see the module docstring."""
    a, b, _ = filter_coefficients(r3_rad_s, kappa, 0.0)
    i, cs, k = plant.inertia_kg_m2, plant.damping_nm_s_per_rad, plant.stiffness_nm_per_rad
    a2 = i * b + cs * a + k
    disc = a2 * a2 - 4.0 * i * k * b
    # disc = (I b - K)^2 + c_s a (2 I b + 2 K + c_s a) >= 0; clip rounding.
    omega2 = (a2 + math.sqrt(max(disc, 0.0))) / (2.0 * i)
    c_star = (i * a + cs) * omega2 - cs * b - k * a
    c_star = max(c_star, 0.0)
    return HopfOnset(mu_nm_s_per_rad=c_star / b, omega_rad_s=math.sqrt(omega2))


def r3_for_onset_frequency(kappa: float, onset_frequency_hz: float) -> float:
    """r3 that puts the undamped-plant onset at ``onset_frequency_hz``: r3 = w / sqrt(kappa)."""
    _check_filter(1.0, kappa)
    if not onset_frequency_hz > 0:
        raise HopfParameterError(f"onset_frequency_hz must be > 0, got {onset_frequency_hz}")
    return 2.0 * math.pi * onset_frequency_hz / math.sqrt(kappa)


def phase_advance(
    s: complex | np.ndarray, advance_s: float, design_omega_rad_s: float
) -> complex | np.ndarray:
    """Phase-advance term of ``flaair_control.core.dsa``: cos(w_c T) + s sin(w_c T) / w_c.

    Applied to the filter state (tau, tau'), it predicts tau(t + T) exactly for a sinusoid at
    the design frequency w_c: at s = j w_c it equals exp(j w_c T).
    """
    wt = design_omega_rad_s * advance_s
    return math.cos(wt) + s * (math.sin(wt) / design_omega_rad_s)


def onset_with_delay(
    plant: LinearStrokePlant,
    r3_rad_s: float,
    kappa: float,
    delay_s: float,
    advance_s: float = 0.0,
    design_omega_rad_s: float | None = None,
    omega_max_rad_s: float | None = None,
) -> HopfOnset:
    """Hopf onset of the loop with a pure delay ``delay_s`` and optional phase advance.

    Loop: Delta(s) = P(s) Q(s) + c s D(s), P = I s^2 + c_s s + K, Q = s^2 + a s + b,
    D(s) = exp(-s delay) * (cos(w_c T_a) + s sin(w_c T_a)/w_c) with T_a = ``advance_s``.
    On s = j w, c(w) = -P Q / (j w D) must be real and positive; the onset is the smallest
    such c (the first crossing as mu rises from 0, which must be destabilising). For the
    undamped plant the trivial c = 0 root at w_n is excluded unless the filter destabilises
    it (then mu* = 0). Solved numerically (grid + brentq on Im c(w)).
    """
    _check_filter(r3_rad_s, kappa)
    a, b, _ = filter_coefficients(r3_rad_s, kappa, 0.0)
    i, cs, k = plant.inertia_kg_m2, plant.damping_nm_s_per_rad, plant.stiffness_nm_per_rad
    wc = design_omega_rad_s if design_omega_rad_s is not None else math.sqrt(b)
    wn = plant.natural_frequency_rad_s
    w_hi = omega_max_rad_s if omega_max_rad_s is not None else 6.0 * max(wn, math.sqrt(b))

    def c_of(w: ArrayLike) -> np.ndarray:
        s = 1j * np.asarray(w, dtype=float)
        p = i * s * s + cs * s + k
        q = s * s + a * s + b
        d = np.exp(-s * delay_s) * phase_advance(s, advance_s, wc)
        return -p * q / (s * d)

    grid = np.linspace(1e-3 * w_hi, w_hi, 20000)
    im = c_of(grid).imag
    scale = i * b * a  # typical size of c*
    candidates: list[tuple[float, float]] = []
    for j in np.nonzero(np.sign(im[:-1]) * np.sign(im[1:]) < 0)[0]:
        w = brentq(lambda x: float(c_of(x).imag), grid[j], grid[j + 1], xtol=1e-12 * w_hi)
        c = float(c_of(w).real)
        if c > 1e-9 * scale:
            candidates.append((c, w))
    if cs == 0.0:
        # Undamped plant: at mu = 0+ the plant pair (on the axis) is destabilised iff the
        # delayed filter feeds energy at w_n, i.e. Re[-H(j w_n) D(j w_n)] > 0 with H = 1/Q.
        s = 1j * wn
        gain = -phase_advance(s, advance_s, wc) * np.exp(-s * delay_s) / (s * s + a * s + b)
        if gain.real > 0:
            return HopfOnset(0.0, wn)
    if not candidates:
        raise HopfParameterError("no Hopf crossing found below omega_max_rad_s")
    c_star, w_star = min(candidates)
    return HopfOnset(mu_nm_s_per_rad=c_star / b, omega_rad_s=w_star)


@dataclass(frozen=True)
class LimitCycle:
    """Describing-function prediction of the dSA limit cycle with quadratic damping."""

    amplitude_rad: float
    omega_rad_s: float
    equivalent_damping_nm_s_per_rad: float

    @property
    def frequency_hz(self) -> float:
        return self.omega_rad_s / (2.0 * math.pi)


def limit_cycle(
    plant: LinearStrokePlant,
    aero_damping_nm_s2: float,
    r3_rad_s: float,
    kappa: float,
    mu_nm_s_per_rad: float,
    delay_s: float = 0.0,
    advance_s: float = 0.0,
    design_omega_rad_s: float | None = None,
) -> LimitCycle:
    """Limit cycle of I phi'' + Gamma |phi'| phi' + c_s phi' + K phi = tau with the dSA filter.

    First-harmonic balance: for phi = A sin(w t) the fundamental of Gamma |phi'| phi' is that of
    a viscous damper c_eq = 8/(3 pi) Gamma w A. The limit cycle is therefore the Hopf onset of
    the linear loop with damping c_s + c_eq: find c_eq with mu*(c_s + c_eq) = mu (mu* rises
    monotonically with damping), take w = w*(c_s + c_eq), then A = 3 pi c_eq / (8 Gamma w).
    Stable (supercritical): more amplitude -> more damping -> decay back. Uses the closed form
    without delay, ``onset_with_delay`` otherwise. Harmonics are neglected.
    """
    if not aero_damping_nm_s2 > 0:
        raise HopfParameterError(f"aero_damping_nm_s2 must be > 0, got {aero_damping_nm_s2}")

    def onset(extra: float) -> HopfOnset:
        p = LinearStrokePlant(
            plant.inertia_kg_m2, plant.stiffness_nm_per_rad, plant.damping_nm_s_per_rad + extra
        )
        if delay_s == 0.0 and advance_s == 0.0:
            return hopf_onset(p, r3_rad_s, kappa)
        return onset_with_delay(p, r3_rad_s, kappa, delay_s, advance_s, design_omega_rad_s)

    mu0 = onset(0.0).mu_nm_s_per_rad
    if mu_nm_s_per_rad <= mu0:
        return LimitCycle(0.0, onset(0.0).omega_rad_s, 0.0)
    hi = plant.inertia_kg_m2 * plant.natural_frequency_rad_s * 1e-3
    while onset(hi).mu_nm_s_per_rad < mu_nm_s_per_rad:
        hi *= 2.0
        if hi > 1e6 * plant.inertia_kg_m2 * plant.natural_frequency_rad_s:
            raise HopfParameterError("no limit cycle found (mu too large)")
    c_eq = brentq(
        lambda x: onset(x).mu_nm_s_per_rad - mu_nm_s_per_rad, 0.0, hi, xtol=1e-15, rtol=1e-10
    )
    w = onset(c_eq).omega_rad_s
    return LimitCycle(3.0 * math.pi * c_eq / (8.0 * aero_damping_nm_s2 * w), w, c_eq)
