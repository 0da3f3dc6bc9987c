"""The effect vocabulary: the search's view of the effect table (`flaair_model.effects`).

`VOCABULARY` is read from the effect table, where each effect is declared once: the channels it
changes, the channels it is searched on, every parameter with its bounds and starting grid
(effects with several parameters are fitted whole: collision's stop, contact stiffness and
contact damping), the fitted plant parameters it trades off against (fitted jointly with it) and
whether it can be told apart from a change of those plant parameters at all.
`candidate_groups` turns it into the parameter sets the search fits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, TypeAlias

from flaair_model.effects import (
    EFFECTS,
    MEASURED_CHANNELS,
    SENSOR_CHANNELS,
    TRUTH_CHANNELS,
    FitParam,
)
from flaair_model.model import Model
from flaair_model.terms import TermKind

__all__ = [
    "CHANNELS",
    "EFFECT_CHANNELS",
    "ENTRIES",
    "NOT_SEPARABLE",
    "PLANT_PARAMETERS",
    "SENSOR_EFFECTS",
    "SENSOR_SIDE",
    "STATUSES",
    "TERM_PREFIX",
    "UPSTREAM_TRUTH",
    "VOCABULARY",
    "EffectSpec",
    "Param",
    "VocabularyEntry",
    "candidate_groups",
    "candidate_specs",
    "param_spec",
    "plant_spec",
    "term_specs",
]

CHANNELS: tuple[str, ...] = MEASURED_CHANNELS
STATUSES: tuple[str, ...] = ("no_discrepancy", "explained", "unexplained")
# Truth channel upstream of each sensor channel, and the model-channel name of the sensors.
UPSTREAM_TRUTH = {"stroke_sensor_v": "stroke_deg", "pitch_sensor_v": "pitch_deg"}
SENSOR_SIDE = {"stroke_sensor_v": "stroke", "pitch_sensor_v": "pitch"}

# The fitted plant parameters (model.yaml `plant:` keys) and the truth channel that sets each.
PLANT_PARAMETERS: dict[str, str] = {
    "stroke_natural_frequency_hz": "stroke_deg",
    "aero_damping_nm_s2": "stroke_deg",
    "actuator_gain_nm_per_v": "stroke_deg",
    "pitch_natural_frequency_hz": "pitch_deg",
    "hinge_damping_nm_s_per_rad": "pitch_deg",
    "inertial_coupling_kg_m2": "pitch_deg",
    "aero_coupling_nm_s2": "pitch_deg",
}


@dataclass(frozen=True)
class EffectSpec:
    """One fittable parameter: of an effect, or (name 'plant') of the plant.

    Attributes
    ----------
    name : effect name (model vocabulary), or 'plant' for a plant parameter.
    key : the fitted parameter's key in the model file.
    judged_on : measured channel the effect is judged on.
    null : parameter value at which the effect does nothing (inf: collision, no contact).
    lower, upper : bounds of the fit.
    grid : starting values tried before the local fit (empty: start at the null value; the
        residual of feedthrough, transmission_nonlinearity and strain_transfer_loss is affine
        in the parameter, so the first Gauss-Newton step is exact).
    step : finite-difference step (in fit space).
    log : fit log(parameter) instead of the parameter.
    channel_param : value of the effect's `channel` parameter, if it has one.
    tested : the significance rule (R3) applies to it (False: a shape parameter of a
        multi-parameter effect, or a plant parameter fitted along).
    unit : (not log) the fit space's unit: the fit sees value / unit. A library term's
        coefficient is fitted in units of its range (a hinge drag's coefficient is 1e-12 N m s^2:
        in its own units a least-squares step below the solver's absolute tolerance, 1e-12,
        ends the fit where it starts).
    """

    name: str
    key: str
    judged_on: str
    null: float
    lower: float
    upper: float
    grid: tuple[float, ...]
    step: float
    log: bool = False
    channel_param: str | None = None
    tested: bool = True
    unit: float = 1.0

    @property
    def label(self) -> str:
        """Name with its sensor channel, e.g. 'sensor_delay[pitch]';
        'collision.contact_damping_ratio' for a parameter
        fitted along (shape parameter or plant parameter).
        """
        if not self.tested:
            return f"{self.name}.{self.key}"
        return f"{self.name}[{self.channel_param}]" if self.channel_param else self.name

    @property
    def address(self) -> str:
        """The parameter's one address in a fit's values: `plant.<key>`, `effect.<name>.<key>`
        or `term.<kind>@<site>` (a term's shape parameter: `term.<kind>@<site>.<key>`).
        """
        if self.is_plant:
            return f"plant.{self.key}"
        if self.is_term:
            place = "@".join(self.term_place)
            return f"term.{place}" if self.key == "coefficient" else f"term.{place}.{self.key}"
        return f"effect.{self.name}.{self.key}"

    @property
    def is_plant(self) -> bool:
        """A plant parameter fitted along with an effect."""
        return self.name == "plant"

    @property
    def is_term(self) -> bool:
        """A parameter of a library term (name 'term:KIND@SITE')."""
        return self.name.startswith(TERM_PREFIX)

    @property
    def term_place(self) -> tuple[str, str]:
        """(kind, site) of a library term's spec."""
        kind, site = self.name[len(TERM_PREFIX) :].split("@")
        return kind, site

    def to_fit(self, value: float) -> float:
        """Physical parameter -> fit-space value."""
        return math.log(value) if self.log else float(value) / self.unit

    def from_fit(self, u: float) -> float:
        """Fit-space value -> physical parameter."""
        return math.exp(u) if self.log else float(u) * self.unit

    def params(self, value: float, channel: str | None = None) -> dict[str, Any]:
        """Effect parameter dict for the model."""
        p: dict[str, Any] = {self.key: float(value)}
        if self.channel_param is not None:
            p["channel"] = channel or self.channel_param
        return p

    def effect_size(self, value: float) -> float:
        """Distance of `value` from the null value (|value| for a null at infinity)."""
        return abs(value) if math.isinf(self.null) else abs(value - self.null)


TERM_PREFIX = "term:"


def term_specs(
    kind: TermKind,
    site: str,
    channel: str,
    coefficient_scale: float,
    shape_start: dict[str, Any] | None = None,
) -> tuple[EffectSpec, ...]:
    """The fittable parameters of library term `kind` at `site`, judged on `channel`.

    The coefficient (null 0, tested) within +-`coefficient_scale` (the size of the feature's
    whole share of the channel), then its shape parameters (log fit, fitted along).
    """
    name = f"{TERM_PREFIX}{kind.name}@{site}"
    scale = float(coefficient_scale)
    specs = [
        EffectSpec(
            name,
            "coefficient",
            channel,
            0.0,
            -scale,
            scale,
            (-0.1 * scale, 0.1 * scale),
            1e-4,
            unit=scale,
        )
    ]
    for sh in kind.shape:
        specs.append(
            EffectSpec(
                name,
                sh.key,
                channel,
                (shape_start or {}).get(sh.key, sh.grid[0]),
                sh.lower,
                sh.upper,
                (),
                1e-3,
                log=True,
                tested=False,
            )
        )
    return tuple(specs)


# One fittable parameter of an effect: the effect table's fit specification.
Param: TypeAlias = FitParam


@dataclass(frozen=True)
class VocabularyEntry:
    """One effect of the vocabulary, as the search sees it (built from its `EffectEntry`).

    Attributes
    ----------
    name : effect name (a key of the model's `effects:`).
    acts_on : measured channels it changes.
    searched_on : channels it is searched on (physics on the truth, sensor effects on the sensors).
    params : its parameters, the first one tested for significance; all fitted together.
    per_sensor : it has a `channel` parameter (found per sensor chain, merged to 'both' when equal).
    trades_off : fitted plant parameters it is fitted jointly with.
    separable : its signature differs from every change of the fitted plant parameters.
    note : why it is (not) separable.
    """

    name: str
    acts_on: tuple[str, ...]
    searched_on: tuple[str, ...]
    params: tuple[Param, ...]
    per_sensor: bool = False
    trades_off: tuple[str, ...] = ()
    separable: bool = True
    note: str = ""


VOCABULARY: tuple[VocabularyEntry, ...] = tuple(
    VocabularyEntry(
        e.name, e.acts_on, e.searched_on, e.fit, e.per_sensor, e.trades_off, e.separable, e.note
    )
    for e in EFFECTS
)
ENTRIES: dict[str, VocabularyEntry] = {e.name: e for e in VOCABULARY}
# Which measured channels each effect can possibly change (the model's structure).
EFFECT_CHANNELS: dict[str, tuple[str, ...]] = {e.name: e.acts_on for e in VOCABULARY}
SENSOR_EFFECTS: tuple[str, ...] = tuple(
    e.name for e in VOCABULARY if set(e.acts_on) <= set(SENSOR_CHANNELS)
)
NOT_SEPARABLE: tuple[str, ...] = tuple(e.name for e in VOCABULARY if not e.separable)


def param_spec(
    name: str, p: Param, channel: str, tested: bool = True, channel_param: str | None = None
) -> EffectSpec:
    """Effect `name`'s parameter `p` (its effect-table fit specification) as a fittable spec
    judged on `channel`.
    """
    return EffectSpec(
        name,
        p.key,
        channel,
        p.null,
        p.lower,
        p.upper,
        p.grid,
        p.step,
        p.log,
        channel_param=channel_param,
        tested=tested,
    )


def _spec(entry: VocabularyEntry, p: Param, channel: str, first: bool) -> EffectSpec:
    side = SENSOR_SIDE.get(channel) if entry.per_sensor else None
    return param_spec(entry.name, p, channel, first, side)


def _order(channel: str) -> list[VocabularyEntry]:
    entries = [e for e in VOCABULARY if channel in e.searched_on]
    if channel == "pitch_deg":  # the pitch's own physics first, then the stroke physics seen there
        entries.sort(key=lambda e: "stroke_deg" in e.searched_on)
    return entries


def candidate_specs(channel: str) -> tuple[EffectSpec, ...]:
    """The tested (first) parameter of every vocabulary effect searched on `channel`."""
    if channel not in CHANNELS:
        raise KeyError(f"unknown channel {channel!r}")
    return tuple(_spec(e, e.params[0], channel, True) for e in _order(channel))


def plant_spec(key: str, model: Model, channel: str, rel_range: float = 0.5) -> EffectSpec:
    """A plant parameter as a fittable spec (log fit,
    within x(1 -+ rel_range) of its value in `model`).
    """
    v = float(getattr(model.plant, key))
    return EffectSpec(
        "plant",
        key,
        channel,
        v,
        v * (1.0 - rel_range),
        v * (1.0 + rel_range),
        (),
        1e-4,
        log=True,
        tested=False,
    )


def candidate_groups(
    channel: str, plant: Model | None = None
) -> tuple[tuple[EffectSpec, ...], ...]:
    """The parameter sets the search fits on `channel`: every separable effect whole, with the
    fitted plant parameters it trades off against (when `plant` is given; those that the channel
    sees: the stroke parameters on either truth channel, the pitch ones on pitch_deg).
    """
    groups = []
    for e in _order(channel):
        if plant is not None and not e.separable:
            continue
        specs = [_spec(e, p, channel, i == 0) for i, p in enumerate(e.params)]
        if plant is not None and channel in TRUTH_CHANNELS:
            specs += [
                plant_spec(k, plant, channel)
                for k in e.trades_off
                if channel == "pitch_deg" or PLANT_PARAMETERS[k] == channel
            ]
        groups.append(tuple(specs))
    return tuple(groups)
