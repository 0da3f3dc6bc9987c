"""Model parameters: nominal plant, sensors, noise, and the effects a robot carries.

Frozen dataclasses, SI units, validated on construction (numpy only, no file I/O: see
`model_io`). The numbers live in `config/model.yaml`; this module holds none of them. The
effects themselves (their parameters, kernel terms, channels, fit and draw ranges) are
declared once in `flaair_model.effects`; this module builds and combines them in a `Model`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields, is_dataclass, replace
from typing import Any, cast

from flaair_model.effects import (
    EFFECT_NAMES,
    EFFECT_TYPES,
    PER_CHANNEL_EFFECTS,
    Effect,
    SensorEffect,
)
from flaair_model.pvdf import PvdfMaterial, SensorBeam, pitch_volts_per_rad, stroke_volts_per_rad
from flaair_model.term_entry import term_from_dict
from flaair_model.terms import MAX_DYNAMICS_TERMS, DiscoveredTerm
from flaair_model.validation import SIDES, ModelError, check_fields, check_number

__all__ = [
    "Model",
    "NoiseParams",
    "PerChannel",
    "PlantParams",
    "SensorParams",
    "effect_from_params",
    "effect_params",
    "with_effect_on",
    "with_effects",
    "without_effect_on",
    "without_effects",
]


# --------------------------------------------------------------------------- nominal model


@dataclass(frozen=True)
class PlantParams:
    """Stroke and passive-pitch dynamics (shared/model-spec.md, section Dynamics)."""

    stroke_inertia_kg_m2: float
    stroke_natural_frequency_hz: float
    aero_damping_nm_s2: float
    actuator_gain_nm_per_v: float
    pitch_inertia_kg_m2: float
    pitch_natural_frequency_hz: float
    hinge_damping_nm_s_per_rad: float
    inertial_coupling_kg_m2: float
    aero_coupling_nm_s2: float
    transmission_ratio_rad_per_m: float

    def __post_init__(self) -> None:
        check_fields(
            self,
            "plant",
            {
                "stroke_inertia_kg_m2": "pos",
                "stroke_natural_frequency_hz": "pos",
                "aero_damping_nm_s2": "nonneg",
                "actuator_gain_nm_per_v": "nonzero",
                "pitch_inertia_kg_m2": "pos",
                "pitch_natural_frequency_hz": "pos",
                "hinge_damping_nm_s_per_rad": "nonneg",
                "inertial_coupling_kg_m2": "finite",
                "aero_coupling_nm_s2": "finite",
                "transmission_ratio_rad_per_m": "pos",
            },
        )

    @property
    def stroke_stiffness_nm_per_rad(self) -> float:
        """K = I (2 pi f_stroke)^2."""
        return self.stroke_inertia_kg_m2 * (2.0 * math.pi * self.stroke_natural_frequency_hz) ** 2

    @property
    def hinge_stiffness_nm_per_rad(self) -> float:
        """k_h = I_p (2 pi f_pitch)^2."""
        return self.pitch_inertia_kg_m2 * (2.0 * math.pi * self.pitch_natural_frequency_hz) ** 2


_MATERIAL_RULES = {f.name: "pos" for f in fields(PvdfMaterial)}
_BEAM_RULES = {f.name: "pos" for f in fields(SensorBeam)}


@dataclass(frozen=True)
class SensorParams:
    """Charge-amplifier reference and the two PVDF beams (paper Table 1)."""

    reference_voltage_v: float
    pvdf: PvdfMaterial
    stroke: SensorBeam
    pitch: SensorBeam

    def __post_init__(self) -> None:
        check_fields(self, "sensors", {"reference_voltage_v": "finite"})
        sections: tuple[tuple[str, Any, Any, Any], ...] = (
            ("pvdf", self.pvdf, PvdfMaterial, _MATERIAL_RULES),
            ("stroke", self.stroke, SensorBeam, _BEAM_RULES),
            ("pitch", self.pitch, SensorBeam, _BEAM_RULES),
        )
        for section, obj, kind, rules in sections:
            if not isinstance(obj, kind):
                raise ModelError(
                    f"sensors.{section} must be a {kind.__name__}, got {type(obj).__name__}"
                )
            # PvdfMaterial/SensorBeam are frozen dataclasses owned by pvdf.py: check, don't coerce
            values = {
                name: check_number(f"sensors.{section}.{name}", getattr(obj, name))
                for name in rules
            }
            for name, value in values.items():
                if not value > 0:
                    raise ModelError(f"sensors.{section}.{name} must be > 0, got {value:g}")
            object.__setattr__(self, section, replace(obj, **values))

    def stroke_volts_per_rad(self, transmission_ratio_rad_per_m: float) -> float:
        """Signed actuator-sensor output per radian of stroke (needs T_r from the plant).

        Use `Model.stroke_volts_per_rad` when a whole model is at hand.
        """
        return stroke_volts_per_rad(self.pvdf, self.stroke, transmission_ratio_rad_per_m)

    def pitch_volts_per_rad(self) -> float:
        """Signed hinge-sensor output per radian of pitch.

        Use `Model.pitch_volts_per_rad` when a whole model is at hand.
        """
        return pitch_volts_per_rad(self.pvdf, self.pitch)


@dataclass(frozen=True)
class NoiseParams:
    """Noise added only on request (synthetic measured data)."""

    sensor_noise_v_rms: float
    tracking_noise_deg_rms: float

    def __post_init__(self) -> None:
        check_fields(
            self, "noise", {"sensor_noise_v_rms": "nonneg", "tracking_noise_deg_rms": "nonneg"}
        )


@dataclass(frozen=True)
class PerChannel:
    """One sensor effect with its own value on each sensor chain.

    `stroke` and `pitch` are effects of one `PER_CHANNEL_EFFECTS` type whose `channel` is
    'stroke' and 'pitch'. In config/model.yaml::

        sensor_delay:
          stroke: {delay_s: 1.5e-4}
          pitch: {delay_s: 4.0e-4}
    """

    stroke: SensorEffect
    pitch: SensorEffect

    def __post_init__(self) -> None:
        kind = type(self.stroke)
        name = next((n for n, k in EFFECT_TYPES.items() if k is kind), "")
        if name not in PER_CHANNEL_EFFECTS:
            raise ModelError(
                "effects: per-channel values exist only for "
                f"{', '.join(PER_CHANNEL_EFFECTS)}, got {kind.__name__}"
            )
        for side in SIDES:
            e: Any = getattr(self, side)
            if type(e) is not kind:
                raise ModelError(
                    f"effects.{name}.{side} must be a {kind.__name__}, got {type(e).__name__}"
                )
            if e.channel != side:
                raise ModelError(
                    f"effects.{name}.{side}.channel must be {side!r}, got {e.channel!r}"
                )

    def on(self, side: str) -> SensorEffect:
        """The effect on sensor chain `side`."""
        effect: SensorEffect = getattr(self, side)
        return effect


def _per_channel_from_params(name: str, params: Mapping[str, Any]) -> Effect | PerChannel:
    """{stroke: {...}, pitch: {...}} -> PerChannel (one side only: that side's effect)."""
    built: dict[str, Any] = {}
    for side, sub in params.items():
        if is_dataclass(sub) and not isinstance(sub, type):
            built[side] = effect_from_params(name, sub)
            continue
        if not isinstance(sub, Mapping):
            raise ModelError(
                f"effects.{name}.{side} must be a mapping of parameters, got {type(sub).__name__}"
            )
        if sub.get("channel", side) != side:
            raise ModelError(
                f"effects.{name}.{side}.channel must be {side!r}, got {sub['channel']!r}"
            )
        built[side] = effect_from_params(name, {**sub, "channel": side})
    if set(built) == set(SIDES):
        return PerChannel(built["stroke"], built["pitch"])
    only: Effect | PerChannel = next(iter(built.values()))
    return only


def effect_from_params(name: str, params: Any) -> Effect | PerChannel:
    """Build (and validate) one effect from its name and a parameter dict or dataclass (or None).

    A sensor effect (`PER_CHANNEL_EFFECTS`) may give each chain its own parameters:
    ``{"stroke": {...}, "pitch": {...}}`` (or a `PerChannel`).

    Raises
    ------
    ModelError
        Unknown effect name, unknown or missing parameter, bad value.
    """
    if name not in EFFECT_TYPES:
        raise ModelError(f"effects: unknown effect {name!r} (known: {', '.join(EFFECT_NAMES)})")
    kind = EFFECT_TYPES[name]
    if isinstance(params, PerChannel):
        if not isinstance(params.stroke, kind):
            raise ModelError(
                f"effects.{name} must hold {kind.__name__} entries, got "
                f"{type(params.stroke).__name__}"
            )
        return params
    if is_dataclass(params) and not isinstance(params, type):
        if not isinstance(params, kind):
            raise ModelError(
                f"effects.{name} must be a {kind.__name__}, got {type(params).__name__}"
            )
        return cast(Effect, params)
    if params is None:
        params = {}
    if not isinstance(params, Mapping):
        raise ModelError(
            f"effects.{name} must be a mapping of parameters, got {type(params).__name__}"
        )
    if name in PER_CHANNEL_EFFECTS and params and set(params) <= set(SIDES):
        return _per_channel_from_params(name, params)
    known = {f.name for f in fields(kind)}
    unknown = sorted(set(params) - known)
    if unknown:
        side_hint = (
            " or per channel {stroke: {...}, pitch: {...}}" if name in PER_CHANNEL_EFFECTS else ""
        )
        raise ModelError(
            f"effects.{name}: unknown parameter(s) {', '.join(map(str, unknown))} "
            f"(known: {', '.join(sorted(known))}{side_hint})"
        )
    try:
        effect: Effect = kind(**params)
        return effect
    except TypeError as exc:
        required = [f.name for f in fields(kind) if f.name not in params]
        raise ModelError(f"effects.{name}: missing parameter(s) {', '.join(required)}") from exc


def effect_params(effect: Effect | PerChannel) -> dict[str, Any]:
    """The parameter dict of an effect as config/model.yaml
    writes it (per channel: {stroke, pitch}).
    """
    if isinstance(effect, PerChannel):
        return {
            side: {
                f.name: getattr(effect.on(side), f.name)
                for f in fields(effect.on(side))
                if f.name != "channel"
            }
            for side in SIDES
        }
    return {f.name: getattr(effect, f.name) for f in fields(effect)}


# --------------------------------------------------------------------------- model


@dataclass(frozen=True)
class Model:
    """Whole model: nominal plant, sensors, noise and the effects that are on.

    `effects` is a tuple of (name, effect) pairs, stored in `EFFECT_NAMES` order so that two
    models with the same effects compare equal. A mapping is accepted and converted.
    """

    plant: PlantParams
    sensors: SensorParams
    noise: NoiseParams
    effects: tuple[tuple[str, Effect | PerChannel], ...] = ()
    discovered: tuple[DiscoveredTerm, ...] = ()

    def __post_init__(self) -> None:
        for section, kind in (
            ("plant", PlantParams),
            ("sensors", SensorParams),
            ("noise", NoiseParams),
        ):
            if not isinstance(getattr(self, section), kind):
                raise ModelError(
                    f"{section} must be a {kind.__name__}, got "
                    f"{type(getattr(self, section)).__name__}"
                )
        raw = self.effects
        if isinstance(raw, Mapping):
            pairs = list(raw.items())
        else:
            pairs = []
            for item in raw:
                if not (isinstance(item, tuple) and len(item) == 2):
                    raise ModelError(f"effects must be (name, effect) pairs, got {item!r}")
                pairs.append(item)
        built: dict[str, Effect | PerChannel] = {}
        for name, params in pairs:
            if name in built:
                raise ModelError(f"effects.{name} given twice")
            built[name] = effect_from_params(name, params)
        object.__setattr__(
            self, "effects", tuple((n, built[n]) for n in EFFECT_NAMES if n in built)
        )
        terms = tuple(
            t if isinstance(t, DiscoveredTerm) else term_from_dict(t, f"discovered[{i}]")
            for i, t in enumerate(self.discovered)
        )
        places = [(t.kind, t.acts_on) for t in terms]
        if len(set(places)) < len(places):
            raise ModelError("discovered: a term is given twice on the same site")
        if sum(t.is_dynamics for t in terms) > MAX_DYNAMICS_TERMS:
            raise ModelError(
                f"discovered: at most {MAX_DYNAMICS_TERMS} terms may act on the dynamics"
            )
        object.__setattr__(self, "discovered", terms)

    def effect(self, name: str) -> Effect | PerChannel | None:
        """The effect called `name` if it is on, else None (unknown names raise ModelError).

        A sensor effect with its own value per chain is
        a `PerChannel`; `effect_on` gives one chain's.
        """
        if name not in EFFECT_TYPES:
            raise ModelError(f"effects: unknown effect {name!r} (known: {', '.join(EFFECT_NAMES)})")
        for n, e in self.effects:
            if n == name:
                return e
        return None

    def effect_on(self, name: str, side: str) -> Effect | None:
        """The effect called `name` as it acts on sensor
        chain `side` ('stroke' or 'pitch'), else None.

        A sensor effect on the other chain only is None; an effect without a `channel` parameter
        is returned as it is.
        """
        if side not in SIDES:
            raise ModelError(f"sensor chain must be one of {', '.join(SIDES)}, got {side!r}")
        e = self.effect(name)
        if isinstance(e, PerChannel):
            return e.on(side)
        if e is not None and getattr(e, "channel", side) not in (side, "both"):
            return None
        return e

    @property
    def effect_names(self) -> tuple[str, ...]:
        """Names of the effects that are on."""
        return tuple(n for n, _ in self.effects)

    @property
    def stroke_volts_per_rad(self) -> float:
        """Nominal signed stroke-sensor gain dV_s/dphi (effects not included)."""
        return self.sensors.stroke_volts_per_rad(self.plant.transmission_ratio_rad_per_m)

    @property
    def pitch_volts_per_rad(self) -> float:
        """Nominal signed pitch-sensor gain dV_p/dpsi (effects not included)."""
        return self.sensors.pitch_volts_per_rad()

    @property
    def stroke_gain_deg_per_v(self) -> float:
        """Nominal stroke gain as a positive magnitude in deg/V (paper convention)."""
        return math.degrees(1.0 / abs(self.stroke_volts_per_rad))

    @property
    def pitch_gain_deg_per_v(self) -> float:
        """Nominal pitch gain as a positive magnitude in deg/V (paper convention)."""
        return math.degrees(1.0 / abs(self.pitch_volts_per_rad))

    @property
    def stroke_polarity(self) -> int:
        """Sign of the stroke gain: angle = polarity * gain * (V - V_HREF)."""
        return 1 if self.stroke_volts_per_rad > 0 else -1

    @property
    def pitch_polarity(self) -> int:
        """Sign of the pitch gain: angle = polarity * gain * (V - V_HREF)."""
        return 1 if self.pitch_volts_per_rad > 0 else -1


def with_effects(
    model: Model, effects: Mapping[str, Mapping[str, Any] | Effect | PerChannel]
) -> Model:
    """Model with the given effects added (replacing any of the same name).

    Parameters
    ----------
    model
        Base model.
    effects
        {name: parameter dict or effect dataclass}.
    """
    merged: dict[str, Any] = dict(model.effects)
    for name, params in effects.items():
        merged[name] = effect_from_params(name, params)
    return replace(model, effects=tuple(merged.items()))


def without_effects(model: Model) -> Model:
    """The nominal model: the same plant, sensors and noise with every effect off."""
    return replace(model, effects=())


def with_effect_on(model: Model, name: str, side: str, params: Mapping[str, Any] | Effect) -> Model:
    """Model with sensor effect `name` set on chain `side` only; the other chain keeps its value.

    `params` are the effect's parameters without `channel`; the result holds one entry for
    `side`, or a `PerChannel` when the other chain has the effect too.
    """
    if name not in PER_CHANNEL_EFFECTS:
        raise ModelError(
            f"effects.{name} has no per-channel value (only {', '.join(PER_CHANNEL_EFFECTS)})"
        )
    if side not in SIDES:
        raise ModelError(f"sensor chain must be one of {', '.join(SIDES)}, got {side!r}")
    values: Any = (
        effect_params(params) if is_dataclass(params) and not isinstance(params, type) else params
    )
    new = effect_from_params(name, {**values, "channel": side})
    other = "pitch" if side == "stroke" else "stroke"
    kept: Any = model.effect_on(name, other)
    if kept is None:
        return with_effects(model, {name: new})
    kept = replace(kept, channel=other)
    return with_effects(model, {name: PerChannel(**{side: new, other: kept})})


def without_effect_on(model: Model, name: str, side: str) -> Model:
    """Model with sensor effect `name` removed from chain `side` only (the other chain keeps it)."""
    effects = tuple((n, e) for n, e in model.effects if n != name)
    if name in PER_CHANNEL_EFFECTS:
        kept: Any = model.effect_on(name, "pitch" if side == "stroke" else "stroke")
        if kept is not None:
            effects += ((name, replace(kept, channel="pitch" if side == "stroke" else "stroke")),)
    return replace(model, effects=effects)
