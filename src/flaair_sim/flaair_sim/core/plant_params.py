"""The plant's parameter vector: how a `Model` (with
its effects) becomes the numbers the kernels read.

`KERNEL_LAYOUT` is the one declaration of that vector: one `KernelSlot` per number, in vector
order, saying which effect-table kernel term (`flaair_model.effects`) lands there and whether
(and over which inertia) the RK4 kernel's constants tuple carries it. The `P_*` indices, the
effect terms' places, the constants tuple's order and length (`C_*`, `N_CONSTANTS`) and the
discovered terms' slots (`P_TERMS`, `TERM_SLOT`) all derive from it; tests/test_effect_table.py
checks that the kernels read exactly this layout.

`prepare(model, fs_hz)` maps the model's parameters and effects to one float vector plus the
RK4 substep counts and the sensor delays; the numba kernels in `flaair_sim.core.plant` read only
that vector, so a batch of robots is a matrix of such rows.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Literal, NamedTuple

import numpy as np

from flaair_model.effects import EFFECTS, PLANT_TERMS, SCALE_TERMS, SENSOR_TERMS, TermContext
from flaair_model.model import Model
from flaair_model.terms import MAX_DYNAMICS_TERMS, PRIMITIVES
from flaair_model.validation import SIDES, ModelError

__all__ = [
    "CONSTANT_DIVISOR",
    "CONSTANT_SOURCE",
    "CONTACT_ON_INDEX",
    "C_CC",
    "C_CP",
    "C_CSTRUCT",
    "C_DP",
    "C_GA",
    "C_GAMMA",
    "C_HCUBIC",
    "C_JC",
    "C_K",
    "C_KC",
    "C_KH",
    "C_PHI_LIM",
    "C_TERM_SLOTS",
    "GA_INDEX",
    "HELD_LEN",
    "HELD_LOWPASS",
    "KERNEL_LAYOUT",
    "MAX_FACTORS",
    "MAX_OMEGA_H",
    "MAX_OMEGA_H_CONTACT",
    "MAX_OMEGA_H_LOWPASS",
    "MAX_POWER",
    "N_CONSTANTS",
    "N_CONSTANTS_WITH_TERMS",
    "N_KERNEL_PARAMS",
    "P_CC",
    "P_CONTACT_ON",
    "P_CP",
    "P_CSTRUCT",
    "P_DP",
    "P_DP_FRAC",
    "P_DS_FRAC",
    "P_FT",
    "P_GA",
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
    "P_HYST_FRAC",
    "P_HYST_SAT",
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
    "TERM_LOWPASS",
    "TERM_SLOT",
    "KernelSlot",
    "Prepared",
    "coefficients",
    "prepare",
]

# Largest (fastest linear rate) x (RK4 substep) allowed: a numerical-method setting, not a
# model number. 0.1 keeps RK4's per-cycle error ~1e-6 and is far inside its stability region.
MAX_OMEGA_H = 0.1
# Finer in the (rare) sample periods touching the collision stop, where the force has kinks.
MAX_OMEGA_H_CONTACT = 0.05
# A low-pass term's state decays (no phase to accumulate, as an oscillator's does): RK4's local
# error (w h)^5 / 120 is 2.6e-4 of the state at 0.5, the low-pass a fraction of the torque.
MAX_OMEGA_H_LOWPASS = 0.5


class KernelSlot(NamedTuple):
    """One number of the kernels' parameter vector.

    Attributes
    ----------
    name : the index's name without its prefix (`P_<name>`, `C_<name>` in the constants).
    term : the effect-table kernel term written here (`flaair_model.effects`), or None.
    chain : for a per-sensor-chain term, its chain (0 stroke, 1 pitch); None: plant-wide.
    constant : how the RK4 constants tuple carries it: "" not at all, "as_is", or divided by
        the inertia of its equation ("over_stroke_inertia", "over_pitch_inertia").
    """

    name: str
    term: str | None
    chain: int | None
    constant: Literal["", "as_is", "over_stroke_inertia", "over_pitch_inertia"]


_S: Literal["over_stroke_inertia"] = "over_stroke_inertia"
_P: Literal["over_pitch_inertia"] = "over_pitch_inertia"
# The vector, in order; the discovered dynamics terms' slots follow it (from P_TERMS on).
KERNEL_LAYOUT: tuple[KernelSlot, ...] = (
    KernelSlot("I", "inertia_factor", None, ""),  # stroke inertia, kg m^2
    KernelSlot("GAMMA", None, None, _S),  # aerodynamic damping, N m s^2
    KernelSlot("K", None, None, _S),  # stroke stiffness, N m/rad
    KernelSlot("GA", None, None, _S),  # actuator gain, N m/V
    KernelSlot("IP", "inertia_factor", None, ""),  # pitch inertia, kg m^2
    KernelSlot("CP", None, None, _P),  # hinge damping, N m s/rad
    KernelSlot("KH", None, None, _P),  # hinge stiffness, N m/rad
    KernelSlot("JC", None, None, _P),  # inertial coupling, kg m^2
    KernelSlot("DP", None, None, _P),  # aerodynamic coupling, N m s^2
    KernelSlot("CSTRUCT", "structural_damping_nm_s_per_rad", None, _S),
    KernelSlot("HCUBIC", "hinge_cubic_per_rad2", None, "as_is"),
    KernelSlot("CONTACT_ON", "contact_on", None, ""),
    KernelSlot("PHI_LIM", "stroke_limit_rad", None, "as_is"),
    KernelSlot("KC", "contact_stiffness_nm_per_rad", None, _S),
    KernelSlot("CC", "contact_damping_nm_s_per_rad", None, _S),
    KernelSlot("GS", "gain_factor", 0, ""),  # stroke sensor, V/rad
    KernelSlot("GP", "gain_factor", 1, ""),  # pitch sensor, V/rad
    KernelSlot("TCUBIC", "transmission_cubic_per_rad2", None, ""),
    KernelSlot("FT", "feedthrough_v_per_v", None, ""),
    KernelSlot("HYST_FRAC", "hysteresis_fraction", None, ""),  # actuator hysteresis: 0 off
    KernelSlot("HYST_SAT", "hysteresis_saturation_v", None, ""),  # its saturation, V
    KernelSlot("VREF", None, None, ""),  # charge amplifiers' reference, V
    KernelSlot("HPS_ON", None, None, ""),  # stroke chain's high-pass on (1.0)
    KernelSlot("HPS_B0", "highpass_b0", 0, ""),
    KernelSlot("HPS_B1", "highpass_b1", 0, ""),
    KernelSlot("HPS_A1", "highpass_a1", 0, ""),
    KernelSlot("HPP_ON", None, None, ""),  # pitch chain's high-pass on (1.0)
    KernelSlot("HPP_B0", "highpass_b0", 1, ""),
    KernelSlot("HPP_B1", "highpass_b1", 1, ""),
    KernelSlot("HPP_A1", "highpass_a1", 1, ""),
    KernelSlot("DS_FRAC", "delay_samples", 0, ""),  # fractional part of the stroke delay
    KernelSlot("DP_FRAC", "delay_samples", 1, ""),
    KernelSlot("NTERMS", None, None, ""),  # number of discovered dynamics terms (last row)
)
_INDEX = {slot.name: i for i, slot in enumerate(KERNEL_LAYOUT)}


def _at(names: str, index: dict[str, int]) -> tuple[int, ...]:
    """The places of the space-separated `names` (a name the table lacks is a KeyError)."""
    return tuple(index[name] for name in names.split())


P_I, P_GAMMA, P_K, P_GA, P_IP, P_CP, P_KH, P_JC, P_DP = _at("I GAMMA K GA IP CP KH JC DP", _INDEX)
P_CSTRUCT, P_HCUBIC, P_CONTACT_ON, P_PHI_LIM, P_KC, P_CC = _at(
    "CSTRUCT HCUBIC CONTACT_ON PHI_LIM KC CC", _INDEX
)
P_GS, P_GP, P_TCUBIC, P_FT, P_VREF = _at("GS GP TCUBIC FT VREF", _INDEX)
P_HYST_FRAC, P_HYST_SAT = _at("HYST_FRAC HYST_SAT", _INDEX)
P_HPS_ON, P_HPS_B0, P_HPS_B1, P_HPS_A1 = _at("HPS_ON HPS_B0 HPS_B1 HPS_A1", _INDEX)
P_HPP_ON, P_HPP_B0, P_HPP_B1, P_HPP_A1 = _at("HPP_ON HPP_B0 HPP_B1 HPP_A1", _INDEX)
(P_DS_FRAC, P_DP_FRAC, P_NTERMS) = _at("DS_FRAC DP_FRAC NTERMS", _INDEX)
GA_INDEX, CONTACT_ON_INDEX = P_GA, P_CONTACT_ON  # the names batch engines read
# Each dynamics slot of the discovered terms: [equation (1 stroke, 2 pitch; 0 empty),
# coefficient / inertia, the monomial's exponents over flaair_model.terms.PRIMITIVES, the
# low-pass's corner in rad/s (a `lowpass(x)` form: its monomial filtered; 0: the monomial)].
P_TERMS = len(KERNEL_LAYOUT)
TERM_SLOT = 3 + len(PRIMITIVES)
TERM_LOWPASS = TERM_SLOT - 1  # the corner's place in a slot
# A monomial has at most this many factors (primitives with a nonzero power): a canonical form
# writes each of its states as one primitive or two (phi*abs(phi)), over at most three states.
MAX_FACTORS = (TERM_SLOT - 3) // 2
# ... and each factor at most this power (a canonical form's total degree is at most three).
MAX_POWER = 7
N_KERNEL_PARAMS = P_TERMS + MAX_DYNAMICS_TERMS * TERM_SLOT
# The state the kernel holds between samples besides the mechanics: [the actuator's hysteretic
# voltage, the last drive sample, each low-pass term slot's filter state].
HELD_LOWPASS = 2
HELD_LEN = HELD_LOWPASS + MAX_DYNAMICS_TERMS

# The RK4 kernel's constants tuple `c`: the slots with a `constant`, in layout order, each
# p[CONSTANT_SOURCE[j]] times (1, 1 / stroke inertia, 1 / pitch inertia)[CONSTANT_DIVISOR[j]].
_CONSTANTS = tuple(i for i, slot in enumerate(KERNEL_LAYOUT) if slot.constant)
CONSTANT_SOURCE: tuple[int, ...] = _CONSTANTS
CONSTANT_DIVISOR: tuple[int, ...] = tuple(
    ("as_is", _S, _P).index(KERNEL_LAYOUT[i].constant) for i in _CONSTANTS
)
N_CONSTANTS = len(_CONSTANTS)
_C_INDEX = {KERNEL_LAYOUT[i].name: j for j, i in enumerate(_CONSTANTS)}
C_GAMMA, C_K, C_GA, C_CP, C_KH, C_JC, C_DP = _at("GAMMA K GA CP KH JC DP", _C_INDEX)
C_CSTRUCT, C_HCUBIC, C_PHI_LIM, C_KC, C_CC = _at("CSTRUCT HCUBIC PHI_LIM KC CC", _C_INDEX)
# A model with discovered dynamics terms gets the longer tuple: the constants, then each term
# slot as a tuple of its fields (`term_kernel.SLOT_FIELDS`), at c[C_TERM_SLOTS[slot]].
C_TERM_SLOTS = tuple(N_CONSTANTS + slot for slot in range(MAX_DYNAMICS_TERMS))
N_CONSTANTS_WITH_TERMS = N_CONSTANTS + MAX_DYNAMICS_TERMS


def _check_layout() -> None:
    """The table covers the effect table's kernel terms and ends on the term count."""
    if len(_C_INDEX) != N_CONSTANTS or len(_INDEX) != P_TERMS or P_NTERMS != P_TERMS - 1:
        raise ImportError("KERNEL_LAYOUT: names must be unique and NTERMS its last row")
    named = {slot.term for slot in KERNEL_LAYOUT if slot.term is not None}
    if named != set(PLANT_TERMS + SCALE_TERMS + SENSOR_TERMS):
        raise ImportError(
            "KERNEL_LAYOUT and the effect table's kernel terms differ: "
            f"{sorted(named ^ set(PLANT_TERMS + SCALE_TERMS + SENSOR_TERMS))}"
        )


_check_layout()


class Prepared(NamedTuple):
    """A model as the kernel runs it at one sample rate (`prepare`).

    ``delay_lengths``: each sensor's delay line (its whole samples, + 1 with a fractional
    part), kept beside the rest: a block loop reads it every block.
    """

    params: np.ndarray
    n_substeps: int
    n_substeps_contact: int
    delay_stroke_samples: int
    delay_pitch_samples: int
    delay_lengths: tuple[int, int]


def _split_delay(delay_samples: float) -> tuple[int, float]:
    whole = math.floor(delay_samples + 1e-9)  # tolerate 10/fs * fs = 9.999999999
    frac = delay_samples - whole
    return whole, (0.0 if frac < 1e-9 else frac)


# Where each kernel term of the effect table (flaair_model.effects) lands in the vector.
_PLANT_INDEX = {s.term: i for i, s in enumerate(KERNEL_LAYOUT) if s.term in PLANT_TERMS}
_SCALE_INDEX = {
    term: tuple(i for i, s in enumerate(KERNEL_LAYOUT) if s.term == term) for term in SCALE_TERMS
}
_SENSOR_INDEX = {  # per chain: (stroke, pitch)
    term: tuple(
        next(i for i, s in enumerate(KERNEL_LAYOUT) if s.term == term and s.chain == chain)
        for chain in (0, 1)
    )
    for term in SENSOR_TERMS
}
_HIGHPASS_ON = (P_HPS_ON, P_HPP_ON)
_DELAY_FRACTION = _SENSOR_INDEX.pop("delay_samples")


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
    p[P_GA] = pl.actuator_gain_nm_per_v
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

    _write_dynamics_terms(p, model)

    rates = [
        math.sqrt(stiffness / p[P_I]),
        math.sqrt(hinge_stiffness / p[P_IP]),
        p[P_CP] / p[P_IP],
        p[P_CSTRUCT] / p[P_I],
        *(
            p[P_TERMS + slot * TERM_SLOT + TERM_LOWPASS] * MAX_OMEGA_H / MAX_OMEGA_H_LOWPASS
            for slot in range(MAX_DYNAMICS_TERMS)
        ),
    ]
    substeps = max(1, math.ceil(max(rates) / fs_hz / MAX_OMEGA_H))
    substeps_contact = substeps
    if p[P_CONTACT_ON] > 0:
        rates += [math.sqrt((stiffness + p[P_KC]) / p[P_I]), p[P_CC] / p[P_I]]
        substeps_contact = max(1, math.ceil(max(rates) / fs_hz / MAX_OMEGA_H_CONTACT))
    p.setflags(write=False)
    lengths = (
        delay_int[0] + (1 if p[P_DS_FRAC] > 0 else 0),
        delay_int[1] + (1 if p[P_DP_FRAC] > 0 else 0),
    )
    return Prepared(p, substeps, substeps_contact, delay_int[0], delay_int[1], lengths)


def _write_dynamics_terms(p: np.ndarray, model: Model) -> None:
    """The model's discovered dynamics terms into their slots of `p` (`TERM_SLOT`)."""
    dynamics = [t for t in model.discovered if t.is_dynamics]
    p[P_NTERMS] = len(dynamics)
    for slot, dterm in enumerate(dynamics):
        base = P_TERMS + slot * TERM_SLOT
        stroke = dterm.acts_on == "stroke_dynamics"
        p[base] = 1.0 if stroke else 2.0
        p[base + 1] = dterm.coefficient / (p[P_I] if stroke else p[P_IP])
        if sum(1 for e in dterm.monomial if e) > MAX_FACTORS:  # no canonical form has more
            raise ModelError(
                f"discovered.{dterm.kind}: a monomial of more than {MAX_FACTORS} factors"
            )
        if max(dterm.monomial) > MAX_POWER:
            raise ModelError(f"discovered.{dterm.kind}: a factor to a power over {MAX_POWER}")
        p[base + 2 : base + TERM_LOWPASS] = dterm.monomial
        if dterm.is_filtered:  # a continuous first order, integrated with the mechanics
            p[base + TERM_LOWPASS] = 2.0 * math.pi * dict(dterm.shape)["corner_hz"]


# The rate `coefficients` prepares at: only the sensor delays' slots (in samples) depend on it.
_COEFFICIENTS_RATE_HZ = 20000.0


def coefficients(model: Model) -> np.ndarray:
    """The model's resolved parameter vector for a reader with no sample rate: its nominal
    values with every effect and discovered term applied (P_I with a wing's damage, P_GS with
    a film's strain transfer, P_CONTACT_ON with a stop), read by index, never by effect name.
    The sensor delays' slots (in samples) are at 20 kHz.
    """
    return prepare(model, _COEFFICIENTS_RATE_HZ).params
