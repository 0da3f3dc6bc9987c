"""The plant's parameter vector: how a `Model` (with its effects) becomes the numbers the kernels read.

`prepare(model, fs_hz)` maps the model's parameters and effects to one float vector (layout:
the `P_*` indices) plus the RK4 substep counts and the sensor delays; the numba kernels in
`flaair_sim.core.plant` read only that vector, so a batch of robots is a matrix of such rows.
"""
from __future__ import annotations

import math
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from scipy.signal import butter

from flaair_model.model import Model, ModelError

__all__ = [
    "MAX_OMEGA_H",
    "MAX_OMEGA_H_CONTACT",
    "GA_INDEX",
    "CONTACT_ON_INDEX",
    "N_KERNEL_PARAMS",
    "P_I",
    "P_GAMMA",
    "P_K",
    "P_IP",
    "P_CP",
    "P_KH",
    "P_JC",
    "P_DP",
    "P_CSTRUCT",
    "P_HCUBIC",
    "P_PHI_LIM",
    "P_KC",
    "P_CC",
    "P_GS",
    "P_GP",
    "P_TCUBIC",
    "P_FT",
    "P_VREF",
    "P_HPS_ON",
    "P_HPS_B0",
    "P_HPS_B1",
    "P_HPS_A1",
    "P_HPP_ON",
    "P_HPP_B0",
    "P_HPP_B1",
    "P_HPP_A1",
    "P_DS_FRAC",
    "P_DP_FRAC",
    "Prepared",
    "prepare",
]

# Largest (fastest linear rate) x (RK4 substep) allowed: a numerical-method setting, not a
# model number. 0.1 keeps RK4's per-cycle error ~1e-6 and is far inside its stability region.
MAX_OMEGA_H = 0.1
# Finer in the (rare) sample periods touching the collision stop, where the force has kinks.
MAX_OMEGA_H_CONTACT = 0.05
# Layout of the per-model parameter vector handed to the numba kernels (read by the kernels in
# flaair_sim.core.plant and by batch engines).
(
    P_I, P_GAMMA, P_K, GA_INDEX, P_IP, P_CP, P_KH, P_JC, P_DP, P_CSTRUCT, P_HCUBIC,
    CONTACT_ON_INDEX, P_PHI_LIM, P_KC, P_CC,
    P_GS, P_GP, P_TCUBIC, P_FT, P_VREF,
    P_HPS_ON, P_HPS_B0, P_HPS_B1, P_HPS_A1,
    P_HPP_ON, P_HPP_B0, P_HPP_B1, P_HPP_A1,
    P_DS_FRAC, P_DP_FRAC,
    N_KERNEL_PARAMS,
) = range(31)


class Prepared(NamedTuple):
    params: np.ndarray
    n_substeps: int
    n_substeps_contact: int
    delay_stroke_samples: int
    delay_pitch_samples: int

    @property
    def delay_lengths(self) -> tuple[int, int]:
        return (
            self.delay_stroke_samples + (1 if self.params[P_DS_FRAC] > 0 else 0),
            self.delay_pitch_samples + (1 if self.params[P_DP_FRAC] > 0 else 0),
        )


def _split_delay(delay_samples: float) -> tuple[int, float]:
    whole = math.floor(delay_samples + 1e-9)  # tolerate 10/fs * fs = 9.999999999
    frac = delay_samples - whole
    return whole, (0.0 if frac < 1e-9 else frac)


@lru_cache(maxsize=4096)  # a 1000-model batch fits
def prepare(model: Model, fs_hz: float) -> Prepared:
    """Numeric parameter vector and integer settings of `model` at `fs_hz` (cached)."""
    pl = model.plant
    p = np.zeros(N_KERNEL_PARAMS)
    inertia = pl.stroke_inertia_kg_m2
    stiffness = pl.stroke_stiffness_nm_per_rad
    pitch_inertia = pl.pitch_inertia_kg_m2
    hinge_stiffness = pl.hinge_stiffness_nm_per_rad
    damage = model.effect("wing_damage")
    factor = damage.inertia_factor if damage is not None else 1.0
    p[P_I] = inertia * factor
    p[P_IP] = pitch_inertia * factor
    p[P_GAMMA] = pl.aero_damping_nm_s2
    p[P_K] = stiffness
    p[GA_INDEX] = pl.actuator_gain_nm_per_v
    p[P_CP] = pl.hinge_damping_nm_s_per_rad
    p[P_KH] = hinge_stiffness
    p[P_JC] = pl.inertial_coupling_kg_m2
    p[P_DP] = pl.aero_coupling_nm_s2
    structural = model.effect("structural_damping")
    if structural is not None:
        p[P_CSTRUCT] = 2.0 * structural.damping_ratio * math.sqrt(stiffness * inertia)
    hinge = model.effect("hinge_stiffening")
    if hinge is not None:
        p[P_HCUBIC] = hinge.cubic_per_rad2
    collision = model.effect("collision")
    if collision is not None:
        p[CONTACT_ON_INDEX] = 1.0
        p[P_PHI_LIM] = math.radians(collision.stroke_limit_deg)
        p[P_KC] = collision.contact_stiffness_ratio * stiffness
        p[P_CC] = 2.0 * collision.contact_damping_ratio * math.sqrt(p[P_KC] * inertia)

    # sensor chains: each effect with a `channel` may hold its own value per chain (model.effect_on)
    gains = {"stroke": model.stroke_volts_per_rad, "pitch": model.pitch_volts_per_rad}
    delay_int = [0, 0]
    for i, (which, hp_base, frac_index) in enumerate((("stroke", P_HPS_ON, P_DS_FRAC), ("pitch", P_HPP_ON, P_DP_FRAC))):
        loss = model.effect_on("strain_transfer_loss", which)
        if loss is not None:
            gains[which] *= loss.efficiency
        highpass = model.effect_on("charge_amp_highpass", which)
        if highpass is not None:
            if not highpass.corner_hz < fs_hz / 2:
                raise ModelError(
                    f"effects.charge_amp_highpass.corner_hz must be below fs_hz/2 = {fs_hz / 2:g}, got {highpass.corner_hz:g}"
                )
            b, a = butter(1, highpass.corner_hz, btype="highpass", fs=fs_hz)
            b, a = b / a[0], a / a[0]
            p[hp_base : hp_base + 4] = (1.0, b[0], b[1], a[1])
        delay = model.effect_on("sensor_delay", which)
        if delay is not None:
            delay_int[i], p[frac_index] = _split_delay(delay.delay_s * fs_hz)
    p[P_GS], p[P_GP] = gains["stroke"], gains["pitch"]
    nonlinearity = model.effect("transmission_nonlinearity")
    if nonlinearity is not None:
        p[P_TCUBIC] = nonlinearity.cubic_per_rad2
    feed = model.effect("feedthrough")
    if feed is not None:
        p[P_FT] = feed.gain_v_per_v
    p[P_VREF] = model.sensors.reference_voltage_v

    rates = [
        math.sqrt(stiffness / p[P_I]),
        math.sqrt(hinge_stiffness / p[P_IP]),
        p[P_CP] / p[P_IP],
        p[P_CSTRUCT] / p[P_I],
    ]
    substeps = max(1, math.ceil(max(rates) / fs_hz / MAX_OMEGA_H))
    substeps_contact = substeps
    if collision is not None:
        rates += [math.sqrt((stiffness + p[P_KC]) / p[P_I]), p[P_CC] / p[P_I]]
        substeps_contact = max(1, math.ceil(max(rates) / fs_hz / MAX_OMEGA_H_CONTACT))
    p.setflags(write=False)
    return Prepared(p, substeps, substeps_contact, delay_int[0], delay_int[1])
