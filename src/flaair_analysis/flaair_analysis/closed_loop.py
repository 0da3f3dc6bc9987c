"""The one compiled closed-loop batch engine: many robots, each flapping under its own drive (pure).

The sweeps (`flaair_tools.sweeps`) run it; it reads the plant and the controller only through
their public names: `flaair_sim.core.plant` (`prepare`, `mechanical_constants`, `rk4_step`: the
compiled kernel published for batch engines), `flaair_control.core.dsa` (`DsaParams`, `KrSchedule`,
`filter_coefficients`) and `flaair_control.core.stroke` (`track_sample`).

One simulation is the plant's numba RK4 (``flaair_sim.core.plant``: the same kernels and parameter
vector, so a point equals the plant model) closed sample by sample through the drive:

* ``SYNC``: open loop, drive = A sin(2 pi f t);
* ``DSA``: the dSA filter of ``flaair_control.core.dsa`` (its discrete coefficients, phase-advanced
  for the half-sample zero-order hold) on the true stroke velocity; drive = torque / G_a;
* ``DSA_STROKE``: the same filter, its gain moved by the stroke-amplitude controller
  (``flaair_control.core.stroke.track_sample``: the very tracker the controller core runs).

Ideal proprioception (the sweep asks about the wing, not the sensor): the loop sees the true stroke.
The drive is clamped to drive_limit_v. ``run_rows`` runs a chunk of rows through one compiled call
and summarises each with ``flaair_analysis.wingbeat`` over the steady window: the result of
a row depends on that row alone, so any chunking or cluster gives the same numbers bit for bit.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Any, cast

import numpy as np
from numba import njit, prange

from flaair_analysis import wingbeat
from flaair_control.core import dsa, stroke
from flaair_model.model import Model

# the plant's own kernels
from flaair_sim.core.plant_kernel import rk4_step
from flaair_sim.core.plant_params import HELD_LEN, P_CONTACT_ON, P_HYST_FRAC, prepare
from flaair_sim.core.term_kernel import mechanical_constants

# rk4_step is inlined into the kernels below, and numba's cache of them is keyed on this file
# alone: after a change to flaair_sim.core.plant_kernel, touch this file (or re-run setup).

SYNC, DSA, DSA_STROKE = 0, 1, 2
MODE_NAMES = {SYNC: "sync_open_loop", DSA: "dsa", DSA_STROKE: "dsa_stroke_control"}
_FMA = {"contract"}


@njit(cache=True, fastmath=_FMA)
def _one(
    p: np.ndarray,
    inv_ga: float,
    nsub: int,
    mode: int,
    n: int,
    h: float,
    amplitude_v: float,
    omega: float,
    b: np.ndarray,
    a: np.ndarray,
    gain_scale: float,
    track_c: np.ndarray,
    u_ff: float,
    phi0: float,
    limit_v: float,
    phi_out: np.ndarray,
    psi_out: np.ndarray,
) -> tuple[float, float]:
    """One robot over n samples; the last phi_out.size samples of stroke and pitch (rad) are kept.

    ``inv_ga`` is 1 / G_a (V / N m), the actuator gain's inverse. Returns the final command
    (drive amplitude V for SYNC, mu for the dSA modes) and the largest |drive| over the kept
    window (V; = limit_v when the clamp acts).
    """
    c = mechanical_constants(p)
    held = np.zeros(HELD_LEN)  # no low-pass term: the sweeps run without discovered terms
    phi, dphi, psi, dpsi = phi0, 0.0, 0.0, 0.0
    z1, z2 = 0.0, 0.0  # dSA filter state (direct form II transposed, as scipy lfilter)
    s = np.zeros(9)
    s[1], s[2], s[5] = -np.inf, np.inf, np.nan
    keep0 = n - phi_out.shape[0]
    hs = h / nsub
    u = u_ff
    peak = 0.0
    for k in range(n):
        if mode == SYNC:
            v = amplitude_v * math.sin(omega * k * h)
        else:
            y = b[0] * dphi + z1
            z1 = b[1] * dphi - a[1] * y + z2
            z2 = b[2] * dphi - a[2] * y
            if mode == DSA_STROKE:
                stroke.track_sample(phi, True, s, track_c)
                u = u_ff * math.exp(s[4])
                v = (u * gain_scale) * y * inv_ga
            else:
                v = gain_scale * y * inv_ga
        if v > limit_v:
            v = limit_v
        elif v < -limit_v:
            v = -limit_v
        if k >= keep0:
            peak = max(peak, abs(v))
            phi_out[k - keep0] = phi
            psi_out[k - keep0] = psi
        for _ in range(nsub):
            phi, dphi, psi, dpsi, _hit = rk4_step(
                phi, dphi, psi, dpsi, v, c, hs, 0, 0.0, 0.0, held, False
            )
    return u, peak


@njit(cache=True)
def _batch(
    params: np.ndarray,
    inv_gas: np.ndarray,
    nsubs: np.ndarray,
    modes: np.ndarray,
    n: int,
    h: float,
    amps: np.ndarray,
    omegas: np.ndarray,
    bs: np.ndarray,
    as_: np.ndarray,
    scales: np.ndarray,
    track_cs: np.ndarray,
    u_ffs: np.ndarray,
    phi0s: np.ndarray,
    limit_v: float,
    phi_out: np.ndarray,
    psi_out: np.ndarray,
    u_out: np.ndarray,
) -> None:
    for i in range(params.shape[0]):
        u_out[i, 0], u_out[i, 1] = _one(
            params[i],
            inv_gas[i],
            nsubs[i],
            modes[i],
            n,
            h,
            amps[i],
            omegas[i],
            bs[i],
            as_[i],
            scales[i],
            track_cs[i],
            u_ffs[i],
            phi0s[i],
            limit_v,
            phi_out[i],
            psi_out[i],
        )


@njit(cache=True, parallel=True)
def _batch_parallel(
    params: np.ndarray,
    inv_gas: np.ndarray,
    nsubs: np.ndarray,
    modes: np.ndarray,
    n: int,
    h: float,
    amps: np.ndarray,
    omegas: np.ndarray,
    bs: np.ndarray,
    as_: np.ndarray,
    scales: np.ndarray,
    track_cs: np.ndarray,
    u_ffs: np.ndarray,
    phi0s: np.ndarray,
    limit_v: float,
    phi_out: np.ndarray,
    psi_out: np.ndarray,
    u_out: np.ndarray,
) -> None:
    for i in prange(params.shape[0]):
        u_out[i, 0], u_out[i, 1] = _one(
            params[i],
            inv_gas[i],
            nsubs[i],
            modes[i],
            n,
            h,
            amps[i],
            omegas[i],
            bs[i],
            as_[i],
            scales[i],
            track_cs[i],
            u_ffs[i],
            phi0s[i],
            limit_v,
            phi_out[i],
            psi_out[i],
        )


def damaged_model(model: Model, inertia_factor: float, aero_damping_factor: float) -> Model:
    """The model with wing_damage and its aerodynamic damping (Gamma, D_p) scaled."""
    effects: dict[str, Any] = dict(model.effects)
    if inertia_factor != 1.0:
        effects["wing_damage"] = {"inertia_factor": inertia_factor}
    pl = replace(
        model.plant,
        aero_damping_nm_s2=model.plant.aero_damping_nm_s2 * aero_damping_factor,
        aero_coupling_nm_s2=model.plant.aero_coupling_nm_s2 * aero_damping_factor,
    )
    return replace(model, plant=pl, effects=cast(Any, effects))  # a mapping: Model converts it


def _filter(
    row: dict[str, Any], model: Model, fs: float, mu: float
) -> tuple[np.ndarray, np.ndarray]:
    values = {
        **row,
        "mu_nm_s_per_rad": mu,
        "sync_amplitude_v": 0.0,
        "sync_frequency_hz": 1.0,
        "sync_phase_rad": 0.0,
        "compensate_delay": True,
        "compensation_frequency_hz": None,
    }
    params = dsa.dsa_params(
        values,
        actuator_gain_nm_per_v=model.plant.actuator_gain_nm_per_v,
        sample_rate_hz=fs,
        loop_delay_s=0.5 / fs,
        kr_schedule=dsa.KrSchedule(0.0, 0.0, 0.0, 0.0),
    )
    return dsa.filter_coefficients(params, True)  # the controller core's own discretization


def run_rows(
    rows: list[dict[str, Any]], model: Model, parallel: bool = False
) -> list[dict[str, Any]]:
    """Simulate a chunk of rows (one compiled call) and summarise each over its steady window.

    A row holds: mode (SYNC/DSA/DSA_STROKE), inertia_factor, aero_damping_factor, sample_rate_hz,
    duration_s, steady_s, start_stroke_deg, drive_limit_v, drive_amplitude_v, frequency_hz
    (sync), r3_rad_s, kappa, mu_nm_s_per_rad (the dSA gain, or u_ff with the controller),
    stroke controller tracker (``track``: tracker_constants vector) and the wingbeat detector
    (hysteresis_deg, min_wingbeat_hz, max_wingbeat_hz). Returns per row the steady stroke
    frequency (Hz), stroke amplitude (deg), pitch amplitude (deg) and the final command.
    """
    m = len(rows)
    fs = float(rows[0]["sample_rate_hz"])
    n = round(rows[0]["duration_s"] * fs)
    keep = round(rows[0]["steady_s"] * fs)
    kernel_rows, inv_gas = [], np.empty(m)
    nsubs, modes = np.empty(m, np.int64), np.empty(m, np.int64)
    amps, omegas, scales, u_ffs, phi0s = (np.zeros(m) for _ in range(5))
    bs, as_ = np.zeros((m, 3)), np.zeros((m, 3))
    track = np.zeros((m, len(rows[0]["track"])))
    for i, row in enumerate(rows):
        if float(row["sample_rate_hz"]) != fs or round(row["duration_s"] * fs) != n:
            raise ValueError("rows of one chunk must share sample_rate_hz and duration_s")
        robot = damaged_model(model, row["inertia_factor"], row["aero_damping_factor"])
        prep = prepare(robot, fs)
        if prep.params[P_CONTACT_ON] > 0:
            raise ValueError("the sweep batch has no collision stop")
        if prep.params[P_HYST_FRAC] > 0:
            raise ValueError("the sweep batch has no actuator hysteresis")
        if robot.discovered:
            raise ValueError(
                "the sweep batch runs the model without discovered terms; run the "
                "sweep on a model without them"
            )
        kernel_rows.append(prep.params)
        inv_gas[i] = 1.0 / robot.plant.actuator_gain_nm_per_v  # G_a, as prepare writes it
        nsubs[i], modes[i] = prep.n_substeps, row["mode"]
        phi0s[i] = math.radians(row["start_stroke_deg"]) if row["mode"] != SYNC else 0.0
        if row["mode"] == SYNC:
            amps[i], omegas[i] = row["drive_amplitude_v"], 2.0 * math.pi * row["frequency_hz"]
        else:
            mu = row["mu_nm_s_per_rad"]
            ref = mu if mu > 0 else 1.0
            bs[i], as_[i] = _filter(row, model, fs, ref)
            scales[i] = mu / ref if row["mode"] == DSA else 1.0 / ref
            u_ffs[i] = mu
            track[i] = row["track"]
    phi, psi = np.empty((m, keep)), np.empty((m, keep))
    u_out = np.empty((m, 2))
    kernel = _batch_parallel if parallel else _batch
    kernel(
        np.array(kernel_rows),
        inv_gas,
        nsubs,
        modes,
        n,
        1.0 / fs,
        amps,
        omegas,
        bs,
        as_,
        scales,
        track,
        u_ffs,
        phi0s,
        float(rows[0]["drive_limit_v"]),
        phi,
        psi,
        u_out,
    )
    out = []
    for i, row in enumerate(rows):
        beats = wingbeat.summarize(
            np.degrees(phi[i]),
            np.degrees(psi[i]),
            np.ones(keep, bool),
            wingbeat.WingbeatParams(
                fs, row["hysteresis_deg"], row["min_wingbeat_hz"], row["max_wingbeat_hz"]
            ),
        )
        ok = beats.amplitude_deg.size > 0
        out.append(
            {
                "stroke_frequency_hz": float(np.mean(beats.frequency_hz)) if ok else 0.0,
                "stroke_amplitude_deg": float(np.mean(beats.amplitude_deg))
                if ok
                else float(np.degrees(np.ptp(phi[i])) / 2),
                "pitch_amplitude_deg": float(np.mean(beats.pitch_amplitude_deg))
                if ok
                else float(np.degrees(np.ptp(psi[i])) / 2),
                "final_command": float(u_out[i, 0]),
                "peak_drive_v": float(u_out[i, 1]),
                "drive_clamped": bool(u_out[i, 1] >= row["drive_limit_v"]),
            }
        )
    return out


def warm_up(model: Model, row: dict[str, Any]) -> float:
    """Compile (or load from numba's cache) and run the
    kernels once on a 20 ms copy of ``row``; seconds taken.
    """
    t0 = time.perf_counter()
    tiny = {**row, "duration_s": 0.02, "steady_s": 0.01}
    run_rows([{**tiny, "mode": mode} for mode in (SYNC, DSA, DSA_STROKE)], model)
    return time.perf_counter() - t0
