r"""Closed-loop stroke-amplitude controller core (paper Fig. 1c, "closed-loop stroke control").

Pure numpy/scipy/numba; explicit state; ``step(state, inputs, params) -> (state, outputs)``.

What it holds
-------------
The per-wingbeat stroke amplitude A = (max - min) / 2 of the *estimated* stroke angle (the
proprioceptive actuator's front end), at ``setpoint_deg``. A wingbeat ends at an upward
Schmitt-trigger crossing of the stroke (hysteresis ``crossing_hysteresis_deg``); if none comes
for 1 / ``min_wingbeat_hz`` (the wing barely moves) that window counts as a wingbeat too, so
a stalled wing is still pushed up.

What it moves (the command u)
-----------------------------
* ``mode = "sync"``: the drive amplitude (V) of a sine at the fixed ``sync_frequency_hz``.
* ``mode = "dsa"``: the dSA loop gain mu (N m s / rad). The dSA filter of
  ``flaair_control.core.dsa`` runs at a fixed reference gain mu_ref (``dsa_params``); its output is
  scaled by u / mu_ref, which is the filter with gain u (c = mu kappa r3^2 is linear in mu).
  The frequency stays free: it emerges from the loop.

Control law (integral action on the log amplitude)
--------------------------------------------------
Once per wingbeat k, with the measured amplitude A_k::

    z_{k+1} = clip(z_k + g * clip(ln(A_sp / A_k), -ln 2, ln 2), ln(u_min/u_ff), ln(u_max/u_ff))
    u       = u_ff * exp(z),       g = lambda / epsilon

u_ff is the feed-forward command that the plant's amplitude response puts at the setpoint, and
epsilon = d ln A / d ln u is the slope of that response at the setpoint (``design``). If the plant
answered at once, the loop would remove the fraction lambda (``error_fraction_per_wingbeat``) of
the log error per wingbeat; the wing's amplitude envelope lags by its own time constant, so
lambda is chosen below 1. Working on logs makes the gain scale-free: the loop gain is the same
for a 5 deg and a 25 deg setpoint and for any wing whose response has the same slope, and a
wing that lost inertia is absorbed into z (the learned correction), not into the gain.
Anti-windup: z is clipped to the command limits. A new setpoint moves u_ff at once (``retarget``),
z is kept.

Design from the plant's amplitude response (``design``; nominal plant, config/model.yaml)
-----------------------------------------------------------------------------------------
The plant's stroke torques come from the model's kernel by their describing function
N(w, A) = K_eq + j w c_eq (``StrokePlant.dynamic_stiffness``): an effect or a discovered term in
the model reaches the design. For the nominal plant N = K + j w (8 / (3 pi)) Gamma w A.

* Synchronous, at 140 Hz (the stroke resonance): first-harmonic balance,
  A |N(w, A) - I w^2| = G_a V. On resonance V ~ A^2, so
  epsilon = 0.500 (0.5-1 off resonance): 15 deg needs u_ff = 10.78 V, 20 deg 19.17 V; the RK4
  plant driven open loop at 10.78 V flaps at 15 deg within 2 % (tests/test_control_stroke.py).
* dSA (r3 = 180 rad/s, kappa = 0.5; the Hopf onset of the plant linearised at A, as
  ``flaair_control.core.hopf.limit_cycle``): sqrt(kappa) r3 lies
  below the resonance, so the onset is mu* = 0 and the amplitude grows with mu: 15 deg needs
  mu_ff = 4.27e-7 N m s/rad, 20 deg 5.81e-7; epsilon = 0.94 at 15 deg, 0.92 at 20 deg.
* lambda = 0.35 per wingbeat (config/flaair.yaml). The resonant wing's amplitude envelope has
  the time constant 2 I / c_eq = 2.3 wingbeats at 15 deg (c_eq = 8/(3 pi) Gamma w A), so the
  integrator is kept well below deadbeat. Measured on the simulated robot from the bags
  (bench/bench_stroke.py): setpoint step 15 -> 20 deg settles to 0.5 deg in 10 wingbeats (dSA,
  2.4 deg overshoot) and 7 (sync); 30 % inertia loss in 14 / 11; an obstacle at 13 deg in
  16 / 19; steady error < 0.01 deg in all six.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np
from numba import njit

from flaair_control.core import dsa, hopf
from flaair_model.model import Model
from flaair_model.schema import ParamSpec
from flaair_sim.core.describing import pitch_response, stroke_dynamic_stiffness
from flaair_sim.core.plant_params import P_GA, P_I, P_K, coefficients

__all__ = [
    "MODES",
    "NODE_PARAMS",
    "StrokeInputs",
    "StrokeOutputs",
    "StrokeParameterError",
    "StrokeParams",
    "StrokePlant",
    "StrokeSignals",
    "StrokeState",
    "command",
    "design",
    "dsa_gain_for_amplitude",
    "initial_state",
    "last_amplitude_deg",
    "params_from_values",
    "retarget",
    "step",
    "sync_drive_for_amplitude",
    "track_sample",
    "tracker_constants",
    "tracker_initial_state",
    "wingbeats",
]


MODES = ("sync", "dsa")
# The dSA limit cycle's fixed point of onset frequency and describing function (`design`).
_ONSET_ITERATIONS, _ONSET_RTOL = 50, 1e-12

# tracker state layout (float64 vector, updated in place by the numba kernel)
_HIGH, _MAX, _MIN, _SINCE, _Z, _AMP, _BEATS, _PERIOD, _NSTATE = range(9)
# tracker constants layout
_HYST, _MIN_PERIOD, _MAX_PERIOD, _GAIN, _LNCLIP, _ZMIN, _ZMAX, _SETPOINT, _NCONST = range(9)


class StrokeParameterError(ValueError):
    """A stroke-controller parameter or input is invalid; the message names it."""


@dataclass(frozen=True)
class StrokeParams:
    """Stroke-amplitude controller parameters (SI inside; units in names).

    ``command_*`` are volts of drive amplitude in sync mode and N m s / rad of mu in dsa mode.
    ``dsa_params`` (dsa mode) is the dSA filter at a reference gain mu_ref, with its
    K_r schedule (a synchronous kick that starts the wing, then asynchronous).
    """

    mode: str
    setpoint_deg: float
    sample_rate_hz: float
    command_nominal: float
    command_min: float
    command_max: float
    elasticity: float
    error_fraction_per_wingbeat: float
    crossing_hysteresis_deg: float
    min_wingbeat_hz: float
    max_wingbeat_hz: float
    sync_frequency_hz: float
    dsa_params: dsa.DsaParams | None = None

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise StrokeParameterError(f"mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        for name in (
            "setpoint_deg",
            "sample_rate_hz",
            "command_nominal",
            "elasticity",
            "min_wingbeat_hz",
            "max_wingbeat_hz",
            "sync_frequency_hz",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise StrokeParameterError(f"{name} must be finite and > 0, got {v}")
        if not (0 < self.command_min <= self.command_nominal <= self.command_max < math.inf):
            raise StrokeParameterError(
                f"need 0 < command_min <= command_nominal <= command_max, got {self.command_min}, "
                f"{self.command_nominal}, {self.command_max}"
            )
        if not (0 < self.error_fraction_per_wingbeat <= 1):
            raise StrokeParameterError(
                "error_fraction_per_wingbeat must be in (0, 1], got "
                f"{self.error_fraction_per_wingbeat}"
            )
        if not (math.isfinite(self.crossing_hysteresis_deg) and self.crossing_hysteresis_deg >= 0):
            raise StrokeParameterError(
                f"crossing_hysteresis_deg must be >= 0, got {self.crossing_hysteresis_deg}"
            )
        if not self.min_wingbeat_hz < self.max_wingbeat_hz:
            raise StrokeParameterError("min_wingbeat_hz must be below max_wingbeat_hz")
        if self.mode == "dsa":
            if self.dsa_params is None:
                raise StrokeParameterError(
                    "dsa mode needs dsa_params (the dSA filter at a reference gain mu_ref)"
                )
            if self.dsa_params.sample_rate_hz != self.sample_rate_hz:
                raise StrokeParameterError("dsa_params.sample_rate_hz differs from sample_rate_hz")

    @property
    def gain(self) -> float:
        """Integral gain g = lambda / epsilon on ln(A_sp / A) per wingbeat."""
        return self.error_fraction_per_wingbeat / self.elasticity


def tracker_constants(params: StrokeParams) -> np.ndarray:
    """Constant vector of the numba wingbeat tracker (also used by batch kernels)."""
    c = np.empty(_NCONST)
    c[_HYST] = math.radians(params.crossing_hysteresis_deg)
    c[_MIN_PERIOD] = params.sample_rate_hz / params.max_wingbeat_hz
    c[_MAX_PERIOD] = params.sample_rate_hz / params.min_wingbeat_hz
    c[_GAIN] = params.gain
    c[_LNCLIP] = math.log(2.0)
    c[_ZMIN] = math.log(params.command_min / params.command_nominal)
    c[_ZMAX] = math.log(params.command_max / params.command_nominal)
    c[_SETPOINT] = math.radians(params.setpoint_deg)
    return c


def tracker_initial_state() -> np.ndarray:
    """Tracker at rest: z = 0 (u = u_ff), no wingbeat seen."""
    s = np.zeros(_NSTATE)
    s[_MAX], s[_MIN] = -np.inf, np.inf
    s[_AMP] = np.nan
    return s


@njit(cache=True)
def track_sample(stroke_rad: float, valid: bool, s: np.ndarray, c: np.ndarray) -> bool:
    """Advance the wingbeat tracker by one sample (state ``s`` in place); True at a wingbeat end.

    At a wingbeat end the amplitude is in s[_AMP] and the integrator s[_Z] has been updated.
    Invalid samples are skipped (they neither extend the extremes nor trigger a crossing).
    """
    s[_SINCE] += 1.0
    end = False
    if valid:
        if stroke_rad > s[_MAX]:
            s[_MAX] = stroke_rad
        if stroke_rad < s[_MIN]:
            s[_MIN] = stroke_rad
        if s[_HIGH] == 0.0:
            if stroke_rad > c[_HYST]:
                s[_HIGH] = 1.0
                end = s[_SINCE] >= c[_MIN_PERIOD]
        elif stroke_rad < -c[_HYST]:
            s[_HIGH] = 0.0
    if not end and s[_SINCE] >= c[_MAX_PERIOD]:
        end = True
    if end:
        amp = 0.5 * (s[_MAX] - s[_MIN]) if s[_MAX] >= s[_MIN] else 0.0
        s[_AMP] = amp
        s[_PERIOD] = s[_SINCE]
        s[_BEATS] += 1.0
        ratio = math.log(c[_SETPOINT] / amp) if amp > 0.0 else c[_LNCLIP]
        ratio = min(max(ratio, -c[_LNCLIP]), c[_LNCLIP])
        s[_Z] = min(max(s[_Z] + c[_GAIN] * ratio, c[_ZMIN]), c[_ZMAX])
        s[_SINCE] = 0.0
        s[_MAX] = stroke_rad if valid else -np.inf
        s[_MIN] = stroke_rad if valid else np.inf
    return end


@njit(cache=True)
def _track_block(
    stroke_rad: np.ndarray,
    valid: np.ndarray,
    s: np.ndarray,
    c: np.ndarray,
    z_out: np.ndarray,
    amp_out: np.ndarray,
) -> None:
    """Tracker over a block; per-sample z (after the sample)
    and the amplitude at wingbeat ends (else NaN).
    """
    for k in range(stroke_rad.shape[0]):
        x = stroke_rad[k]
        ok = valid[k] and x == x
        if track_sample(x, ok, s, c):
            amp_out[k] = s[_AMP]
        else:
            amp_out[k] = np.nan
        z_out[k] = s[_Z]


class StrokeState(NamedTuple):
    """Tracker vector (see ``tracker_initial_state``) and the dSA filter state (dsa mode)."""

    tracker: np.ndarray
    dsa_state: dsa.DsaState


class StrokeSignals(NamedTuple):
    """Internal signals of one block."""

    command: np.ndarray  # u per drive sample (V or N m s/rad)
    wingbeat_amplitude_deg: np.ndarray  # amplitude at the sample a wingbeat ended, NaN elsewhere
    drive_unclipped_v: np.ndarray  # drive before the safety chain


def initial_state(params: StrokeParams) -> StrokeState:
    """Controller at rest."""
    dsa_state = (
        dsa.initial_state(params.dsa_params)
        if params.dsa_params is not None
        else dsa.DsaState(np.zeros(2), np.zeros(2))
    )
    return StrokeState(tracker_initial_state(), dsa_state)


def command(state: StrokeState, params: StrokeParams) -> float:
    """Current command u = u_ff exp(z)."""
    return params.command_nominal * math.exp(state.tracker[_Z])


def last_amplitude_deg(state: StrokeState) -> float:
    """Amplitude of the last completed wingbeat (NaN before the first)."""
    return math.degrees(state.tracker[_AMP])


def wingbeats(state: StrokeState) -> int:
    """Wingbeats completed so far."""
    return int(state.tracker[_BEATS])


class StrokeInputs(NamedTuple):
    """One wing-state block of the front end's estimate,
    and where the drive block it produces starts.

    stroke_rad, stroke_velocity_rad_s, valid: the estimate (NaN / invalid samples are skipped
    by the tracker and drive the dSA filter as 0). first_drive_index: stream index of the
    first sample of the returned drive block (the sine phase and the K_r schedule are
    evaluated at index / fs).
    """

    stroke_rad: np.ndarray
    stroke_velocity_rad_s: np.ndarray
    valid: np.ndarray
    first_drive_index: int


class StrokeOutputs(NamedTuple):
    """The next drive block (before the safety chain) and the internal signals."""

    drive_v: np.ndarray
    signals: StrokeSignals


def step(
    state: StrokeState, inputs: StrokeInputs, params: StrokeParams
) -> tuple[StrokeState, StrokeOutputs]:
    """Advance over one wing-state block; return the next drive block (before the safety chain)."""
    stroke_rad, stroke_velocity_rad_s, valid, first_drive_index = inputs
    x = np.ascontiguousarray(stroke_rad, dtype=float).ravel()
    ok = np.ascontiguousarray(valid, dtype=np.bool_).ravel()
    if ok.shape != x.shape:
        raise StrokeParameterError(f"valid has {ok.size} samples, stroke_rad {x.size}")
    tracker = state.tracker.copy()
    z, amp = np.empty(x.size), np.empty(x.size)
    _track_block(x, ok, tracker, tracker_constants(params), z, amp)
    # the drive block is applied after this block: it uses the command reached at its end
    u = np.full(x.size, params.command_nominal * math.exp(tracker[_Z]))
    t = (first_drive_index + np.arange(x.size)) / params.sample_rate_hz
    dsa_state = state.dsa_state
    if params.mode == "sync":
        drive = u * np.sin(2.0 * np.pi * params.sync_frequency_hz * t)
    else:
        assert params.dsa_params is not None  # StrokeParams requires it for mode 'dsa'
        v = np.where(ok, np.asarray(stroke_velocity_rad_s, dtype=float).ravel(), np.nan)
        dsa_state, dsa_out = dsa.step(
            dsa_state, dsa.DsaInputs(v, t[0] if x.size else 0.0), params.dsa_params
        )
        sig = dsa_out.signals
        drive = (
            sig.kr * sig.sync_v
            + (1.0 - sig.kr) * (u / params.dsa_params.mu_nm_s_per_rad) * sig.async_v
        )
    return StrokeState(tracker, dsa_state), StrokeOutputs(
        drive, StrokeSignals(u, np.degrees(amp), drive)
    )


def retarget(
    params: StrokeParams, setpoint_deg: float, command_nominal: float, elasticity: float
) -> StrokeParams:
    """Parameters for a new setpoint at run time (u_ff and epsilon from ``design``).

    Keep the state: z, the learned correction u / u_ff, carries over, so u jumps by the ratio
    of the feed-forwards and the integrator only removes what the model got wrong.
    """
    command_nominal = min(max(command_nominal, params.command_min), params.command_max)
    return replace(
        params, setpoint_deg=setpoint_deg, command_nominal=command_nominal, elasticity=elasticity
    )


# --------------------------------------------------------------------------- design


@dataclass(frozen=True, eq=False)
class StrokePlant:
    """The plant as the design reads it: a model's resolved kernel parameters
    (`flaair_sim.core.plant_params.coefficients`). The stroke's torques at a wingbeat come from
    the kernel by their describing function (`flaair_sim.core.describing`), with the pitch the
    hinge makes of the stroke: a force the kernel computes (an effect, a discovered term)
    reaches the design with nothing written here.
    """

    params: np.ndarray

    @classmethod
    def from_model(cls, model: Model) -> StrokePlant:
        """From a flaair_model Model, as the plant resolves it (a damaged wing's inertia too)."""
        return cls(coefficients(model))

    @property
    def inertia_kg_m2(self) -> float:
        """The stroke inertia I."""
        return float(self.params[P_I])

    @property
    def stiffness_nm_per_rad(self) -> float:
        """The stroke stiffness K (the linear part)."""
        return float(self.params[P_K])

    @property
    def actuator_gain_nm_per_v(self) -> float:
        """The actuator gain G_a."""
        return float(self.params[P_GA])

    def dynamic_stiffness(self, omega_rad_s: float, amplitude_rad: float) -> complex:
        """N = K_eq + j w c_eq (N m/rad): the stroke torques but the drive's and the inertia's at
        phi = A cos(w t), per radian, with the pitch the hinge makes of that stroke.
        """
        pitch = complex(pitch_response(self.params, omega_rad_s, amplitude_rad)) * amplitude_rad
        return complex(stroke_dynamic_stiffness(self.params, omega_rad_s, amplitude_rad, pitch))


def sync_drive_for_amplitude(
    plant: StrokePlant, amplitude_deg: float, frequency_hz: float
) -> float:
    """Drive amplitude (V) for stroke amplitude ``amplitude_deg`` at ``frequency_hz`` (first
    harmonic): A |N(w, A) - I w^2| / G_a.
    """
    a = math.radians(amplitude_deg)
    w = 2.0 * math.pi * frequency_hz
    n = plant.dynamic_stiffness(w, a)
    return a * abs(n - plant.inertia_kg_m2 * w * w) / plant.actuator_gain_nm_per_v


def dsa_gain_for_amplitude(
    plant: StrokePlant, amplitude_deg: float, r3_rad_s: float, kappa: float
) -> float:
    """Mu (N m s/rad) whose dSA limit cycle has ``amplitude_deg``.

    First-harmonic balance, as ``hopf.limit_cycle`` with the plant's own torques: at the
    amplitude A the plant is the linear one with K_eq and c_eq of N(w, A)
    (`StrokePlant.dynamic_stiffness`), and the limit cycle is that plant's Hopf onset. The
    onset's frequency w and N(w, A) are solved together by fixed-point iteration (the onset
    frequency is set mostly by the filter: a few steps).
    """
    a = math.radians(amplitude_deg)
    i = plant.inertia_kg_m2
    onset = hopf.hopf_onset(hopf.LinearStrokePlant(i, plant.stiffness_nm_per_rad), r3_rad_s, kappa)
    for _ in range(_ONSET_ITERATIONS):
        w = onset.omega_rad_s
        n = plant.dynamic_stiffness(w, a)
        if not (n.real > 0 and n.imag >= 0):
            raise StrokeParameterError(f"no dSA gain gives {amplitude_deg} deg")
        onset = hopf.hopf_onset(hopf.LinearStrokePlant(i, n.real, n.imag / w), r3_rad_s, kappa)
        if abs(onset.omega_rad_s - w) <= _ONSET_RTOL * w:
            return onset.mu_nm_s_per_rad
    raise StrokeParameterError(f"the dSA limit cycle at {amplitude_deg} deg did not converge")


def design(
    plant: StrokePlant,
    mode: str,
    setpoint_deg: float,
    *,
    sync_frequency_hz: float = 0.0,
    r3_rad_s: float = 0.0,
    kappa: float = 0.0,
) -> tuple[float, float]:
    """Feed-forward command u_ff and response slope epsilon = d ln A / d ln u at the setpoint.

    sync: from ``sync_drive_for_amplitude`` at ``sync_frequency_hz``; dsa: from
    ``dsa_gain_for_amplitude`` with the filter (r3, kappa). Slope by central differences of
    the inverse response at A (1 +- 1 %).
    """
    if not (math.isfinite(setpoint_deg) and setpoint_deg > 0):
        raise StrokeParameterError(f"setpoint_deg must be finite and > 0, got {setpoint_deg}")
    if mode == "sync":

        def inverse(a: float) -> float:
            return sync_drive_for_amplitude(plant, a, sync_frequency_hz)
    elif mode == "dsa":

        def inverse(a: float) -> float:
            return dsa_gain_for_amplitude(plant, a, r3_rad_s, kappa)
    else:
        raise StrokeParameterError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    u = inverse(setpoint_deg)
    h = 0.01
    slope_inverse = (
        math.log(inverse(setpoint_deg * (1 + h))) - math.log(inverse(setpoint_deg * (1 - h)))
    ) / (math.log1p(h) - math.log1p(-h))
    return u, 1.0 / slope_inverse


def params_from_values(
    values: Mapping[str, Any], plant: StrokePlant, sample_rate_hz: float, loop_delay_s: float
) -> StrokeParams:
    """StrokeParams from the ``stroke_controller_node``
    section of config/flaair.yaml (pure mapping).

    ``loop_delay_s`` is what the dSA phase advance compensates (block transport, ZOH, the front
    end's velocity delay); u_ff and epsilon come from ``design`` at ``setpoint_deg``.
    """
    mode = values["mode"]
    if mode not in MODES:
        raise StrokeParameterError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    u_ff, epsilon = design(
        plant,
        mode,
        values["setpoint_deg"],
        sync_frequency_hz=values["sync_frequency_hz"],
        r3_rad_s=values["r3_rad_s"],
        kappa=values["kappa"],
    )
    dsa_params = None
    if mode == "dsa":
        kick = dsa.KrSchedule(1.0, 0.0, values["kick_s"], values["kick_ramp_s"])
        dsa_params = dsa.dsa_params(
            {
                **values,
                "mu_nm_s_per_rad": u_ff,
                "sync_amplitude_v": values["kick_amplitude_v"],
                "sync_phase_rad": 0.0,
            },
            actuator_gain_nm_per_v=plant.actuator_gain_nm_per_v,
            sample_rate_hz=sample_rate_hz,
            loop_delay_s=loop_delay_s,
            kr_schedule=kick,
        )
        low, high = values["mu_min_nm_s_per_rad"], values["mu_max_nm_s_per_rad"]
    else:
        low, high = values["drive_amplitude_min_v"], values["drive_amplitude_max_v"]
    return StrokeParams(
        mode=mode,
        setpoint_deg=values["setpoint_deg"],
        sample_rate_hz=sample_rate_hz,
        command_nominal=min(max(u_ff, low), high),
        command_min=low,
        command_max=high,
        elasticity=epsilon,
        error_fraction_per_wingbeat=values["error_fraction_per_wingbeat"],
        crossing_hysteresis_deg=values["crossing_hysteresis_deg"],
        min_wingbeat_hz=values["min_wingbeat_hz"],
        max_wingbeat_hz=values["max_wingbeat_hz"],
        sync_frequency_hz=values["sync_frequency_hz"],
        dsa_params=dsa_params,
    )


# The stroke_controller_node parameters (values:
# config/flaair.yaml); `params_from_values` maps them.
_F, _I, _S, _B = float, int, str, bool
NODE_PARAMS = [
    ParamSpec(name, kind, text, *rng, read_only=name not in ("setpoint_deg",))  # type: ignore[misc]
    for name, kind, text, *rng in (  # rng: (min, max[, choices]) or none
        ("sample_rate_hz", _F, "Sample rate of every block stream [Hz]", 1000.0, 1.0e6),
        ("block_size", _I, "Samples per block", 1, 100000),
        ("drive_limit_v", _F, "Drive clamp [V]", 0.0, 300.0),
        ("model_file", _S, "Model YAML for the design (empty: config/model.yaml)"),
        ("mode", _S, "sync (drive amplitude) | dsa (loop gain mu)", None, None, MODES),
        ("setpoint_deg", _F, "Stroke amplitude to hold; settable while running [deg]", 0.1, 80.0),
        ("sync_frequency_hz", _F, "sync: drive frequency; dsa: kick frequency [Hz]", 1.0, 5000.0),
        ("error_fraction_per_wingbeat", _F, "lambda: log error removed per wingbeat", 0.01, 1.0),
        ("crossing_hysteresis_deg", _F, "Wingbeat detector hysteresis [deg]", 0.0, 20.0),
        ("min_wingbeat_hz", _F, "Longest wingbeat [Hz]", 1.0, 1000.0),
        ("max_wingbeat_hz", _F, "Shortest wingbeat [Hz]", 2.0, 5000.0),
        ("drive_amplitude_min_v", _F, "sync: command floor [V]", 0.0, 300.0),
        ("drive_amplitude_max_v", _F, "sync: command ceiling [V]", 0.0, 300.0),
        ("mu_min_nm_s_per_rad", _F, "dsa: command floor [N m s/rad]", 0.0, 1.0),
        ("mu_max_nm_s_per_rad", _F, "dsa: command ceiling", 0.0, 1.0),
        ("r3_rad_s", _F, "dSA r3 [rad/s]", 1e-3, 1e6),
        ("kappa", _F, "dSA kappa", 1e-6, 1e3),
        ("kick_amplitude_v", _F, "dsa: start kick amplitude [V]", 0.0, 300.0),
        ("kick_s", _F, "dsa: kick length [s]", 0.0, 10.0),
        ("kick_ramp_s", _F, "dsa: kick hand-over [s]", 0.0, 10.0),
        ("compensate_delay", _B, "dSA phase advance for the loop delay"),
        ("compensation_frequency_hz", _F, "Delay cancelled exactly here [Hz]", 1.0, 5000.0),
        ("velocity_delay_s", _F, "Front-end velocity delay (< 0: from its config) [s]", -1.0, 0.1),
        ("blocks_in_flight", _I, "Command blocks in the loop", 1, 100),
        ("slew_limit_v_per_s", _F, "Slew limit [V/s]", 1.0, 1e9),
        ("watchdog_timeout_s", _F, "Wall-clock silence to trip [s]", 1e-3, 100.0),
        ("invalid_timeout_s", _F, "Signal time without a valid block to trip [s]", 1e-4, 10.0),
        ("ramp_down_s", _F, "Drive ramp to zero after a trip [s]", 0.0, 10.0),
        ("start_delay_s", _F, "Wait after the peers appear [s]", 0.0, 60.0),
        ("start_retry_s", _F, "Resend a start block after [s]", 0.1, 60.0),
        ("run_time_s", _F, "Stop after this much signal time (0: never) [s]", 0.0, 1e6),
    )
]
