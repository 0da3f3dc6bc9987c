"""Damage to the simulated robot mid-run: a parameter change at a given sample time.

The plant runs on `damaged(model, params)` from the first block whose first sample is at or
after `time_s` (`model_at`), so the change lands between blocks, never inside the kernel:
  * ``inertia_factor``: wing (stroke and pitch) inertia scaled (the `wing_damage` effect);
  * ``stiffness_factor``: stroke stiffness K scaled (the stroke natural frequency by its root);
  * ``actuator_gain``: the actuator's torque per volt scaled;
  * ``stroke_film_gain``, ``pitch_film_gain``: a film's volts per radian scaled, a debonding
    film (the `strain_transfer_loss` effect on that chain, on top of any already there).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple

from flaair_model.model import Model, with_effect_on, with_effects


@dataclass(frozen=True)
class DamageParams:
    """When and how the robot changes (1.0: unchanged; time_s < 0: never)."""

    time_s: float
    inertia_factor: float
    stiffness_factor: float
    stroke_film_gain: float
    pitch_film_gain: float
    actuator_gain: float

    def __post_init__(self) -> None:
        for name in ("inertia_factor", "stroke_film_gain", "pitch_film_gain"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise ValueError(f"damage parameter '{name}' must be in (0, 1]")
        for name in ("stiffness_factor", "actuator_gain"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"damage parameter '{name}' must be > 0")

    @property
    def active(self) -> bool:
        """A change is scheduled and changes something."""
        changes = (
            self.inertia_factor,
            self.stiffness_factor,
            self.stroke_film_gain,
            self.pitch_film_gain,
            self.actuator_gain,
        )
        return self.time_s >= 0.0 and any(v != 1.0 for v in changes)


def _film(model: Model, side: str, gain: float) -> Model:
    if gain == 1.0:
        return model
    before = model.effect_on("strain_transfer_loss", side)
    efficiency = getattr(before, "efficiency", 1.0) if before is not None else 1.0
    return with_effect_on(model, "strain_transfer_loss", side, {"efficiency": efficiency * gain})


def damaged(model: Model, params: DamageParams) -> Model:
    """The model after the damage (the same model if nothing changes)."""
    if not params.active:
        return model
    out = model
    if params.inertia_factor != 1.0:
        before = model.effect("wing_damage")
        factor = getattr(before, "inertia_factor", 1.0) if before is not None else 1.0
        out = with_effects(out, {"wing_damage": {"inertia_factor": factor * params.inertia_factor}})
    if params.stiffness_factor != 1.0:
        f = out.plant.stroke_natural_frequency_hz * math.sqrt(params.stiffness_factor)
        out = replace(out, plant=replace(out.plant, stroke_natural_frequency_hz=f))
    if params.actuator_gain != 1.0:
        gain = out.plant.actuator_gain_nm_per_v * params.actuator_gain
        out = replace(out, plant=replace(out.plant, actuator_gain_nm_per_v=gain))
    out = _film(out, "stroke", params.stroke_film_gain)
    return _film(out, "pitch", params.pitch_film_gain)


def model_at(start_s: float, healthy: Model, damaged_model: Model, params: DamageParams) -> Model:
    """The model a block starting at `start_s` runs on."""
    return damaged_model if params.active and start_s >= params.time_s else healthy


class DamagedModels(NamedTuple):
    """The scheduled damage and the two models it turns into (without and with the obstacle)."""

    params: DamageParams
    model: Model
    obstacle_model: Model


def damaged_models(params: DamageParams, model: Model, obstacle_model: Model) -> DamagedModels:
    """The damage schedule with its models built once."""
    return DamagedModels(params, damaged(model, params), damaged(obstacle_model, params))
