"""The plant's parameter vector: how a `Model` (with
its effects) becomes the numbers the kernels read.

Each effect's kernel terms come from its entry in the effect table (`flaair_model.effects`);
this module only says where each term lands in the vector.

`prepare(model, fs_hz)` maps the model's parameters and effects to one float vector (layout:
the `P_*` indices) plus the RK4 substep counts and the sensor delays; the numba kernels in
`flaair_sim.core.plant` read only that vector, so a batch of robots is a matrix of such rows.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from flaair_model.effects import EFFECTS, TermContext
from flaair_model.model import SIDES, Model, ModelError
from flaair_model.terms import MAX_DYNAMICS_TERMS, PRIMITIVES

__all__ = [
    "CONTACT_ON_INDEX",
    "GA_INDEX",
    "MAX_DYNAMICS_TERMS",
    "MAX_OMEGA_H",
    "MAX_OMEGA_H_CONTACT",
    "N_KERNEL_PARAMS",
    "P_CC",
    "P_CP",
    "P_CSTRUCT",
    "P_DP",
    "P_DP_FRAC",
    "P_DS_FRAC",
    "P_FT",
    "P_GAMMA",
    "P_GP",
    "P_GS",
    "P_HCUBIC",
    "P_HPP_A1",
    "P_HPP_B0",
    "P_HPP_B1",
    "P_HPP_ON",
    "P_HPS_A1",
    "P_HPS_B0",
    "P_HPS_B1",
    "P_HPS_ON",
    "P_I",
    "P_IP",
    "P_JC",
    "P_K",
    "P_KC",
    "P_KH",
    "P_NTERMS",
    "P_PHI_LIM",
    "P_TCUBIC",
    "P_TERMS",
    "P_VREF",
    "TERM_SLOT",
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
    P_I,
    P_GAMMA,
    P_K,
    GA_INDEX,
    P_IP,
    P_CP,
    P_KH,
    P_JC,
    P_DP,
    P_CSTRUCT,
    P_HCUBIC,
    CONTACT_ON_INDEX,
    P_PHI_LIM,
    P_KC,
    P_CC,
    P_GS,
    P_GP,
    P_TCUBIC,
    P_FT,
    P_VREF,
    P_HPS_ON,
    P_HPS_B0,
    P_HPS_B1,
    P_HPS_A1,
    P_HPP_ON,
    P_HPP_B0,
    P_HPP_B1,
    P_HPP_A1,
    P_DS_FRAC,
    P_DP_FRAC,
    P_NTERMS,
    P_TERMS,
) = range(32)
# Each dynamics slot of the discovered terms: [equation (1 stroke, 2 pitch; 0 empty),
# coefficient / inertia, the monomial's exponents over flaair_model.terms.PRIMITIVES].
TERM_SLOT = 2 + len(PRIMITIVES)
N_KERNEL_PARAMS = P_TERMS + MAX_DYNAMICS_TERMS * TERM_SLOT


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


# Where each kernel term of the effect table (flaair_model.effects) lands in the vector.
_PLANT_INDEX = {
    "structural_damping_nm_s_per_rad": P_CSTRUCT,
    "hinge_cubic_per_rad2": P_HCUBIC,
    "contact_on": CONTACT_ON_INDEX,
    "stroke_limit_rad": P_PHI_LIM,
    "contact_stiffness_nm_per_rad": P_KC,
    "contact_damping_nm_s_per_rad": P_CC,
    "transmission_cubic_per_rad2": P_TCUBIC,
    "feedthrough_v_per_v": P_FT,
}
_SCALE_INDEX = {"inertia_factor": (P_I, P_IP)}
_SENSOR_INDEX = {  # per chain: (stroke, pitch)
    "highpass_b0": (P_HPS_B0, P_HPP_B0),
    "highpass_b1": (P_HPS_B1, P_HPP_B1),
    "highpass_a1": (P_HPS_A1, P_HPP_A1),
    "gain_factor": (P_GS, P_GP),
}
_HIGHPASS_ON = (P_HPS_ON, P_HPP_ON)
_DELAY_FRACTION = (P_DS_FRAC, P_DP_FRAC)


@lru_cache(maxsize=4096)  # a 1000-model batch fits
def prepare(model: Model, fs_hz: float) -> Prepared:
    """Numeric parameter vector and integer settings of `model` at `fs_hz` (cached).

    The nominal plant and sensor gains first; then each effect the model carries writes the
    kernel terms its entry in `flaair_model.effects.EFFECTS` computes.
    """
    pl = model.plant
    p = np.zeros(N_KERNEL_PARAMS)
    inertia = pl.stroke_inertia_kg_m2
    stiffness = pl.stroke_stiffness_nm_per_rad
    hinge_stiffness = pl.hinge_stiffness_nm_per_rad
    p[P_I] = inertia
    p[P_IP] = pl.pitch_inertia_kg_m2
    p[P_GAMMA] = pl.aero_damping_nm_s2
    p[P_K] = stiffness
    p[GA_INDEX] = pl.actuator_gain_nm_per_v
    p[P_CP] = pl.hinge_damping_nm_s_per_rad
    p[P_KH] = hinge_stiffness
    p[P_JC] = pl.inertial_coupling_kg_m2
    p[P_DP] = pl.aero_coupling_nm_s2
    p[P_GS], p[P_GP] = model.stroke_volts_per_rad, model.pitch_volts_per_rad
    p[P_VREF] = model.sensors.reference_voltage_v

    context = TermContext(inertia, stiffness, fs_hz)
    delay_int = [0, 0]
    for entry in EFFECTS:
        if model.effect(entry.name) is None:
            continue
        sides = (
            [(i, model.effect_on(entry.name, side)) for i, side in enumerate(SIDES)]
            if entry.per_sensor
            else [(None, model.effect(entry.name))]
        )
        for i, effect in sides:
            if effect is None:
                continue
            for term, value in entry.terms(effect, context).items():
                if i is None and term in _PLANT_INDEX:
                    p[_PLANT_INDEX[term]] = value
                elif i is None and term in _SCALE_INDEX:
                    for index in _SCALE_INDEX[term]:
                        p[index] *= value
                elif i is not None and term == "delay_samples":
                    delay_int[i], p[_DELAY_FRACTION[i]] = _split_delay(value)
                elif i is not None and term in _SENSOR_INDEX:
                    index = _SENSOR_INDEX[term][i]
                    p[index] = p[index] * value if term == "gain_factor" else value
                    if term.startswith("highpass_"):
                        p[_HIGHPASS_ON[i]] = 1.0
                else:
                    raise ModelError(
                        f"effects.{entry.name}: kernel term {term!r} is not one the "
                        "plant knows "
                        f"({'per sensor chain' if i is not None else 'plant-wide'})"
                    )

    dynamics = [t for t in model.discovered if t.is_dynamics]
    p[P_NTERMS] = len(dynamics)
    for slot, dterm in enumerate(dynamics):
        base = P_TERMS + slot * TERM_SLOT
        stroke = dterm.acts_on == "stroke_dynamics"
        p[base] = 1.0 if stroke else 2.0
        p[base + 1] = dterm.coefficient / (p[P_I] if stroke else p[P_IP])
        p[base + 2 : base + TERM_SLOT] = dterm.monomial

    rates = [
        math.sqrt(stiffness / p[P_I]),
        math.sqrt(hinge_stiffness / p[P_IP]),
        p[P_CP] / p[P_IP],
        p[P_CSTRUCT] / p[P_I],
    ]
    substeps = max(1, math.ceil(max(rates) / fs_hz / MAX_OMEGA_H))
    substeps_contact = substeps
    if p[CONTACT_ON_INDEX] > 0:
        rates += [math.sqrt((stiffness + p[P_KC]) / p[P_I]), p[P_CC] / p[P_I]]
        substeps_contact = max(1, math.ceil(max(rates) / fs_hz / MAX_OMEGA_H_CONTACT))
    p.setflags(write=False)
    return Prepared(p, substeps, substeps_contact, delay_int[0], delay_int[1])
