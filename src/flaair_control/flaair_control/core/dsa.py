r"""Delayed-stretch-activation (dSA) controller core (paper eqs. dsa, dsaconst).

Pure numpy/scipy; explicit state; ``step(state, DsaInputs(velocity_block, t_start_s), params)``.

Filter
------
The dSA filter turns the estimated stroke velocity phi' (rad/s) into an actuator torque::

    tau'' + a tau' + b tau = -c phi',   a = r3 (1 + kappa), b = kappa r3^2, c = mu kappa r3^2

H(s) = T(s)/Phi'(s) = -c / ((s + r3)(s + kappa r3)). ``mu`` is dimensional (N m s / rad): at DC
tau = -mu phi'. The torque becomes drive volts through the actuator gain G_a
(``actuator_gain_nm_per_v``), is blended with a synchronous sine and clipped::

    drive = K_r(t) * sync(t) + (1 - K_r(t)) * tau / G_a,   |drive| <= drive_limit_v
    sync(t) = sync_amplitude_v * sin(2 pi sync_frequency_hz t + sync_phase_rad)

K_r(t) is a piecewise-linear ramp given as data (``KrSchedule``). The filter runs all the time
(driven by the measured velocity) whatever K_r is, so the hand-over is bumpless.

Discretization
--------------
Bilinear (Tustin) transform with frequency pre-warping at the compensation/design frequency
w_c (default sqrt(kappa) r3, the delay-free Hopf onset, see ``flaair_control.core.hopf``): the
discrete filter's frequency response equals H(j w_c) exactly at w_c; elsewhere the frequency is
warped by about ((w T_s)^2 - (w_c T_s)^2) / 12 (T_s = 50 us): < 1e-4 over 100-200 Hz, 1e-3 at
400 Hz (magnitude error ~2x that above the filter corners). A sampled step enters as a ramp over
one sample, so the step response is the continuous one half a sample late. Tustin has
no half-sample lag (unlike ZOH discretization of a sampled, not held, input), which matters
here because the onset is very phase-sensitive. Implemented as scipy.signal.bilinear with an
effective rate fs_eff = w_c / (2 tan(w_c / (2 fs))), and run as scipy.signal.lfilter's
arithmetic compiled with the rest of the block (``flaair_model.lfilter``: same samples, same
state); the state is the lfilter ``zi`` vector, so splitting a record into blocks changes nothing.

Transport delay and its compensation
------------------------------------
The loop works in blocks: the velocity block of samples [kN, (k+1)N) is only complete at the
end of block k, so the drive it produces is applied during block k+1. Velocity sample n
therefore first acts on drive sample n + N: a pure delay of N samples (0.5 ms at N = 10,
fs = 20 kHz). The zero-order hold of the drive adds T_s/2, and a backward-difference velocity
estimate another T_s/2, so T_loop = (N + 1) T_s = 0.55 ms for the nominal loop. At 140 Hz
that is a phase lag w T_loop = 27.7 deg (25.2 deg for the block alone). The onset condition
(filter phase lag = 90 deg at the crossing) then holds at a *lower* frequency, and since the
undamped loop's threshold mu* ~ I (w*^2 - w_n^2) the onset collapses: with the nominal plant
and a 150 Hz design the uncompensated loop is already unstable at mu = 0+ and oscillates at
the plant's 140 Hz instead of 150 Hz (``hopf.onset_with_delay``).

Compensation (``loop_delay_s`` > 0): a phase-advance term. The filter output is replaced by
the prediction of tau one loop delay ahead for a sinusoid at w_c,

    tau_adv = cos(w_c T) tau + sin(w_c T) / w_c * tau'       (T = loop_delay_s)

i.e. H_adv(s) = H(s) (cos(w_c T) + s sin(w_c T)/w_c), which equals H(j w_c) exp(j w_c T) at
w_c. The delay is cancelled exactly at w_c = the undelayed onset frequency, so the delayed,
compensated loop has the undelayed onset (mu*, w*) -- exactly when the plant is undamped and
w_c = sqrt(kappa) r3, and to first order in the frequency mismatch otherwise. (Shifting r3
instead would fix the onset frequency but not mu*, since the filter gain changes too.)
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import Any, NamedTuple

import numpy as np
from numba import njit
from scipy import signal

from flaair_model.lfilter import float_block, lfilter_sample, normalized_ba

__all__ = [
    "DSA_VALUE_KEYS",
    "SIGNAL_ROWS",
    "DsaInputs",
    "DsaOutputs",
    "DsaParameterError",
    "DsaParams",
    "DsaSignals",
    "DsaState",
    "KrSchedule",
    "continuous_response",
    "dsa_params",
    "filter_block",
    "filter_coefficients",
    "frequency_response",
    "initial_state",
    "loop_delay_s",
    "step",
]


class DsaParameterError(ValueError):
    """A dSA parameter or input is invalid; the message names it."""


@dataclass(frozen=True)
class KrSchedule:
    """Piecewise-linear K_r(t): ``start_value`` until ``start_time_s``, linear to ``end_value``
    over ``duration_s``, then ``end_value``. K_r = 1 fully synchronous, 0 fully asynchronous.
    """

    start_value: float
    end_value: float
    start_time_s: float
    duration_s: float

    def __post_init__(self) -> None:
        for name in ("start_value", "end_value"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0.0 <= v <= 1.0):
                raise DsaParameterError(f"KrSchedule.{name} must be in [0, 1], got {v}")
        if not math.isfinite(self.start_time_s):
            raise DsaParameterError(
                f"KrSchedule.start_time_s must be finite, got {self.start_time_s}"
            )
        if not (math.isfinite(self.duration_s) and self.duration_s >= 0):
            raise DsaParameterError(f"KrSchedule.duration_s must be >= 0, got {self.duration_s}")

    def value(self, t_s: np.ndarray) -> np.ndarray:
        """K_r at times ``t_s`` (s)."""
        t = np.asarray(t_s, dtype=float)
        if self.duration_s == 0.0:
            return np.where(t < self.start_time_s, self.start_value, self.end_value)
        frac = np.clip((t - self.start_time_s) / self.duration_s, 0.0, 1.0)
        return self.start_value + (self.end_value - self.start_value) * frac


@dataclass(frozen=True)
class DsaParams:
    """dSA controller parameters (SI; units in names)."""

    r3_rad_s: float
    kappa: float
    mu_nm_s_per_rad: float
    actuator_gain_nm_per_v: float
    sample_rate_hz: float
    drive_limit_v: float
    sync_amplitude_v: float
    sync_frequency_hz: float
    sync_phase_rad: float
    kr_schedule: KrSchedule
    loop_delay_s: float  # 0: no phase advance
    compensation_frequency_hz: float | None  # None: at the filter's design frequency

    def __post_init__(self) -> None:
        positive = (
            "r3_rad_s",
            "kappa",
            "actuator_gain_nm_per_v",
            "sample_rate_hz",
            "drive_limit_v",
        )
        for name in positive:
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise DsaParameterError(f"{name} must be finite and > 0, got {v}")
        for name in ("mu_nm_s_per_rad", "sync_amplitude_v", "sync_frequency_hz", "sync_phase_rad"):
            v = getattr(self, name)
            if not math.isfinite(v):
                raise DsaParameterError(f"{name} must be finite, got {v}")
        if not (math.isfinite(self.loop_delay_s) and self.loop_delay_s >= 0):
            raise DsaParameterError(f"loop_delay_s must be >= 0, got {self.loop_delay_s}")
        if self.compensation_frequency_hz is not None and not (
            math.isfinite(self.compensation_frequency_hz)
            and 0 < self.compensation_frequency_hz < self.sample_rate_hz / 2
        ):
            raise DsaParameterError(
                "compensation_frequency_hz must be in (0, fs/2), got "
                f"{self.compensation_frequency_hz}"
            )
        if self.design_omega_rad_s >= math.pi * self.sample_rate_hz:
            raise DsaParameterError("sqrt(kappa) * r3_rad_s must lie below the Nyquist frequency")

    @property
    def a(self) -> float:
        """A = r3 (1 + kappa) (1/s)."""
        return self.r3_rad_s * (1.0 + self.kappa)

    @property
    def b(self) -> float:
        """B = kappa r3^2 (1/s^2)."""
        return self.kappa * self.r3_rad_s**2

    @property
    def c(self) -> float:
        """C = mu kappa r3^2 (N m / rad / s)."""
        return self.mu_nm_s_per_rad * self.b

    @property
    def design_omega_rad_s(self) -> float:
        """w_c: pre-warp and delay-compensation frequency (default sqrt(kappa) r3)."""
        if self.compensation_frequency_hz is not None:
            return 2.0 * math.pi * self.compensation_frequency_hz
        return math.sqrt(self.kappa) * self.r3_rad_s

    @cached_property
    def kernel_args(self) -> tuple[np.ndarray, np.ndarray]:
        """``filter_block``'s arguments after the block and the state (once per parameter set:
        hashing the dataclass for a cache, or a dozen attribute reads a block, cost more than a
        block): the normalized (b, a) of the advanced and the raw filter as the rows of one
        array, and the rate, K_r's ramp, the sine, G_a and the limit as another (two arguments,
        not fourteen: a compiled call pays for each argument it is handed).
        """
        kr = self.kr_schedule
        coefficients = np.vstack(
            [
                *normalized_ba(*filter_coefficients(self, True)),
                *normalized_ba(*filter_coefficients(self, False)),
            ]
        )
        scalars = np.array(
            [
                self.sample_rate_hz,
                kr.start_value,
                kr.end_value,
                kr.start_time_s,
                kr.duration_s,
                self.sync_amplitude_v,
                2.0 * np.pi * self.sync_frequency_hz,
                self.sync_phase_rad,
                self.actuator_gain_nm_per_v,
                self.drive_limit_v,
            ],
            dtype=np.float64,
        )
        coefficients.flags.writeable = scalars.flags.writeable = False
        return coefficients, scalars


def loop_delay_s(
    block_size: int, sample_rate_hz: float, velocity_delay_samples: float = 0.5
) -> float:
    """Total loop delay to compensate: block transport + ZOH (T_s/2) + velocity estimator.

    ``velocity_delay_samples`` is the estimator's group delay in samples (0.5 for a backward
    difference of the angle).
    """
    if block_size < 1:
        raise DsaParameterError(f"block_size must be >= 1, got {block_size}")
    return (block_size + 0.5 + velocity_delay_samples) / sample_rate_hz


# The values `dsa_params` reads from a controller's section (or a sweep's row).
DSA_VALUE_KEYS: tuple[str, ...] = (
    "r3_rad_s",
    "kappa",
    "mu_nm_s_per_rad",
    "drive_limit_v",
    "sync_amplitude_v",
    "sync_frequency_hz",
    "sync_phase_rad",
    "compensate_delay",
    "compensation_frequency_hz",
)


def dsa_params(
    values: Mapping[str, Any],
    *,
    actuator_gain_nm_per_v: float,
    sample_rate_hz: float,
    loop_delay_s: float,
    kr_schedule: KrSchedule,
) -> DsaParams:
    """The one way to build `DsaParams` from configured values (keys: `DSA_VALUE_KEYS`).

    `loop_delay_s` is the delay the phase advance would cancel; it applies only when
    ``values["compensate_delay"]`` is true (0: no phase advance).
    """
    missing = [key for key in DSA_VALUE_KEYS if key not in values]
    if missing:
        raise DsaParameterError(f"dSA values lack {', '.join(missing)}")
    return DsaParams(
        r3_rad_s=values["r3_rad_s"],
        kappa=values["kappa"],
        mu_nm_s_per_rad=values["mu_nm_s_per_rad"],
        actuator_gain_nm_per_v=actuator_gain_nm_per_v,
        sample_rate_hz=sample_rate_hz,
        drive_limit_v=values["drive_limit_v"],
        sync_amplitude_v=values["sync_amplitude_v"],
        sync_frequency_hz=values["sync_frequency_hz"],
        sync_phase_rad=values["sync_phase_rad"],
        kr_schedule=kr_schedule,
        loop_delay_s=loop_delay_s if values["compensate_delay"] else 0.0,
        compensation_frequency_hz=values["compensation_frequency_hz"],
    )


@lru_cache(maxsize=64)
def filter_coefficients(params: DsaParams, advanced: bool) -> tuple[np.ndarray, np.ndarray]:
    """Discrete (b, a) of the dSA filter (velocity -> torque), optionally phase-advanced."""
    wc = params.design_omega_rad_s
    if advanced and params.loop_delay_s > 0:
        wt = wc * params.loop_delay_s
        num = [-params.c * math.sin(wt) / wc, -params.c * math.cos(wt)]
    else:
        num = [0.0, -params.c]
    den = [1.0, params.a, params.b]
    fs = params.sample_rate_hz
    fs_eff = wc / (2.0 * math.tan(wc / (2.0 * fs)))  # pre-warp at w_c
    bz, az = signal.bilinear(num, den, fs=fs_eff)
    bz = np.atleast_1d(np.asarray(bz, dtype=float))
    az = np.atleast_1d(np.asarray(az, dtype=float))
    if bz.size < 3:
        bz = np.concatenate([np.zeros(3 - bz.size), bz])
    return bz, az


class DsaState(NamedTuple):
    """Filter state (lfilter ``zi``) of the commanded (advanced) and raw torque filters."""

    zi_advanced: np.ndarray
    zi_raw: np.ndarray


class DsaSignals(NamedTuple):
    """Internal signals of one block (all the length of the block)."""

    torque_raw_nm: np.ndarray  # tau: dSA filter output without phase advance
    torque_nm: np.ndarray  # commanded asynchronous torque (phase-advanced tau)
    async_v: np.ndarray  # torque_nm / G_a
    sync_v: np.ndarray  # synchronous sine
    kr: np.ndarray  # K_r(t)
    drive_unclipped_v: np.ndarray  # K_r sync + (1 - K_r) async, before the limit
    velocity_valid: np.ndarray  # False where the input was non-finite (replaced by 0)


def initial_state(params: DsaParams) -> DsaState:
    """Filter at rest."""
    return DsaState(np.zeros(2), np.zeros(2))


class DsaInputs(NamedTuple):
    """One block of estimated stroke velocity (rad/s; non-finite samples count as 0, flagged in
    ``velocity_valid``) and the time (s) at which the first sample of the *returned drive block*
    is applied: the sync sine and K_r are evaluated at t_start_s + n / fs. In the block loop
    this is the start of the next block (velocity block k produces drive block k + 1).
    """

    stroke_velocity_rad_s: np.ndarray
    t_start_s: float


class DsaOutputs(NamedTuple):
    """Drive volts (|drive| <= drive_limit_v) and the controller's internal signals."""

    drive_v: np.ndarray
    signals: DsaSignals


# The rows of `filter_block`'s signals, in order.
SIGNAL_ROWS = (
    "torque_nm",
    "torque_raw_nm",
    "async_v",
    "sync_v",
    "kr",
    "drive_unclipped_v",
    "drive_v",
)
_TORQUE, _TORQUE_RAW, _ASYNC, _SYNC, _KR, _UNCLIPPED, _DRIVE = range(len(SIGNAL_ROWS))


@njit(cache=True)
def filter_block(
    v_in: np.ndarray,
    t_start_s: float,
    zi_adv: np.ndarray,
    zi_raw: np.ndarray,
    coefficients: np.ndarray,
    scalars: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """One block: both filters, K_r, the sync sine, the blend and the clip, sample by sample
    (``coefficients, scalars``: `DsaParams.kernel_args`).

    Returns the signals as rows of one array (`SIGNAL_ROWS`: one allocation, one object to
    hand back) and the two filter states as the rows of another.
    """
    b_adv, a_adv, b_raw, a_raw = coefficients[0], coefficients[1], coefficients[2], coefficients[3]
    fs, kr_start, kr_end, kr_t0, kr_duration = (
        scalars[0],
        scalars[1],
        scalars[2],
        scalars[3],
        scalars[4],
    )
    sync_amplitude_v, sync_omega, sync_phase_rad = scalars[5], scalars[6], scalars[7]
    gain, limit_v = scalars[8], scalars[9]
    n = v_in.size
    z = np.empty((2, zi_adv.size))
    z[0], z[1] = zi_adv, zi_raw
    out = np.empty((7, n))
    for i in range(n):
        x = v_in[i]
        if not np.isfinite(x):
            x = 0.0
        torque = lfilter_sample(b_adv, a_adv, z[0], x)
        out[_TORQUE, i] = torque
        out[_TORQUE_RAW, i] = lfilter_sample(b_raw, a_raw, z[1], x)
        t = t_start_s + i / fs
        if kr_duration == 0.0:
            kr = kr_start if t < kr_t0 else kr_end
        else:
            kr = kr_start + (kr_end - kr_start) * min(max((t - kr_t0) / kr_duration, 0.0), 1.0)
        sync = sync_amplitude_v * np.sin(sync_omega * t + sync_phase_rad)
        async_v = torque / gain
        u = kr * sync + (1.0 - kr) * async_v
        out[_KR, i], out[_SYNC, i], out[_ASYNC, i], out[_UNCLIPPED, i] = kr, sync, async_v, u
        out[_DRIVE, i] = 0.0 if np.isnan(u) else min(max(u, -limit_v), limit_v)
    return out, z


def step(state: DsaState, inputs: DsaInputs, params: DsaParams) -> tuple[DsaState, DsaOutputs]:
    """Advance the controller over one block (one compiled kernel, `filter_block`)."""
    v = float_block(inputs.stroke_velocity_rad_s)
    t_start_s = float(inputs.t_start_s)
    if not math.isfinite(t_start_s):
        raise DsaParameterError(f"t_start_s must be finite, got {t_start_s}")
    out, z = filter_block(v, t_start_s, state.zi_advanced, state.zi_raw, *params.kernel_args)
    signals = DsaSignals(
        out[_TORQUE_RAW],
        out[_TORQUE],
        out[_ASYNC],
        out[_SYNC],
        out[_KR],
        out[_UNCLIPPED],
        np.isfinite(v),
    )
    return DsaState(z[0], z[1]), DsaOutputs(out[_DRIVE], signals)


def frequency_response(
    params: DsaParams, frequency_hz: np.ndarray, advanced: bool = True
) -> np.ndarray:
    """Discrete filter response torque/velocity (N m s / rad) at ``frequency_hz``."""
    bz, az = filter_coefficients(params, advanced)
    _, h = signal.freqz(
        bz, az, worN=np.asarray(frequency_hz, dtype=float), fs=params.sample_rate_hz
    )
    return np.asarray(h)


def continuous_response(
    params: DsaParams, frequency_hz: np.ndarray, advanced: bool = True
) -> np.ndarray:
    """Continuous-time H(j w) (times the phase-advance term if ``advanced``)."""
    s = 2j * np.pi * np.asarray(frequency_hz, dtype=float)
    h = -params.c / (s * s + params.a * s + params.b)
    if advanced and params.loop_delay_s > 0:
        wc = params.design_omega_rad_s
        wt = wc * params.loop_delay_s
        h = h * (math.cos(wt) + s * math.sin(wt) / wc)
    return h
