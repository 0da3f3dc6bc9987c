"""Plant dynamics and sensor chain (shared/model-spec.md), with the effects of docs/ARCHITECTURE.md.

Dynamics (SI units)::

    I phi'' + Gamma |phi'| phi' + K phi = G_a V                      (+ effects)
    I_p psi'' + c_p psi' + k_h psi = -J_c phi'' - D_p |phi'| phi'

Integration is fixed-step RK4 (numba), with the drive held constant over each sample period
(zero-order hold) and `n_substeps` RK4 steps per sample chosen from the fastest linear rate of
the model (natural frequencies, damping rates); a sample period in which the collision stop is
touched is redone with more substeps, chosen from the contact's stiffness and damping, and the
substep that enters the contact is split at the impact (the contact damper makes the force
jump there). Kernels are compiled with fused multiply-add allowed but no reassociation, so
results are deterministic: block stepping, whole records and batches agree bit for bit.

Sample convention: output sample k is the state at t_k = k / fs (so sample 0 is the rest
state); drive sample k is then held over [t_k, t_k+1). Feedthrough adds gain * drive[k] to
sensor sample k. With the actuator's hysteresis (an effect), the actuator sees drive[k] less
its hysteretic voltage, taken exactly at each sample's jump (`hysteresis_kernel`).

Sensor chain per channel, in order: transduction (nominal gain from pvdf.py, with
transmission_nonlinearity on the stroke sensor and strain_transfer_loss scaling the
deviation), feedthrough (stroke), charge-amplifier high-pass (first-order, bilinear with
pre-warped corner, scipy `lfilter` zi convention), sensor delay (integer samples + linear
interpolation between the two neighbouring samples for the fractional part), + V_HREF, noise.

Each effect's coefficients come from its entry in the effect table (`flaair_model.effects`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from flaair_model.last_call import remember_last
from flaair_model.model import Model
from flaair_sim.core import plant_params as pp
from flaair_sim.core.plant_kernel import run_batch, run_model
from flaair_sim.core.plant_params import prepare
from flaair_sim.core.plant_terms import (
    add_batch_sensor_terms,
    add_sensor_terms,
    batch_drives,
    drive_seen,
    terms_state,
)
from flaair_sim.core.sensor_kernel import add_sensor_noise, sensor_channel_kernel

# Also the compiled kernel (`Prepared`, `prepare`, `mechanical_constants`, `rk4_step`), for
# batch engines that step many robots at once (flaair_analysis.closed_loop).
__all__ = [
    "PlantState",
    "SimOutput",
    "initial_state",
    "n_substeps",
    "sensor_chain",
    "simulate",
    "simulate_batch",
    "simulate_batch_from",
    "step",
    "warm_up",
]


class SimOutput(NamedTuple):
    """Simulated signals, one value per sample (rad, rad, V, V)."""

    stroke_rad: np.ndarray
    pitch_rad: np.ndarray
    stroke_sensor_v: np.ndarray
    pitch_sensor_v: np.ndarray


class PlantState(NamedTuple):
    """Plant state between blocks (arrays are read-only; a NamedTuple, cheap to build once a
    block).

    Attributes
    ----------
    mechanical : (4,) [phi rad, phi' rad/s, psi rad, psi' rad/s] at the next sample time.
    highpass_zi : (2,) high-pass filter state [stroke, pitch] (scipy lfilter zi of each channel).
    delay_stroke_v, delay_pitch_v : the last sensor-voltage deviations that entered the delay
        line, oldest first (length = integer delay in samples, + 1 with a fractional part).
    fs_hz : sample rate the state belongs to.
    sample_index : number of samples simulated so far.
    terms : state of the model's drive and sensor terms (`plant_terms.terms_state`; None: rest).
    actuator : (HELD_LEN,) what the kernel holds between samples besides the mechanics: the
        actuator's hysteretic voltage V, the last drive sample V, each low-pass term's filter
        state and output (`plant_params.HELD_LEN`)
        (None: rest).
    """

    mechanical: np.ndarray
    highpass_zi: np.ndarray
    delay_stroke_v: np.ndarray
    delay_pitch_v: np.ndarray
    fs_hz: float
    sample_index: int = 0
    terms: np.ndarray | None = None
    actuator: np.ndarray | None = None


def n_substeps(model: Model, fs_hz: float) -> tuple[int, int]:
    """RK4 substeps per sample for `model` at `fs_hz`:
    (free flight, sample periods touching the stop).
    """
    prep = prepare(model, _check_fs(fs_hz))
    return prep.n_substeps, prep.n_substeps_contact


# --------------------------------------------------------------------------- public API


def _check_fs(fs_hz: float) -> float:
    fs = float(fs_hz)
    if not (math.isfinite(fs) and fs > 0):
        raise ValueError(f"fs_hz must be a finite number > 0, got {fs_hz!r}")
    return fs


_SMALL = 64  # samples: up to this many, a Python sum beats numpy's reduction


def _check_drive(drive_v: np.ndarray, ndim: tuple[int, ...] = (1,)) -> np.ndarray:
    drive = np.ascontiguousarray(drive_v, dtype=np.float64)
    if drive.ndim not in ndim:
        raise ValueError(
            f"drive_v must have {' or '.join(map(str, ndim))} dimension(s), got shape {drive.shape}"
        )
    # a finite sum proves every sample finite (fast path); otherwise check sample by sample. A
    # block's few samples are summed in Python: a numpy reduction costs ~2 us of fixed overhead.
    total = (
        sum(drive.ravel().tolist())
        if drive.size <= _SMALL
        else float(np.add.reduce(drive, axis=None))
    )
    if not math.isfinite(total) and not np.all(np.isfinite(drive)):
        raise ValueError("drive_v must be finite")
    return drive


# A block loop passes the same immutable Model every block, and `prepare`'s lru_cache hashes the
# whole nested model on each call.
_prepare_same = remember_last(prepare)


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def _fit_history(hist: np.ndarray, length: int) -> np.ndarray:
    # keep the newest samples; rest (zero deviation) fills a longer line
    if hist.shape[0] >= length:
        return hist[hist.shape[0] - length :].copy()
    return np.concatenate([np.zeros(length - hist.shape[0]), hist])


def initial_state(params: PlantStepParams) -> PlantState:
    """At-rest state (phi = phi' = psi = psi' = 0,
    sensor chain at V_HREF) for the model and rate.
    """
    fs = _check_fs(params.sample_rate_hz)
    len_s, len_p = prepare(params.model, fs).delay_lengths
    return PlantState(
        mechanical=_frozen(np.zeros(4)),
        highpass_zi=_frozen(np.zeros(2)),
        actuator=_frozen(np.zeros(pp.HELD_LEN)),
        delay_stroke_v=_frozen(np.zeros(len_s)),
        delay_pitch_v=_frozen(np.zeros(len_p)),
        fs_hz=fs,
        sample_index=0,
    )


class PlantInputs(NamedTuple):
    """One block of plant inputs.

    drive_v: drive voltage per sample (V, bias removed), held over each sample period.
    noise_rng: if given, sensor-voltage noise `model.noise.sensor_noise_v_rms` is added, drawn
    as noise_rng.standard_normal((n, 2)) so that the draw does not depend on the block split.
    """

    drive_v: np.ndarray
    noise_rng: np.random.Generator | None = None


class PlantStepParams(NamedTuple):
    """What `step` runs with: the model (it may change between blocks) and the sample rate."""

    model: Model
    sample_rate_hz: float


def warm_up(params: PlantStepParams, n: int = 10) -> None:
    """Load the compiled kernels (and what the model's effects and terms import) now, with a
    throwaway block from rest, not on the first live block, when the drive would queue behind it.
    """
    step(initial_state(params), PlantInputs(np.zeros(n)), params)


def step(
    state: PlantState, inputs: PlantInputs, params: PlantStepParams
) -> tuple[PlantState, SimOutput]:
    """Advance the plant over one block of drive samples.

    Parameters
    ----------
    state
        State from `initial_state` or a previous `step` (same sample rate).
    inputs
        The block's drive and, for noisy sensors, the generator to draw the noise from.
    params
        Model and sample rate. The model may change between blocks (the sensor-chain state
        is adapted).

    Returns
    -------
    (PlantState, SimOutput)
    """
    drive_v_block, rng = inputs
    model, fs_hz = params
    fs = _check_fs(fs_hz)
    if fs != state.fs_hz:
        raise ValueError(f"fs_hz {fs:g} differs from the state's fs_hz {state.fs_hz:g}")
    drive = _check_drive(drive_v_block)
    prep = _prepare_same(model, fs)
    terms = terms_state(model, state.terms)
    seen = drive_seen(model, fs, drive, state.sample_index, terms)
    len_s, len_p = prep.delay_lengths
    x = state.mechanical.copy()
    actuator = np.zeros(pp.HELD_LEN) if state.actuator is None else state.actuator.copy()
    zi = state.highpass_zi.copy()
    hist_s = _fit_history(state.delay_stroke_v, len_s)
    hist_p = _fit_history(state.delay_pitch_v, len_p)
    n = drive.shape[0]
    # one buffer: the noise goes onto both sensor rows in one call
    signals = np.empty((4, n))
    # indexed rows: cheaper than unpacking the array
    phi, psi, vs, vp = signals[0], signals[1], signals[2], signals[3]
    run_model(
        x,
        actuator,
        zi,
        hist_s,
        hist_p,
        seen,
        1.0 / fs,
        prep.n_substeps,
        prep.n_substeps_contact,
        prep.params,
        prep.delay_stroke_samples,
        prep.delay_pitch_samples,
        phi,
        psi,
        vs,
        vp,
        float(state.sample_index),
    )
    add_sensor_terms(model, fs, drive, state.sample_index, phi, psi, vs, vp, terms)
    if not math.isfinite(sum(x.tolist())):
        # Only a drive far outside any actuator's range (kV and up) gets here: the nodes clamp
        # to drive_limit_v before the model, so this is a caller's error, never a silent NaN.
        raise ValueError(
            f"drive_v up to {np.abs(drive).max():.3g} V drove the plant model out of "
            "its range (the simulation diverged); clamp the drive to the actuator's "
            "limit"
        )
    if rng is not None:
        add_sensor_noise(signals[2:], rng.standard_normal((n, 2)), model.noise.sensor_noise_v_rms)
    new_state = PlantState(
        mechanical=_frozen(x),
        highpass_zi=_frozen(zi),
        delay_stroke_v=_frozen(hist_s),
        delay_pitch_v=_frozen(hist_p),
        fs_hz=fs,
        sample_index=state.sample_index + n,
        terms=_frozen(terms),
        actuator=_frozen(actuator),
    )
    return new_state, SimOutput(phi, psi, vs, vp)


def simulate(
    drive_v: np.ndarray,
    fs_hz: float,
    model: Model,
    *,
    noise: bool = False,
    rng: np.random.Generator | None = None,
) -> SimOutput:
    """Whole record from rest: `step` applied once to the whole drive.

    Parameters
    ----------
    drive_v
        Drive voltage per sample (V).
    fs_hz
        Sample rate.
    model
        Model.
    noise
        Add sensor-voltage noise (model.noise) drawn from `rng` (default: a fresh generator).
    rng
        Random generator used when noise is True.
    """
    state = initial_state(PlantStepParams(model, fs_hz))
    if noise and rng is None:
        rng = np.random.default_rng()
    _, out = step(
        state, PlantInputs(drive_v, rng if noise else None), PlantStepParams(model, fs_hz)
    )
    return out


def _batch_tables(
    models: list[Model], fs: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-model parameter, substep, delay and history-length tables of a batch."""
    m = len(models)
    preps = [prepare(model, fs) for model in models]
    params = np.array([prep.params for prep in preps]).reshape(m, pp.N_KERNEL_PARAMS)
    nsubs = np.array(
        [(prep.n_substeps, prep.n_substeps_contact) for prep in preps], dtype=np.int64
    ).reshape(m, 2)
    delays = np.array(
        [(prep.delay_stroke_samples, prep.delay_pitch_samples) for prep in preps], dtype=np.int64
    ).reshape(m, 2)
    hist_len = np.array([prep.delay_lengths for prep in preps], dtype=np.int64).reshape(m, 2)
    # read-only, as `prepare`'s own: numba types read-only and writable arrays apart, and would
    # compile the kernels once for each
    params.setflags(write=False)
    return params, nsubs, delays, hist_len


def simulate_batch(
    drive_v: np.ndarray, fs_hz: float, models: Sequence[Model], *, out: SimOutput | None = None
) -> SimOutput:
    """Many models over one drive, in parallel (no noise); equals `simulate` model by model.

    Parameters
    ----------
    drive_v
        (n_samples,) shared drive, or (n_models, n_samples) one drive per model.
    fs_hz
        Sample rate.
    models
        The models.
    out
        Optional preallocated output (four C-contiguous float64 (n_models, n_samples)
        arrays), written in place and returned: saves allocating (and page-faulting)
        4 x 8 x n_models x n_samples bytes on every call of a fitting loop.

    Returns
    -------
    SimOutput
        Arrays of shape (n_models, n_samples).
    """
    fs = _check_fs(fs_hz)
    drive = _check_drive(drive_v, (1, 2))
    models = list(models)
    m = len(models)
    if drive.ndim == 1:
        drive = drive[None, :]
    elif drive.shape[0] != m:
        raise ValueError(f"drive_v has {drive.shape[0]} rows for {m} models")
    n = drive.shape[1]
    params, nsubs, delays, hist_len = _batch_tables(models, fs)
    commanded, (drive, states) = drive, batch_drives(models, fs, drive)
    if out is None:
        phi, psi, vs, vp = (np.empty((m, n)) for _ in range(4))
    else:
        for name, array in zip(SimOutput._fields, out, strict=True):
            if not (
                isinstance(array, np.ndarray)
                and array.shape == (m, n)
                and array.dtype == np.float64
                and array.flags.c_contiguous
                and array.flags.writeable
            ):
                raise ValueError(
                    f"out.{name} must be a writeable C-contiguous float64 array of shape {(m, n)}"
                )
        phi, psi, vs, vp = out
    if m == 1:  # skip the thread pool
        run_model(
            np.zeros(4),
            np.zeros(pp.HELD_LEN),
            np.zeros(2),
            np.zeros(hist_len[0, 0]),
            np.zeros(hist_len[0, 1]),
            drive[0],
            1.0 / fs,
            nsubs[0, 0],
            nsubs[0, 1],
            params[0],
            delays[0, 0],
            delays[0, 1],
            phi[0],
            psi[0],
            vs[0],
            vp[0],
            0.0,
        )
    elif m:
        x0 = np.zeros((m, 4))
        run_batch(drive, 1.0 / fs, nsubs, params, delays, hist_len, x0, phi, psi, vs, vp)
    add_batch_sensor_terms(models, fs, commanded, states, phi, psi, vs, vp)
    return SimOutput(phi, psi, vs, vp)


# ------------------------------------------------------------- from a moving state, sensor chain


def simulate_batch_from(
    drive_v: np.ndarray, fs_hz: float, models: Sequence[Model], mechanical0: np.ndarray
) -> SimOutput:
    """Many models over one drive, each starting from a given mechanical state (no noise).

    Parameters
    ----------
    drive_v
        (n_samples,) shared drive, or (n_models, n_samples) one drive per model (V).
    fs_hz
        Sample rate.
    models
        The models.
    mechanical0
        (4,) or (n_models, 4) initial [phi rad, phi' rad/s, psi rad, psi' rad/s]; the sensor
        chain starts at rest. With zeros this equals `simulate_batch`.

    Returns
    -------
    SimOutput
        Arrays of shape (n_models, n_samples).
    """
    fs = _check_fs(fs_hz)
    rows = np.atleast_2d(_check_drive(drive_v, (1, 2)))
    models = list(models)
    m = len(models)
    if rows.shape[0] not in (1, m):
        raise ValueError(f"drive_v has {rows.shape[0]} rows for {m} models")
    x0 = np.broadcast_to(np.asarray(mechanical0, dtype=np.float64), (m, 4)).copy()
    if not np.all(np.isfinite(x0)):
        raise ValueError("mechanical0 must be finite")
    params, nsubs, delays, hist_len = _batch_tables(models, fs)
    n = rows.shape[1]
    phi, psi, vs, vp = (np.empty((m, n)) for _ in range(4))
    seen, states = batch_drives(models, fs, rows)
    if m:
        run_batch(seen, 1.0 / fs, nsubs, params, delays, hist_len, x0, phi, psi, vs, vp)
    add_batch_sensor_terms(models, fs, rows, states, phi, psi, vs, vp)
    return SimOutput(phi, psi, vs, vp)


def sensor_chain(
    model: Model, fs_hz: float, stroke_rad: np.ndarray, pitch_rad: np.ndarray, drive_v: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Both charge-amplifier outputs (V) for a given motion: the plant's sensor chain alone.

    Transduction (transmission_nonlinearity, strain_transfer_loss), feedthrough, high-pass
    and delay from rest, + V_HREF, exactly as `simulate` applies them to its own motion; lets a
    caller try sensor effects on a motion (simulated or measured) without integrating again.
    """
    fs = _check_fs(fs_hz)
    prep = prepare(model, fs)
    p = prep.params
    phi = np.asarray(stroke_rad, dtype=np.float64)
    psi = np.asarray(pitch_rad, dtype=np.float64)
    drive = np.asarray(drive_v, dtype=np.float64)
    vs = np.ascontiguousarray(
        p[pp.P_GS] * (phi + p[pp.P_TCUBIC] * phi * phi * phi) + p[pp.P_FT] * drive
    )
    vp = np.ascontiguousarray(p[pp.P_GP] * psi)
    len_s, len_p = prep.delay_lengths
    sensor_channel_kernel(
        vs,
        p[pp.P_HPS_ON],
        p[pp.P_HPS_B0],
        p[pp.P_HPS_B1],
        p[pp.P_HPS_A1],
        0.0,
        np.zeros(len_s),
        prep.delay_stroke_samples,
        p[pp.P_DS_FRAC],
        p[pp.P_VREF],
    )
    sensor_channel_kernel(
        vp,
        p[pp.P_HPP_ON],
        p[pp.P_HPP_B0],
        p[pp.P_HPP_B1],
        p[pp.P_HPP_A1],
        0.0,
        np.zeros(len_p),
        prep.delay_pitch_samples,
        p[pp.P_DP_FRAC],
        p[pp.P_VREF],
    )
    add_sensor_terms(model, fs, drive, 0, phi, psi, vs, vp, terms_state(model))
    return vs, vp
