"""Checks every model dataclass runs on construction: numbers, rules, sensor channels.

Pure and at the bottom of `flaair_model`: `model` (the nominal plant and sensors) and `effects`
(the effect table) both build on it, so neither imports the other's internals.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from typing import Any

__all__ = [
    "CHANNELS",
    "SIDES",
    "ModelError",
    "check_channel",
    "check_fields",
    "check_number",
    "coerce_number",
]

CHANNELS = ("stroke", "pitch", "both")
SIDES = ("stroke", "pitch")  # the two sensor chains


class ModelError(ValueError):
    """Invalid model: the message names the offending parameter, key or section."""


def coerce_number(value: Any) -> Any:
    """A numeric string as a float (YAML 1.1 reads "1e-11", without a dot, as a string)."""
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


def check_number(where: str, value: Any) -> float:
    """`value` as a finite float, else a `ModelError` naming `where`."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ModelError(f"{where} must be a number, got {value!r}")
    number = float(value)
    if not math.isfinite(number):
        raise ModelError(f"{where} must be finite, got {number}")
    return number


def check_fields(obj: object, prefix: str, rules: Mapping[str, str]) -> None:
    """Coerce each float field of a frozen dataclass to float and check it against its rule.

    Rules: "pos" (> 0), "nonneg" (>= 0), "finite", "nonzero", "unit" (in (0, 1]).
    """
    for name, rule in rules.items():
        where = f"{prefix}.{name}"
        value = check_number(where, getattr(obj, name))
        if rule == "pos" and not value > 0:
            raise ModelError(f"{where} must be > 0, got {value:g}")
        if rule == "nonneg" and not value >= 0:
            raise ModelError(f"{where} must be >= 0, got {value:g}")
        if rule == "nonzero" and value == 0:
            raise ModelError(f"{where} must be nonzero, got {value:g}")
        if rule == "unit" and not 0 < value <= 1:
            raise ModelError(f"{where} must be in (0, 1], got {value:g}")
        object.__setattr__(obj, name, value)


def check_channel(obj: object, prefix: str) -> None:
    """The effect's `channel` is one of `CHANNELS`."""
    channel = getattr(obj, "channel")  # noqa: B009 (any effect object carries it)
    if channel not in CHANNELS:
        raise ModelError(f"{prefix}.channel must be one of {', '.join(CHANNELS)}, got {channel!r}")
