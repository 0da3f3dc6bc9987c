"""What the search found, as the result lists it: one entry per effect, with the parameters of
the model it ended on (a sensor effect found on both sensors once, its channel 'a+b').
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, cast

from flaair_model.effects import Effect
from flaair_model.model import Model, PerChannel, effect_params

from .effect_judging import FoundEffect

__all__ = ["merge_sensor_channels"]


def _effect_params_dict(model: Model, name: str) -> dict[str, Any]:
    def clean(d: dict[str, Any]) -> dict[str, Any]:
        return {
            k: clean(v) if isinstance(v, dict) else (v if isinstance(v, str) else float(v))
            for k, v in d.items()
        }

    return clean(effect_params(cast(Effect | PerChannel, model.effect(name))))  # an effect on


def merge_sensor_channels(found: list[FoundEffect], model: Model) -> list[FoundEffect]:
    """One entry per effect name (a sensor effect on both sensors once, channel 'a+b')."""
    by_name: dict[str, FoundEffect] = {}
    order = []
    for f in found:
        params = _effect_params_dict(model, f.name)
        if f.name in by_name:
            prev = by_name[f.name]
            by_name[f.name] = replace(
                prev,
                channel=f"{prev.channel}+{f.channel}",
                parameters=params,
                evidence={**prev.evidence, "merged_from": f.evidence},
            )
        else:
            by_name[f.name] = replace(f, parameters=params)
            order.append(f.name)
    return [by_name[n] for n in order]
