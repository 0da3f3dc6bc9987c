"""The randomized off-nominal robot generator for the discrepancy workflow's benchmark and tests.

Every robot's plant is off nominal (natural frequencies within +-3 %, damping, gain and couplings
within +-15 %: a fabrication spread), its noise 1-2x the model's, its truth at the DAQ rate or at
a 2 kHz video rate. A family says what the robot hides (`FAMILIES`); `random_robot` draws one
deterministically, `random_effect` one effect at a random strength from the effect table's draw
ranges, `DISCOVER_KINDS` the physics outside the vocabulary that a library term expresses;
`true_plant` and `effective_plant` are what the identification must find. The runs of a robot
are `datasets.make_runs`'.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from flaair_model.effects import EFFECTS, ENTRIES
from flaair_model.model import Model
from flaair_model.model_io import load_model
from flaair_model.terms import DiscoveredTerm

from .case import DatasetCase
from .datasets import true_model
from .vocabulary import PLANT_PARAMETERS

__all__ = [
    "COEFFICIENT_SPREAD",
    "COMPOSED_DISCOVER_KINDS",
    "DISCOVER_KINDS",
    "EFFECT_NAMES_ORDER",
    "FAMILIES",
    "FREQUENCY_SPREAD",
    "OWN_FAMILY_EFFECTS",
    "DiscoverKind",
    "effective_plant",
    "random_effect",
    "random_robot",
    "true_plant",
]

FAMILIES = (
    "offnominal_null",
    "offnominal_single",
    "offnominal_pair",
    "offnominal_outside",
    "offnominal_discover",
    "offnominal_own",
)


@dataclass(frozen=True)
class DiscoverKind:
    """Physics outside the vocabulary (and outside `OUTSIDE_KINDS`) that a library term expresses.

    The coefficient is drawn as sign x uniform(low, high) x the reference (`scale`: the nominal
    stroke stiffness 'K', hinge stiffness 'k_h', or 1); a shape parameter uniform in its range.
    """

    name: str
    kind: str
    acts_on: str
    low: float
    high: float
    sign: float  # +1 or -1; 0: a random sign
    scale: str
    shape: tuple[Any, ...] = ()  # ((key, low, high), ...)
    note: str = ""

    def draw(self, rng: np.random.Generator, model: Model) -> DiscoveredTerm:
        """One robot's term."""
        ref = {
            "K": model.plant.stroke_stiffness_nm_per_rad,
            "k_h": model.plant.hinge_stiffness_nm_per_rad,
            "1": 1.0,
        }[self.scale]
        sign = self.sign or float(rng.choice([-1.0, 1.0]))
        value = sign * float(rng.uniform(self.low, self.high)) * ref
        shape = tuple((k, float(rng.uniform(lo, hi))) for k, lo, hi in self.shape)
        return DiscoveredTerm(self.kind, self.acts_on, value, shape)


DISCOVER_KINDS: tuple[DiscoverKind, ...] = (
    DiscoverKind(
        "flexure_friction",
        "sign_velocity",
        "stroke_dynamics",
        0.015,
        0.04,
        -1.0,
        "K",
        note="dry friction in the stroke flexure: K x 0.015-0.04 rad",
    ),
    DiscoverKind(
        "flexure_stiffening",
        "cube_angle",
        "stroke_dynamics",
        0.3,
        0.8,
        -1.0,
        "K",
        note="a flexure stiffening with the cube of the stroke",
    ),
    DiscoverKind(
        "amplifier_bandwidth",
        "drive_lag",
        "drive",
        1.0,
        1.0,
        1.0,
        "1",
        (("corner_hz", 350.0, 900.0),),
        note="a drive amplifier with a finite bandwidth",
    ),
    DiscoverKind(
        "film_drive_leak",
        "drive_leak",
        "pitch_sensor_v",
        1e-4,
        4e-4,
        0.0,
        "1",
        note="the drive leaking into the hinge film",
    ),
    DiscoverKind(
        "sensor_crosstalk",
        "crosstalk",
        "pitch_sensor_v",
        0.01,
        0.04,
        0.0,
        "1",
        note="the stroke charge amplifier's output crossing into the pitch one",
    ),
    DiscoverKind(
        "hinge_friction",
        "sign_velocity",
        "pitch_dynamics",
        0.01,
        0.03,
        -1.0,
        "k_h",
        note="dry friction in the wing hinge: k_h x 0.01-0.03 rad",
    ),
    # composed forms: products of primitives that no row of the term library lists
    DiscoverKind(
        "stroke_position_drag",
        "phi*abs(dphi)",
        "stroke_dynamics",
        2e-4,
        5e-4,
        -1.0,
        "K",
        note="a stroke flexure whose stiffness grows with the rate: K x 2-5e-4 s/rad x |dphi|",
    ),
    DiscoverKind(
        "hinge_stroke_friction",
        "psi*sign(dphi)",
        "pitch_dynamics",
        0.05,
        0.15,
        -1.0,
        "k_h",
        note="a hinge stiffness switching with the stroke's direction: k_h x 5-15 %",
    ),
    DiscoverKind(
        "hinge_quadratic_drag",
        "dpsi*abs(dpsi)",
        "pitch_dynamics",
        3.5e-7,
        9.5e-7,
        -1.0,
        "k_h",
        note="quadratic air drag on the wing's own pitch rate: k_h x 3.5-9.5e-7 s^2",
    ),
)
# The kinds whose form is composed from the primitives (no row of the library lists it).
COMPOSED_DISCOVER_KINDS = tuple(k.name for k in DISCOVER_KINDS if "*" in k.kind)
# Fabrication spread of the plant: natural frequencies within +-3 %, damping, gain and
# couplings within +-15 % of nominal.
FREQUENCY_SPREAD = 0.03
COEFFICIENT_SPREAD = 0.15
_FREQUENCIES = ("stroke_natural_frequency_hz", "pitch_natural_frequency_hz")
_COEFFICIENTS = (
    "aero_damping_nm_s2",
    "actuator_gain_nm_per_v",
    "hinge_damping_nm_s_per_rad",
    "inertial_coupling_kg_m2",
    "aero_coupling_nm_s2",
)
_SEPARABLE = tuple(e.name for e in EFFECTS if e.separable and not e.own_family)
# Effects drawn in a family of their own (`offnominal_own`), in table order.
OWN_FAMILY_EFFECTS = tuple(e.name for e in EFFECTS if e.own_family)


def random_effect(name: str, rng: np.random.Generator) -> dict[str, Any]:
    """One effect at a random strength, from its draw ranges in the effect table (inside the range
    the run set can resolve).
    """
    entry = ENTRIES[name]
    side = str(rng.choice(["stroke", "pitch", "both"]))
    sign = float(rng.choice([-1.0, 1.0]))
    params: dict[str, Any] = {}
    for r in entry.draw:
        value = (
            float(np.exp(rng.uniform(np.log(r.low), np.log(r.high))))
            if r.log
            else float(rng.uniform(r.low, r.high))
        )
        params[r.key] = sign * value if r.signed else value
    if entry.per_sensor:
        params["channel"] = side
    return params


def random_robot(family: str, draw: int) -> DatasetCase:
    """Draw `draw` of a family of off-nominal robots (deterministic in family and draw).

    Every robot's plant is off nominal (natural frequencies within +-3 %, damping, gain and
    couplings within +-15 %), its noise 1-2x the model's, its truth at the DAQ rate or at a
    2 kHz video rate (NaN between frames). Families: ``offnominal_null`` (no effect),
    ``offnominal_single`` (each vocabulary effect in turn, random strength; wing_damage is hidden,
    since a plant change reproduces it), ``offnominal_pair`` (two separable effects),
    ``offnominal_outside`` (physics outside the vocabulary: a drifting pitch-sensor gain or a
    second stroke resonance), ``offnominal_discover`` (physics outside the vocabulary that the
    term library expresses: each of `DISCOVER_KINDS` in turn, random strength),
    ``offnominal_own`` (each effect drawn in a family of its own, `OWN_FAMILY_EFFECTS`, in
    turn: the actuator's hysteresis).
    """
    if family not in FAMILIES:
        raise KeyError(f"unknown family {family!r} (known: {', '.join(FAMILIES)})")
    rng = np.random.default_rng([FAMILIES.index(family), draw])
    scale = tuple(
        (k, float(1.0 + rng.uniform(-FREQUENCY_SPREAD, FREQUENCY_SPREAD))) for k in _FREQUENCIES
    ) + tuple(
        (k, float(1.0 + rng.uniform(-COEFFICIENT_SPREAD, COEFFICIENT_SPREAD)))
        for k in _COEFFICIENTS
    )
    noise = float(rng.uniform(1.0, 2.0))
    video = int(rng.choice([1, 10]))
    effects: tuple[Any, ...] = ()
    hidden: tuple[Any, ...] = ()
    terms: tuple[Any, ...] = ()
    outside, strength = "", 0.0
    names = list(EFFECT_NAMES_ORDER)
    if family == "offnominal_single":
        name = names[draw % len(names)]
        pair = (name, random_effect(name, rng))
        hidden, effects = ((pair,), ()) if name == "wing_damage" else ((), (pair,))
    elif family == "offnominal_own":
        name = OWN_FAMILY_EFFECTS[draw % len(OWN_FAMILY_EFFECTS)]
        effects = ((name, random_effect(name, rng)),)
    elif family == "offnominal_pair":
        a, b = rng.choice(len(_SEPARABLE), size=2, replace=False)
        effects = tuple((n, random_effect(n, rng)) for n in (_SEPARABLE[a], _SEPARABLE[b]))
    elif family == "offnominal_discover":
        terms = (DISCOVER_KINDS[draw % len(DISCOVER_KINDS)].draw(rng, _nominal()),)
    elif family == "offnominal_outside":
        outside = ("sensor_gain_drift", "second_resonance")[draw % 2]
        strength = float(
            rng.uniform(0.2, 0.4) if outside == "sensor_gain_drift" else rng.uniform(0.1, 0.2)
        )
    group = {
        "offnominal_null": "null",
        "offnominal_single": "single",
        "offnominal_pair": "pair",
        "offnominal_outside": "outside",
        "offnominal_discover": "discover",
        "offnominal_own": "single",
    }[family]
    return DatasetCase(
        f"{family}_{draw:03d}",
        group,
        effects,
        outside,
        strength,
        noise,
        seed=1000 * (1 + FAMILIES.index(family)) + draw,
        plant_scale=scale,
        hidden=hidden,
        video_every=video,
        terms=terms,
    )


def _nominal() -> Model:
    return load_model()


EFFECT_NAMES_ORDER = (*_SEPARABLE, "wing_damage")


def true_plant(case: DatasetCase, model: Model) -> dict[str, Any]:
    """{plant key: true value} of the case's robot."""
    return {k: float(getattr(true_model(case, model).plant, k)) for k, _ in case.plant_scale}


def effective_plant(case: DatasetCase, model: Model) -> dict[str, Any]:
    """{fitted plant key: value} the identification must find for the case's robot.

    The true plant, with a hidden wing_damage (inertias x f) folded in: dividing both equations of
    motion by f, the natural frequencies become f_n / sqrt(f) and the damping, gain and coupling
    coefficients c / f, at the model's inertias.
    """
    plant = true_model(case, model).plant
    damage = float(dict(case.hidden).get("wing_damage", {}).get("inertia_factor", 1.0))
    return {
        k: float(getattr(plant, k))
        / (math.sqrt(damage) if k.endswith("_natural_frequency_hz") else damage)
        for k in PLANT_PARAMETERS
    }
