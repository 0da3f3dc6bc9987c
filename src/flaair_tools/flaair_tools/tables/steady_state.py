"""The model on a table: each point's steady-state response, through the simulator's own core. Pure.

Every (drive level, frequency) point is one row of a `flaair_sim.core.plant.simulate_batch` call:
the sine fades in over `ramp_wingbeats` (a raised cosine, so the start transient is small), runs
for `settle_s`, and the response is read over the last `measure_wingbeats` whole wingbeats:
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

from flaair_model.model import Model
from flaair_model.settings import TableSettings
from flaair_sim.core.plant import simulate_batch

__all__ = ["MAX_BATCH_ROWS", "point_drives", "steady_response", "unsettled_fraction"]

MAX_BATCH_ROWS = 240  # rows per simulate_batch call (bounds the (rows, samples) arrays' memory)


def point_drives(
    frequency_hz: np.ndarray, amplitude_v: np.ndarray, bias_v: np.ndarray, s: TableSettings
) -> tuple[np.ndarray, np.ndarray]:
    """(P, n) drive of each point and (P,) samples of its measuring window.

    The record is `settle_s` plus the slowest point's measuring window; each sine (and its bias)
    fades in over `ramp_wingbeats` of its own period.
    """
    f = np.asarray(frequency_hz, dtype=float)
    fs = s.sample_rate_hz
    window = np.round(s.measure_wingbeats * fs / f).astype(np.int64)
    n = math.ceil(s.settle_s * fs) + int(window.max())
    t = np.arange(n) / fs
    ramp_s = s.ramp_wingbeats / f[:, None]
    env = np.where(t < ramp_s, 0.5 - 0.5 * np.cos(np.pi * np.minimum(t / ramp_s, 1.0)), 1.0)
    drive = env * (
        np.asarray(bias_v, dtype=float)[:, None]
        + np.asarray(amplitude_v, dtype=float)[:, None] * np.sin(2.0 * np.pi * f[:, None] * t)
    )
    return drive, window


def _read(
    x: np.ndarray, window: np.ndarray, f: np.ndarray, fs: float, tail: int
) -> tuple[np.ndarray, np.ndarray]:
    """Peak to peak and fundamental phase (rad, against sin(2 pi f t)) over each row's window."""
    n = x.shape[1]
    seg = x[:, n - tail :]
    k = np.arange(n - tail, n)
    inside = k[None, :] >= (n - window)[:, None]
    pp = np.where(inside, seg, -np.inf).max(axis=1) - np.where(inside, seg, np.inf).min(axis=1)
    wt = 2.0 * np.pi * f[:, None] * (k[None, :] / fs)
    basis = np.stack([np.ones_like(wt), np.cos(wt), np.sin(wt)], axis=-1) * inside[..., None]
    gram = np.einsum("pki,pkj->pij", basis, basis)
    rhs = np.einsum("pki,pk->pi", basis, np.where(inside, seg, 0.0))
    coef = np.linalg.solve(gram, rhs[..., None])[..., 0]
    return pp, np.arctan2(coef[:, 1], coef[:, 2])


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
    drive, window = point_drives(f, amplitude_v, bias_v, s)
    m, p = len(models), f.size
    tail = 2 * int(window.max())
    rows = [(i, j) for i in range(m) for j in range(p)]
    keys = ("pp_s", "ph_s", "pp_p", "ph_p", "pp_s_before")
    out = {key: np.empty(m * p) for key in keys}
    fs = s.sample_rate_hz
    for start in range(0, len(rows), MAX_BATCH_ROWS):
        chunk = rows[start : start + MAX_BATCH_ROWS]
        pts = np.array([j for _, j in chunk])
        sim = simulate_batch(drive[pts], fs, [models[i] for i, _ in chunk])
        sl = slice(start, start + len(chunk))
        out["pp_s"][sl], out["ph_s"][sl] = _read(sim.stroke_rad, window[pts], f[pts], fs, tail)
        out["pp_p"][sl], out["ph_p"][sl] = _read(sim.pitch_rad, window[pts], f[pts], fs, tail)
        before = sim.stroke_rad[:, : sim.stroke_rad.shape[1] - int(window.max())]
        out["pp_s_before"][sl] = _read(before, window[pts], f[pts], fs, tail)[0]
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


def unsettled_fraction(response: dict[str, np.ndarray]) -> float:
    """The largest relative change of the stroke's peak to peak between the last two windows."""
    return float(np.max(response["settle_change"]))
