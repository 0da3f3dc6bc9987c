"""Proprioceptive health: per-wingbeat estimates of the robot and its films, and change detection.

One ``step(state, inputs, params) -> (state, outputs)`` takes a block of the two film voltages
and the drive applied to the same samples and returns the wingbeats it closes, each with its
estimates, and the change events the sequential test raises. Live (the health node, block by
block) and offline (`bin/flaair health` on a bag, one call on the whole record) run the same
function and get the same numbers.

Estimator (per wingbeat, between upward crossings of the stroke film's angle, Schmitt trigger
at +-hysteresis_rad, crossing times interpolated): the fundamental (complex amplitude at the
wingbeat's own frequency w) of the drive D, the stroke angle S and the pitch angle P, the
angles read through the model's film gains. The model (shared/model-spec.md), its stroke torques
replaced by their describing function K_eq + j w c(A) (`flaair_sim.core.stroke_dynamic_stiffness`,
from the plant's own kernel: for the nominal plant K and c = c_struct + 8/(3 pi) Gamma w A),
gives with the stroke film's gain a_s, the pitch film's a_p and the wing inertia ratio r
(actuator gain as modelled):

    G_a a_s D / S = K_eq - r I w^2 + j w c(A),   A = |S| / a_s
    a_p = |P| / |H_p(w, r, A) A|

The imaginary part (the power the drive puts in, which the aerodynamic damping takes out) gives
a_s, the real part r, the pitch film's reading against the pitch the hinge makes of that stroke
a_p; H_p, the pitch per radian of stroke, is solved from the kernel's pitch torques
(`flaair_sim.core.pitch_response`; for a linear hinge (J_c w^2 - j w c_d(A)) /
(k_h - r I_p w^2 + j w c_p)). A changed actuator gain g moves both film gains by sqrt(g) and
the product a_s a_p by g: the `actuator_gain` series is that product. A changed stroke
stiffness reads as an inertia change (K / r is what the resonance shows).

Change detection (`change_test`): a CUSUM per watched series (the inertia, the stroke film, the
pitch film's reading against the stroke film's, and each film's zero, `film_zeros`) on pairs of
wingbeats, its threshold derived for a false-alarm rate an hour, and the cause named by the
signature it leaves on the series (a ratio, or an amplifier's offset in degrees), with the
causes the films and the drive cannot tell from it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit

from flaair_model.lfilter import float_block
from flaair_model.notes import WARNING, Note
from flaair_sim.core.describing import pitch_response, stroke_dynamic_stiffness
from flaair_sim.core.plant_params import P_GA, P_I, P_K

from . import change_test

PARAMETERS = ("wing_inertia", "stroke_film_gain", "pitch_film_gain", "actuator_gain")
_ZOH_S = 0.5  # the drive is held over each sample: its effect lags it by half a sample
_HARMONICS = 3  # harmonics fitted beside the fundamental's mean (`fundamentals`)


@dataclass(frozen=True)
class HealthParams:
    """Every setting of the health monitor (config/flaair.yaml `health_node`; units in names).

    The plant is the model's resolved parameter vector (`flaair_sim.core.plant_params.prepare`:
    its nominal values with its effects and discovered terms), read only through the plant's own
    kernel (`stroke_dynamic_stiffness`) and its indices; the film gains are the model's or a
    calibration's; the rest are tunables.
    """

    sample_rate_hz: float
    plant: np.ndarray = field(repr=False, compare=False)  # the model's `prepare` vector
    stroke_volts_per_rad: float
    pitch_volts_per_rad: float
    reference_voltage_v: float
    hysteresis_rad: float
    min_frequency_hz: float
    max_frequency_hz: float
    min_drive_v: float
    min_stroke_rad: float
    average_wingbeats: int
    warmup_wingbeats: int
    baseline_wingbeats: int
    detect_change: float  # the smallest relative change the test accumulates (change_test)
    false_alarms_per_hour: float  # the rate the CUSUM thresholds are derived for
    sigma_floor: float
    confirm_wingbeats: int
    event_significance: float  # an event's shift from 1 must exceed this many of its stderrs
    max_amplitude_change: float
    max_baseline_scatter: float
    stroke_film_delay_s: float  # the films' lag behind the motion (calibration's lag_s)
    pitch_film_delay_s: float
    # a healthy run's baseline of this robot (`change_test.baseline_of`): judged from the start
    baseline: change_test.Baseline | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.sample_rate_hz > 0:
            raise ValueError("health parameter 'sample_rate_hz' must be > 0")
        if not (self.plant[P_I] > 0 and self.plant[P_K] > 0 and self.plant[P_GA] != 0):
            raise ValueError("health parameter 'plant': the model's inertia and stiffness > 0")
        if not 0 < self.min_frequency_hz < self.max_frequency_hz < self.sample_rate_hz / 4:
            raise ValueError(
                "health parameters 'min_frequency_hz' < 'max_frequency_hz' < fs/4 needed"
            )
        for name in ("average_wingbeats", "baseline_wingbeats", "confirm_wingbeats"):
            if getattr(self, name) < 1:
                raise ValueError(f"health parameter '{name}' must be >= 1")
        if self.stroke_volts_per_rad == 0 or self.pitch_volts_per_rad == 0:
            raise ValueError("health parameter 'stroke_volts_per_rad' must be non-zero")
        if not 0 < self.detect_change < 1:
            raise ValueError("health parameter 'detect_change' must be in (0, 1)")
        if not self.false_alarms_per_hour > 0:
            raise ValueError("health parameter 'false_alarms_per_hour' must be > 0")

    @property
    def change(self) -> change_test.ChangeParams:
        """The change test's settings."""
        return change_test.ChangeParams(
            self.warmup_wingbeats,
            self.baseline_wingbeats,
            self.detect_change,
            self.false_alarms_per_hour,
            self.sigma_floor,
            self.confirm_wingbeats,
            self.event_significance,
            self.max_baseline_scatter,
        )


class HealthInputs(NamedTuple):
    """One block: film voltages (V) and the drive (V) applied to the same samples."""

    stroke_sensor_v: np.ndarray
    pitch_sensor_v: np.ndarray
    drive_v: np.ndarray


class HealthState(NamedTuple):
    """Samples since the last crossing, the trigger, recent estimates and the tests' state."""

    sample_index: int
    pending: np.ndarray  # (3, m): stroke rad, pitch rad, drive V since `last_cross`'s sample
    pending_start: int  # sample index of pending[:, 0]
    last_cross: float  # fractional sample index of the last upward crossing (nan: none yet)
    armed: bool  # the stroke went below -hysteresis since the last crossing
    wingbeat: int  # wingbeats closed so far
    recent: np.ndarray  # (average_wingbeats, 4) last raw estimates (nan: none)
    detector: change_test.ChangeState
    quiet: bool  # the last wingbeat (or silence) gave no estimate
    last_amplitudes: np.ndarray  # (2,) |S| rad and |D| V of the last wingbeat (nan: none)
    rate_memory: np.ndarray  # (2,) |S| rad two wingbeats back, the last wingbeat's period s


class Wingbeat(NamedTuple):
    """One closed wingbeat: index, end sample, frequency, estimates and standard errors."""

    wingbeat: int
    sample_index: int
    time_s: float
    frequency_hz: float
    estimate: np.ndarray  # (4,) PARAMETERS, ratio to the model; nan: no estimate
    stderr: np.ndarray  # (4,)
    valid: bool


class HealthEvent(NamedTuple):
    """A detected change: parameter, ratio to the value before (a gain, the inertia) or a film
    zero's move in degrees (an amplifier's offset), its stderr, where and when, and the causes
    the films and the drive cannot tell from it.
    """

    parameter: str
    ratio: float  # nan for an offset
    stderr: float  # of the ratio, or of the offset (deg)
    sample_index: int
    time_s: float
    wingbeat: int
    alternatives: tuple[str, ...] = ()
    offset_deg: float = math.nan  # a film's zero moved by this much (its angle); nan for a ratio


class HealthOutputs(NamedTuple):
    """What one step closed: wingbeats, events and log notes."""

    wingbeats: list[Wingbeat]
    events: list[HealthEvent]
    notes: list[Note]


def initial_state(params: HealthParams) -> HealthState:
    """Nothing seen yet: no crossing, no estimate, baselines to learn."""
    return HealthState(
        0,
        np.zeros((3, 0)),
        0,
        math.nan,
        False,
        0,
        np.full((params.average_wingbeats, 4), np.nan),
        change_test.initial(params.change, baseline=params.baseline),
        False,
        np.full(2, np.nan),
        np.full(2, np.nan),
    )


def fundamentals(x: np.ndarray, theta_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(k,) complex amplitudes C of the fundamental of each row of `x` (k, n), x ~ mean +
    Re(C e^(j theta)), and (k,) the means, by least squares on a mean, the fundamental and its
    next `_HARMONICS - 1` harmonics.

    A wingbeat spans a whole number of samples, not of periods: a plain projection on e^(-j
    theta) leaks the mean and the conjugate into C by about one sample in n (1.5 % at 10 kHz and
    150 Hz), a scatter that changes with the sample rate; the fit has none for any n.
    """
    n = theta_rad.size
    if n < (1 + 2 * _HARMONICS) * 2:  # too few samples for the harmonics: the projection
        basis = np.exp(-1j * theta_rad)
        mean = x.mean(axis=1)
        projected: np.ndarray = (2.0 / n) * ((x - mean[:, None]) @ basis)
        return projected, mean
    coef = _harmonic_fit(np.ascontiguousarray(x, dtype=np.float64), theta_rad, _HARMONICS)
    out: np.ndarray = coef[1] - 1j * coef[1 + _HARMONICS]
    means: np.ndarray = coef[0]
    return out, means


@njit(cache=True)
def _harmonic_fit(x: np.ndarray, theta: np.ndarray, harmonics: int) -> np.ndarray:
    """(1 + 2 harmonics, k) least-squares coefficients of each row of `x` (k, n) on a mean,
    cos(h theta) and sin(h theta), h = 1..harmonics, by the normal equations (the columns are
    near-orthogonal over a wingbeat: their Gram matrix is well conditioned).
    """
    n = theta.size
    m = 1 + 2 * harmonics
    design = np.empty((n, m))
    for i in range(n):
        design[i, 0] = 1.0
        for h in range(harmonics):
            design[i, 1 + h] = math.cos((h + 1) * theta[i])
            design[i, 1 + harmonics + h] = math.sin((h + 1) * theta[i])
    return np.linalg.solve(design.T @ design, design.T @ x.T)


def film_zeros(fund: np.ndarray, means: np.ndarray, params: HealthParams) -> np.ndarray:
    """(2,) each film's zero: the wingbeat's mean angle over its amplitude (the stroke's less
    the static response to the drive's mean, G_a D0 / K), from `fundamentals` of the film angles
    and the drive. A charge amplifier's offset moves it; the gains and the wing's motion do not.
    """
    static = params.plant[P_GA] * means[2] / params.plant[P_K]
    amplitude = np.maximum(np.abs(fund[:2]), 1e-12)
    zeros: np.ndarray = np.array([means[0] - static, means[1]]) / amplitude
    return zeros


def wingbeat_estimate(
    fund: np.ndarray,
    omega_rad_s: float,
    log_rate_per_s: float,
    params: HealthParams,
) -> tuple[np.ndarray | None, np.ndarray]:
    """Raw estimates (PARAMETERS, ratios to the model) of one wingbeat (None if not estimable)
    and the fundamentals' amplitudes (|S| rad, |D| V).

    Parameters
    ----------
    fund
        (3,) complex: the wingbeat's fundamentals (`fundamentals`, phase 0 at its start) of the
        film angles through the model's gains (stroke, pitch) and of the drive.
    omega_rad_s
        The wingbeat's angular frequency.
    log_rate_per_s
        The stroke amplitude's logarithmic rate (its growth per second, from the last wingbeat).
    params
        Model constants and limits.
    """
    w = omega_rad_s
    s, p, d = fund
    s = s * np.exp(1j * w * params.stroke_film_delay_s)  # the motion leads its film reading
    p = p * np.exp(1j * w * params.pitch_film_delay_s)
    d = d * np.exp(-1j * w * _ZOH_S / params.sample_rate_hz)
    amps = np.array([abs(s), abs(d)])
    if abs(d) < params.min_drive_v or abs(s) < params.min_stroke_rad:
        return None, amps
    ratio = d / s
    lam = log_rate_per_s
    plant = params.plant
    g0, inertia = plant[P_GA], plant[P_I]
    q = g0 * ratio.imag  # drive's power in, per unit amplitude
    if q <= 0:
        return None, amps
    # The stroke torques at the fundamental from the plant's kernel, N(A) = K_eq + j w c_eq(A),
    # c_eq taken as c0 + c1 A about the amplitude at hand (exact for viscous and quadratic
    # damping): the drive's power balance is then a quadratic in a_s.
    pitch = p * s.conjugate() / abs(s)  # the pitch against a stroke of phase 0 (model gains)
    k_eq, c0 = _stiffness_damping(plant, w, 0.0, pitch)
    r, a_s = 1.0, 1.0
    for _ in range(3):  # r and a_s are coupled only through the amplitude's rate
        probe = abs(s) / a_s
        k_eq, c_probe = _stiffness_damping(plant, w, probe, pitch)
        c1 = (c_probe - c0) / probe
        big_b = 2.0 * r * inertia * lam * w + w * c0
        b = c1 * w * abs(s)
        a_s = (big_b + math.sqrt(max(big_b * big_b + 4.0 * q * b, 0.0))) / (2.0 * q)
        c_eq = c0 + c1 * abs(s) / a_s
        r = (k_eq + lam * c_eq - g0 * a_s * ratio.real) / (inertia * (w * w - lam * lam))
    if not a_s > 0:
        return None, amps
    amp = abs(s) / a_s
    a_p = abs(p) / (abs(complex(pitch_response(plant, w, amp, lam, r))) * amp)
    return np.array([r, a_s, a_p, a_s * a_p]), amps


def _stiffness_damping(
    plant: np.ndarray, omega: float, amplitude: float, pitch: complex
) -> tuple[float, float]:
    """K_eq (N m/rad) and c_eq (N m s/rad) of the stroke torques at amplitude `amplitude`."""
    n = complex(stroke_dynamic_stiffness(plant, omega, amplitude, pitch))
    return n.real, n.imag / omega


@njit(cache=True)
def _extended(
    pending: np.ndarray,
    vs: np.ndarray,
    vp: np.ndarray,
    dv: np.ndarray,
    reference_v: float,
    stroke_v_per_rad: float,
    pitch_v_per_rad: float,
) -> np.ndarray:
    """`pending` (3, m) followed by the block's film angles (model gains) and drive (non-finite
    drive samples as 0): one kernel, for a block's few samples.
    """
    m = pending.shape[1]
    buf = np.empty((3, m + vs.size))
    buf[:, :m] = pending
    for i in range(vs.size):
        buf[0, m + i] = (vs[i] - reference_v) / stroke_v_per_rad
        buf[1, m + i] = (vp[i] - reference_v) / pitch_v_per_rad
        buf[2, m + i] = dv[i] if np.isfinite(dv[i]) else 0.0
    return buf


def _crossings(
    stroke: np.ndarray, first_new: int, start: int, armed: bool, h: float
) -> tuple[list[float], bool]:
    """Upward crossings (fractional sample indices) of a Schmitt trigger at +-h among the
    samples from `first_new` on (the earlier ones only locate the zero crossing).
    """
    found, armed_after = _crossing_kernel(stroke, first_new, start, armed, h)
    crossings: list[float] = found.tolist()
    return crossings, bool(armed_after)


@njit(cache=True)
def _crossing_kernel(
    stroke: np.ndarray, first_new: int, start: int, armed: bool, h: float
) -> tuple[np.ndarray, bool]:
    """`_crossings` sample by sample (a block's few samples: numpy's per-call cost dominated)."""
    out = np.empty(stroke.size)
    m = 0
    side_before = -1 if armed else 1
    for i in range(first_new, stroke.size):
        x = stroke[i]
        if x < -h:
            side = -1
        elif x > h:
            side = 1
        else:
            continue  # the trigger's state only changes outside the band
        if side == 1 and side_before == -1:
            k = i - 1
            while k > 0 and stroke[k] > 0:
                k -= 1
            a, b = stroke[k], stroke[k + 1]
            frac = -a / (b - a) if b != a and a <= 0 < b else 0.0
            out[m] = float(start + k) + frac  # exact integer first: the same for any block split
            m += 1
        side_before = side
    return out[:m], side_before == -1


def warm_up(params: HealthParams) -> None:
    """Load the monitor's compiled kernels now (a throwaway run over a few synthetic wingbeats),
    not on the first live blocks, which would queue up behind the load.
    """
    fs, f_hz = params.sample_rate_hz, 0.5 * (params.min_frequency_hz + params.max_frequency_hz)
    phase = 2.0 * np.pi * f_hz * np.arange(int(12 * fs / f_hz)) / fs
    stroke_rad = 4.0 * max(params.min_stroke_rad, params.hysteresis_rad) * np.sin(phase)
    films = (
        params.reference_voltage_v + params.stroke_volts_per_rad * stroke_rad,
        params.reference_voltage_v + params.pitch_volts_per_rad * 0.5 * np.cos(phase),
    )
    drive_v = 4.0 * params.min_drive_v * np.sin(phase + 0.3) + params.min_drive_v
    step(initial_state(params), HealthInputs(*films, drive_v), params)


def step(
    state: HealthState, inputs: HealthInputs, params: HealthParams
) -> tuple[HealthState, HealthOutputs]:
    """Advance the monitor over one block; see the module docstring.

    Parameters
    ----------
    state
        From `initial_state` or a previous `step`.
    inputs
        Film voltages and the drive of the same samples (equal lengths).
    params
        Model constants and tunables.

    Returns
    -------
    (HealthState, HealthOutputs)
    """
    # one argument type for the kernels (a read-only CDR view, a strided slice: copied), so
    # none is compiled again in a live node for a layout the set-up's warm-up did not meet
    vs, vp, dv = (float_block(a) for a in inputs)
    if not vs.size == vp.size == dv.size:
        raise ValueError("health inputs 'stroke_sensor_v', 'pitch_sensor_v', 'drive_v' differ")
    fs = params.sample_rate_hz
    buf = _extended(
        state.pending,
        vs,
        vp,
        dv,
        params.reference_voltage_v,
        params.stroke_volts_per_rad,
        params.pitch_volts_per_rad,
    )
    start = state.pending_start
    crossings, armed = _crossings(
        buf[0], state.pending.shape[1], start, state.armed, params.hysteresis_rad
    )
    beats: list[Wingbeat] = []
    events: list[HealthEvent] = []
    notes: list[Note] = []
    last, wb, recent, det, quiet, amps_before, memory = (
        state.last_cross,
        state.wingbeat,
        state.recent,
        state.detector,
        state.quiet,
        state.last_amplitudes,
        state.rate_memory,
    )
    for c in crossings:
        if math.isfinite(last):
            period = (c - last) / fs
            est, amps, zeros, film_amps = _one_wingbeat(
                buf, start, last, c, amps_before, memory, params
            )
            wb += 1
            memory = np.array([amps_before[0], period])
            steady = bool(
                np.all(np.abs(amps - amps_before) <= params.max_amplitude_change * amps_before)
            )
            amps_before = amps
            if est is not None and not steady:  # transient: no quasi-steady estimate
                beats.append(_beat(wb, math.ceil(c), fs, 1.0 / period, None, recent))
            elif est is None:
                if not quiet:
                    notes.append(Note(WARNING, _quiet_text(wb), "health_quiet"))
                quiet = True
                beats.append(_beat(wb, math.ceil(c), fs, 1.0 / period, None, recent))
            else:
                quiet = False
                recent = np.vstack([recent[1:], est[None, :]])
                beats.append(_beat(wb, math.ceil(c), fs, 1.0 / period, est, recent))
                det, found, det_notes = change_test.step(
                    det, est, zeros, 1.0 / period, params.change
                )
                notes.extend(det_notes)
                for ch in found:
                    ev = _event(ch, math.ceil(c), fs, wb, film_amps)
                    events.append(ev)
                    notes.append(Note(WARNING, "health event: " + event_text(ev), ""))
        last = c
    end = state.sample_index + vs.size
    keep_from = math.ceil(last) if math.isfinite(last) else start
    longest = int(fs / params.min_frequency_hz) + 2
    if end - keep_from > longest:  # no wingbeat for longer than the slowest: keep only a tail
        if not quiet:
            notes.append(Note(WARNING, "health: no wingbeat (wing stalled or drive off)", ""))
        quiet, keep_from = True, end - longest
    pending = np.ascontiguousarray(buf[:, keep_from - start :])
    new_state = HealthState(
        end, pending, keep_from, last, armed, wb, recent, det, quiet, amps_before, memory
    )
    return new_state, HealthOutputs(beats, events, notes)


def _one_wingbeat(
    buf: np.ndarray,
    start: int,
    last: float,
    cross: float,
    amps_before: np.ndarray,
    memory: np.ndarray,
    params: HealthParams,
) -> tuple[np.ndarray | None, np.ndarray, np.ndarray, np.ndarray]:
    """The wingbeat between the crossings at fractional sample indices `last` and `cross` (`buf`
    from sample `start`): its estimate (None: none), its stroke and drive amplitudes, the films'
    zeros and amplitudes.
    """
    nan2 = np.full(2, np.nan)
    fs = params.sample_rate_hz
    period = (cross - last) / fs
    i0, i1 = math.ceil(last) - start, math.ceil(cross) - start
    # a wingbeat longer than the slowest has no estimate; its first samples may even be gone
    # with a quiet stretch (i0 < 0: the drive off between runs)
    in_range = 1.0 / params.max_frequency_hz <= period <= 1.0 / params.min_frequency_hz
    if not (in_range and i0 >= 0 and i1 > i0):
        return None, nan2, nan2, nan2
    w = 2.0 * math.pi / period
    theta = w * (math.ceil(last) - last) / fs + w * np.arange(i1 - i0) / fs
    fund, means = fundamentals(buf[:, i0:i1], theta)
    lam = _log_rate(abs(fund[0]), amps_before[0], period, *memory)
    est, amps = wingbeat_estimate(fund, w, lam, params)
    return est, amps, film_zeros(fund, means, params), np.abs(fund[:2])


def _log_rate(
    amp: float, amp_before: float, period: float, amp_two_before: float, period_before: float
) -> float:
    """The stroke amplitude's log rate, from its fundamental's amplitude `amp` over this wingbeat
    (`period` s) and the last one (`period_before`), against the amplitude two wingbeats back;
    against the last wingbeat's alone when there is none (0 without either).

    Over two wingbeats: a one-wingbeat difference carries each amplitude's noise into two
    successive rates with opposite signs, and under the dSA loop it tripled the stroke film
    gain's scatter a wingbeat (2.8 % against 1.5 %).
    """
    if amp > 0 and amp_two_before > 0 and math.isfinite(period_before):
        return math.log(amp / amp_two_before) / (period + period_before)
    if not (math.isfinite(amp_before) and amp_before > 0 and amp > 0):
        return 0.0
    return math.log(amp / amp_before) / period


def _beat(
    wb: int, idx: int, fs: float, f: float, est: np.ndarray | None, recent: np.ndarray
) -> Wingbeat:
    """A Wingbeat record: the mean of the recent estimates and its standard error."""
    if est is None:
        nan = np.full(4, np.nan)
        return Wingbeat(wb, idx, idx / fs, f, nan, nan.copy(), False)
    good = recent[np.isfinite(recent[:, 0])]
    mean = good.mean(axis=0)
    err = (
        good.std(axis=0, ddof=1) / math.sqrt(good.shape[0])
        if good.shape[0] > 1
        else np.full(4, np.nan)
    )
    return Wingbeat(wb, idx, idx / fs, f, mean, err, True)


def no_baseline_text(beats: list[Wingbeat], params: HealthParams) -> str:
    """What a run whose wingbeats `beats` gave no baseline could not judge, and why: a drive
    whose frequency sweeps (a chirp) is outside what the monitor judges.
    """
    f = np.array([b.frequency_hz for b in beats if b.valid])
    if f.size and (f.max() - f.min()) / np.median(f) > 2.0 * params.max_baseline_scatter:
        return (
            f"the drive frequency sweeps ({f.min():.0f}-{f.max():.0f} Hz over its {f.size} "
            "estimated wingbeats): a swept drive (a chirp) is outside what the monitor can "
            "judge (it needs a steady drive); no baseline was learned and no event raised"
        )
    return (
        f"no baseline could be learned from its {f.size} estimated wingbeat(s) (it takes "
        f"{params.warmup_wingbeats} + {params.baseline_wingbeats} steady ones, scattered at most "
        f"{params.max_baseline_scatter:g}): no change could be judged (0 events is no verdict)"
    )


def _quiet_text(wb: int) -> str:
    return f"health: wingbeat {wb} too quiet to estimate (drive off or wing stalled)"


def change_text(
    parameter: str, ratio: float, stderr: float, offset_deg: float, alternatives: Sequence[str]
) -> str:
    """What changed and by how much: "stroke_film_gain x0.950 (+-0.004)", "stroke_amplifier_offset
    +0.52 deg (+-0.01)", with the causes not told apart from it.
    """
    also = f" (or {', '.join(alternatives)}: not told apart)" if alternatives else ""
    if math.isfinite(ratio):
        return f"{parameter} x{ratio:.3f} (+-{stderr:.3f}){also}"
    return f"{parameter} {offset_deg:+.2f} deg (+-{stderr:.2f}){also}"


def event_text(e: HealthEvent) -> str:
    """One event in a line (its log, its diagnostics entry)."""
    what = change_text(e.parameter, e.ratio, e.stderr, e.offset_deg, e.alternatives)
    return f"{what} at {e.time_s:.3f} s, wingbeat {e.wingbeat}"


def _event(
    ch: change_test.Change, idx: int, fs: float, wb: int, film_amps: np.ndarray
) -> HealthEvent:
    """The event of a named change at sample `idx`; an offset in degrees of its film's angle
    (its amplitude `film_amps`, rad).
    """
    if ch.is_ratio:
        return HealthEvent(ch.cause, ch.size, ch.stderr, idx, idx / fs, wb, ch.alternatives)
    amp_deg = math.degrees(film_amps[0 if ch.cause.startswith("stroke") else 1])
    return HealthEvent(
        ch.cause,
        math.nan,
        ch.stderr * amp_deg,
        idx,
        idx / fs,
        wb,
        ch.alternatives,
        ch.size * amp_deg,
    )
