"""The model on a table: each point's steady-state response, through the simulator's own core. Pure.

Every (drive level, frequency) point is one row of a `flaair_sim.core.plant.simulate_batch_from`
call: it starts from the plant's harmonic-balance steady state (the stroke's torques by their
describing function, from the plant's own kernel), so only what that start misses (harmonics,
sensor effects) has to settle,
runs for `settle_s`, and the response is read over the last `measure_wingbeats` whole wingbeats:
peak to peak (max - min, as a video reading gives it) and the fundamental's phase (a least-squares
fit of mean, cosine and sine; the drive's zero-order hold, half a sample, is taken out of the
stroke's phase). Because the same numba RK4 plant runs every point, whatever the
model carries (vocabulary effects, discovered terms on the dynamics or the drive) is in the
response; nothing is linearised. Several models at once (a fit's Jacobian) are one batch too.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba import njit

from flaair_model.model import Model
from flaair_model.settings import TableSettings
from flaair_sim.core.describing import pitch_response, stroke_dynamic_stiffness
from flaair_sim.core.plant import simulate_batch_from
from flaair_sim.core.plant_params import P_GA, P_I, P_K, prepare

__all__ = [
    "MAX_BATCH_ROWS",
    "harmonic_balance_start",
    "point_drives",
    "steady_response",
]

MAX_BATCH_ROWS = 240  # rows per simulate_batch call (bounds the (rows, samples) arrays' memory)
_COUPLING_PROBE_RAD = 0.3  # a pitch per radian of stroke that any pitch term on the stroke feels
# The stroke amplitude's fixed point: damped half-steps from the linear response contract by about
# half an iteration, so secant steps take over after a few, each within a tenth of the amplitude
# (a stop's or a dry friction's kink keeps the damped step); stopped at a relative move of 1e-12.
_HB_ITERATIONS, _HB_DAMPED, _HB_SECANT_REACH, _HB_TOL = 30, 6, 0.1, 1e-12


def point_drives(
    frequency_hz: np.ndarray, amplitude_v: np.ndarray, bias_v: np.ndarray, s: TableSettings
) -> tuple[np.ndarray, np.ndarray]:
    """(P, n) drive of each point (bias + sine from t = 0) and (P,) samples of its window.

    The record is `settle_s` plus the slowest point's measuring window.
    """
    f = np.asarray(frequency_hz, dtype=float)
    fs = s.sample_rate_hz
    window = np.round(s.measure_wingbeats * fs / f).astype(np.int64)
    n = max(math.ceil(s.settle_s * fs), int(window.max())) + int(window.max())
    t = np.arange(n) / fs
    drive = np.asarray(bias_v, dtype=float)[:, None] + np.asarray(amplitude_v, dtype=float)[
        :, None
    ] * np.sin(2.0 * np.pi * f[:, None] * t)
    return drive, window


_DRIVES: dict[tuple[bytes, bytes, bytes, TableSettings], tuple[np.ndarray, np.ndarray]] = {}


def _cached_drives(
    f: np.ndarray, amplitude_v: np.ndarray, bias_v: np.ndarray, s: TableSettings
) -> tuple[np.ndarray, np.ndarray]:
    """`point_drives`, kept for the last few tables (a fit asks for the same table hundreds of
    times; the (P, n) sines were an eighth of its time).
    """
    a, b = np.asarray(amplitude_v, dtype=float), np.asarray(bias_v, dtype=float)
    key = (f.tobytes(), a.tobytes(), b.tobytes(), s)
    if key not in _DRIVES:
        if len(_DRIVES) >= 8:
            _DRIVES.pop(next(iter(_DRIVES)))
        drive, window = point_drives(f, a, b, s)
        drive.flags.writeable = window.flags.writeable = False
        _DRIVES[key] = (drive, window)
    return _DRIVES[key]


def _secant(
    amp: np.ndarray,
    residual: np.ndarray,
    amp_before: np.ndarray,
    residual_before: np.ndarray,
    damped: np.ndarray,
) -> np.ndarray:
    """Each point's secant step towards its residual's zero where it is finite and within
    `_HB_SECANT_REACH` of the amplitude; elsewhere the damped step.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        secant = -residual * (amp - amp_before) / (residual - residual_before)
    ok = np.isfinite(secant) & (np.abs(secant) <= _HB_SECANT_REACH * np.abs(amp))
    return np.where(ok, secant, damped)


def harmonic_balance_start(
    model: Model,
    frequency_hz: np.ndarray,
    amplitude_v: np.ndarray,
    bias_v: np.ndarray,
    fs_hz: float,
) -> np.ndarray:
    """(P, 4) the plant's steady state at t = 0 by harmonic balance (the start of each point).

    The stroke's torques by their describing function at the amplitude (from the plant's own
    kernel, `flaair_sim.core.stroke_dynamic_stiffness`: nominal terms, effects and discovered
    terms alike), solved for the stroke amplitude by fixed-point iteration (damped steps from the
    linear response, then secant steps once near the fixed point, until every amplitude moves by
    less than `_HB_TOL` of itself); the pitch the hinge
    makes of that stroke from the kernel's pitch torques the same way
    (`flaair_sim.core.pitch_response`). What the start misses (harmonics, sensor effects) the
    simulation, which starts here, settles.
    """
    p = prepare(model, fs_hz).params
    w = 2.0 * np.pi * np.asarray(frequency_hz, dtype=float)
    v = np.asarray(amplitude_v, dtype=float)
    inertia, gain, k = p[P_I], p[P_GA], p[P_K]
    amp = gain * v / np.abs(k - inertia * w**2 + 1j * 1e-3 * k)
    pitch_per_stroke = np.zeros_like(w, dtype=complex)
    # The pitch is solved along the stroke's iteration only where the stroke's torques depend on
    # it (a pitch term on the stroke); else once, at the stroke's amplitude (the same start).
    n = stroke_dynamic_stiffness(p, w, amp)
    coupled = np.any(stroke_dynamic_stiffness(p, w, amp, _COUPLING_PROBE_RAD * amp + 0j) != n)
    last: tuple[np.ndarray, np.ndarray] | None = None  # the previous amplitude and its residual
    for i in range(_HB_ITERATIONS):
        if i:
            n = stroke_dynamic_stiffness(p, w, amp, pitch_per_stroke * amp)
        c = np.maximum(n.imag / w, 1e-3 * k / w)
        h = gain / (n.real - inertia * w**2 + 1j * c * w)
        residual = np.abs(h) * v - amp
        step = 0.5 * residual
        if i >= _HB_DAMPED and last is not None:
            step = _secant(amp, residual, *last, step)
        last = amp, residual
        amp = amp + step
        if coupled:
            pitch_per_stroke = pitch_response(p, w, amp, start=pitch_per_stroke)
        if np.all(np.abs(step) <= _HB_TOL * np.abs(amp)):
            break
    if not coupled:
        pitch_per_stroke = pitch_response(p, w, amp)
    # drive v sin(wt) = Re(-i v e^{iwt}), held over each sample: half a sample late
    phi = h * (-1j * v) * np.exp(-0.5j * w / fs_hz)
    psi = pitch_per_stroke * phi
    static = gain * np.asarray(bias_v, dtype=float) / k
    return np.stack([phi.real + static, (1j * w * phi).real, psi.real, (1j * w * psi).real], axis=1)


@njit(cache=True)
def _read_rows(x, window, f, fs, end, pp, phase):  # type: ignore[no-untyped-def]  # numba
    """Peak to peak and fundamental phase (rad, against sin(2 pi f t)) of each row's samples
    [end - window, end): max - min, and least squares of mean, cosine and sine (the cosine and
    sine of each sample by rotation from the window's first, not a call each).
    """
    for r in range(x.shape[0]):
        hi, lo = -np.inf, np.inf
        g = np.zeros((3, 3))
        rhs = np.zeros(3)
        basis = np.empty(3)
        finite = True
        d = 2.0 * np.pi * f[r] / fs
        cd, sd = np.cos(d), np.sin(d)
        k0 = end - window[r]
        c, s = np.cos(d * k0), np.sin(d * k0)
        for k in range(k0, end):
            v = x[r, k]
            finite = finite and np.isfinite(v)
            hi, lo = max(hi, v), min(lo, v)
            basis[0], basis[1], basis[2] = 1.0, c, s
            for i in range(3):
                rhs[i] += basis[i] * v
                for j in range(i, 3):
                    g[i, j] += basis[i] * basis[j]
            c, s = c * cd - s * sd, s * cd + c * sd
        if not (finite and np.isfinite(hi) and np.isfinite(lo)):  # a model that diverged
            pp[r] = phase[r] = np.nan
            continue
        for i in range(3):
            for j in range(i):
                g[i, j] = g[j, i]
        coef = np.linalg.solve(g, rhs)
        pp[r] = hi - lo
        phase[r] = np.arctan2(coef[1], coef[2])


@njit(cache=True)
def _peak_to_peak(x, window, end, pp):  # type: ignore[no-untyped-def]  # numba
    """Max - min of each row's samples [end - window, end) (NaN where any is not finite)."""
    for r in range(x.shape[0]):
        hi, lo = -np.inf, np.inf
        finite = True
        for k in range(end - window[r], end):
            v = x[r, k]
            finite = finite and np.isfinite(v)
            hi, lo = max(hi, v), min(lo, v)
        pp[r] = hi - lo if finite else np.nan


def _read(
    x: np.ndarray, window: np.ndarray, f: np.ndarray, fs: float, end: int
) -> tuple[np.ndarray, np.ndarray]:
    pp, phase = np.empty(x.shape[0]), np.empty(x.shape[0])
    _read_rows(x, window, f, fs, end, pp, phase)
    return pp, phase


def _wrap_deg(x: np.ndarray) -> np.ndarray:
    return (np.asarray(x) + 180.0) % 360.0 - 180.0


def steady_response(
    models: Sequence[Model],
    frequency_hz: np.ndarray,
    amplitude_v: np.ndarray,
    bias_v: np.ndarray,
    s: TableSettings,
) -> dict[str, np.ndarray]:
    """Every model's steady-state response at every point.

    Parameters
    ----------
    models
        M models (each simulated at every point).
    frequency_hz, amplitude_v, bias_v
        (P,) the points: drive frequency, sine amplitude and bias at the actuator.
    s
        The tables' settings (sample rate, ramp, settling time, measuring window).

    Returns
    -------
    dict
        (M, P) arrays: `stroke_pp_deg`, `stroke_amplitude_deg` (half of it), `pitch_pp_deg`,
        `pitch_amplitude_deg`, `stroke_phase_deg` (stroke against the drive, negative = lag),
        `pitch_phase_deg` (pitch against stroke), each wrapped to [-180, 180); `settle_change`
        (the stroke's relative change of peak to peak over the window before: not settled if
        large).
    """
    f = np.asarray(frequency_hz, dtype=float)
    drive, window = _cached_drives(f, amplitude_v, bias_v, s)
    m, p = len(models), f.size
    rows = [(i, j) for i in range(m) for j in range(p)]
    a, b = np.asarray(amplitude_v, dtype=float), np.asarray(bias_v, dtype=float)
    starts = [harmonic_balance_start(model, f, a, b, s.sample_rate_hz) for model in models]
    keys = ("pp_s", "ph_s", "pp_p", "ph_p", "pp_s_before")
    out = {key: np.empty(m * p) for key in keys}
    fs = s.sample_rate_hz
    for start in range(0, len(rows), MAX_BATCH_ROWS):
        chunk = rows[start : start + MAX_BATCH_ROWS]
        pts = np.array([j for _, j in chunk])
        x0 = np.array([starts[i][j] for i, j in chunk])
        sim = simulate_batch_from(drive[pts], fs, [models[i] for i, _ in chunk], x0)
        sl = slice(start, start + len(chunk))
        n, w = drive.shape[1], window[pts]
        out["pp_s"][sl], out["ph_s"][sl] = _read(sim.stroke_rad, w, f[pts], fs, n)
        out["pp_p"][sl], out["ph_p"][sl] = _read(sim.pitch_rad, w, f[pts], fs, n)
        before = np.empty(len(chunk))
        _peak_to_peak(sim.stroke_rad, w, n - int(window.max()), before)
        out["pp_s_before"][sl] = before
    shaped = {k: v.reshape(m, p) for k, v in out.items()}
    stroke_pp = np.degrees(shaped["pp_s"])
    pitch_pp = np.degrees(shaped["pp_p"])
    return {
        "stroke_pp_deg": stroke_pp,
        "stroke_amplitude_deg": stroke_pp / 2.0,
        "pitch_pp_deg": pitch_pp,
        "pitch_amplitude_deg": pitch_pp / 2.0,
        # the plant holds each drive sample over its period: a half-sample lag not in the lab's
        "stroke_phase_deg": _wrap_deg(np.degrees(shaped["ph_s"] + np.pi * f / fs)),
        "pitch_phase_deg": _wrap_deg(np.degrees(shaped["ph_p"] - shaped["ph_s"])),
        "settle_change": np.abs(shaped["pp_s"] - shaped["pp_s_before"])
        / np.maximum(shaped["pp_s"], 1e-12),
    }
