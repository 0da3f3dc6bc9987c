"""Simulated runs for the health monitor's tests and benchmark: the dSA loop (or a sync sine)
on the simulated robot, a damage applied at a given time (model changed between blocks).
"""

from __future__ import annotations

import numpy as np

from flaair_control.core import dsa, hopf
from flaair_model.model import Model
from flaair_sim.core import plant

FS = 20000.0
BLOCK = 10
KAPPA = 0.5


def dsa_params(
    model: Model,
    sync_v: float = 20.0,
    kr=(1.0, 0.0, 0.3, 0.3),
    sync_hz: float = 60.0,
    mu_factor: float = 10.0,
    block: int = BLOCK,
) -> dsa.DsaParams:
    """The paper's sync -> self-excited transition (tests/test_control_dsa.py's loop)."""
    lin = hopf.LinearStrokePlant(
        model.plant.stroke_inertia_kg_m2, model.plant.stroke_stiffness_nm_per_rad
    )
    r3 = hopf.r3_for_onset_frequency(KAPPA, 142.0)
    mu = mu_factor * hopf.hopf_onset(lin, r3, KAPPA).mu_nm_s_per_rad
    return dsa.DsaParams(
        r3_rad_s=r3,
        kappa=KAPPA,
        mu_nm_s_per_rad=mu,
        actuator_gain_nm_per_v=model.plant.actuator_gain_nm_per_v,
        sample_rate_hz=FS,
        drive_limit_v=100.0,
        sync_amplitude_v=sync_v,
        sync_frequency_hz=sync_hz,
        kr_schedule=dsa.KrSchedule(*kr),
        loop_delay_s=dsa.loop_delay_s(block, FS),
        sync_phase_rad=0.0,
        compensation_frequency_hz=None,
    )


def run(
    model: Model,
    duration_s: float,
    damaged: Model | None = None,
    damage_s: float = np.inf,
    seed: int = 7,
    sine: tuple[float, float] | None = None,
    kr=(1.0, 0.0, 0.3, 0.3),
    sync_hz: float = 60.0,
    mu_factor: float = 10.0,
    block: int = BLOCK,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(stroke film V, pitch film V, applied drive V) of a noisy run; the model becomes
    `damaged` from the first block at or after `damage_s`. `sine` = (amplitude V, frequency Hz)
    drives open loop instead of the dSA loop; `kr` the K_r schedule (start, end, ramp start s,
    ramp duration s), `sync_hz` the synchronous drive's frequency, `mu_factor` the dSA gain over
    its Hopf onset (sets the self-excited amplitude); `block` the samples a step takes (the
    dSA loop's delay with it; longer blocks run faster).
    """
    p = dsa_params(model, kr=kr, sync_hz=sync_hz, mu_factor=mu_factor, block=block)
    rng = np.random.default_rng(seed)
    before = plant.PlantStepParams(model, FS)  # built once: a step's params cost more than it
    after = before if damaged is None else plant.PlantStepParams(damaged, FS)
    state = plant.initial_state(before)
    ctrl = dsa.initial_state(p)
    vpr, vref = model.stroke_volts_per_rad, model.sensors.reference_voltage_v
    drive = np.zeros(block)
    prev = 0.0
    n_blocks = int(duration_s * FS / block)
    vs, vp, dv = (np.empty(n_blocks * block) for _ in range(3))
    for k in range(n_blocks):
        t = k * block / FS
        if sine is not None:
            drive = sine[0] * np.sin(2 * np.pi * sine[1] * (k * block + np.arange(block)) / FS)
        m = after if t >= damage_s else before
        state, out = plant.step(state, plant.PlantInputs(drive, rng), m)
        sl = slice(k * block, (k + 1) * block)
        vs[sl], vp[sl], dv[sl] = out.stroke_sensor_v, out.pitch_sensor_v, drive
        if sine is None:
            phi = (out.stroke_sensor_v - vref) / vpr  # the controller reads the (damaged) film
            vel = np.diff(np.concatenate([[prev], phi])) * FS
            prev = phi[-1]
            ctrl, (drive, _) = dsa.step(ctrl, dsa.DsaInputs(vel, (k + 1) * block / FS), p)
    return vs, vp, dv
